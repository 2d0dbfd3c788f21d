#!/usr/bin/env python
"""Measure both reconstruction methods on the cases outside the drawn envelope (docs/envelope.md).

Four cases, each a sweep of one quantity on twin scenes built by ``tests/strategies.py``
(paper.toml with the robot posed; the paper's noise, lighting and set):

* ``a_pointing_side`` / ``a_pointing_top``: a straight two-tube robot (60 mm) whose axis is
  at an angle (deg) to a camera's optical axis, tip towards that camera (0 deg: end on, a
  blob ~14 px across); without the actuation unit, which would sit right behind the robot in
  that view. ``a_pointing_side_unit``: the same with the unit, as the rig has it.
* ``b_epipolar``: the same robot at an angle (deg) to the rig's epipolar planes, which are the
  planes x = const (90 deg: along x, the paper's insertion axis; 0 deg: along (0, 1, 1)).
* ``c_fold`` / ``c_fold_tilt``: the inner tube turns through a bend angle (deg) in the plane
  the side camera sees edge on, so past 90 deg it folds back over itself in the side view;
  then a 180 deg fold tilted (deg) out of that plane, which separates the two legs in the
  side view (at 90 deg the top camera sees the fold edge on instead).
* ``d_contrast``: a plain backdrop whose gray (0-1) is brought down to the Nitinol tubes'
  (~0.5); the measured median contrast (gray levels, signed) is reported with it.

Scenes without the actuation unit show the 8 mm of outer tube the twin hides in it, behind
the base; those reconstructions are scored on their points beyond the base plane only.

Each scene is rendered once (6 background pairs and one frame pair, ~5 s) and
reconstructed by ``paper`` and ``fast``. A result is *within* when the paper method's mean
error is at most one voxel edge (max of ``voxel_size_mm``) and the fast method's mean is at
most 1.5 pixel footprints and its tip error at most 3 (the bounds of
tests/test_properties.py); ``length_ok`` also checks the arc length (3 voxel edges, 9
footprints; see ``accuracy_bounds`` in tests/test_envelope_cases.py). A FrameError is an
acceptable outcome outside the envelope; a result that is not within is a silently wrong
shape.

Usage::

    .venv/bin/python scripts/measure_envelope.py --out out/envelope [--quick] [--cases b_epipolar,d_contrast]

Writes ``envelope.csv`` in ``--out`` and prints one table per case.
"""
from __future__ import annotations


import argparse
import csv
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

