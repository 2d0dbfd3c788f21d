"""Reconstruct every frame of a session directory and score it against ground truth.

Outputs (documented in ``docs/outputs.md``), written as the work goes so that an
interrupted run keeps what it finished:

* ``frames/NNNNNN.csv``: the backbone of each frame, ``x_mm,y_mm,z_mm``, base first;
* ``backbones.npz``: all backbones (``frame_NNNNNN`` arrays) and the frame indices;
* ``summary.json``: method, parameters, per-frame results and aggregates.
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

from .session import Session, SessionError

__all__ = ["reconstruct_session", "write_json_atomic", "load_background_frames", "summarize", "format_table"]


def write_json_atomic(path: Path, data: dict) -> None:
    """Write JSON to a temporary name and rename it: readers never see half a file."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(data, indent=2, allow_nan=False, default=_json_default) + "\n")
    os.replace(tmp, path)


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


def summarize(records: list, method: str, params, session_dir, mm_px: float) -> dict:
    """Aggregate per-frame records into the summary.json document."""
    ok = [r for r in records if r["status"] == "ok"]
    scored = [r for r in ok if r.get("mean_error_mm") is not None]
    ms = np.array([r["ms"] for r in ok]) if ok else np.array([])
    # Largest voxel edge of each frame (methods that carve voxels).
    voxel = np.array([max(r["voxel_size_mm"]) for r in ok if r.get("voxel_size_mm")], float)

    def agg(key, fn):
        vals = np.array([r[key] for r in scored], float)
        return _finite(fn(vals)) if vals.size else None

    return {
        "format": "ctr-bench-summary",
        "version": 1,
        "method": method,
        "params": params_to_dict(params),
        "session": str(session_dir),
        "frames": len(records),
        "failed_frames": len(records) - len(ok),
        "scored_frames": len(scored),
        "mm_per_px": mm_px,
        "mean_error_mm": agg("mean_error_mm", np.mean),
        "max_error_mm": agg("max_error_mm", np.max),
        "tip_error_mm_median": agg("tip_error_mm", np.median),
        "tip_error_mm_max": agg("tip_error_mm", np.max),
        "length_error_mm_median": agg("length_error_mm", np.median),
        "voxel_edge_mm_median": _finite(np.median(voxel)) if voxel.size else None,
        "voxel_edge_mm_max": _finite(np.max(voxel)) if voxel.size else None,
        "ms_per_pair_median": _finite(np.median(ms)) if ms.size else None,
        "ms_per_pair_p95": _finite(np.percentile(ms, 95)) if ms.size else None,
        "per_frame": records,
    }


def reconstruct_session(session_dir, out_dir, method: str = "paper", params=None, progress=None, frames=None) -> dict:
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
    mm_px = mm_per_pixel(session)
    wanted = set(frames) if frames is not None else None
    todo = [f for f in session.frames if wanted is None or f.index in wanted]
    records, backbones = [], {}
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
            backbones[fr.index] = pts
            np.savetxt(out / "frames" / f"{fr.index:06d}.csv", pts, delimiter=",", fmt="%.4f", header="x_mm,y_mm,z_mm", comments="")
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
            try:
                truth = session.truth(fr.index)
                if truth is not None:
                    if "backbone_world_mm" not in truth:
                        raise SessionError(f"{session.dir / 'truth' / f'{fr.index:06d}.npz'}: no backbone_world_mm array")
                    errs = backbone_errors(pts, truth["backbone_world_mm"])
                    rec.update({k: _finite(v) for k, v in errs.items()})
            except Exception as exc:  # noqa: BLE001 - a bad truth file costs the score, not the frame
                rec["note"] = f"not scored: {_one_line(exc)}"
        records.append(rec)
        summary = summarize(records, method, params, session.dir, mm_px)
        write_json_atomic(out / "summary.json", summary)
        if progress:
            post = {"ms": f"{rec['ms']:.0f}"} if rec["status"] == "ok" else {"failed": fr.index}
            progress("reconstruct", n + 1, len(todo), **post)
    np.savez_compressed(
        out / "backbones.npz",
        frames=np.array(sorted(backbones), dtype=np.int64),
        **{f"frame_{i:06d}": p for i, p in backbones.items()},
    )
    summary = summarize(records, method, params, session.dir, mm_px)
    write_json_atomic(out / "summary.json", summary)
    return summary


def format_table(summary: dict) -> str:
    """The per-frame table printed at the end of ``run`` and ``reconstruct``."""
    px = summary.get("mm_per_px") or float("nan")
    lines = [f"{'frame':>5}  {'tip mm':>7}  {'mean mm':>7}  {'max mm':>7}  {'ms/pair':>7}  status"]

    def f(v, w=7, p=3):
        return f"{v:{w}.{p}f}" if v is not None else f"{'-':>{w}}"

    for r in summary["per_frame"]:
        status = "ok" if r["status"] == "ok" else f"failed: {r['reason']}"
        lines.append(
            f"{r['frame']:>5}  {f(r.get('tip_error_mm'))}  {f(r.get('mean_error_mm'))}  {f(r.get('max_error_mm'))}  {f(r.get('ms'), p=1)}  {status}"
        )
    s = summary
    lines.append("")
    lines.append(f"method {s['method']}: {s['frames']} frames, {s['failed_frames']} failed; pixel footprint {px:.4f} mm")
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
    if s.get("ms_per_pair_median") is not None:
        lines.append(f"time per pair: median {s['ms_per_pair_median']:.1f} ms, p95 {s['ms_per_pair_p95']:.1f} ms")
    return "\n".join(lines)
