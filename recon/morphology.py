"""Structuring elements for binary morphology on silhouettes.

One owner of the disk that the silhouette's closing and the centerline's erosions use.

The binary image operations of recon/ (regions and their statistics, distance transforms,
dilation and erosion) run through OpenCV rather than scikit-image or SciPy: on the paper
rig's 1024x768 silhouettes OpenCV is 3-30x faster with the same results
(``scripts/bench_libraries.py``; figures and the choice, operation by operation, in
docs/libraries.md).
"""
from __future__ import annotations

import cv2
import numpy as np

__all__ = ["disk", "near_mask"]


def disk(radius_px: int) -> np.ndarray:
    """A filled disk of ``radius_px`` as a structuring element.

    Parameters
    ----------
    radius_px : int
        Radius in pixels (truncated to an integer); 0 gives a single pixel.

    Returns
    -------
    (2r+1, 2r+1) uint8 array
        OpenCV's ellipse element (1 inside, 0 outside). From radius 2 on it is fuller on
        the rim than ``skimage.morphology.disk`` (at r = 3, rows 2 and 4 reach the edge), so
        the two are not interchangeable without changing the silhouettes and centerlines.
    """
    d = 2 * int(radius_px) + 1
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (d, d))


def near_mask(mask: np.ndarray, uv: np.ndarray, tol_px: float) -> np.ndarray:
    """Whether a nonzero pixel of ``mask`` lies within ``tol_px`` of each point.

    Parameters
    ----------
    mask : (H, W) array
        Nonzero on the region (a silhouette, a foreground).
    uv : (m, 2) array
        Points (image frame, px), rounded to their pixels.
    tol_px : float
        Reach (px) over pixel centres: 1.5 reads the 3x3 pixels around a point.

    Returns
    -------
    (m,) bool array
        False where every pixel within reach lies outside the image.
    """
    r = int(np.floor(tol_px))
    dv, du = np.mgrid[-r : r + 1, -r : r + 1]
    keep = du**2 + dv**2 <= tol_px**2
    du, dv = du[keep], dv[keep]
    u = np.rint(uv[:, 0]).astype(np.int64)[:, None] + du[None, :]
    v = np.rint(uv[:, 1]).astype(np.int64)[:, None] + dv[None, :]
    h, w = mask.shape
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    hit = np.zeros(u.shape, bool)
    hit[inside] = mask[v[inside], u[inside]] != 0
    return hit.any(axis=1)
