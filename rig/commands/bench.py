"""``ctr-bench bench [SCENE]``: every method on the same rendered frames, side by side, on one core.

The scene is rendered once into a cache (``out/bench-cache/<scene>-<WxH>-<hash>``,
:mod:`rig.render_cache`: the hash covers the scene file, frame counts, model, image scale and the twin's code), then
each method reconstructs the same frames in the same process:

* ``paper``: the paper's method (:mod:`recon.paper`);
* ``fast``: :mod:`recon.fast`;
* ``icp-epipolar``: icpReconstructor's EpipolarReconstructor (:mod:`rig.peers`),
  when that package imports (the optional extra ``peers``); otherwise the
  bench says why it is skipped.

Timing is on one core: the process is pinned to one CPU, OpenCV and the BLAS
pools use one thread. Each method runs the whole sequence ``--repeats``
times in order (its state, e.g. the fast method's previous-frame prior, reset
before each pass); a frame's time is its fastest pass, which discounts
interruptions by other processes on a shared machine; the table gives the
median and 95th percentile over frames. Errors are from the first pass
(:func:`recon.metrics.backbone_errors` against the twin's ground truth):
mean = mean over frames of the per-frame mean error, max = largest per-frame
maximum, tip = median of the per-frame tip errors; a frame whose ground truth
cannot be used is left out of them and listed under the table (``score_notes``
in ``--json``, naming the truth file). Peak memory is the
tracemalloc peak (Python and NumPy heap) of one more reconstruction of the
first frame, made after the timed passes (for the fast method with its NumPy
code: numba's allocations are invisible to tracemalloc); model memory is what
the prepared method keeps (background models).

``--scaling`` adds the resolution study: the scene rendered with every camera
scaled to half, full and double resolution (512x384, 1024x768, 2048x1536),
each method on each, and the paper's method at 50^3, 100^3 and 200^3 voxels.
"""
from __future__ import annotations

import json
import os
import sys
import time
import tracemalloc
from dataclasses import replace
from pathlib import Path

from rig.render_cache import DEFAULT_CACHE_DIR, cached_session

from .render import add_scene_options, load_scene_from_args

METHODS = ("paper", "fast", "icp-epipolar")
PEERS = ("icp-epipolar",)


def method_list(text: str) -> list:
    """``--methods``'s type: known names, comma-separated, checked when the options are read (before any render).

    A peer that is known but not installed is accepted here and skipped with its reason later.
    """
    import argparse

    names = [m.strip() for m in text.split(",")]
    bad = [m for m in names if m not in METHODS]
    if bad or len(set(names)) != len(names):
        why = f"unknown method {bad[0]!r}" if bad else "a method named twice"
        raise argparse.ArgumentTypeError(f"{why} in {text!r} (known: {', '.join(METHODS)})")
    return names


# ----------------------------------------------------------------------------- one core
def pin_one_core() -> int:
    """Pin this process to one CPU and keep OpenCV/BLAS single-threaded; returns the CPU."""
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    cpu = -1
    if hasattr(os, "sched_setaffinity"):
        cpus = sorted(os.sched_getaffinity(0))
        cpu = cpus[-1]
        os.sched_setaffinity(0, {cpu})
    import cv2

    cv2.setNumThreads(1)
    try:  # numpy may have been imported before the variables were set
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)
    except ImportError:
        pass
    return cpu


# ----------------------------------------------------------------------------- sessions
def load_session(path: Path) -> dict:
    """Background stacks, frame images and ground-truth backbones of a session, in memory.

    A frame whose ground truth cannot be used (:class:`rig.session.TruthError`: its
    file missing, unreadable, of the wrong shape or not finite) is kept, unscored: its
    truth is None and ``truth_notes`` holds ``"not scored: <message naming the file>"``
    at its position (None for the other frames).
    """
    from rig.reconstruct import load_background_frames
    from rig.session import Session, TruthError

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
        from rig.peers import prepare_peer

        return prepare_peer(name, rig, backgrounds)
    from recon.methods import prepare

    return prepare(name, rig, backgrounds, params)


def method_status(name: str) -> tuple[bool, str]:
    if name in PEERS:
        from rig.peers import peer_status

        return peer_status(name)
    from recon.methods import get_method

    try:
        get_method(name)
    except ValueError as exc:
        return False, str(exc)
    return True, "available"


