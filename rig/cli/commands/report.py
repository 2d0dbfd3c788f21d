"""``ctr-bench report DIR``: (re)build the HTML report of a run / reconstruct output directory."""
from __future__ import annotations

import sys
from pathlib import Path

from rig.bench.report import MAX_DETAIL_FRAMES, MAX_MESH_FRAMES, build_report


def _run(args) -> int:
    meshes = True if args.meshes else (False if args.no_meshes else None)
    log = None if args.quiet else (lambda msg: print(msg, file=sys.stderr))
    index = build_report(Path(args.dir), meshes=meshes, max_detail_frames=args.max_frames, overlays=not args.no_overlays, log=log)
    print(f"report: {index}")
    return 0


def register(sub) -> None:
    p = sub.add_parser("report", help="build the HTML report (figures, overlays, tube meshes) of an output directory",
                       description="Rebuild DIR/report/index.html from what ctr-bench run or reconstruct wrote in DIR: "
                       "3D and projected backbones over time, errors along the backbone and per frame, timing, the "
                       "reconstruction reprojected on both camera images per frame, failed frames with their reasons, and "
                       f"tube meshes (DIR/meshes: PLY, OBJ, GLB; written for runs of up to {MAX_MESH_FRAMES} frames unless "
                       "--meshes / --no-meshes say otherwise). Static files only: open index.html in any browser, offline.")
    p.add_argument("dir", help="output directory of ctr-bench run / reconstruct (holds summary.json)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--meshes", action="store_true", help="write tube meshes of every frame, however many")
    g.add_argument("--no-meshes", action="store_true", help="write no mesh files")
    p.add_argument("--max-frames", type=int, default=MAX_DETAIL_FRAMES, metavar="N",
                   help=f"frames with their own camera overlay at most (default {MAX_DETAIL_FRAMES}; beyond, the failed, "
                   "worst and evenly spaced ones)")
    p.add_argument("--no-overlays", action="store_true", help="skip the per-frame camera overlays (fast)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=_run)
