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
import os
import subprocess
import sys
import time

import numpy as np


def _worker(scene_path: str | None, frames: int) -> dict:
    """Runs in a child process with the platform already chosen through the environment."""
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    from dataclasses import replace

    import cv2

    import twin  # noqa: F401  (binds the OpenGL platform)
    from twin.groundtruth import extend_to_mesh_start, inside_fraction, projected_tube_area_px
    from twin.scene import load_scene
    from twin.simulator import Twin

    from .render import DEFAULT_SCENE

    cv2.setNumThreads(1)
    scene = load_scene(scene_path or DEFAULT_SCENE)
    n = min(frames, len(scene.joints))
    idx = np.linspace(0, len(scene.joints) - 1, n).round().astype(int)
    t0 = time.perf_counter()
    tw = Twin(scene)
    tw.background(0)  # first use: context, shaders, the cached set
    tw.frame(int(idx[0]))
    t_setup = time.perf_counter() - t0
    t0 = time.perf_counter()
    for i in range(n):
        tw.background(i + 1)
    t_bg = (time.perf_counter() - t0) / n
    inside, t_frames = [], []
    for i in idx:
        t0 = time.perf_counter()
        f = tw.frame(int(i))
        t_frames.append(time.perf_counter() - t0)
        inside += list(inside_fraction(f).values())
    # Area check without the actuation unit, so the whole swept tube is visible.
    bare = Twin(replace(scene, dressing=replace(scene.dressing, actuation_unit=False)))
    ratios = []
    for i in idx[:: max(1, n // 4)]:
        f = bare.frame(int(i))
        bb = extend_to_mesh_start(f.backbone)
        for name, cam in f.cameras.items():
            ratios.append(float((f.labels[name] > 0).sum() / projected_tube_area_px(cam, bb)))
    return {
        "platform": os.environ.get("PYOPENGL_PLATFORM"),
        "supersample": tw.renderer.supersample,
        "width": scene.rig[scene.rig.names[0]].width,
        "height": scene.rig[scene.rig.names[0]].height,
        "setup_s": t_setup,
        "frame_pair_ms_median": 1e3 * float(np.median(t_frames)),
        "frame_pairs_per_s": float(1.0 / np.median(t_frames)),
        "background_pair_ms": 1e3 * t_bg,
        "background_pairs_per_s": float(1.0 / t_bg),
        "inside_fraction_min": float(min(inside)),
        "inside_fraction_mean": float(np.mean(inside)),
        "area_ratio_min": float(min(ratios)),
        "area_ratio_max": float(max(ratios)),
        "frames": int(n),
    }


def _run(args) -> int:
    from twin.gl import available_platforms

    platforms = args.platform or available_platforms()
    if not platforms:
        raise ValueError("no offscreen OpenGL platform found (install libegl-mesa0 or libosmesa6; scripts/setup.sh does)")
    results = {}
    for plat in platforms:
        env = dict(os.environ, CTR_BENCH_GL=plat, PYOPENGL_PLATFORM=plat, LP_NUM_THREADS="1", OMP_NUM_THREADS="1")
        cmd = [sys.executable, "-m", "rig.commands.render_bench", "--worker", args.scene or "", str(args.n_frames)]
        print(f"rendering with {plat} on one core ...", file=sys.stderr)
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
        if proc.returncode != 0:
            last = (proc.stderr.strip().splitlines() or ["no output"])[-1]
            results[plat] = {"platform": plat, "error": last}
            continue
        results[plat] = json.loads(proc.stdout.strip().splitlines()[-1])
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    print(f"{'platform':>8}  {'ss':>2}  {'pairs/s':>7}  {'ms/pair':>7}  {'bg pairs/s':>10}  {'inside min':>10}  {'area ratio':>13}")
    for plat, r in results.items():
        if "error" in r:
            print(f"{plat:>8}  failed: {r['error']}")
            continue
        print(
            f"{plat:>8}  {r['supersample']:>2}  {r['frame_pairs_per_s']:7.2f}  {r['frame_pair_ms_median']:7.1f}  "
            f"{r['background_pairs_per_s']:10.2f}  {r['inside_fraction_min']:10.4f}  {r['area_ratio_min']:6.4f}-{r['area_ratio_max']:6.4f}"
        )
    r0 = next(iter(results.values()))
    if "width" in r0:
        print(f"\n{r0['width']}x{r0['height']}, {r0['frames']} robot frame pairs with ground truth (labels, depth) and noise; "
              "one core (LP_NUM_THREADS=1, pinned). 'inside min': smallest fraction of backbone points projecting inside the "
              "rendered silhouette over all frames and cameras; 'area ratio': silhouette area / analytic projected tube area.")
    return 0


def register(sub) -> None:
    from .options import count

    p = sub.add_parser("render-bench", help="twin rendering throughput per OpenGL platform (one core) and truth checks")
    p.add_argument("scene", nargs="?", default=None, help="scene TOML file (default: scenes/paper.toml, shipped with ctr-bench)")
    p.add_argument("--n-frames", type=count(1), default=8, metavar="N",
                   help="robot frames to time, evenly spaced over the scene (default 8)")
    p.add_argument("--platform", action="append", choices=["osmesa", "egl"], help="platform(s) to time (default: all available)")
    p.add_argument("--json", action="store_true", help="print one JSON object keyed by platform")
    p.set_defaults(func=_run)


if __name__ == "__main__" and len(sys.argv) >= 4 and sys.argv[1] == "--worker":
    print(json.dumps(_worker(sys.argv[2] or None, int(sys.argv[3]))))
