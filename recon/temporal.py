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

from .geometry import arc_length, interp_rows

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


def shape_distance(a: np.ndarray, b: np.ndarray, step_mm: float = 2.0, sa=None, sb=None) -> float:
    """Largest distance between two backbones at equal arc length, over their common length.

    Parameters
    ----------
    a, b : (n, 3) and (m, 3) arrays
        Backbones, base first (world, mm).
    step_mm : float, optional
        Arc-length step (mm) of the samples compared, from the base.
    sa, sb : (n,) and (m,) arrays, optional
        :func:`recon.geometry.arc_length` of ``a`` and ``b`` (mm), where the caller has them already.

    Returns
    -------
    float
        The largest distance (mm) between ``a`` and ``b`` at the same arc length.
    """
    sa = arc_length(a) if sa is None else sa
    sb = arc_length(b) if sb is None else sb
    s = np.arange(0.0, min(sa[-1], sb[-1]) + 1e-9, step_mm)
    if not s.size:
        return 0.0
    return float(np.max(np.linalg.norm(interp_rows(s, sa, a) - interp_rows(s, sb, b), axis=1)))


def jump_check(prev_points, prev_tip, points, tip, limits: JumpLimits = JumpLimits()) -> str | None:
    """The reason this backbone is an implausible jump from the previous one, or None.

    Parameters
    ----------
    prev_points, points : (n, 3) arrays or None
        Previous and current backbones, base first (world, mm); ``prev_points`` None for the first frame.
    prev_tip, tip : (3,) arrays
        Previous and current tip (world, mm).
    limits : JumpLimits, optional
        Largest plausible changes.

    Returns
    -------
    str or None
        Every limit exceeded, with the change (mm), joined by ``"; "``; None when none is (or there is no
        previous frame).
    """
    if prev_points is None:
        return None
    reasons = []
    dtip = float(np.linalg.norm(np.asarray(tip) - np.asarray(prev_tip)))
    if dtip > limits.tip_mm:
        reasons.append(f"tip moved {dtip:.1f} mm (> {limits.tip_mm:g})")
    sa, sb = arc_length(prev_points), arc_length(points)
    la, lb = float(sa[-1]), float(sb[-1])
    if abs(lb - la) > limits.length_mm:
        reasons.append(f"length changed {lb - la:+.1f} mm (> {limits.length_mm:g})")
    ds = shape_distance(prev_points, points, sa=sa, sb=sb)
    if ds > limits.shape_mm:
        reasons.append(f"shape moved up to {ds:.1f} mm (> {limits.shape_mm:g})")
    return "; ".join(reasons) if reasons else None
