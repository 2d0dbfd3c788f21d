"""Reconstruct every frame of a session directory and score it against ground truth.

Outputs (documented in ``docs/outputs.md``), written as the work goes so that an
interrupted run keeps what it finished:

* ``frames/NNNNNN.csv``: the backbone of each frame, ``s_mm,x_mm,y_mm,z_mm,tx,ty,tz``, base first
  (:mod:`rig.backbone_csv`);
* ``frames.csv``: one row per frame (time, status, reason, figures);
* ``backbones.npz``: all backbones (``frame_NNNNNN`` arrays) and the frame indices;
* ``summary.json``: method, parameters, per-frame results and aggregates.

Every reconstructed backbone is judged against its images by the
method-independent self-check (:mod:`recon.selfcheck`, ``docs/selfcheck.md``):
a frame whose backbone does not explain the images is ``suspect`` (not
``ok``), with the reason; it is still written and scored, so that a benchmark
can count silent wrong shapes (``ok`` frames with large errors).
"""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

from recon.errors import FrameError
from recon.methods import get_method
from recon.metrics import backbone_errors
from recon.params import params_to_dict
from recon.selfcheck import SelfCheckParams, check_backbone, prepare_selfcheck
from rig.backbone_csv import FrameTable, write_backbone_csv

from .session import Session, SessionError

__all__ = ["reconstruct_session", "write_json_atomic", "load_background_frames", "summarize", "format_table",
           "selfcheck_tube_radii_mm", "selfcheck_record"]

#: Per-frame statuses: reconstructed and passed the self-check, reconstructed but the
#: self-check doubts it, not reconstructed.
STATUSES = ("ok", "suspect", "failed")


def write_json_atomic(path: Path, data: dict) -> None:
    """Write JSON to a temporary name and rename it: readers never see half a file.

    JSON has no NaN or infinity: such values (an unknown figure, a limit
    that is off) are written as null rather than aborting the write.
    """
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(_json_safe(data), indent=2, allow_nan=False, default=_json_default) + "\n")
    os.replace(tmp, path)


def _json_safe(o):
    """``o`` with every non-finite float (NumPy's too) replaced by None, containers copied."""
    if isinstance(o, dict):
        return {k: _json_safe(v) for k, v in o.items()}
    if isinstance(o, np.ndarray):
        return _json_safe(o.tolist())
    if isinstance(o, (list, tuple)):
        return [_json_safe(v) for v in o]
    if isinstance(o, (float, np.floating)):
        return float(o) if np.isfinite(o) else None
    return o


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serializable: {type(o).__name__}")


def _finite(x):
    """JSON has no NaN: report unknown values as null."""
    if x is None:
        return None
    x = float(x)
    return x if np.isfinite(x) else None


def load_background_frames(session: Session) -> dict:
    """Background stacks by camera, checked against the rig's image sizes."""
    out = {}
    for cam in session.cameras:
        stack = session.background_stack(cam)
        c = session.rig[cam]
        if stack.shape[1:] != (c.height, c.width):
            raise SessionError(
                f"{session.dir / 'background' / cam}: frames are {stack.shape[2]}x{stack.shape[1]} "
                f"but rig.json says {c.width}x{c.height}"
            )
        out[cam] = stack
    return out


def _background_error(session: Session, exc: Exception) -> str:
    """One line naming the background directory at fault (the camera's, when the message names one)."""
    msg = " ".join(str(exc).split())
    cam, sep, rest = msg.partition(": ")
    if sep and cam in session.cameras:
        return f"{session.dir / 'background' / cam}: {rest}"
    return f"{session.dir / 'background'}: {msg}"


def _one_line(exc: Exception) -> str:
    """A per-frame failure reason: the exception's message on one line."""
    msg = " ".join(str(exc).split())
    if isinstance(exc, (FrameError, SessionError)):
        return msg
    # Not a foreseen failure: say what it was, still on one line.
    return f"unexpected {type(exc).__name__}: {msg}" if msg else f"unexpected {type(exc).__name__}"


