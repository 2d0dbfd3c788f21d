"""Rigid transforms and polylines: the one place the project inverts, chains and applies poses and measures curves.

Transforms
----------
Every transform is a 4x4 homogeneous matrix in mm named ``T_<to>_<from>``: ``T_cam_world`` maps world
points into the camera frame, ``X_cam = T_cam_world @ X_world``. Names chain like the matrices do
(``T_a_c = T_a_b @ T_b_c``, :func:`compose`) and invert by swapping them (``T_b_a =
invert_transform(T_a_b)``). Rotations are 3x3 ``R_<to>_<from>``, angles in rad.

Polylines
---------
A polyline is an ``(m, d)`` array of vertices in its own frame and units (mm for backbones, px for image
curves); its arc length ``s`` runs from the first vertex along the straight segments. Arc lengths,
resampling and closest points are computed here only.

The compiled kernels of :mod:`recon._kernels` keep their own arithmetic: ``project_nb`` applies
``T_cam_world`` and ``rays_nb`` ``R_world_cam`` point by point inside numba loops (fused with the
distortion and the epipolar angles), where a call into NumPy would leave the compiled path.
"""
from __future__ import annotations

from functools import reduce

import numpy as np

__all__ = [
    "make_transform",
    "invert_transform",
    "compose",
    "transform_points",
    "transform_directions",
    "rotation_matrix",
    "rotation_from_rotvec",
    "look_at",
    "arc_length",
    "interp_rows",
    "points_at_arc_length",
    "resample_arc",
    "resample_polyline",
    "closest_arc_length",
]

#: Ways :func:`resample_arc` places its samples (see there).
RESAMPLE_MODES = ("end", "steps", "spread")

# A polyline's closest-point search holds (points x segments) floats at once; this bounds it (~16 MB each).
_CLOSEST_CHUNK = 2_000_000


# ----------------------------------------------------------------------------- rigid transforms
def make_transform(R_a_b, t_a_b_mm) -> np.ndarray:
    """The 4x4 transform ``T_a_b`` from its rotation and translation.

    Parameters
    ----------
    R_a_b : (3, 3) array
        Rotation taking frame-b directions to frame a.
    t_a_b_mm : (3,) array
        Origin of frame b in frame a (mm).

    Returns
    -------
    (4, 4) float64 array
        ``T_a_b`` (mm): ``X_a = R_a_b @ X_b + t_a_b``.
    """
    T = np.eye(4)
    T[:3, :3] = R_a_b
    T[:3, 3] = t_a_b_mm
    return T


def invert_transform(T_a_b) -> np.ndarray:
    """Inverse of a rigid transform: ``T_a_b -> T_b_a`` (mm).

    Uses the rotation's transpose, not a general matrix inverse: exact for a rigid transform and cheaper.

    Parameters
    ----------
    T_a_b : (4, 4) array
        Rigid transform from frame b to frame a (mm).

    Returns
    -------
    (4, 4) float64 array
        ``T_b_a`` (mm), from frame a to frame b.
    """
    T = np.asarray(T_a_b, dtype=np.float64)
    R_b_a = T[:3, :3].T
    return make_transform(R_b_a, -R_b_a @ T[:3, 3])


def compose(*transforms) -> np.ndarray:
    """Chain transforms left to right: ``compose(T_a_b, T_b_c, T_c_d) = T_a_d``.

    Parameters
    ----------
    *transforms : (4, 4) arrays
        At least one; the ``<from>`` frame of each is the ``<to>`` frame of the next (mm).

    Returns
    -------
    (4, 4) float64 array
        Their product, from the last one's ``<from>`` frame to the first one's ``<to>`` frame (mm).
    """
    if not transforms:
        raise ValueError("compose needs at least one transform")
    return reduce(np.matmul, (np.asarray(T, dtype=np.float64) for T in transforms))


def transform_points(T_a_b, points_b_mm) -> np.ndarray:
    """Points of frame b in frame a.

    Parameters
    ----------
    T_a_b : (4, 4) array
        Rigid transform from frame b to frame a (mm).
    points_b_mm : (..., 3) array
        Points in frame b (mm).

    Returns
    -------
    (..., 3) float64 array
        The same points in frame a (mm).
    """
    T = np.asarray(T_a_b, dtype=np.float64)
    return np.asarray(points_b_mm, dtype=np.float64) @ T[:3, :3].T + T[:3, 3]


def transform_directions(T_a_b, directions_b) -> np.ndarray:
    """Directions (free vectors) of frame b in frame a: rotated, not translated.

    Parameters
    ----------
    T_a_b : (4, 4) array
        Rigid transform from frame b to frame a (mm; only its rotation is used).
    directions_b : (..., 3) array
        Vectors in frame b (any unit; lengths are kept).

    Returns
    -------
    (..., 3) float64 array
        The same vectors in frame a.
    """
    return np.asarray(directions_b, dtype=np.float64) @ np.asarray(T_a_b, dtype=np.float64)[:3, :3].T


