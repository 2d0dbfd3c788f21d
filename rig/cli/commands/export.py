"""``ctr-bench export RUN --mcap FILE``: a run's images, cameras and backbones as ROS 2 messages in MCAP."""
from __future__ import annotations

import sys
from pathlib import Path

from rig.bench.mcap_export import export_mcap
from rig.progress import Progress


def _run(args) -> int:
    out = Path(args.mcap)
    if out.suffix != ".mcap":
        raise ValueError(f"--mcap {out}: the file name must end in .mcap")
    if not out.parent.is_dir():
        raise ValueError(f"--mcap {out}: folder {out.parent} does not exist")
    progress = Progress(enabled=not args.quiet)
    try:
        counts = export_mcap(Path(args.run), out, images=not args.no_images, progress=lambda d, n: progress("export", d, n))
    finally:
        progress.close()
    for topic, n in sorted(counts.items()):
        print(f"{topic:32s} {n:6d} messages", file=sys.stderr)
    print(f"mcap: {out} ({out.stat().st_size / 1e6:.1f} MB)")
    return 0


def register(sub) -> None:
    p = sub.add_parser("export", help="export a run as ROS 2 messages in an MCAP file (Foxglove, ros2 bag play)",
                       description="Write RUN (an output directory of ctr-bench run / reconstruct) as an MCAP file in ROS 2 "
                       "message encoding: per frame both camera images (sensor_msgs/CompressedImage, PNG) with their "
                       "camera_info, the backbone (nav_msgs/Path on /ctr/backbone), the tube (visualization_msgs/Marker on "
                       "/ctr/tube) and tf for the cameras and the robot base; lengths in metres. No ROS install needed.")
    p.add_argument("run", help="output directory of ctr-bench run / reconstruct (holds summary.json)")
    p.add_argument("--mcap", required=True, metavar="FILE", help="the .mcap file to write")
    p.add_argument("--no-images", action="store_true", help="leave the camera images out (a much smaller file)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_run)
