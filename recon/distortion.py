"""OpenCV's lens distortion model: 4, 5, 8, 12 or 14 coefficients.

The one owner of the distortion formula. The twin renders through it, the methods
reconstruct through it and calibration estimates it, so all three agree with each
other and with OpenCV (``cv2.projectPoints``, ``cv2.undistortPointsIter``).

Coefficients, in OpenCV's order::

    k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4 [tau_x tau_y]]]]

radial ``k1..k3`` over the rational denominator ``k4..k6``, tangential ``p1 p2``, thin
prism ``s1..s4`` and a tilted sensor ``tau_x tau_y`` (rad).

The formula functions :func:`distort_xy`, :func:`undistort_step` and :func:`untilt_xy`
use nothing but arithmetic and :mod:`math` on their coefficients, so the same source runs
element-wise on NumPy arrays here and on scalars in the numba kernels
(``recon._kernels`` compiles them). Coefficients are always scalars; ``x, y`` may be
arrays of any float dtype (float32 stays float32 when the coefficients are float32).
"""
from __future__ import annotations

import functools
import math

import numpy as np

__all__ = [
    "MODEL_SIZES",
    "MODEL_NAMES",
    "COEFFICIENT_NAMES",
    "as_coefficients",
    "padded",
    "model_size",
    "tilt_matrix",
    "distort_xy",
    "untilt_xy",
    "undistort_step",
    "distort_normalized",
    "undistort_normalized",
]

#: The coefficient counts OpenCV accepts.
MODEL_SIZES = (4, 5, 8, 12, 14)
#: Names for each count (``--model`` accepts either).
MODEL_NAMES = {"k1k2p1p2": 4, "plumb_bob": 5, "rational_polynomial": 8, "thin_prism": 12, "tilted": 14}
#: The 14 coefficients' names, in OpenCV's order.
COEFFICIENT_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tau_x", "tau_y")


def as_coefficients(dist, source: str = "dist") -> np.ndarray:
    """Distortion coefficients as a float64 array of 5, 8, 12 or 14 values.

    Four coefficients (``k1 k2 p1 p2``) gain ``k3 = 0``; other counts than
    :data:`MODEL_SIZES` raise ``ValueError`` naming ``source``.

    Parameters
    ----------
    dist : array_like
        4, 5, 8, 12 or 14 coefficients in OpenCV's order (any shape, raveled; ``tau_x
        tau_y`` in rad).
    source : str
        What the coefficients belong to, e.g. ``"camera 'side'"``; the messages start with it.

    Returns
    -------
    ndarray
        ``(5,)``, ``(8,)``, ``(12,)`` or ``(14,)`` float64, a fresh copy.

    Raises
    ------
    ValueError
        Another count, or a non-finite coefficient.
    """
    d = np.asarray(dist, np.float64).ravel()
    if d.size not in MODEL_SIZES:
        raise ValueError(f"{source}: OpenCV distortion has 4, 5, 8, 12 or 14 coefficients, got {d.size}")
    if not np.all(np.isfinite(d)):
        raise ValueError(f"{source}: distortion coefficients must be finite, got {d.tolist()}")
    return np.concatenate([d, [0.0]]) if d.size == 4 else d.copy()


def padded(dist) -> np.ndarray:
    """The 14-coefficient form of any OpenCV coefficient vector (zeros appended).

    Parameters
    ----------
    dist : array_like
        At most 14 coefficients in OpenCV's order (not checked: use :func:`as_coefficients` first).

    Returns
    -------
    ndarray
        ``(14,)`` float64, ``k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4 tau_x tau_y``.
    """
    d = np.asarray(dist, np.float64).ravel()
    out = np.zeros(14)
    out[: d.size] = d
    return out


def model_size(dist) -> int:
    """The shortest OpenCV layout (5, 8, 12 or 14) that holds every non-zero coefficient of ``dist``.

    Parameters
    ----------
    dist : array_like
        At most 14 coefficients in OpenCV's order.

    Returns
    -------
    int
        5, 8, 12 or 14 (5 also for all-zero or 4-coefficient input).
    """
    d = padded(dist)
    nz = np.flatnonzero(d)
    last = int(nz[-1]) + 1 if nz.size else 0
    return next(n for n in MODEL_SIZES[1:] if n >= last)


@functools.lru_cache(maxsize=64)
def tilt_matrix(tau_x: float, tau_y: float) -> tuple:
    """OpenCV's tilted-sensor projection (``computeTiltProjectionMatrix``) and its inverse.

    Parameters
    ----------
    tau_x, tau_y : float
        The sensor's tilt about the camera's x and y axes (rad); coefficients 13 and 14.

    Returns
    -------
    (M, M_inv) : two (3, 3) arrays
        ``M`` maps distorted normalized points on the ideal sensor plane to the
        tilted one (homogeneous); ``M_inv`` undoes it. Read-only (cached per angle pair).
    """
    cx, sx = math.cos(tau_x), math.sin(tau_x)
    cy, sy = math.cos(tau_y), math.sin(tau_y)
    rot_x = np.array([[1.0, 0.0, 0.0], [0.0, cx, sx], [0.0, -sx, cx]])
    rot_y = np.array([[cy, 0.0, -sy], [0.0, 1.0, 0.0], [sy, 0.0, cy]])
    rot = rot_y @ rot_x
    proj_z = np.array([[rot[2, 2], 0.0, -rot[0, 2]], [0.0, rot[2, 2], -rot[1, 2]], [0.0, 0.0, 1.0]])
    proj_z_inv = np.array([[1.0 / rot[2, 2], 0.0, rot[0, 2] / rot[2, 2]], [0.0, 1.0 / rot[2, 2], rot[1, 2] / rot[2, 2]],
                           [0.0, 0.0, 1.0]])
    m, m_inv = proj_z @ rot, rot.T @ proj_z_inv
    m.setflags(write=False)
    m_inv.setflags(write=False)
    return m, m_inv