os.environ.setdefault("OMP_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
import strategies as S  # noqa: E402
from test_envelope_cases import scored  # noqa: E402

from recon.errors import FrameError  # noqa: E402

# One OpenCV thread: results repeat from run to run (as in tests/conftest.py).
cv2.setNumThreads(1)

METHODS = ("paper", "fast")
COLUMNS = ("case", "quantity", "unit", "value", "method", "status", "mean_error_mm", "tip_error_mm",
           "length_error_mm", "bound_mm", "within", "length_ok", "derived", "derived_value")


@dataclass(frozen=True)
class Sweep:
    """One case: a quantity swept over values, a scene builder, and an optional derived measure.

    Attributes
    ----------
    case : str
    quantity, unit : str
        What is swept and its unit.
    values, quick : tuple of float
        The full sweep and the ``--quick`` one.
    build : callable(value) -> dict
        Scene dict for one value.
    derived : str
        Name and unit of the derived measure ("" for none).
    measure : callable(scene, frame, stacks) -> float, optional
        The derived measure from the rendered truth.
    clip_to_base : bool
        Score only the reconstructed points beyond the base plane (scenes without the
        actuation unit, see :func:`strategies.beyond_base`).
    """

    case: str
    quantity: str
    unit: str
    values: tuple
    quick: tuple
    build: Callable
    derived: str = ""
    measure: Callable | None = None
    clip_to_base: bool = False


def _overlap(scene, frame, stacks) -> float:
    """Backbone length one camera sees on top of another part of the robot (mm), the larger of the two views."""
    width = scene.robot.tubes[1].outer_diameter_mm
    return max(S.self_overlap_mm(cam, frame.backbone.p_world_mm, width) for cam in frame.cameras.values())


def _contrast(scene, frame, stacks) -> float:
    """The median robot contrast (gray levels, negative: robot darker) of the view where it is smaller."""
    return min(S.robot_contrast_dn(frame, stacks).values(), key=abs)


#: Gray levels under which a robot pixel counts as faint: about 0.25 (the paper's binarization
#: threshold) of the robot's peak difference of ~100 gray levels.
FAINT_DN = 25.0


def _faint_side(scene, frame, stacks) -> float:
    """Share of the side view's robot pixels within :data:`FAINT_DN` of the background (%)."""
    return 100.0 * S.faint_fraction(frame, stacks, FAINT_DN)["side"]


_OVERLAP = "self-overlap in one view (mm)"
_POINTING = (90, 60, 40, 25, 15, 10, 5, 3, 2, 1, 0)

SWEEPS = (
    Sweep("a_pointing_side", "angle between the tube and the side camera's optical axis", "deg",
          _POINTING, (90, 25, 5, 0), lambda v: S.pointing_dict(v, "side"), clip_to_base=True),
    Sweep("a_pointing_top", "angle between the tube and the top camera's optical axis", "deg",
          _POINTING, (90, 25, 5, 0), lambda v: S.pointing_dict(v, "top"), clip_to_base=True),
    # The same robot with the actuation unit, as the rig has it: pointing at a camera puts the
    # unit (a dark block) behind the robot in that camera's view.
    Sweep("a_pointing_side_unit", "angle between the tube and the side camera's optical axis, actuation unit behind", "deg",
          (90, 60, 50, 40, 30, 25, 15, 5), (90, 40, 25), lambda v: S.pointing_dict(v, "side", actuation_unit=True),
          f"side-view robot pixels < {FAINT_DN:g} gray levels off the background (%)", _faint_side),
    Sweep("b_epipolar", "angle between the tube and the epipolar planes x = const", "deg",
          (90, 45, 30, 20, 15, 10, 7, 5, 3, 2, 0), (90, 20, 5, 0), S.epipolar_dict, clip_to_base=True),
    Sweep("c_fold", "bend of the inner tube in the plane the side camera sees edge on", "deg",
          (60, 75, 90, 120, 150, 180, 210, 240), (90, 150, 210), lambda v: S.fold_dict(v, 0.0), _OVERLAP, _overlap),
    Sweep("c_fold_tilt", "tilt of a 180 deg fold out of the side camera's edge-on plane", "deg",
          (0, 1, 2, 3, 4, 5, 10, 20, 45, 70, 85, 90), (0, 2, 10, 90), lambda v: S.fold_dict(180.0, v), _OVERLAP, _overlap),
    Sweep("d_contrast", "gray of a plain backdrop behind the paper's Nitinol tubes", "1",
          (0.86, 0.75, 0.65, 0.6, 0.55, 0.5, 0.47, 0.45, 0.4, 0.35, 0.3, 0.25, 0.2), (0.86, 0.55, 0.47, 0.3), S.contrast_dict,
          "median robot - backdrop, lower view (gray levels)", _contrast),
)


def evaluate(method: str, scene, stacks: dict, frame, clip_to_base: bool = False) -> dict:
    """Reconstruct ``frame`` with ``method`` and score it against the twin's truth.

    Returns
    -------
    dict
        ``status`` ("ok", "FrameError: <reason>" or "error: <type>: <message>"), the three
        errors (mm; NaN unless ok), ``bound_mm`` (the mean-error bound: paper one voxel
        edge, fast 1.5 pixel footprints), ``within`` ("yes"/"no"/"": the mean bound, and
        for fast the tip bound of 3 footprints) and ``length_ok`` (arc length within the
        bound of :func:`test_envelope_cases.accuracy_bounds`).
    """
    out = {"status": "ok", "mean_error_mm": np.nan, "tip_error_mm": np.nan, "length_error_mm": np.nan,
           "bound_mm": np.nan, "within": "", "length_ok": ""}
    try:
        e, bounds = scored(method, scene, stacks, frame, clip_to_base)
    except FrameError as exc:
        out["status"] = f"FrameError: {exc}"
        return out
    except Exception as exc:  # noqa: BLE001 -- anything else is a defect to report, not to stop the sweep
        out["status"] = f"error: {type(exc).__name__}: {' '.join(str(exc).split())}"
        return out
    out.update({k: e[k] for k in ("mean_error_mm", "tip_error_mm", "length_error_mm")})
    out["bound_mm"] = bounds["mean_error_mm"]
    ok = e["mean_error_mm"] <= bounds["mean_error_mm"] and e["tip_error_mm"] <= bounds["tip_error_mm"]
    out["within"] = "yes" if ok else "no"
    out["length_ok"] = "yes" if abs(e["length_error_mm"]) <= bounds["length_error_mm"] else "no"
    return out


def _fmt(row: dict) -> str:
    """One method's cell of the printed table."""
    if row["status"] != "ok":
        return row["status"][:58]
    flag = "" if row["within"] == "yes" else "  WRONG"
    if row["within"] == "yes" and row["length_ok"] == "no":
        flag = "  (length)"  # within the mean bound, but the curve wanders: its arc length is off
    return (f"mean {row['mean_error_mm']:.3f} tip {row['tip_error_mm']:.2f} len {row['length_error_mm']:+.2f}"
            f" (<= {row['bound_mm']:.3f}){flag}")


def print_table(sweep: Sweep, rows: list) -> None:
    """Print one case: swept value, derived measure, then each method's outcome."""
    print(f"\n== {sweep.case}: {sweep.quantity} ({sweep.unit})")
    head = f"{'value':>7} " + (f"{'derived':>9} " if sweep.derived else "") + "".join(f"{m:<62}" for m in METHODS)
    if sweep.derived:
        print(f"   derived = {sweep.derived}")
    print(head)
    for v in dict.fromkeys(r["value"] for r in rows):
        by = {r["method"]: r for r in rows if r["value"] == v}
        d = f"{by[METHODS[0]]['derived_value']:9.2f} " if sweep.derived else ""
        print(f"{v:>7g} " + d + "".join(f"{_fmt(by[m]):<62}" for m in METHODS))
    sys.stdout.flush()


def run_sweep(sweep: Sweep, values, progress) -> list:
    """Render each value's scene and evaluate both methods; one row per (value, method)."""
    from twin.scene import scene_from_dict

    rows = []
    for v in values:
        t0 = time.perf_counter()
        scene = scene_from_dict(sweep.build(v), source=f"<{sweep.case}={v}>")
        stacks, frames = S.render_scene(scene)
        derived = sweep.measure(scene, frames[0], stacks) if sweep.measure else np.nan
        for m in METHODS:
            row = {"case": sweep.case, "quantity": sweep.quantity, "unit": sweep.unit, "value": float(v), "method": m,
                   "derived": sweep.derived, "derived_value": derived}
            row.update(evaluate(m, scene, stacks, frames[0], sweep.clip_to_base))
            rows.append(row)
        progress(f"{sweep.case} = {v:g} {sweep.unit}: " + "; ".join(f"{r['method']} {r['status'][:40]} {r['within']}" for r in rows[-2:])
                 + f" ({time.perf_counter() - t0:.1f} s)")
    return rows


def write_csv(path: Path, rows: list) -> None:
    """All rows so far (rewritten after each case, so an interrupted run keeps what it measured)."""
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=COLUMNS)
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{r[k]:.4f}" if isinstance(r[k], float) and np.isfinite(r[k]) else ("" if isinstance(r[k], float) else r[k]))
                        for k in COLUMNS})


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True, help="folder for envelope.csv")
    ap.add_argument("--quick", action="store_true", help="3-4 values per case instead of 7-9")
    ap.add_argument("--cases", default="", help=f"comma-separated subset of: {', '.join(s.case for s in SWEEPS)}")
    args = ap.parse_args(argv)
    wanted = [c for c in args.cases.split(",") if c]
    unknown = sorted(set(wanted) - {s.case for s in SWEEPS})
    if unknown:
        ap.error(f"unknown case(s): {', '.join(unknown)}")
    sweeps = [s for s in SWEEPS if not wanted or s.case in wanted]
    args.out.mkdir(parents=True, exist_ok=True)
    total = sum(len(s.quick if args.quick else s.values) for s in sweeps)
    done = [0]
    t_start = time.perf_counter()

    def progress(msg: str) -> None:
        done[0] += 1
        print(f"[{done[0]}/{total} {time.perf_counter() - t_start:6.0f} s] {msg}", file=sys.stderr, flush=True)

    rows = []
    for sweep in sweeps:
        case_rows = run_sweep(sweep, sweep.quick if args.quick else sweep.values, progress)
        rows += case_rows
        write_csv(args.out / "envelope.csv", rows)
        print_table(sweep, case_rows)
    print(f"\nwrote {args.out / 'envelope.csv'} ({len(rows)} rows, {time.perf_counter() - t_start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
