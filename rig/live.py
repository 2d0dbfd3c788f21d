"""Optional live view of a run in the rerun viewer (https://rerun.io).

``ctr-bench run --live`` (and ``reconstruct --live``) log, frame by frame, both camera
images with the reprojected reconstruction and truth, the 3D backbones and the errors.
It needs the optional extra ``live`` (``pip install 'ctr-bench[live]'``, i.e. rerun-sdk,
a large download); without it a one-line message says so and the run goes on — the
static report (``rig/bench/report.py``) never needs it.

The data to log is prepared by :func:`prepare_frame` (plain numpy, testable without
rerun); :class:`LiveLogger` sends it.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from recon.rigcal import load_rig_calibration
from rig.rundir import JOURNAL, last_journal_record, record_backbone
from rig.session import read_image

__all__ = ["LiveLogger", "prepare_frame", "import_rerun", "NOT_INSTALLED"]

NOT_INSTALLED = "live view off: rerun-sdk is not installed (pip install 'ctr-bench[live]'); the run goes on without it"

RECON_RGB = (0, 114, 178)
TRUTH_RGB = (230, 159, 0)


def import_rerun():
    """The ``rerun`` module, or None when it is not installed."""
    try:
        import rerun  # noqa: F401
    except ImportError:
        return None
    return rerun


def _finite_rows(a) -> np.ndarray | None:
    if a is None:
        return None
    a = np.asarray(a, dtype=np.float32)
    a = a[np.all(np.isfinite(a), axis=1)]
    return a if len(a) >= 1 else None


def prepare_frame(frame: int, t_s: float, images: dict | None = None, backbone_mm=None, truth_mm=None,
                  errors: dict | None = None, recon_uv: dict | None = None, truth_uv: dict | None = None,
                  status: str = "ok", reason: str | None = None) -> dict:
    """What to log for one frame, as plain arrays (no rerun needed).

    Returns
    -------
    dict
        ``frame``, ``t_s`` and ``entries``: a list of ``(entity_path, kind, data, rgb)``
        with kind one of ``"image"`` (uint8 array), ``"line3d"`` ((n, 3) float32 mm),
        ``"line2d"`` ((n, 2) float32 px), ``"scalar"`` (float) and ``"text"`` (str).
        Non-finite points are dropped; unknown errors (None) are left out.
    """
    entries = []
    for cam, img in (images or {}).items():
        entries.append((f"cameras/{cam}/image", "image", np.asarray(img, dtype=np.uint8), None))
        for name, uvs, rgb in (("truth", truth_uv, TRUTH_RGB), ("reconstruction", recon_uv, RECON_RGB)):
            uv = _finite_rows((uvs or {}).get(cam))
            if uv is not None:
                entries.append((f"cameras/{cam}/{name}", "line2d", uv, rgb))
    for name, pts, rgb in (("truth", truth_mm, TRUTH_RGB), ("reconstruction", backbone_mm, RECON_RGB)):
        p = _finite_rows(pts)
        if p is not None:
            entries.append((f"world/{name}", "line3d", p, rgb))
    for key, v in (errors or {}).items():
        if v is not None and np.isfinite(v):
            entries.append((f"errors/{key}", "scalar", float(v), None))
    if status != "ok":
        entries.append(("log", "text", f"frame {frame} failed: {reason}", None))
    return {"frame": int(frame), "t_s": float(t_s), "entries": entries}


class LiveLogger:
    """Sends frames to a rerun viewer; silent no-op (after one message) without rerun-sdk.

    Parameters
    ----------
    app_id : str
    spawn : bool
        Start a viewer (rerun's default); False only records to rerun's default sink.
    rr : module, optional
        The rerun module (tests pass a stand-in); default: ``import rerun`` when installed.
    stream : file
        Where the one-line "not installed" message goes.
    """

    def __init__(self, app_id: str = "ctr-bench", spawn: bool = True, rr=None, stream=None):
        self.rr = rr if rr is not None else import_rerun()
        self.enabled = self.rr is not None
        self._stream = stream or sys.stderr
        self._logged = set()
        self._warned = False
        if not self.enabled:
            print(NOT_INSTALLED, file=self._stream)
            return
        self.rr.init(app_id, spawn=spawn)

    # ------------------------------------------------------------------ sending
    def _set_time(self, frame: int, t_s: float) -> None:
        rr = self.rr
        if hasattr(rr, "set_time"):  # rerun >= 0.23
            rr.set_time("frame", sequence=frame)
            rr.set_time("time", duration=t_s)
        else:
            rr.set_time_sequence("frame", frame)
            rr.set_time_seconds("time", t_s)

    def emit(self, prepared: dict) -> None:
        """Send a :func:`prepare_frame` result."""
        if not self.enabled:
            return
        rr = self.rr
        self._set_time(prepared["frame"], prepared["t_s"])
        scalar = getattr(rr, "Scalars", None) or getattr(rr, "Scalar")
        for path, kind, data, rgb in prepared["entries"]:
            if kind == "image":
                rr.log(path, rr.Image(data))
            elif kind == "line2d":
                rr.log(path, rr.LineStrips2D([data], colors=[rgb]))
            elif kind == "line3d":
                rr.log(path, rr.LineStrips3D([data], colors=[rgb]))
            elif kind == "scalar":
                rr.log(path, scalar(data))
            elif kind == "text":
                rr.log(path, rr.TextLog(data))

    def log_frame(self, frame: int, t_s: float, **kw) -> dict:
        """Prepare (see :func:`prepare_frame`) and send one frame; returns what was prepared."""
        prepared = prepare_frame(frame, t_s, **kw)
        self.emit(prepared)
        return prepared

    # ------------------------------------------------------------- run watching
    def watch(self, session_dir, out_dir, progress=None):
        """A ``progress(stage, done, total, **postfix)`` callable for ``reconstruct_session``.

        After each frame the run (:class:`rig.rundir.RunWriter`: ``reconstruct``, ``run``,
        ``experiment``'s ``live/``) has already appended the frame's record to its journal
        (``frames.jsonl``) and written the backbone CSV the record lists; this reads them
        through :mod:`rig.rundir` (and the session's images and truth), logs the frame, then
        calls ``progress``. Without rerun it returns ``progress`` itself.
        """
        if not self.enabled:
            return progress
        session_dir, out_dir = Path(session_dir), Path(out_dir)
        rig = None
        try:
            rig = load_rig_calibration(session_dir / "rig.json")
        except (OSError, ValueError):
            pass

        def callback(stage, done, total, **postfix):
            if progress is not None:
                progress(stage, done, total, **postfix)
            try:
                self._log_latest(session_dir, out_dir, rig)
            except Exception as exc:  # noqa: BLE001 - a live view never stops a run
                if not self._warned:
                    self._warned = True
                    print(f"live view: {type(exc).__name__}: {exc}", file=self._stream)

        return callback

    def _log_latest(self, session_dir: Path, out_dir: Path, rig) -> None:
        r = last_journal_record(out_dir / JOURNAL)
        if r is None or r["frame"] in self._logged:
            return
        fr = r["frame"]
        self._logged.add(fr)
        cams = rig.names if rig is not None else []
        images = {}
        for cam in cams:
            p = session_dir / "frames" / cam / f"{fr:06d}.png"
            if p.exists():
                images[cam] = read_image(p)
        pts = record_backbone(out_dir, r)  # ok and suspect frames list theirs; None for a failed one
        truth_mm, truth_uv = None, {}
        tp = session_dir / "truth" / f"{fr:06d}.npz"
        if tp.exists():
            with np.load(tp) as z:
                truth_mm = z["backbone_world_mm"] if "backbone_world_mm" in z.files else None
                truth_uv = {c: z[f"centerline_px_{c}"] for c in cams if f"centerline_px_{c}" in z.files}
        recon_uv = {c: rig[c].project(pts)[0] for c in cams} if pts is not None and rig is not None else {}
        errors = {k: r.get(k) for k in ("mean_error_mm", "max_error_mm", "tip_error_mm", "ms")}
        self.log_frame(fr, r.get("t_s") or 0.0, images=images, backbone_mm=pts, truth_mm=truth_mm, errors=errors,
                       recon_uv=recon_uv, truth_uv=truth_uv, status=r["status"], reason=r.get("reason"))