def mm_per_pixel(session: Session) -> float:
    """Mean pixel footprint (mm) of the cameras at the robot base."""
    base = session.rig.base_point_world_mm
    return float(np.mean([session.rig[c].mm_per_pixel_at(base) for c in session.cameras]))


def selfcheck_tube_radii_mm(session: Session, params):
    """(outermost, innermost) tube radius (mm) the self-check draws the tube with.

    The robot in session.json when it has one (it is the robot in the images),
    else the method's ``outer_tube_radius_mm`` / ``inner_tube_radius_mm``;
    None when neither says.
    """
    radii = session.robot_tube_radii_mm
    if radii is not None:
        return radii
    if hasattr(params, "outer_tube_radius_mm") and hasattr(params, "inner_tube_radius_mm"):
        return float(params.outer_tube_radius_mm), float(params.inner_tube_radius_mm)
    return None


def selfcheck_record(rec: dict, check_model, images: dict, pts: np.ndarray, radii_mm, params: SelfCheckParams) -> None:
    """Judge a reconstructed backbone and record the verdict in its per-frame record.

    Sets ``rec["selfcheck"]`` (``recon.selfcheck.SelfCheck.to_dict``) and, when
    the check fails, ``status = "suspect"`` with the check's reason. A check
    that cannot run makes the frame suspect too: an unverified shape must not
    pass as ``ok``.
    """
    try:
        sc = check_backbone(check_model, images, pts, radii_mm, params)
    except Exception as exc:  # noqa: BLE001 - a crashing check must not cost the frame
        if os.environ.get("CTR_BENCH_DEBUG") and not isinstance(exc, ValueError):
            raise
        rec["selfcheck"] = {"ok": False, "reason": f"self-check could not run: {_one_line(exc)}", "ms": None, "views": {}}
        rec.update(status="suspect", reason=rec["selfcheck"]["reason"])
        return
    rec["selfcheck"] = sc.to_dict()
    if not sc.ok:
        rec.update(status="suspect", reason=sc.reason)


def _error_aggregates(records: list) -> dict:
    """Error aggregates (mm) over the scored frames among ``records``."""
    scored = [r for r in records if r.get("mean_error_mm") is not None]

    def agg(key, fn):
        vals = np.array([r[key] for r in scored], float)
        return _finite(fn(vals)) if vals.size else None

    return {
        "scored_frames": len(scored),
        "mean_error_mm": agg("mean_error_mm", np.mean),
        "max_error_mm": agg("max_error_mm", np.max),
        "tip_error_mm_median": agg("tip_error_mm", np.median),
        "tip_error_mm_max": agg("tip_error_mm", np.max),
        "length_error_mm_median": agg("length_error_mm", np.median),
    }