def distort_xy(x, y, d, m):
    """Ideal normalized ``x, y`` (x/z, y/z) -> distorted normalized coordinates.

    Parameters
    ----------
    x, y : arrays or floats
        Ideal (pinhole) normalized image coordinates (unitless).
    d : sequence of 14 floats
        :func:`padded` coefficients.
    m : (3, 3) array
        The tilt matrix (:func:`tilt_matrix`); only used when ``tau_x`` or ``tau_y`` is non-zero.

    Returns
    -------
    xd, yd : arrays or floats
        Distorted normalized coordinates (unitless), of ``x``'s shape and dtype; the pixel
        is ``K @ (xd, yd, 1)``.
    """
    r2 = x * x + y * y
    radial = (1.0 + r2 * (d[0] + r2 * (d[1] + r2 * d[4]))) / (1.0 + r2 * (d[5] + r2 * (d[6] + r2 * d[7])))
    xy2 = 2.0 * x * y
    xd = x * radial + d[2] * xy2 + d[3] * (r2 + 2.0 * x * x) + r2 * (d[8] + r2 * d[9])
    yd = y * radial + d[2] * (r2 + 2.0 * y * y) + d[3] * xy2 + r2 * (d[10] + r2 * d[11])
    if d[12] != 0.0 or d[13] != 0.0:
        w = 1.0 / (m[2, 0] * xd + m[2, 1] * yd + m[2, 2])
        xt = (m[0, 0] * xd + m[0, 1] * yd + m[0, 2]) * w
        yd = (m[1, 0] * xd + m[1, 1] * yd + m[1, 2]) * w
        xd = xt
    return xd, yd


def untilt_xy(x, y, d, m_inv):
    """Distorted normalized coordinates on the tilted sensor -> on the ideal sensor plane (as OpenCV's
    undistortion starts); the identity without tilt. ``m_inv`` is :func:`tilt_matrix`'s inverse.

    Parameters
    ----------
    x, y : arrays or floats
        Distorted normalized coordinates on the tilted sensor (unitless; ``K^-1`` of the pixel).
    d : sequence of 14 floats
        :func:`padded` coefficients; only ``tau_x, tau_y`` (``d[12], d[13]``) are read.
    m_inv : (3, 3) array
        The inverse tilt matrix (:func:`tilt_matrix`).

    Returns
    -------
    x, y : arrays or floats
        Distorted normalized coordinates on the ideal sensor plane (the inputs themselves without tilt).
    """
    if d[12] == 0.0 and d[13] == 0.0:
        return x, y
    w = 1.0 / (m_inv[2, 0] * x + m_inv[2, 1] * y + m_inv[2, 2])
    return (m_inv[0, 0] * x + m_inv[0, 1] * y + m_inv[0, 2]) * w, (m_inv[1, 0] * x + m_inv[1, 1] * y + m_inv[1, 2]) * w


def undistort_step(x, y, x0, y0, d):
    """One fixed-point step of OpenCV's undistortion: the ideal point whose distortion is ``x0, y0``
    (untilted distorted normalized coordinates), refined from the estimate ``x, y``.

    Parameters
    ----------
    x, y : arrays or floats
        The current estimate of the ideal normalized coordinates (unitless); start at ``x0, y0``.
    x0, y0 : arrays or floats
        The distorted normalized coordinates after :func:`untilt_xy` (unitless).
    d : sequence of 14 floats
        :func:`padded` coefficients (the tilt terms are not read here).

    Returns
    -------
    x, y : arrays or floats
        The next estimate (unitless). The iteration need not converge (strong pincushion):
        :func:`undistort_normalized` checks and falls back to Newton steps.
    """
    r2 = x * x + y * y
    icdist = (1.0 + r2 * (d[5] + r2 * (d[6] + r2 * d[7]))) / (1.0 + r2 * (d[0] + r2 * (d[1] + r2 * d[4])))
    xy2 = 2.0 * x * y
    dx = d[2] * xy2 + d[3] * (r2 + 2.0 * x * x) + r2 * (d[8] + r2 * d[9])
    dy = d[2] * (r2 + 2.0 * y * y) + d[3] * xy2 + r2 * (d[10] + r2 * d[11])
    return (x0 - dx) * icdist, (y0 - dy) * icdist