def _aggregates(best_ms, errors: list) -> dict:
    """Time (ms per pair, over the frames reconstructed: finite ``best_ms``) and error (mm, over the scored
    frames: ``errors`` not None) figures of a method's run."""
    import numpy as np

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
    import numpy as np

    from recon.errors import FrameError
    from recon.metrics import backbone_errors

    tracemalloc.start()
    t0 = time.perf_counter()
    rec = make_method(name, data["rig"], data["backgrounds"], params)
    prepare_s = time.perf_counter() - t0
    model_mib = tracemalloc.get_traced_memory()[0] / 2**20  # what the prepared method keeps (background models)
    tracemalloc.stop()
    n = len(data["frames"])
    best = np.full(n, np.inf)
    errors, failures, extras = [None] * n, [None] * n, {}
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
                    errors[i] = backbone_errors(result.points_world_mm, truth, data["rig"])
                if getattr(result, "jump_flag", False):
                    extras.setdefault("jump_flags", []).append(i)
    ok = np.isfinite(best)
    out = {"method": name, "frames": n, "failed_frames": int(n - ok.sum()), "passes": passes, "prepare_s": prepare_s,
           **_aggregates(best, errors), "failures": sorted({f for f in failures if f})[:5],
           "score_notes": [note for note in data.get("truth_notes") or () if note]}
    out.update(extras)
    if memory and ok.any():
        out["peak_memory_mib"] = _peak_memory_mib(rec, data["frames"][int(np.flatnonzero(ok)[0])])
    out["model_memory_mib"] = model_mib
    return out


def _peak_memory_mib(rec, frames: dict) -> float:
    """Peak memory (MiB) of one reconstruction of ``frames``, traced by tracemalloc.

    numba's allocator is invisible to tracemalloc: the fast method's NumPy path is
    measured instead (the same arrays).
    """
    from recon.errors import FrameError
    import recon.subpixel as sp

    if hasattr(rec, "reset"):
        rec.reset()
    use_numba = sp.USE_NUMBA
    sp.USE_NUMBA = False
    tracemalloc.start()
    try:
        rec(frames)
    except FrameError:
        pass
    finally:
        sp.USE_NUMBA = use_numba
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return peak / 2**20


# ----------------------------------------------------------------------------- report
def _f(v, w=8, p=3):
    return f"{v:{w}.{p}f}" if isinstance(v, (int, float)) else f"{'-':>{w}}"


