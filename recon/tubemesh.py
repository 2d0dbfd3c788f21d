"""Tube meshes of a backbone: circles along the curve, patched into a closed surface.

This is the picture of Morimoto & Sketch (their Fig. 8): a circle is drawn at each
backbone point, in the plane whose normal is the direction of the curve there, and
consecutive circles are joined by quadrilateral "patches" (two triangles each). The
ends are closed by fans, so the mesh is watertight.

Numpy only; exporters (PLY, OBJ, glTF) live in ``rig/bench/meshes.py``.

Conventions: points in any length unit (world mm in ctr-bench), ordered base to tip;
faces are wound so that their normals point outwards.
"""
from __future__ import annotations

import numpy as np

__all__ = ["clean_polyline", "tangents", "transport_frames", "tube_mesh", "swept_rings", "radii_along"]


def clean_polyline(points, min_step: float = 1e-9) -> np.ndarray:
    """Drop consecutive (near-)duplicate points, which have no direction.

    Parameters
    ----------
    points : (n, 3) array
    min_step : float
        Points closer than this to the previous kept point are dropped.

    Returns
    -------
    (m, 3) array, m <= n; the first point is always kept.
    """
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(P) == 0:
        return P
    keep = [0]
    for i in range(1, len(P)):
        if np.linalg.norm(P[i] - P[keep[-1]]) > min_step:
            keep.append(i)
    return P[keep]