def distort_normalized(xy: np.ndarray, dist) -> np.ndarray:
    """Apply the distortion ``dist`` (any OpenCV count) to ideal normalized coordinates ``xy`` (n, 2).

    Parameters
    ----------
    xy : (n, 2) array
        Ideal (pinhole) normalized coordinates ``(x/z, y/z)`` in the camera frame (unitless).
    dist : array_like
        4, 5, 8, 12 or 14 OpenCV coefficients.

    Returns
    -------
    (n, 2) ndarray
        Distorted normalized coordinates (unitless); a float64 copy of ``xy`` when all
        coefficients are zero. A rational model's pole gives inf or NaN.
    """
    d = padded(dist)
    if not np.any(d):
        return np.array(xy, dtype=np.float64, copy=True)
    m, _ = tilt_matrix(float(d[12]), float(d[13]))
    xd, yd = distort_xy(xy[:, 0], xy[:, 1], d, m)
    return np.stack([xd, yd], axis=1)


def undistort_normalized(xy_d: np.ndarray, dist, max_iterations: int = 100, eps: float = 1e-14) -> np.ndarray:
    """Invert :func:`distort_normalized` by OpenCV's fixed-point iteration.

    Parameters
    ----------
    xy_d : (n, 2) array
        Distorted normalized coordinates (unitless).
    dist : array
        4, 5, 8, 12 or 14 OpenCV coefficients.
    max_iterations : int
        Upper bound on the iterations; they stop earlier once no point moves by more
        than ``eps`` (normalized units, ~1e-11 px at f = 1000 px).

    Returns
    -------
    (n, 2) array
        Ideal normalized coordinates. Where the fixed-point iteration (OpenCV's)
        does not settle (strong pincushion toward the corners), damped Newton steps
        on the distortion solve it (:func:`_newton_undistort`); where the lens folds
        (no solution nearby) the closest point they reach is returned.
    """
    d = padded(dist)
    if not np.any(d):
        return np.array(xy_d, dtype=np.float64, copy=True)
    m, m_inv = tilt_matrix(float(d[12]), float(d[13]))
    x0, y0 = untilt_xy(xy_d[:, 0], xy_d[:, 1], d, m_inv)
    x, y = x0, y0
    for _ in range(max_iterations):
        xn, yn = undistort_step(x, y, x0, y0, d)
        moved = np.nanmax(np.abs(xn - x) + np.abs(yn - y), initial=0.0)
        x, y = xn, yn
        if not moved > eps:
            break
    xu = np.stack([x, y], axis=1)
    # The fixed point diverges where the lens magnifies strongly (pincushion, k1..k3 > 0, toward the corners
    # of a wide field: seen 9,000 px off on a wide-suite camera): there, Newton steps on the distortion itself.
    xt, yt = distort_xy(xu[:, 0], xu[:, 1], d, m)
    bad = ~(np.abs(xt - xy_d[:, 0]) + np.abs(yt - xy_d[:, 1]) <= _SOLVED)
    if bad.any():
        xu[bad] = _newton_undistort(np.asarray(xy_d, np.float64)[bad], d, m)
    return xu


#: Residual (normalized units, ~1e-7 px at f = 1000 px) below which an undistorted point counts as solved.
_SOLVED = 1e-10


def _newton_undistort(xy_d: np.ndarray, d, m, steps: int = 60) -> np.ndarray:
    """Ideal normalized points (n, 2) whose distortion is ``xy_d`` (n, 2): damped Newton steps on
    :func:`distort_xy` from ``xy_d`` itself, the Jacobian by central differences, each step halved until
    the residual falls. A point with no solution nearby (the lens folds there) ends where the residual
    stops falling."""
    x = xy_d.copy()
    h = 1e-7

    def residual(p):
        xd, yd = distort_xy(p[:, 0], p[:, 1], d, m)
        return np.stack([xd, yd], axis=1) - xy_d

    r = residual(x)
    for _ in range(steps):
        jx = (residual(x + [h, 0.0]) - residual(x - [h, 0.0])) / (2 * h)
        jy = (residual(x + [0.0, h]) - residual(x - [0.0, h])) / (2 * h)
        det = jx[:, 0] * jy[:, 1] - jy[:, 0] * jx[:, 1]
        det = np.where(np.abs(det) > 1e-300, det, 1e-300)
        step = -np.stack([jy[:, 1] * r[:, 0] - jy[:, 0] * r[:, 1], -jx[:, 1] * r[:, 0] + jx[:, 0] * r[:, 1]], axis=1) / det[:, None]
        norm = np.linalg.norm(r, axis=1)
        scale = np.ones(len(x))
        for _ in range(30):  # backtracking: halve the steps that do not lower the residual
            trial = x + scale[:, None] * step
            rt = residual(trial)
            worse = ~(np.linalg.norm(rt, axis=1) < norm) & (norm > 0)
            if not worse.any():
                break
            scale[worse] *= 0.5
        better = np.linalg.norm(rt, axis=1) < norm
        x[better], r[better] = trial[better], rt[better]
        if not (np.abs(r).sum(axis=1) > 1e-15).any() or not better.any():
            break
    return x
