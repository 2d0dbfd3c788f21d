"""Every method on the same rendered frames, side by side, on one core (``ctr-bench bench [SCENE]``).

The scene is rendered once into a cache (``out/bench-cache/<scene>-<WxH>-<hash>``,
:mod:`rig.bench.render_cache`: the hash covers the scene file, frame counts, model, image scale and the twin's code), then
each method reconstructs the same frames in the same process:

* ``paper``: the paper's method (:mod:`recon.paper`);
* ``fast``: :mod:`recon.fast`;
* ``icp-epipolar``: icpReconstructor's EpipolarReconstructor (:mod:`rig.bench.peers`),
  when that package imports (the optional extra ``peers``); otherwise the
  bench says why it is skipped.

Timing is on one core: the process is pinned to one CPU, OpenCV and the BLAS
pools use one thread. Each method runs the whole sequence ``--repeats``
times in order (its state, e.g. the fast method's previous-frame prior, reset
before each pass); a frame's time is its fastest pass, which discounts
interruptions by other processes on a shared machine; the table gives the
median and 95th percentile over frames. Errors are from the first pass
(:func:`rig.scoring.score_frame` against the twin's ground truth, over what both
cameras see, as ``reconstruct`` scores):
mean = mean over frames of the per-frame mean error, max = largest per-frame
maximum, tip = median of the per-frame tip errors; a frame whose ground truth
cannot be used, or a backbone nothing of which both cameras see, is left out of
them and listed under the table (``score_notes`` in ``--json``, naming the truth
file). Peak memory is the
tracemalloc peak (Python and NumPy heap) of one more reconstruction of the
first frame, made after the timed passes (numba's allocations are invisible to
tracemalloc: for the fast method the arrays its compiled kernels allocate are not
counted); model memory is what
the prepared method keeps (background models).

``--scaling`` adds the resolution study: the scene rendered with every camera
scaled to half, full and double resolution (512x384, 1024x768, 2048x1536),
each method on each, and the paper's method at 50^3, 100^3 and 200^3 voxels.
"""
from __future__ import annotations

import sys
import time
import tracemalloc
from dataclasses import replace
from pathlib import Path

import numpy as np

from recon.carving import CarvingParams
from recon.errors import FrameError
from recon.methods import get_method, prepare
from recon.paper import PaperParams
from rig.bench.peers import peer_status, prepare_peer
from rig.bench.reconstruct import load_background_frames
from rig.bench.render_cache import cached_session
from rig.scoring import score_frame
from rig.session import Session, TruthError
from rig.tables import cell

METHODS = ("paper", "fast", "icp-epipolar")


PEERS = ("icp-epipolar",)


# ----------------------------------------------------------------------------- sessions
def load_session(path: Path) -> dict:
    """Background stacks, frame images and ground-truth backbones of a session, in memory.

    A frame whose ground truth cannot be used (:class:`rig.session.TruthError`: its
    file missing, unreadable, of the wrong shape or not finite) is kept, unscored: its
    truth is None and ``truth_notes`` holds ``"not scored: <message naming the file>"``
    at its position (None for the other frames).
    """
    s = Session(path)
    frames, truths, notes = [], [], []
    for fr in s.frames:
        frames.append(s.frame_images(fr.index))
        try:
            t = s.truth(fr.index)
        except TruthError as exc:
            t = None
            notes.append(f"not scored: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}")
        else:
            notes.append(None)
        truths.append(None if t is None else t["backbone_world_mm"])
    cam0 = s.rig[s.cameras[0]]
    return {"session": s, "rig": s.rig, "backgrounds": load_background_frames(s), "frames": frames, "truths": truths,
            "truth_notes": notes, "size": (cam0.width, cam0.height)}


# ----------------------------------------------------------------------------- methods
def make_method(name: str, rig, backgrounds, params=None):
    """The per-frame callable of a method or peer (ValueError when a peer is unavailable)."""
    if name in PEERS:
        return prepare_peer(name, rig, backgrounds)

    return prepare(name, rig, backgrounds, params)


def method_status(name: str) -> tuple[bool, str]:
    if name in PEERS:
        return peer_status(name)

    try:
        get_method(name)
    except ValueError as exc:
        return False, str(exc)
    return True, "available"


