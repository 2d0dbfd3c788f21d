"""Frame-to-frame consistency of the ``fast`` method: flag shapes that jump implausibly.

A concentric tube robot moves by its actuators' insertion and rotation; between
two frames its tip cannot move, its length cannot change and its shape cannot
deform by more than the actuation allows. :func:`jump_check` compares a new
backbone with the previous frame's and returns a reason when one of those
limits is exceeded. The frame is still returned (the jump may be real, e.g.
frames dropped), but flagged, so downstream users (``summary.json``) can tell.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["JumpLimits", "jump_check", "shape_distance"]


@dataclass(frozen=True)
class JumpLimits:
    """Largest plausible change between consecutive frames.

    Attributes
    ----------
    tip_mm : float
        Tip displacement (mm).
    length_mm : float
        Change of backbone length (mm), i.e. insertion between frames.
    shape_mm : float
        Largest distance between the two backbones at equal arc length from
        the base, over their common length (mm).
    """

    tip_mm: float = 25.0
    length_mm: float = 15.0
    shape_mm: float = 25.0


def _at_arc_length(points: np.ndarray, s: np.ndarray) -> np.ndarray:
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    return np.stack([np.interp(s, cum, points[:, j]) for j in range(3)], axis=1), cum[-1]


def shape_distance(a: np.ndarray, b: np.ndarray, step_mm: float = 2.0) -> float:
    """Largest distance (mm) between backbones ``a`` and ``b`` at equal arc length, over the common length."""
    la = float(np.sum(np.linalg.norm(np.diff(a, axis=0), axis=1)))
    lb = float(np.sum(np.linalg.norm(np.diff(b, axis=0), axis=1)))
    s = np.arange(0.0, min(la, lb) + 1e-9, step_mm)
    pa, _ = _at_arc_length(a, s)
    pb, _ = _at_arc_length(b, s)
    return float(np.max(np.linalg.norm(pa - pb, axis=1))) if s.size else 0.0


def jump_check(prev_points, prev_tip, points, tip, limits: JumpLimits = JumpLimits()) -> str | None:
    """The reason this backbone is an implausible jump from the previous one, or None.

    Parameters
    ----------
    prev_points, points : (n, 3) arrays
        Previous and current backbones, base first (mm).
    prev_tip, tip : (3,) arrays
    limits : JumpLimits
    """
    if prev_points is None:
        return None
    reasons = []
    dtip = float(np.linalg.norm(np.asarray(tip) - np.asarray(prev_tip)))
    if dtip > limits.tip_mm:
        reasons.append(f"tip moved {dtip:.1f} mm (> {limits.tip_mm:g})")
    la = float(np.sum(np.linalg.norm(np.diff(prev_points, axis=0), axis=1)))
    lb = float(np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1)))
    if abs(lb - la) > limits.length_mm:
        reasons.append(f"length changed {lb - la:+.1f} mm (> {limits.length_mm:g})")
    ds = shape_distance(prev_points, points)
    if ds > limits.shape_mm:
        reasons.append(f"shape moved up to {ds:.1f} mm (> {limits.shape_mm:g})")
    return "; ".join(reasons) if reasons else None