def rotation_matrix(axis, angle_rad: float) -> np.ndarray:
    """Rotation about ``axis`` by ``angle_rad`` (Rodrigues' formula).

    Parameters
    ----------
    axis : (3,) array
        Rotation axis in the frame the matrix acts in (any length; a zero axis gives the identity).
    angle_rad : float
        Angle (rad), right-handed about ``axis``.

    Returns
    -------
    (3, 3) float64 array
        The rotation matrix.
    """
    axis = np.asarray(axis, dtype=np.float64)
    n = np.linalg.norm(axis)
    if n == 0.0:
        return np.eye(3)
    k = axis / n
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle_rad) * K + (1.0 - np.cos(angle_rad)) * (K @ K)


def rotation_from_rotvec(rotvec_rad) -> np.ndarray:
    """Rotation of a rotation vector: about its direction by its length.

    Parameters
    ----------
    rotvec_rad : (3,) array
        Rotation vector (rad), in the frame the matrix acts in.

    Returns
    -------
    (3, 3) float64 array
        The rotation matrix; the identity for a zero vector.
    """
    v = np.asarray(rotvec_rad, dtype=np.float64)
    return rotation_matrix(v, float(np.linalg.norm(v)))


def look_at(eye_world_mm, target_world_mm, down_world) -> np.ndarray:
    """``T_cam_world`` of a camera at ``eye`` looking at ``target`` (OpenCV camera frame).

    The camera z axis points from eye to target and its y axis (image down) is as close as possible to
    ``down_world``; x = y cross z (image right).

    Parameters
    ----------
    eye_world_mm : (3,) array
        Optical centre (world, mm).
    target_world_mm : (3,) array
        A point on the optical axis (world, mm), not at the eye.
    down_world : (3,) array
        Direction the image's v axis should follow (world), not parallel to the line of sight.

    Returns
    -------
    (4, 4) float64 array
        ``T_cam_world`` (mm).

    Raises
    ------
    ValueError
        ``down_world`` is parallel to the line of sight.
    """
    eye = np.asarray(eye_world_mm, dtype=np.float64)
    z = np.asarray(target_world_mm, dtype=np.float64) - eye
    z /= np.linalg.norm(z)
    down = np.asarray(down_world, dtype=np.float64)
    y = down - np.dot(down, z) * z
    if np.linalg.norm(y) < 1e-9:
        raise ValueError("look_at: 'down' is parallel to the viewing direction")
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    return invert_transform(make_transform(np.stack([x, y, z], axis=1), eye))


# ----------------------------------------------------------------------------- polylines
def arc_length(points) -> np.ndarray:
    """Cumulative arc length of a polyline at its vertices.

    Parameters
    ----------
    points : (m, d) array
        Vertices in order (any frame; mm or px).

    Returns
    -------
    (m,) float64 array
        Arc length from the first vertex to each vertex, in the units of ``points`` (0 first; ``[0]``
        for fewer than two vertices). The last value is the polyline's length.
    """
    d = np.diff(points, axis=0)
    if not issubclass(d.dtype.type, np.inexact):
        d = d.astype(float)
    # Summed column by column, in the order np.linalg.norm(d, axis=1) sums them (the same values, bit for
    # bit), without its reduction over a short axis and the concatenation: ~12 calls a frame in the fast method.
    sq = np.zeros(len(d))
    for j in range(d.shape[1]):
        sq += d[:, j] * d[:, j]
    out = np.zeros(len(d) + 1)
    np.cumsum(np.sqrt(sq, out=sq), out=out[1:])
    return out


def interp_rows(x, xp, fp) -> np.ndarray:
    """Linear interpolation of every column of ``fp`` (m, d) at ``x``: :func:`numpy.interp` per column.

    Parameters
    ----------
    x : (n,) array
        Where to interpolate, in the units of ``xp`` (e.g. arc length, mm or px).
    xp : (m,) array
        Increasing abscissae of the rows of ``fp``.
    fp : (m, d) array
        Values (e.g. points of a polyline, in its own frame and units).

    Returns
    -------
    (n, d) float64 array
        The rows at ``x``; beyond ``xp`` the end rows.
    """
    out = np.empty((len(x), fp.shape[1]))  # filled column by column: no per-column arrays to stack
    for j in range(fp.shape[1]):
        out[:, j] = np.interp(x, xp, fp[:, j])
    return out


def points_at_arc_length(points, s) -> np.ndarray:
    """Points of a polyline at given arc lengths.

    Parameters
    ----------
    points : (m, d) array
        The polyline (any frame; mm or px).
    s : (n,) array
        Arc lengths from its first vertex, in the units of ``points``.

    Returns
    -------
    (n, d) float64 array
        The points at ``s``; clamped to the end vertices outside ``[0, length]``.
    """
    return interp_rows(s, arc_length(points), points)


