"""The per-frame backbone CSV of a run (``frames/NNNNNN.csv``) and the run's frame table (``frames.csv``).

One owner for both formats (docs/outputs.md):

* ``frames/NNNNNN.csv``: ``s_mm,x_mm,y_mm,z_mm,tx,ty,tz``, base first: arc
  length from the first point (mm), the point (world, mm) and the unit
  tangent (world). Files of older runs hold ``x_mm,y_mm,z_mm`` only; both read back.
* ``frames.csv``: one row per frame, appended as the run goes:
  ``frame,t_s,status,reason,n_points,length_mm,mean_error_mm,max_error_mm,tip_error_mm,ms``
  (empty where a figure is unknown).
"""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from recon.backbone import arc_length

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


def write_backbone_csv(path, points_mm) -> None:
    """Write a backbone (n, 3) world mm, base first, with its arc length and tangents."""
    p = np.asarray(points_mm, np.float64).reshape(-1, 3)
    s = arc_length(p) if len(p) else np.zeros(0)
    rows = np.column_stack([s, p, _tangents(p)])
    np.savetxt(path, rows, delimiter=",", fmt=["%.4f"] * 4 + ["%.6f"] * 3, header=",".join(BACKBONE_COLUMNS), comments="")


def read_backbone_csv(path) -> np.ndarray:
    """The backbone (n, 3) world mm of a ``frames/NNNNNN.csv`` (either column layout).

    Raises ``ValueError`` naming the file when it has no ``x_mm,y_mm,z_mm`` columns or is unreadable.
    """
    path = Path(path)
    with open(path) as fh:
        header = fh.readline().strip().split(",")
    try:
        cols = [header.index(c) for c in ("x_mm", "y_mm", "z_mm")]
    except ValueError:
        raise ValueError(f"{path}: not a backbone CSV (header {','.join(header)!r}, need x_mm,y_mm,z_mm)") from None
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return data[:, cols].reshape(-1, 3) if data.size else np.zeros((0, 3))


class FrameTable:
    """``frames.csv`` of a run, one row appended (and flushed) per frame: an interrupted run keeps its rows."""

    def __init__(self, path):
        self._fh = open(path, "w", newline="")
        self._w = csv.writer(self._fh)
        self._w.writerow(FRAME_COLUMNS)
        self._fh.flush()

    def add(self, rec: dict) -> None:
        """Append a frame's record (the per-frame dict of summary.json)."""
        def cell(k):
            v = rec.get(k)
            return "" if v is None else (f"{v:.6g}" if isinstance(v, float) else v)

        self._w.writerow([cell(k) for k in FRAME_COLUMNS])
        self._fh.flush()

    def close(self) -> None:
        self._fh.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