def summarize(records: list, method: str, params, session_dir, mm_px: float, selfcheck: SelfCheckParams | None = None) -> dict:
    """Aggregate per-frame records into the summary.json document.

    Error and time aggregates are over the ``ok`` frames (as before the
    self-check existed); ``reconstructed`` holds the same over ``ok`` and
    ``suspect`` frames together.
    """
    ok = [r for r in records if r["status"] == "ok"]
    suspect = [r for r in records if r["status"] == "suspect"]
    done = [r for r in records if r["status"] in ("ok", "suspect")]
    errors = _error_aggregates(ok)
    ms = np.array([r["ms"] for r in ok]) if ok else np.array([])
    ms_done = np.array([r["ms"] for r in done]) if done else np.array([])
    # Largest voxel edge of each frame (methods that carve voxels).
    voxel = np.array([max(r["voxel_size_mm"]) for r in ok if r.get("voxel_size_mm")], float)
    check_ms = np.array([r["selfcheck"]["ms"] for r in done if (r.get("selfcheck") or {}).get("ms") is not None], float)

    return {
        "format": "ctr-bench-summary",
        "version": 1,
        "method": method,
        "params": params_to_dict(params),
        "session": str(session_dir),
        "frames": len(records),
        "ok_frames": len(ok),
        "suspect_frames": len(suspect),
        "failed_frames": sum(r["status"] == "failed" for r in records),
        "jump_frames": sum(bool(r.get("jump_flag")) for r in records),
        "suspect_list": [r["frame"] for r in suspect],
        "mm_per_px": mm_px,
        **errors,
        "reconstructed": {
            "frames": len(done),
            **_error_aggregates(done),
            "ms_per_pair_median": _finite(np.median(ms_done)) if ms_done.size else None,
            "ms_per_pair_p95": _finite(np.percentile(ms_done, 95)) if ms_done.size else None,
        },
        "selfcheck": params_to_dict(selfcheck) if selfcheck is not None else None,
        "selfcheck_ms_median": _finite(np.median(check_ms)) if check_ms.size else None,
        "selfcheck_ms_max": _finite(np.max(check_ms)) if check_ms.size else None,
        "voxel_edge_mm_median": _finite(np.median(voxel)) if voxel.size else None,
        "voxel_edge_mm_max": _finite(np.max(voxel)) if voxel.size else None,
        "ms_per_pair_median": _finite(np.median(ms)) if ms.size else None,
        "ms_per_pair_p95": _finite(np.percentile(ms, 95)) if ms.size else None,
        "per_frame": records,
    }


def _prepare_check(session: Session, method: str, params, backgrounds: dict, selfcheck):
    """The self-check model and the tube radii (mm) it draws with; ``(None, None)`` when ``selfcheck`` is None."""
    if selfcheck is None:
        return None, None
    radii_mm = selfcheck_tube_radii_mm(session, params)
    if radii_mm is None:
        raise SessionError(f"{session.dir / 'session.json'}: no robot tubes and method {method!r} has no tube radii: "
                           "the self-check cannot draw the tube (reconstruct_session(selfcheck=None) skips it)")
    try:
        return prepare_selfcheck(session.rig, backgrounds, selfcheck), radii_mm
    except ValueError as exc:
        raise SessionError(_background_error(session, exc)) from None


def _describe(rec: dict, result, pts: np.ndarray) -> None:
    """What a reconstructed frame's record says of its backbone (points, length, tip, stages' times, voxels)."""
    rec.update(
        n_points=int(len(pts)),
        length_mm=_finite(result.length_mm),
        tip_world_mm=[float(v) for v in result.tip_world_mm],
        transition_s_mm=_finite(result.transition_s_mm),
        timings_ms={k: round(float(v), 3) for k, v in result.timings_ms.items()},
    )
    voxel = getattr(result, "voxel_size_mm", None)
    if voxel is not None:
        rec["voxel_size_mm"] = [float(v) for v in np.broadcast_to(np.asarray(voxel, float), (3,))]


def _score(rec: dict, session: Session, index: int, pts: np.ndarray) -> None:
    """The frame's errors against the session's ground truth, if it has any; a bad truth file costs the score only."""
    try:
        truth = session.truth(index)
        if truth is not None:
            if "backbone_world_mm" not in truth:
                raise SessionError(f"{session.dir / 'truth' / f'{index:06d}.npz'}: no backbone_world_mm array")
            errs = backbone_errors(pts, truth["backbone_world_mm"], session.rig)
            rec.update({k: _finite(v) for k, v in errs.items()})
    except Exception as exc:  # noqa: BLE001 - a bad truth file costs the score, not the frame
        rec["note"] = f"not scored: {_one_line(exc)}"


