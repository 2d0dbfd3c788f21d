"""A stretch of tube one view lost, found again along the other view's rays.

Where one view's tube fades into the backdrop (a few gray levels off it, often
where its polarity flips on a gradient) and the other view still sees it, the
second view's centerline beyond the first one's end gives, sample by sample, a
ray the tube lies on. Projected into the first view each ray is an epipolar
line, and the tube crosses it once. This module finds those crossings as one
path: candidate points along each ray (world, mm), scored by how much the first
view's background difference looks like a tube there (:func:`tube_contrast`), joined by dynamic
programming under a bound on the step in 3D (the tube cannot jump), shortest
paths preferred (where no view shows the tube, its depth is interpolated
straight between the stretches that do show it).

Pure functions over arrays; :mod:`recon.fast` prepares their inputs and judges
what they find.
"""
from __future__ import annotations

import cv2
import numpy as np

from ._kernels import best_path_nb

__all__ = ["tube_contrast", "ray_candidates", "ray_points", "strongest_candidates", "best_path"]


def tube_contrast(diff: np.ndarray, origin_px, uv: np.ndarray, normals: np.ndarray, radius_px: float) -> np.ndarray:
    """How tube-like the background difference is at points ``uv`` across ``normals``, in robust sigmas (>= 0).

    The mean difference over the tube's middle (+- r/2) against each side
    (1.5 r + 1 to 2.5 r + 1 out): the smaller of the two steps where both have
    the same sign, else 0. A tube of either polarity gives its contrast; the
    edge of a backdrop object left in the difference by a lighting change (one
    side only) gives nothing. Scaled by the median absolute value of all the
    points' readings (most of them lie on backdrop).

    Parameters
    ----------
    diff : (h, w) float32
        Frame minus background over a box (gray levels).
    origin_px : (2,)
        The box's top-left pixel (x0, y0).
    uv : (m, 2)
        Points (image frame, px).
    normals : (m, 2)
        Unit directions across the tube there.
    radius_px : float
        The tube's radius in this view (px).

    Returns
    -------
    (m,) float32
    """
    r = max(float(radius_px), 1.0)
    mid = np.array([-0.5, 0.0, 0.5]) * r
    side = 1.5 * r + 1.0 + np.array([0.0, 0.5, 1.0]) * r

    def mean_at(offsets):
        p = uv[:, None, :] + offsets[None, :, None] * normals[:, None, :] - np.asarray(origin_px, np.float64)
        return _sample(diff, p.reshape(-1, 2)).reshape(len(uv), len(offsets)).mean(axis=1)

    c, lo, hi = mean_at(mid), mean_at(-side), mean_at(side)
    step_lo, step_hi = c - lo, c - hi
    resp = np.where(step_lo * step_hi > 0, np.minimum(np.abs(step_lo), np.abs(step_hi)), 0.0)
    scale = max(float(np.median(np.abs(c - 0.5 * (lo + hi)))) / 0.6745, 1e-3)
    return (resp / scale).astype(np.float32)