def _aggregates(best_ms, errors: list) -> dict:
    """Time (ms per pair, over the frames reconstructed: finite ``best_ms``) and error (mm, over the scored
    frames: ``errors`` not None) figures of a method's run."""
    ok = np.isfinite(best_ms)
    scored = [e for e in errors if e is not None]
    return {
        "ms_per_pair_median": float(np.median(best_ms[ok])) if ok.any() else None,
        "ms_per_pair_p95": float(np.percentile(best_ms[ok], 95)) if ok.any() else None,
        "pairs_per_s": float(1e3 / np.median(best_ms[ok])) if ok.any() else None,
        "mean_error_mm": float(np.mean([e["mean_error_mm"] for e in scored])) if scored else None,
        "max_error_mm": float(np.max([e["max_error_mm"] for e in scored])) if scored else None,
        "tip_error_mm_median": float(np.median([e["tip_error_mm"] for e in scored])) if scored else None,
        "tip_error_mm_max": float(np.max([e["tip_error_mm"] for e in scored])) if scored else None,
        "scored_frames": len(scored),
    }


def run_method(name: str, data: dict, params=None, repeats: int = 3, budget_s: float = 30.0, memory: bool = True) -> dict:
    """Time and score one method on the frames of ``data``; see the module doc for the protocol."""
    tracemalloc.start()
    t0 = time.perf_counter()
    rec = make_method(name, data["rig"], data["backgrounds"], params)
    prepare_s = time.perf_counter() - t0
    model_mib = tracemalloc.get_traced_memory()[0] / 2**20  # what the prepared method keeps (background models)
    tracemalloc.stop()
    n = len(data["frames"])
    best = np.full(n, np.inf)
    errors, failures, extras = [None] * n, [None] * n, {}
    notes = list(data.get("truth_notes") or [None] * n)  # "not scored: ..." per frame, None when scored
    spent = 0.0
    passes = 0
    for p in range(max(1, repeats)):
        if p > 0 and spent > budget_s:
            break
        if hasattr(rec, "reset"):
            rec.reset()
        passes += 1
        for i, frames in enumerate(data["frames"]):
            t = time.perf_counter()
            try:
                result = rec(frames)
            except FrameError as exc:
                dt = time.perf_counter() - t
                spent += dt
                if p == 0:
                    failures[i] = str(exc)
                continue
            dt = time.perf_counter() - t
            spent += dt
            best[i] = min(best[i], 1e3 * dt)
            if p == 0:
                truth = data["truths"][i]
                if truth is not None:
                    errors[i], notes[i] = _score(i, result, truth, data["rig"])
                if getattr(result, "jump_flag", False):
                    extras.setdefault("jump_flags", []).append(i)
    ok = np.isfinite(best)
    out = {"method": name, "frames": n, "failed_frames": int(n - ok.sum()), "passes": passes, "prepare_s": prepare_s,
           **_aggregates(best, errors), "failures": sorted({f for f in failures if f})[:5],
           "score_notes": [note for note in notes if note]}
    out.update(extras)
    if memory and ok.any():
        out["peak_memory_mib"] = _peak_memory_mib(rec, data["frames"][int(np.flatnonzero(ok)[0])])
    out["model_memory_mib"] = model_mib
    return out


def _score(index: int, result, truth, rig) -> tuple:
    """``(errors, None)`` of frame ``index`` (mm, :func:`rig.scoring.score_frame`), or ``(None, "not scored: ...")``."""
    try:
        errs = score_frame(result, truth, rig)
    except ValueError as exc:  # nothing of it seen by both cameras: the frame stays in the time figures
        return None, f"not scored: frame {index}: {str(exc).splitlines()[0]}"
    if any(v is None for v in errs.values()):  # the aggregates are over known figures only
        return None, f"not scored: frame {index}: unknown (non-finite) errors: the backbone has non-finite points"
    return errs, None


def _peak_memory_mib(rec, frames: dict) -> float:
    """Peak memory (MiB) of one reconstruction of ``frames``, traced by tracemalloc.

    numba's allocations are invisible to tracemalloc: for the fast method the arrays its
    compiled kernels allocate are not counted.
    """
    if hasattr(rec, "reset"):
        rec.reset()
    tracemalloc.start()
    try:
        rec(frames)
    except FrameError:
        pass
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return peak / 2**20


