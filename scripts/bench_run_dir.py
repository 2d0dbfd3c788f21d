"""Time per frame of a long run at its start and at its end (issue 15, item 7): it must stay flat.

    .venv/bin/python scripts/bench_run_dir.py bookkeeping --n 10000
    .venv/bin/python scripts/bench_run_dir.py reconstruct --n 10000 --method fast

``bookkeeping`` feeds :class:`rig.bench.reconstruct.RunWriter` (backbone CSV, journal
line, frames.csv row per frame; summary.json every few seconds) one realistic
record and backbone N times: the cost a run adds to each frame's
reconstruction. ``--every-frame`` rewrites summary.json after every frame, as
runs did before the journal, for comparison.

``reconstruct`` runs :func:`rig.bench.reconstruct.reconstruct_session` on a session
of N frames repeating one rendered frame of scenes/paper.toml (hard links, so
the images take no room), timed between successive progress calls.

Both print the mean and median ms per frame over the first and the last
``--window`` frames. A script, not a test: no timed assertion runs in CI.
"""
from __future__ import annotations

import argparse
import csv
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _record(k: int) -> dict:
    """A per-frame record as large as a real one (fast method, self-check on, ground truth)."""
    views = {c: {"unexplained_fraction": 0.01, "unexplained_px": 12, "off_foreground_fraction": 0.02,
                 "centerline_rms_px": 0.4, "visible_px": 900} for c in ("side", "top")}
    return {"frame": k, "t_s": 0.1 * k, "status": "ok", "reason": None, "ms": 4.5, "jump_flag": False, "jump_reason": None,
            "selfcheck": {"ok": True, "reason": None, "ms": 3.0, "views": views}, "n_points": 120, "length_mm": 85.3,
            "tip_world_mm": [80.4, 17.1, 9.05], "transition_s_mm": 50.2,
            "timings_ms": {"coarse": 1.0, "profiles": 2.0, "match": 1.0, "spline": 0.5, "total": 4.5},
            "mean_error_mm": 0.05, "max_error_mm": 0.09, "tip_error_mm": 0.08, "length_error_mm": -0.1, "scored_fraction": 1.0}


def _time_summaries() -> list:
    """(frames in the summary, seconds) of every summary.json write from now on."""
    import rig.rundir

    writes, real = [], rig.rundir.RunWriter.write_summary

    def timed(self, complete=False):
        t0 = time.perf_counter()
        summary = real(self, complete)
        writes.append((len(self.records), time.perf_counter() - t0))
        return summary

    rig.rundir.RunWriter.write_summary = timed
    return writes


def _print_summaries(writes: list) -> None:
    frames, secs = zip(*writes)
    print(f"summary.json written {len(writes)} times, {sum(secs):.1f} s in all; the last ones: "
          + ", ".join(f"{s:.2f} s at {f} frames" for f, s in writes[-3:]))


def bookkeeping(n: int, out: Path, every_frame: bool) -> list:
    """Seconds per frame of the run's bookkeeping over ``n`` frames."""
    import rig.rundir as rr
    from rig.rundir import journal_header

    if every_frame:
        rr.SUMMARY_EVERY_S, rr.SUMMARY_COST_FACTOR = 0.0, 0.0
    header = {**journal_header("fast", {"k": 5}, {"max_unexplained_fraction": 0.2}, out / "session"), "mm_per_px": 0.116}
    pts = np.column_stack([np.linspace(0, 85, 120), np.linspace(0, 17, 120), np.linspace(0, 9, 120)])
    writes = _time_summaries()
    writer = rr.RunWriter(out, header)
    times = []
    for k in range(n):
        t0 = time.perf_counter()
        writer.add(_record(k), pts)
        times.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    writer.finish()
    print(f"finish (backbones.npz, final summary.json): {time.perf_counter() - t0:.2f} s")
    _print_summaries(writes)
    return times


def _long_session(directory: Path, n: int) -> Path:
    """A session of ``n`` frames repeating one rendered frame of the paper scene (PNG hard links, copied rows)."""
    from dataclasses import replace

    from rig.bench.scenes import render_scene_to
    from twin.scene import load_scene

    scene = load_scene(ROOT / "scenes" / "paper.toml")
    scene = replace(scene.with_frames(scene.joints[3:4]), background_frames=8)
    render_scene_to(scene, directory, quiet=True)
    with open(directory / "frames.csv", newline="") as fh:
        header, row = list(csv.reader(fh))[:2]
    cams = [p.name for p in (directory / "frames").iterdir()]
    with open(directory / "frames.csv", "a", newline="") as fh:
        w = csv.writer(fh)
        for i in range(1, n):
            for cam in cams:
                os.link(directory / "frames" / cam / "000000.png", directory / "frames" / cam / f"{i:06d}.png")
            # times move on (0.1 s a frame); joints and skew as in the rendered frame
            w.writerow([i] + [f"{float(v) + 0.1 * i:.6f}" if c.startswith("t") and c.endswith("_s") else v
                              for c, v in zip(header[1:], row[1:])])
    return directory


def reconstruct(n: int, out: Path, method: str, selfcheck: bool) -> list:
    """Seconds per frame (reconstruction and bookkeeping) of ``reconstruct_session`` over ``n`` frames."""
    import cv2

    import rig.bench.reconstruct as rr
    from recon.selfcheck import SelfCheckParams

    cv2.setNumThreads(1)
    session = _long_session(out / "session", n)
    stamps, writes = [], _time_summaries()
    summary = rr.reconstruct_session(session, out / "run", method, progress=lambda *a, **k: stamps.append(time.perf_counter()),
                                     selfcheck=SelfCheckParams() if selfcheck else None)
    print(f"{summary['frames']} frames, {summary['failed_frames']} failed, {summary['suspect_frames']} suspect; "
          f"after the last frame: {time.perf_counter() - stamps[-1]:.1f} s (backbones.npz, final summary.json)")
    _print_summaries(writes)
    return list(np.diff(stamps))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("what", choices=("bookkeeping", "reconstruct"))
    p.add_argument("--n", type=int, default=10_000, help="frames (default 10000)")
    p.add_argument("--window", type=int, default=2000, help="frames averaged at the start and at the end (default 2000)")
    p.add_argument("--method", default="fast")
    p.add_argument("--no-selfcheck", action="store_true", help="reconstruct: without the self-check")
    p.add_argument("--every-frame", action="store_true", help="bookkeeping: summary.json after every frame (the old way)")
    p.add_argument("--out", default=None, help="working directory (default: a temporary one)")
    args = p.parse_args(argv)
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="bench-run-dir-"))
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    t0 = time.perf_counter()
    if args.what == "bookkeeping":
        times = bookkeeping(args.n, out / "run", args.every_frame)
    else:
        times = reconstruct(args.n, out, args.method, not args.no_selfcheck)
    ms = 1e3 * np.asarray(times)
    w = min(args.window, len(ms) // 2)
    for name, part in (("first", ms[:w]), ("last", ms[-w:])):
        print(f"{name} {w} frames: mean {part.mean():.3f} ms, median {np.median(part):.3f} ms, max {part.max():.1f} ms per frame")
    print(f"{len(ms)} frames in {time.perf_counter() - t0:.1f} s; outputs in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
