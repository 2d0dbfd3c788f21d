"""The per-frame backbone CSV of a run (``frames/NNNNNN.csv``) and the run's frame table (``frames.csv``).

One owner for both formats (docs/outputs.md):

* ``frames/NNNNNN.csv``: ``s_mm,x_mm,y_mm,z_mm,tx,ty,tz``, base first: arc
  length from the first point (mm), the point (world, mm) and the unit
  tangent (world). Files of older runs hold ``x_mm,y_mm,z_mm`` only; both read back.
* ``frames.csv``: one row per frame, appended as the run goes:
  ``frame,t_s,status,reason,n_points,length_mm,mean_error_mm,max_error_mm,tip_error_mm,ms``
  (empty where a figure is unknown, NaN and infinities included).

:func:`write_backbone_csv` returns the SHA-1 of the bytes it wrote; the run's
summary records it with the file name, so that a reader can tell the file the
run wrote from a stale one of another run (:func:`read_backbone_csv` ``sha1=``).
"""
from __future__ import annotations

import csv
import hashlib
import io
import math
from pathlib import Path

import numpy as np

from recon.geometry import arc_length

__all__ = ["BACKBONE_COLUMNS", "FRAME_COLUMNS", "write_backbone_csv", "read_backbone_csv", "FrameTable"]

BACKBONE_COLUMNS = ("s_mm", "x_mm", "y_mm", "z_mm", "tx", "ty", "tz")
FRAME_COLUMNS = ("frame", "t_s", "status", "reason", "n_points", "length_mm", "mean_error_mm", "max_error_mm", "tip_error_mm", "ms")


def _tangents(points_mm: np.ndarray) -> np.ndarray:
    """Unit tangents (n, 3) of a polyline (zero where it has no length)."""
    if len(points_mm) < 2:
        return np.zeros_like(points_mm)
    t = np.gradient(points_mm, axis=0)
    n = np.linalg.norm(t, axis=1, keepdims=True)
    return np.divide(t, n, out=np.zeros_like(t), where=n > 0)


def write_backbone_csv(path, points_mm) -> str:
    """Write a backbone (n, 3) world mm, base first, with its arc length and tangents; returns the file's SHA-1 (hex)."""
    p = np.asarray(points_mm, np.float64).reshape(-1, 3)
    s = arc_length(p) if len(p) else np.zeros(0)
    rows = np.column_stack([s, p, _tangents(p)])
    buf = io.BytesIO()
    np.savetxt(buf, rows, delimiter=",", fmt=["%.4f"] * 4 + ["%.6f"] * 3, header=",".join(BACKBONE_COLUMNS), comments="")
    data = buf.getvalue()
    Path(path).write_bytes(data)
    return hashlib.sha1(data).hexdigest()


def read_backbone_csv(path, sha1: str | None = None) -> np.ndarray:
    """The backbone (n, 3) world mm of a ``frames/NNNNNN.csv`` (either column layout).

    Parameters
    ----------
    path : path
    sha1 : str, optional
        The SHA-1 the writing run recorded: other bytes are another run's file.

    Raises
    ------
    ValueError
        Naming the file: no ``x_mm,y_mm,z_mm`` columns, unreadable, or not the file the run wrote.
    """
    path = Path(path)
    data = path.read_bytes()
    if sha1 is not None and hashlib.sha1(data).hexdigest() != sha1:
        raise ValueError(f"{path}: not the file the run wrote (its SHA-1 differs from summary.json's: a stale file of "
                         "another run, or edited since; reconstruct again with --overwrite)")
    header = data.split(b"\n", 1)[0].decode("utf-8", "replace").strip().split(",")
    try:
        cols = [header.index(c) for c in ("x_mm", "y_mm", "z_mm")]
    except ValueError:
        raise ValueError(f"{path}: not a backbone CSV (header {','.join(header)!r}, need x_mm,y_mm,z_mm)") from None
    try:
        rows = np.loadtxt(io.BytesIO(data), delimiter=",", skiprows=1, ndmin=2)
    except ValueError as exc:
        raise ValueError(f"{path}: unreadable ({' '.join(str(exc).split())})") from None
    return rows[:, cols].reshape(-1, 3) if rows.size else np.zeros((0, 3))


def _cell(v):
    """A frames.csv cell: empty for unknown (None, NaN, inf), floats to 6 significant digits."""
    if v is None or (isinstance(v, (float, np.floating)) and not math.isfinite(v)):
        return ""
    return f"{v:.6g}" if isinstance(v, (float, np.floating)) else v


class FrameTable:
    """``frames.csv`` of a run, one row appended (and flushed) per frame: an interrupted run keeps its rows.

    Parameters
    ----------
    path : path
    records : list of dict, optional
        Rows to write first (the frames a resumed run keeps).
    """

    def __init__(self, path, records=()):
        self.path = Path(path)
        self._fh = open(self.path, "w", newline="")
        self._w = csv.writer(self._fh)
        self._w.writerow(FRAME_COLUMNS)
        for rec in records:
            self._w.writerow([_cell(rec.get(k)) for k in FRAME_COLUMNS])
        self._fh.flush()

    def add(self, rec: dict) -> None:
        """Append a frame's record (the per-frame dict of summary.json)."""
        self._w.writerow([_cell(rec.get(k)) for k in FRAME_COLUMNS])
        self._fh.flush()

    def close(self) -> None:
        self._fh.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