def reconstruct_session(session_dir, out_dir, method: str = "paper", params=None, progress=None, frames=None,
                        selfcheck: SelfCheckParams | None = SelfCheckParams()) -> dict:
    """Reconstruct (and score, when the session has ground truth) every frame.

    Parameters
    ----------
    session_dir : path
        A session directory (docs/session-format.md).
    out_dir : path
        Created if missing; CSVs, NPZ and summary.json go there.
    method : str
        A name from :data:`recon.methods.METHODS`.
    params : dataclass, optional
        The method's parameters (defaults when None).
    progress : callable(stage, done, total, **postfix), optional
    frames : iterable of int, optional
        Frame indices to do (default: all committed frames).
    selfcheck : SelfCheckParams or None
        Judge every reconstructed backbone against its images
        (:mod:`recon.selfcheck`); a frame that fails is ``suspect``. None
        disables it (to measure what a run reports without it).

    Returns
    -------
    dict
        The summary (also written to ``out_dir/summary.json``).

    Raises
    ------
    SessionError, ValueError
        Set-up problems (missing files, too few background frames...), one line
        naming the file. Problems of single frames never raise: they are recorded
        as ``failed`` with their reason and the run goes on.
    """
    session = Session(session_dir)
    m = get_method(method)
    params = params if params is not None else m.params_type()
    out = Path(out_dir)
    (out / "frames").mkdir(parents=True, exist_ok=True)
    backgrounds = load_background_frames(session)
    try:
        reconstruct = m.prepare(session.rig, backgrounds, params)
    except ValueError as exc:  # FrameError included
        raise SessionError(_background_error(session, exc)) from None
    check_model, radii_mm = _prepare_check(session, method, params, backgrounds, selfcheck)
    mm_px = mm_per_pixel(session)
    wanted = set(frames) if frames is not None else None
    todo = [f for f in session.frames if wanted is None or f.index in wanted]
    records, backbones = [], {}
    with FrameTable(out / "frames.csv") as table:
        for n, fr in enumerate(todo):
            rec = {"frame": fr.index, "t_s": fr.t_s, "status": "ok", "reason": None}
            # Whatever goes wrong with one frame is that frame's failure, with a
            # one-line reason; the run goes on and keeps what it has written.
            try:
                images = session.frame_images(fr.index)
                for cam, img in images.items():
                    c = session.rig[cam]
                    if img.shape != (c.height, c.width):
                        raise FrameError(f"image is {img.shape[1]}x{img.shape[0]} but the calibration is {c.width}x{c.height}", cam)
                t0 = time.perf_counter()
                result = reconstruct(images)
                rec["ms"] = 1e3 * (time.perf_counter() - t0)
                pts = np.asarray(result.points_world_mm, float)
                if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] == 0 or not np.all(np.isfinite(pts)):
                    raise FrameError("the reconstruction has no valid backbone point")
            except Exception as exc:  # noqa: BLE001 - per-frame isolation is the point
                if os.environ.get("CTR_BENCH_DEBUG") and not isinstance(exc, (FrameError, SessionError)):
                    raise  # a developer asked to see where an unforeseen failure comes from
                rec.pop("ms", None)
                rec.update(status="failed", reason=_one_line(exc))
            if rec["status"] == "ok":
                # The fast method's temporal check: recorded, the frame stays as the self-check judges it.
                rec["jump_flag"] = bool(getattr(result, "jump_flag", False))
                rec["jump_reason"] = getattr(result, "jump_reason", None) if rec["jump_flag"] else None
                if check_model is not None:
                    selfcheck_record(rec, check_model, images, pts, radii_mm, selfcheck)
                own = getattr(result, "suspect_reason", None)
                if own and rec["status"] == "ok":  # the method's own doubt (recorded when the check passed)
                    rec.update(status="suspect", reason=str(own))
                backbones[fr.index] = pts
                write_backbone_csv(out / "frames" / f"{fr.index:06d}.csv", pts)
                _describe(rec, result, pts)
                _score(rec, session, fr.index, pts)
            records.append(rec)
            table.add(rec)
            summary = summarize(records, method, params, session.dir, mm_px, selfcheck)
            write_json_atomic(out / "summary.json", summary)
            if progress:
                post = {"ms": f"{rec['ms']:.0f}"} if rec["status"] == "ok" else {rec["status"]: fr.index}
                progress("reconstruct", n + 1, len(todo), **post)
    np.savez_compressed(
        out / "backbones.npz",
        frames=np.array(sorted(backbones), dtype=np.int64),
        **{f"frame_{i:06d}": p for i, p in backbones.items()},
    )
    summary = summarize(records, method, params, session.dir, mm_px, selfcheck)
    write_json_atomic(out / "summary.json", summary)
    return summary


