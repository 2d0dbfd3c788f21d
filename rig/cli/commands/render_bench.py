"""``ctr-bench render-bench [SCENE]``: twin rendering throughput per OpenGL platform, and truth checks.

Each platform runs in its own process (PyOpenGL binds its platform once per
process), pinned to one CPU core with llvmpipe limited to one thread, so the
figures are one-core figures. Besides pairs per second it reports how well the
ground truth agrees with the rendered images: the fraction of backbone points
that project inside the rendered silhouette, and the ratio of the silhouette
area to the analytic projected tube area.
"""
from __future__ import annotations

import json

from rig.bench.render_speed import render_speed
from rig.cli.options import count
from twin.gl import available_platforms


def _run(args) -> int:
    platforms = args.platform or available_platforms()
    if not platforms:
        raise ValueError("no offscreen OpenGL platform found (install libegl-mesa0 or libosmesa6; scripts/setup.sh does)")
    results = render_speed(args.scene, args.n_frames, platforms)
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    print(f"{'platform':>8}  {'ss':>2}  {'pairs/s':>7}  {'ms/pair':>7}  {'cpu ms':>6}  {'bg pairs/s':>10}  {'inside min':>10}  {'area ratio':>13}")
    for plat, r in results.items():
        if "error" in r:
            print(f"{plat:>8}  failed: {r['error']}")
            continue
        print(
            f"{plat:>8}  {r['supersample']:>2}  {r['frame_pairs_per_s']:7.2f}  {r['frame_pair_ms_median']:7.1f}  {r['frame_pair_cpu_ms_median']:6.1f}  "
            f"{r['background_pairs_per_s']:10.2f}  {r['inside_fraction_min']:10.4f}  {r['area_ratio_min']:6.4f}-{r['area_ratio_max']:6.4f}"
        )
    r0 = next(iter(results.values()))
    if "width" in r0:
        print(f"\n{r0['width']}x{r0['height']}, {r0['frames']} robot frame pairs with ground truth (labels, depth) and noise, in memory; "
              "one core (pinned; llvmpipe rasterizes on the calling thread, LP_NUM_THREADS=0); medians over the frames; 'cpu ms': the process's CPU time per pair, which other "
              "work on that core does not inflate. 'inside min': smallest fraction of backbone points projecting inside the "
              "rendered silhouette over all frames and cameras; 'area ratio': silhouette area / analytic projected tube area.")
    return 0


def register(sub) -> None:
    p = sub.add_parser("render-bench", help="twin rendering throughput per OpenGL platform (one core) and truth checks")
    p.add_argument("scene", nargs="?", default=None, help="scene TOML file (default: scenes/paper.toml, shipped with ctr-bench)")
    p.add_argument("--n-frames", type=count(1), default=8, metavar="N",
                   help="robot frames to time, evenly spaced over the scene (default 8)")
    p.add_argument("--platform", action="append", choices=["osmesa", "egl"], help="platform(s) to time (default: all available)")
    p.add_argument("--json", action="store_true", help="print one JSON object keyed by platform")
    p.set_defaults(func=_run)
