"""Tubes that show one side only: a shiny tube whose shaded side is as gray as the backdrop.

Such a view shows the highlight along the lit side of the tube and little else: the edges found are the
highlight's, and a centerline drawn between them runs off the tube's axis by half the width missing. The
image does not tell which side is lit (the highlight's profile is as sharp on both sides). The rig does: the
outer tube leaves the base along the robot's axis, whose image the calibration gives, and a narrow stretch
there that runs parallel to that line, off it by half the missing width, tells the lit side and the fraction
of the width shown (:func:`lit_side`). :func:`half_lit_moves` then says how far each narrow cross-section of
the view moves. All positions are image pixels (px), OpenCV convention.
"""
from __future__ import annotations

import numpy as np

from ._kernels import running_rank_nb

__all__ = ["BASE_STRETCH", "HALF_LIT_FRACTION", "lit_side", "half_lit_moves"]

#: The first cross-sections from the base that tell which side of the tube a view lights (~48 px at 2 px).
BASE_STRETCH = 24

#: A cross-section narrower than this fraction of the tube's width shows one side of it only.
HALF_LIT_FRACTION = 0.7


def lit_side(base_px, axis_px, full_px: float, c: np.ndarray, d: np.ndarray, width: np.ndarray) -> tuple:
    """Which side of the tube's axis the first centres of a view lie on, where they show one side of the
    outer tube only, and which fraction of its width they show.

    Parameters
    ----------
    base_px, axis_px : (2,) array_like
        The robot's base (px) and the direction of its axis in the image.
    full_px : float
        The outer tube's width (px) at the base (or where the robot enters the view).
    c, d : (k, 2) arrays
        The first centres from the base on (px) and the curve's unit tangents there.
    width : (k,) array
        Their widths (px).

    Returns
    -------
    (side, fraction) : (float, float)
        ``side`` +1 or -1 along the normal ``(-d_y, d_x)``, or 0 where the stretch does not tell; the
        fraction of the tube's width it shows (1 where it does not tell).

    Notes
    -----
    It tells where most of the stretch is narrower than :data:`HALF_LIT_FRACTION` of the tube and those
    narrow centres, at least 1 px short of it on each side, run parallel to the axis (the offset changing
    by no more than 0.02 px a px, scattered by no more than 0.5 px) 0.6-1.4 times half the missing width
    off it. A tube that bends away from the axis does not run parallel to it, and a full one is not narrow.
    The cross-sections at the base itself can read full (the base's own edges).
    """
    a = np.asarray(axis_px, np.float64)
    if not np.linalg.norm(a) > 1e-9 or len(width) < 4:
        return 0.0, 1.0  # the axis seen end on: no line to run parallel to
    a = a / np.linalg.norm(a)
    narrow = (width < HALF_LIT_FRACTION * full_px) & (d @ a > 0.95)
    if 2 * narrow.sum() < len(width):
        return 0.0, 1.0
    w0 = float(np.median(width[narrow]))
    half = 0.5 * (full_px - w0)
    rel = c[narrow] - np.asarray(base_px, np.float64)
    along, off = rel @ a, rel @ np.array([-a[1], a[0]])  # the axis's normal: fitted tangents can bend towards the base's edges
    if np.ptp(along) < 4.0:
        return 0.0, 1.0
    slope, o0 = np.polyfit(along, off, 1)
    resid = off - (slope * along + o0)
    o = float(np.median(off))
    if half < 1.0 or abs(slope) > 0.02 or float(np.std(resid)) > 0.5 or not 0.6 * half <= abs(o) <= 1.4 * half:
        return 0.0, 1.0
    return float(np.sign(o)), w0 / full_px


def half_lit_moves(width: np.ndarray, fraction: float, thinnest_px: float, outer_px: float) -> tuple:
    """Which cross-sections of a view whose base stretch shows ``fraction`` of the tube are narrow, the
    width each should have, and how far its centre moves away from the lit side.

    A cross-section narrower than :data:`HALF_LIT_FRACTION` of the running 80th percentile of the widths
    (41 cross-sections), or of the thinnest tube where that is wider, is taken to show the same fraction:
    its width is ``width / fraction``, within 0.8 times the thinnest tube's and 1.2 times the outer one's,
    and its centre lies half the difference away from the lit side.

    Parameters
    ----------
    width : (n,) array
        The widths (px) of the view's cross-sections, base to tip.
    fraction : float
        From :func:`lit_side`.
    thinnest_px, outer_px : float
        The thinnest and the outer tube's widths (px) at the base.

    Returns
    -------
    (narrow, full, move) : ((n,) bool, (m,) float, (m,) float)
        The narrow cross-sections, their widths (px) and how far (px) each centre moves, away from the lit
        side.
    """
    narrow = width < HALF_LIT_FRACTION * np.maximum(thinnest_px, running_rank_nb(np.asarray(width, np.float64), 41, 32))
    full = np.clip(width[narrow] / fraction, 0.8 * thinnest_px, 1.2 * outer_px)
    return narrow, np.maximum(full, width[narrow]), 0.5 * np.maximum(full - width[narrow], 0.0)