def format_table(summary: dict) -> str:
    """The per-frame table printed at the end of ``run`` and ``reconstruct``."""
    px = summary.get("mm_per_px") or float("nan")
    lines = [f"{'frame':>5}  {'tip mm':>7}  {'mean mm':>7}  {'max mm':>7}  {'ms/pair':>7}  status"]

    def f(v, w=7, p=3):
        return f"{v:{w}.{p}f}" if v is not None else f"{'-':>{w}}"

    for r in summary["per_frame"]:
        status = "ok" if r["status"] == "ok" else f"{r['status']}: {r['reason']}"
        if r.get("jump_flag"):
            status += f" (jump: {r.get('jump_reason')})"
        lines.append(
            f"{r['frame']:>5}  {f(r.get('tip_error_mm'))}  {f(r.get('mean_error_mm'))}  {f(r.get('max_error_mm'))}  {f(r.get('ms'), p=1)}  {status}"
        )
    s = summary
    lines.append("")
    counts = f"{s['frames']} frames, {s['failed_frames']} failed"
    if s.get("suspect_frames") is not None:
        counts += f", {s['suspect_frames']} suspect" if s.get("selfcheck") is not None else " (self-check off)"
    if s.get("jump_frames"):
        counts += f", {s['jump_frames']} with a temporal jump"
    lines.append(f"method {s['method']}: {counts}; pixel footprint {px:.4f} mm")
    if s.get("mean_error_mm") is not None:
        lines.append(
            f"mean error {s['mean_error_mm']:.3f} mm ({s['mean_error_mm'] / px:.2f} px), "
            f"max error {s['max_error_mm']:.3f} mm ({s['max_error_mm'] / px:.2f} px), "
            f"tip error median {s['tip_error_mm_median']:.3f} mm ({s['tip_error_mm_median'] / px:.2f} px), "
            f"max {s['tip_error_mm_max']:.3f} mm"
        )
    if s.get("voxel_edge_mm_median") is not None:
        lines.append(
            f"voxel edge (largest of the three) median {s['voxel_edge_mm_median']:.3f} mm, max {s['voxel_edge_mm_max']:.3f} mm"
            + (f"; mean error {s['mean_error_mm'] / s['voxel_edge_mm_median']:.2f} voxel" if s.get("mean_error_mm") is not None else "")
        )
    rec = s.get("reconstructed") or {}
    if s.get("suspect_frames") and rec.get("mean_error_mm") is not None:
        lines.append(
            f"with the {s['suspect_frames']} suspect frames: mean error {rec['mean_error_mm']:.3f} mm ({rec['mean_error_mm'] / px:.2f} px), "
            f"max error {rec['max_error_mm']:.3f} mm ({rec['max_error_mm'] / px:.2f} px)"
        )
    if s.get("ms_per_pair_median") is not None:
        line = f"time per pair: median {s['ms_per_pair_median']:.1f} ms, p95 {s['ms_per_pair_p95']:.1f} ms"
        if s.get("selfcheck_ms_median") is not None:
            line += f"; self-check median {s['selfcheck_ms_median']:.1f} ms, max {s['selfcheck_ms_max']:.1f} ms"
        lines.append(line)
    return "\n".join(lines)