def format_table(results: dict, title: str = "") -> str:
    lines = [title] if title else []
    lines.append(f"{'method':>17}  {'ok':>5}  {'ms med':>8}  {'ms p95':>8}  {'pairs/s':>8}  {'mean mm':>8}  {'max mm':>8}  {'tip mm':>8}  {'peak MiB':>8}  {'model MiB':>9}")
    for name, r in results.items():
        if "skipped" in r:
            lines.append(f"{name:>17}  skipped: {r['skipped']}")
            continue
        okf = f"{r['frames'] - r['failed_frames']}/{r['frames']}"
        lines.append(
            f"{name:>17}  {okf:>5}  {_f(r['ms_per_pair_median'], p=1)}  {_f(r['ms_per_pair_p95'], p=1)}  {_f(r['pairs_per_s'], p=1)}  "
            f"{_f(r['mean_error_mm'])}  {_f(r['max_error_mm'])}  {_f(r['tip_error_mm_median'])}  {_f(r.get('peak_memory_mib'), p=1)}  "
            f"{_f(r.get('model_memory_mib'), w=9, p=1)}"
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


def _max_pixels(megapixels) -> int | None:
    """``--max-megapixels`` as a pixel count (None: every sensor size), checked against the smallest sensor drawn."""
    from twin.scenegen import IMAGE_SIZES

    if megapixels is None:
        return None
    smallest = IMAGE_SIZES[0][0] * IMAGE_SIZES[0][1]
    if not megapixels * 1e6 >= smallest:
        raise ValueError(f"--max-megapixels must be >= {smallest / 1e6:g} (the smallest sensor drawn, "
                         f"{IMAGE_SIZES[0][0]}x{IMAGE_SIZES[0][1]}), got {megapixels:g}")
    return int(megapixels * 1e6)


def _run_suite(args) -> int:
    """``bench --suite NAME``: the generalization benchmark of :mod:`rig.widebench`."""
    from rig import widebench

    if args.scene is not None:
        raise ValueError(f"--suite {args.suite} draws its own scenes: give either a SCENE or --suite, not both")
    if args.n < 1:
        raise ValueError(f"--n must be >= 1, got {args.n}")
    if args.seed < 0:
        raise ValueError(f"--seed must be >= 0, got {args.seed}")
    max_pixels = _max_pixels(args.max_megapixels)
    pin_one_core()
    methods = args.methods or list(METHODS)
    out = Path(args.out) if args.out else Path("out") / f"bench-{args.suite}-n{args.n}-seed{args.seed}"
    report = widebench.run_suite(args.suite, args.n, args.seed, methods, out, Path(args.cache_dir),
                                 selfcheck=not args.no_selfcheck, quiet=args.quiet, max_pixels=max_pixels)
    if args.json:
        print(widebench.dump(report))
        return 0
    print(widebench.format_suite(report))
    widebench.print_worst(report)
    print(f"\nper-frame rows: {out / 'frames.csv'}; summary: {out / 'summary.json'}; runs: {out / 'runs'}")
    return 0


def _run(args) -> int:
    if args.suite:
        return _run_suite(args)
    cpu = pin_one_core()
    scene = load_scene_from_args(args)
    methods = args.methods or list(METHODS)
    cache = Path(args.cache_dir)
    results = bench(scene, methods, cache, args.repeats, args.quiet)
    report = {"bench": results}
    if args.scaling:
        report["scaling"] = scaling(scene, [m for m in methods], cache, args)
    if args.json:
        out = dict(results)
        if args.scaling:
            out = {"bench": results, "scaling": report["scaling"]}
        print(json.dumps(out, indent=2, default=float))
        return 0
    size = next((r["image_size"] for r in results.values() if "image_size" in r), None)
    print(format_table(results, f"{scene.name}: {len(scene.joints)} frame pairs"
                       + (f" at {size[0]}x{size[1]}" if size else "") + f", one core (cpu {cpu}), best of {args.repeats} passes per frame"))
    rat = format_ratios(results)
    if rat:
        print("\n" + rat)
    _print_score_notes(results)
    if "icp-epipolar" in results and "skipped" not in results["icp-epipolar"]:
        print("\nicp-epipolar runs with two compatibility shims (NumPy 2 int() of 1-element arrays, OpenCV 5 1-D points); see rig/peers.py.")
    if args.scaling:
        print()
        print(format_scaling(report["scaling"]))
        _print_score_notes(report["scaling"])
    return 0


def _print_score_notes(results: dict, file=None) -> None:
    """The frames left unscored (their ground truth unusable), once each, under the table (on ``file``, stdout by default)."""
    file = file or sys.stdout
    notes = list(dict.fromkeys(n for r in results.values() for n in r.get("score_notes", ())))
    if notes:
        print(f"\n{len(notes)} frame(s) not scored (errors are over the other frames):", file=file)
        for note in notes:
            print(f"  {note}", file=file)


def scaling(scene, methods, cache: Path, args) -> dict:
    """The resolution study and the paper method's voxel study (see the module doc)."""
    from recon.carving import CarvingParams
    from recon.paper import PaperParams

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


def register(sub) -> None:
    p = sub.add_parser("bench", help="all methods on the same rendered frames, one core: speed, accuracy, memory",
                       description="Render a scene once (cached), then time and score the paper method, the fast method and "
                       "icpReconstructor's EpipolarReconstructor (when installed) on the same frames, pinned to one core.")
    add_scene_options(p)
    p.add_argument("--methods", type=method_list, default=None, metavar="LIST",
                   help=f"comma-separated subset of {','.join(METHODS)} (default: all)")
    p.add_argument("--repeats", type=int, default=3, help="passes over the sequence per method; a frame's time is its fastest (default 3)")
    p.add_argument("--cache-dir", default=str(DEFAULT_CACHE_DIR), help="where rendered sessions are cached (default %(default)s)")
    p.add_argument("--scaling", action="store_true", help="also the resolution (0.5x, 1x, 2x) and voxel (50^3, 100^3, 200^3) study")
    p.add_argument("--scaling-frames", type=int, default=6, help="frames per scene in the scaling study (default 6)")
    p.add_argument("--json", action="store_true", help="print one JSON object keyed by method name")
    p.add_argument("--suite", choices=["wide"], default=None,
                   help="the generalization benchmark on a seeded set of generated scenes instead of one SCENE (docs/scenes.md)")
    p.add_argument("--n", type=int, default=40, help="--suite: number of scenes (default 40)")
    p.add_argument("--seed", type=int, default=1, help="--suite: seed of the scene draw (default 1, the reported set)")
    p.add_argument("--out", default=None, help="--suite: where frames.csv, summary.json and the runs go "
                   "(default out/bench-SUITE-nN-seedS)")
    p.add_argument("--max-megapixels", type=float, default=None,
                   help="--suite: draw only sensors up to this size (a quick set; other ranges unchanged)")
    p.add_argument("--no-selfcheck", action="store_true", help="--suite: report frames as the methods return them, unchecked")
    p.set_defaults(func=_run)
