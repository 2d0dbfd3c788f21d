"""Twin rendering throughput per OpenGL platform, and truth checks.

Each platform runs in its own process (PyOpenGL binds its platform once per
process), pinned to one CPU core with llvmpipe rasterizing on the calling thread
(``LP_NUM_THREADS=0``: one rasterizer thread on the same core only adds hand-overs), so the
figures are one-core figures. Besides pairs per second it reports how well the
ground truth agrees with the rendered images: the fraction of backbone points
that project inside the rendered silhouette, and the ratio of the silhouette
area to the analytic projected tube area.

A frame pair is what :meth:`twin.simulator.Twin.frame` returns: both cameras' noisy
images with their labels and depth, in memory (nothing is written). Besides wall
time it reports the process's CPU time per pair, which other work on the same core
does not inflate.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from dataclasses import replace

import cv2
import numpy as np

from rig.scenefiles import DEFAULT_SCENE
from twin.groundtruth import extend_to_mesh_start, inside_fraction, projected_tube_area_px
from twin.scene import load_scene
from twin.simulator import Twin

__all__ = ["measure", "render_speed"]


def measure(scene_path: str | None, frames: int) -> dict:
    """One platform's figures: run in a child process whose environment names the platform (:func:`render_speed`).

    Parameters
    ----------
    scene_path : str or None
        Scene TOML (None: the bundled paper scene).
    frames : int
        Robot frames to time, evenly spaced over the scene.

    Returns
    -------
    dict
        ``platform``, ``supersample``, ``width``/``height`` (px), ``setup_s``, ``frame_pair_ms_median``,
        ``frame_pairs_per_s``, ``frame_pair_cpu_ms_median`` (process CPU time), ``background_pair_ms``,
        ``background_pairs_per_s``, the truth checks
        ``inside_fraction_min``/``_mean`` and ``area_ratio_min``/``_max``, and ``frames``.
    """
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})

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
    inside, t_frames, cpu_frames = [], [], []
    for i in idx:
        t0, c0 = time.perf_counter(), time.process_time()
        f = tw.frame(int(i))
        t_frames.append(time.perf_counter() - t0)
        cpu_frames.append(time.process_time() - c0)
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
        "platform": tw.renderer.platform,
        "supersample": tw.renderer.supersample,
        "width": scene.rig[scene.rig.names[0]].width,
        "height": scene.rig[scene.rig.names[0]].height,
        "setup_s": t_setup,
        "frame_pair_ms_median": 1e3 * float(np.median(t_frames)),
        "frame_pairs_per_s": float(1.0 / np.median(t_frames)),
        "frame_pair_cpu_ms_median": 1e3 * float(np.median(cpu_frames)),
        "background_pair_ms": 1e3 * t_bg,
        "background_pairs_per_s": float(1.0 / t_bg),
        "inside_fraction_min": float(min(inside)),
        "inside_fraction_mean": float(np.mean(inside)),
        "area_ratio_min": float(min(ratios)),
        "area_ratio_max": float(max(ratios)),
        "frames": int(n),
    }


def render_speed(scene_path: str | None, frames: int, platforms) -> dict:
    """:func:`measure` for each OpenGL platform, each in its own process on one core.

    Returns platform -> its figures, or ``{"platform": ..., "error": <last line of the child's stderr>}``.
    """
    results = {}
    for plat in platforms:
        env = dict(os.environ, CTR_BENCH_GL=plat, PYOPENGL_PLATFORM=plat, LP_NUM_THREADS="0", OMP_NUM_THREADS="1")
        cmd = [sys.executable, "-m", "rig.bench.render_speed", scene_path or "", str(frames)]
        print(f"rendering with {plat} on one core ...", file=sys.stderr)
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
        if proc.returncode != 0:
            last = (proc.stderr.strip().splitlines() or ["no output"])[-1]
            results[plat] = {"platform": plat, "error": last}
            continue
        results[plat] = json.loads(proc.stdout.strip().splitlines()[-1])
    return results


if __name__ == "__main__" and len(sys.argv) >= 3:
    print(json.dumps(measure(sys.argv[1] or None, int(sys.argv[2]))))