# ----------------------------------------------------------------------------- report


def format_table(results: dict, title: str = "") -> str:
    lines = [title] if title else []
    lines.append(f"{'method':>17}  {'ok':>5}  {'ms med':>8}  {'ms p95':>8}  {'pairs/s':>8}  {'mean mm':>8}  {'max mm':>8}  {'tip mm':>8}  {'peak MiB':>8}  {'model MiB':>9}")
    for name, r in results.items():
        if "skipped" in r:
            lines.append(f"{name:>17}  skipped: {r['skipped']}")
            continue
        okf = f"{r['frames'] - r['failed_frames']}/{r['frames']}"
        lines.append(
            f"{name:>17}  {okf:>5}  {cell(r['ms_per_pair_median'], precision=1, width=8)}  {cell(r['ms_per_pair_p95'], precision=1, width=8)}  {cell(r['pairs_per_s'], precision=1, width=8)}  "
            f"{cell(r['mean_error_mm'], width=8)}  {cell(r['max_error_mm'], width=8)}  {cell(r['tip_error_mm_median'], width=8)}  {cell(r.get('peak_memory_mib'), precision=1, width=8)}  "
            f"{cell(r.get('model_memory_mib'), width=9, precision=1)}"
        )
    return "\n".join(lines)


def format_ratios(results: dict, ref: str = "fast") -> str:
    r0 = results.get(ref)
    if not r0 or "skipped" in r0 or r0.get("ms_per_pair_median") is None:
        return ""
    lines = []
    for name, r in results.items():
        if name == ref or "skipped" in r or r.get("ms_per_pair_median") is None:
            continue
        speed = r["ms_per_pair_median"] / r0["ms_per_pair_median"]
        parts = [f"{ref} vs {name}: {speed:.1f}x faster"]
        for key, label in (("mean_error_mm", "mean"), ("max_error_mm", "max"), ("tip_error_mm_median", "tip")):
            if r.get(key) and r0.get(key) is not None:
                parts.append(f"{label} error x{r0[key] / r[key]:.2f}")
        lines.append(", ".join(parts))
    return "\n".join(lines)


# ----------------------------------------------------------------------------- command
def bench(scene, methods, cache_dir: Path, repeats: int, quiet: bool, factor: float = 1.0, budget_s: float = 30.0,
          params: dict | None = None) -> dict:
    """Results keyed by method label on the scene rendered at ``factor``."""
    path = cached_session(scene, factor, cache_dir, quiet=quiet)
    data = load_session(path)
    results = {}
    for label in methods:
        name, p = (params or {}).get(label, (label, None))
        ok, why = method_status(name)
        if not ok:
            results[label] = {"skipped": why}
            continue
        if not quiet:
            print(f"{label}: {len(data['frames'])} frame pairs at {data['size'][0]}x{data['size'][1]} ...", file=sys.stderr)
        try:
            results[label] = run_method(name, data, p, repeats=repeats, budget_s=budget_s)
        except ValueError as exc:
            results[label] = {"skipped": str(exc).splitlines()[0]}
        results[label]["image_size"] = list(data["size"])
    return results


def scaling(scene, methods, cache: Path, args) -> dict:
    """The resolution study and the paper method's voxel study (see the module doc)."""
    sc = scene.with_frames(scene.joints[: args.scaling_frames]) if args.scaling_frames else scene
    out = {}
    for factor in (0.5, 1.0, 2.0):
        res = bench(sc, methods, cache, max(1, args.repeats - 1), args.quiet, factor=factor, budget_s=20.0)
        for label, r in res.items():
            out[f"{label}@{factor:g}x"] = r
    labels = {}
    for n in (50, 100, 200):
        labels[f"paper-{n}^3"] = ("paper", PaperParams(carving=replace(CarvingParams(), resolution=n)))
    res = bench(sc, list(labels), cache, 1, args.quiet, factor=1.0, budget_s=20.0, params=labels)
    out.update(res)
    return out


def format_scaling(results: dict) -> str:
    lines = ["scaling: " + "; ".join(sorted({f"{r['image_size'][0]}x{r['image_size'][1]}" for r in results.values() if 'image_size' in r}))]
    lines.append(format_table(results))
    return "\n".join(lines)