def _sample(img: np.ndarray, xy: np.ndarray, width: int = 1024) -> np.ndarray:
    """``img`` at points ``xy`` (n, 2) px, bilinear, the border replicated: (n,) float32.

    cv2.remap takes maps under 32767 rows and columns, so the points are laid out ``width`` to a row (a guided
    search reads 240 candidates on each of a few hundred rays: wide-1-53 frame 1 gave over 100,000)."""
    n = len(xy)
    pad = np.zeros((-n % width, 2))
    grid = np.vstack([xy, pad]).astype(np.float32).reshape(-1, width, 2)
    v = cv2.remap(img, grid[..., 0], grid[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return v.reshape(-1)[:n]


def ray_candidates(center_mm: np.ndarray, dirs: np.ndarray, start_mm: np.ndarray, reach_mm: np.ndarray,
                   n: int) -> np.ndarray:
    """``n`` points on each ray within ``reach_mm`` of ``start_mm`` (world, mm): (K, n, 3).

    Parameters
    ----------
    center_mm, dirs : (3,), (K, 3)
        The rays' origin and unit directions, as in :func:`ray_points`.
    start_mm : (3,)
        Where the path starts (the last point both views see).
    reach_mm : (K,)
        How far from ``start_mm`` each ray's point can lie (mm).
    n : int
        Candidates per ray, evenly spaced in depth.

    Returns
    -------
    (K, n, 3) float array
        The candidates (world, mm), ray by ray, nearest the camera first.
    """
    lam_c = (start_mm - center_mm) @ dirs.T  # depth of each ray's point closest to the start
    d_perp2 = np.sum((center_mm + lam_c[:, None] * dirs - start_mm) ** 2, axis=1)
    half = np.sqrt(np.maximum(reach_mm ** 2 - d_perp2, 0.0))
    return ray_points(center_mm, dirs, lam_c - half, lam_c + half, n)


def ray_points(center_mm: np.ndarray, dirs: np.ndarray, depth_lo_mm, depth_hi_mm, n: int) -> np.ndarray:
    """``n`` points on each ray, evenly spaced in depth from ``depth_lo_mm`` to ``depth_hi_mm``.

    Parameters
    ----------
    center_mm : (3,)
        The rays' origin (the camera centre, world mm).
    dirs : (K, 3)
        Unit ray directions (world).
    depth_lo_mm, depth_hi_mm : float or (K,)
        The nearest and farthest depth (mm along each ray): scalars give one
        depth grid for every ray.
    n : int
        Points per ray.

    Returns
    -------
    (K, n, 3) float array
        The points (world, mm), ray by ray, nearest the camera first.
    """
    lo = np.broadcast_to(np.asarray(depth_lo_mm, float), (len(dirs),))
    hi = np.broadcast_to(np.asarray(depth_hi_mm, float), (len(dirs),))
    lam = lo[:, None] + (hi - lo)[:, None] * np.linspace(0.0, 1.0, n)[None, :]
    return center_mm + lam[..., None] * dirs[:, None, :]


def strongest_candidates(contrast: np.ndarray, n_even: int, n_peaks: int) -> np.ndarray:
    """Per ray, which of many candidates a path search looks at.

    ``n_even`` evenly spaced ones (where no view shows the tube, the path
    crosses at the depth it interpolates) and the ``n_peaks`` highest local
    maxima of the contrast along the ray (where the tube crosses it: a tube a
    few px wide falls between evenly spaced candidates that are not dense).

    Parameters
    ----------
    contrast : (K, N)
        Each candidate's tube contrast (:func:`tube_contrast`), candidates in
        depth order along each of the K rays.
    n_even : int
        Evenly spaced candidates kept per ray (the first and last included).
    n_peaks : int
        Local maxima kept per ray, highest first.

    Returns
    -------
    (K, n_even + n_peaks) int array
        Indices into each ray's N candidates: the even ones, then the maxima.
        A ray with fewer maxima repeats its highest (or index 0 where it has
        none); indices may repeat.
    """
    K, N = contrast.shape
    even = np.broadcast_to(np.round(np.linspace(0, N - 1, n_even)).astype(np.int64), (K, n_even))
    c = np.asarray(contrast, float)
    peak = np.zeros_like(c, bool)
    peak[:, 1:-1] = (c[:, 1:-1] >= c[:, :-2]) & (c[:, 1:-1] > c[:, 2:])
    ranked = np.argsort(np.where(peak, -c, np.inf), axis=1, kind="stable")[:, :n_peaks]
    ranked = np.where(np.take_along_axis(peak, ranked, axis=1), ranked, ranked[:, :1])
    return np.concatenate([even, ranked], axis=1)


def best_path(score: np.ndarray, points_mm: np.ndarray, step_mm: np.ndarray, start_mm: np.ndarray,
              stretch_cost: float = 1.0, max_stretch: float = 4.0) -> np.ndarray:
    """The candidate path that scores most (dynamic programming): its index per ray, (K,).

    The path's value is its candidates' ``score`` less ``stretch_cost`` times
    each step's excess length, ``|dX| / step_mm - 1``; a step longer than
    ``max_stretch`` times ``step_mm`` is not allowed, and the first candidate
    lies within ``max_stretch * step_mm[0]`` of ``start_mm``.

    Parameters
    ----------
    score : (K, n)
        Each candidate's score (e.g. its tube response, less a bias).
    points_mm : (K, n, 3)
        The candidates (world, mm): :func:`ray_candidates`.
    step_mm : (K,)
        The least length of each step (mm): what the other view sees of it.
    start_mm : (3,)

    Returns
    -------
    (K,) int array or None
        None where no path keeps to the step bound.
    """
    found, path = best_path_nb(np.ascontiguousarray(score, np.float64), np.ascontiguousarray(points_mm, np.float64),
                               np.ascontiguousarray(step_mm, np.float64), np.asarray(start_mm, np.float64),
                               float(stretch_cost), float(max_stretch))
    return path if found else None