def tangents(points) -> np.ndarray:
    """Unit tangents of a polyline: the normals of the circles.

    Interior points take the bisector of their two segments (the mean of the unit
    directions to the previous and to the next point), which keeps consecutive
    circles from crossing at a bend; the ends take their only segment — so every
    circle faces the next point as in the paper, up to half the turn at that point.

    Parameters
    ----------
    points : (n, 3) array, n >= 2, no repeated consecutive points (see :func:`clean_polyline`)

    Returns
    -------
    (n, 3) array of unit vectors.
    """
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or len(P) < 2:
        raise ValueError(f"tangents: need (n >= 2, 3) points, got shape {P.shape}")
    seg = np.diff(P, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    if np.any(seg_len <= 0):
        raise ValueError("tangents: repeated consecutive points (use clean_polyline first)")
    d = seg / seg_len[:, None]
    T = np.empty_like(P)
    T[0] = d[0]
    T[-1] = d[-1]
    mid = d[:-1] + d[1:]
    n = np.linalg.norm(mid, axis=1)
    # a U-turn (opposite segments) has no bisector: fall back to the incoming segment
    T[1:-1] = np.where(n[:, None] > 1e-9, mid / np.where(n > 1e-9, n, 1.0)[:, None], d[:-1])
    return T


def _any_perpendicular(t: np.ndarray) -> np.ndarray:
    a = np.array([1.0, 0.0, 0.0]) if abs(t[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = a - np.dot(a, t) * t
    return u / np.linalg.norm(u)


def transport_frames(points, T=None) -> np.ndarray:
    """Rotation-minimizing frames along a polyline (double reflection, Wang et al. 2008).

    Parameters
    ----------
    points : (n, 3) array
    T : (n, 3) array, optional
        Unit tangents (default :func:`tangents`).

    Returns
    -------
    (n, 3, 3) array
        Frames whose columns are (u, v, t): ``u`` and ``v`` span the circle's plane,
        ``t`` is the tangent, and (u, v, t) is right-handed. ``u`` turns as little
        as possible from one point to the next, so the mesh does not twist.
    """
    P = np.asarray(points, dtype=np.float64)
    T = tangents(P) if T is None else np.asarray(T, dtype=np.float64)
    n = len(P)
    U = np.empty_like(P)
    U[0] = _any_perpendicular(T[0])
    for i in range(n - 1):
        v1 = P[i + 1] - P[i]
        c1 = np.dot(v1, v1)
        r_l = U[i] - (2.0 / c1) * np.dot(v1, U[i]) * v1
        t_l = T[i] - (2.0 / c1) * np.dot(v1, T[i]) * v1
        v2 = T[i + 1] - t_l
        c2 = np.dot(v2, v2)
        u = r_l - (2.0 / c2) * np.dot(v2, r_l) * v2 if c2 > 1e-18 else r_l
        u -= np.dot(u, T[i + 1]) * T[i + 1]  # exact orthogonality despite rounding
        nu = np.linalg.norm(u)
        U[i + 1] = u / nu if nu > 1e-12 else _any_perpendicular(T[i + 1])
    V = np.cross(T, U)
    return np.stack([U, V, T], axis=2)


def radii_along(s_mm, transition_s_mm, outer_radius_mm: float, inner_radius_mm: float) -> np.ndarray:
    """Per-point radius of a two-tube robot: the outer tube up to its end, the inner after.

    ``transition_s_mm`` is the arc length where the outer tube ends; None or NaN means
    unknown, and the whole backbone gets the outer radius.

    Parameters
    ----------
    s_mm : array_like
        Arc length of each backbone point from the base (mm), any shape.
    transition_s_mm : float or None
        Arc length where the outer tube ends (mm); None or NaN: unknown.
    outer_radius_mm, inner_radius_mm : float
        The tubes' radii (mm).

    Returns
    -------
    ndarray
        Radius per point (mm), float64 of ``s_mm``'s shape: ``outer_radius_mm`` up to and
        at ``transition_s_mm``, ``inner_radius_mm`` beyond it.
    """
    s = np.asarray(s_mm, dtype=np.float64)
    r = np.full(s.shape, float(outer_radius_mm))
    if transition_s_mm is not None and np.isfinite(transition_s_mm):
        r[s > float(transition_s_mm)] = float(inner_radius_mm)
    return r


def tube_mesh(points, radius, sides: int = 16, caps: bool = True) -> tuple:
    """A closed tube of circles along ``points``.

    Parameters
    ----------
    points : (n, 3) array
        Backbone, base first; repeated consecutive points are dropped.
    radius : float or (n,) array
        Tube radius, one value or one per input point (a step between two points
        becomes a short cone).
    sides : int
        Vertices per circle (>= 3).
    caps : bool
        Close both ends with a fan around the end point (watertight mesh).

    Returns
    -------
    vertices : (m, 3) float64
        ``sides`` vertices per circle, circle after circle, then (with caps) the
        two end centres.
    faces : (k, 3) int64
        Triangles, outward normals.
    """
    P0 = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    try:
        r = np.broadcast_to(np.asarray(radius, dtype=np.float64), (len(P0),))
    except ValueError:
        raise ValueError(f"tube_mesh: radius must be a number or one per point ({len(P0)}), got shape {np.shape(radius)}") from None
    if sides < 3:
        raise ValueError(f"tube_mesh: sides must be >= 3, got {sides}")
    # drop repeated points (and their radii)
    keep = [0] if len(P0) else []
    for i in range(1, len(P0)):
        if np.linalg.norm(P0[i] - P0[keep[-1]]) > 1e-9:
            keep.append(i)
    P, r = P0[keep], np.asarray(r)[keep]
    if len(P) < 2:
        raise ValueError("tube_mesh: need at least two distinct backbone points")
    if np.any(r <= 0) or not np.all(np.isfinite(r)):
        raise ValueError("tube_mesh: radius must be positive and finite")
    return swept_rings(P, transport_frames(P), r, sides, caps)


def swept_rings(points_mm, frames, radius_mm, sides: int, caps: bool = True) -> tuple:
    """Triangles of rings of ``radius_mm`` swept along ``points_mm`` in the given cross-section frames.

    The one owner of the tube's triangulation: :func:`tube_mesh` (transported frames) and the
    twin's tube meshes (its backbone's body frames) both call it.

    Parameters
    ----------
    points_mm : (n, 3) float array
        Centre line, n >= 2 distinct points (mm, any frame).
    frames : (n, 3, 3) float array
        Per point, a rotation whose columns 0 and 1 span the cross-section and whose column 2
        is the tangent (same frame as the points).
    radius_mm : float or (n,) float array
        Radius of each ring (mm).
    sides : int
        Vertices per ring (>= 3).
    caps : bool
        Close both ends with a fan around the end point (watertight mesh).

    Returns
    -------
    vertices : (m, 3) float64
        ``sides`` vertices per ring, ring after ring, then (with caps) the two end centres.
    faces : (k, 3) int64
        Triangles with outward normals.
    """
    P = np.asarray(points_mm, dtype=np.float64)
    F = np.asarray(frames, dtype=np.float64)
    r = np.broadcast_to(np.asarray(radius_mm, dtype=np.float64), (len(P),))
    phi = np.linspace(0.0, 2.0 * np.pi, sides, endpoint=False)
    ring = np.cos(phi)[None, :, None] * F[:, None, :, 0] + np.sin(phi)[None, :, None] * F[:, None, :, 1]
    verts = (P[:, None, :] + r[:, None, None] * ring).reshape(-1, 3)
    n = len(P)
    k = np.arange(n - 1)[:, None]
    j = np.arange(sides)[None, :]
    a = k * sides + j
    b = k * sides + (j + 1) % sides
    c = a + sides
    d = b + sides
    # (u, v, t) is right-handed, so (a, b, d) and (a, d, c) face outwards
    faces = [np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)]
    if caps:
        start, end = n * sides, n * sides + 1
        jj = np.arange(sides)
        last = (n - 1) * sides
        faces.append(np.stack([np.full(sides, start), (jj + 1) % sides, jj], axis=1))
        faces.append(np.stack([np.full(sides, end), last + jj, last + (jj + 1) % sides], axis=1))
        verts = np.concatenate([verts, P[:1], P[-1:]])
    return verts, np.concatenate(faces).astype(np.int64)