def _sample_arc_lengths(length: float, step: float, mode: str) -> np.ndarray:
    """Arc lengths (k,) at which :func:`resample_arc` samples a polyline ``length`` long (``length > 0``
    except for ``"spread"``)."""
    if mode == "end":
        n = max(1, int(np.ceil(length / step - 1e-9)))  # the 1e-9: a length of whole steps gets no sliver step
        return np.minimum(np.arange(n + 1) * step, length)
    if mode == "steps":
        return np.arange(0.0, length + 1e-9, step)
    n = max(2, int(np.floor(length / step)) + 1)
    return np.linspace(0.0, length, n) if length > 0 else np.zeros(2)


def resample_arc(points, step: float, mode: str = "end") -> tuple:
    """Points along a polyline by arc length, and their arc lengths.

    Parameters
    ----------
    points : (m, d) array
        The polyline (any frame; mm for backbones, px for image curves).
    step : float
        Arc-length step (> 0), in the units of ``points``.
    mode : {"end", "steps", "spread"}, optional
        ``"end"`` (default): at ``0, step, 2 step, ...`` and at the end itself (the last step may be
        shorter). ``"steps"``: at ``0, step, 2 step, ...`` up to the length (the end only when it falls on
        a step). For both, a polyline of zero length gives its first point. ``"spread"``:
        ``max(2, floor(length / step) + 1)`` points spread evenly from the first to the last vertex
        (spacing at least ``step``; two copies of the first point for zero length).

    Returns
    -------
    points : (n, d) float64 array
        The resampled points (same frame and units).
    s : (n,) float64 array
        Their arc length from the first vertex.
    """
    if mode not in RESAMPLE_MODES:
        raise ValueError(f"resample_arc: mode must be one of {RESAMPLE_MODES}, got {mode!r}")
    s = arc_length(points)
    if s[-1] <= 0.0 and mode != "spread":
        return np.asarray(points)[:1].copy(), s[:1]
    t = _sample_arc_lengths(s[-1], step, mode)
    return interp_rows(t, s, points), t


def resample_polyline(points, step: float, mode: str = "end") -> np.ndarray:
    """Points along a polyline every ``step`` of arc length, first and (by default) last kept.

    Parameters
    ----------
    points : (m, d) array
        The polyline (any frame; mm or px).
    step : float
        Arc-length step (> 0), in the units of ``points``.
    mode : {"end", "steps", "spread"}, optional
        Where the samples go (:func:`resample_arc`); ``"end"`` keeps both end vertices.

    Returns
    -------
    (k, d) float64 array
        The resampled points (same frame and units).
    """
    return resample_arc(points, step, mode)[0]


def closest_arc_length(points, polyline, s_vertices=None) -> tuple:
    """For each point, the arc length along ``polyline`` of its closest point, and the distance.

    Parameters
    ----------
    points : (n, 3) array
        Query points (mm, the polyline's frame).
    polyline : (m, 3) array, m >= 1
        Vertices in order (mm).
    s_vertices : (m,) array, optional
        Arc length of each vertex (mm), e.g. a model's own arc-length parameter; the closest point's arc
        length is interpolated between its segment's ends. Default: :func:`arc_length` of ``polyline``.

    Returns
    -------
    s : (n,) float64 array
        Arc length (mm) of the closest point on the polyline (0 for a single vertex).
    d : (n,) float64 array
        Distance (mm) to that point (the closest-point distance of :mod:`recon.metrics`).
    """
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    V = np.asarray(polyline, dtype=np.float64).reshape(-1, 3)
    if len(V) == 1:
        return np.zeros(len(P)), np.linalg.norm(P - V[0], axis=1)
    A, AB = V[:-1], np.diff(V, axis=0)
    L = np.linalg.norm(AB, axis=1)
    if s_vertices is None:
        s0, ds = arc_length(V)[:-1], L
    else:
        s_v = np.asarray(s_vertices, dtype=np.float64)
        s0, ds = s_v[:-1], np.diff(s_v)
    ab2 = np.where(L > 0, L * L, 1.0)  # a zero-length segment: t = 0, its first vertex
    s_out, d_out = np.empty(len(P)), np.empty(len(P))
    rows = max(1, _CLOSEST_CHUNK // len(A))
    for i in range(0, len(P), rows):
        AP = P[i:i + rows, None, :] - A[None]
        t = np.clip(np.einsum("ijk,jk->ij", AP, AB) / ab2, 0.0, 1.0)
        D = AP - t[:, :, None] * AB[None]
        d2 = np.einsum("ijk,ijk->ij", D, D)
        j = d2.argmin(axis=1)
        k = np.arange(len(j))
        d_out[i:i + rows] = np.sqrt(d2[k, j])
        s_out[i:i + rows] = s0[j] + t[k, j] * ds[j]
    return s_out, d_out
