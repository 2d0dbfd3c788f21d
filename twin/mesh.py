"""Triangle meshes of the twin: the tubes swept along the backbone, the backdrop and the clutter.

All vertices in world mm. Tube surfaces are closed (watertight) swept cylinders,
one per tube, so the step from the outer to the inner tube and both end caps
are real geometry.
"""
from __future__ import annotations

import numpy as np
import trimesh
from numba import njit

from recon.tubemesh import swept_rings

from .robot import Backbone, Joints, Robot

__all__ = ["tube_meshes", "ring_samples", "swept_tube", "vertex_normals", "sample_backbone", "box_mesh", "cylinder_mesh", "plane_mesh"]


def sample_backbone(backbone: Backbone, s_mm: np.ndarray) -> tuple:
    """Positions (n, 3) mm and frames (n, 3, 3) at arc lengths ``s_mm``.

    Arc lengths below the base continue the base straight back along its tangent
    (the tube inside the actuation unit); positions between samples are
    interpolated linearly (samples are <= 0.1 mm apart) and frames taken from the
    nearest sample.
    """
    s = np.asarray(s_mm, dtype=np.float64)
    sb = backbone.s_mm
    p = np.stack([np.interp(s, sb, backbone.p_world_mm[:, k]) for k in range(3)], axis=1)
    idx = np.clip(np.searchsorted(sb, s), 0, len(sb) - 1)
    R = backbone.R_world_body[idx]
    before = s < sb[0]
    if np.any(before):
        t0 = backbone.R_world_body[0][:, 2]
        p[before] = backbone.p_world_mm[0] + (s[before] - sb[0])[:, None] * t0
    return p, R


def swept_tube(points_mm: np.ndarray, frames: np.ndarray, radius_mm: float, sides: int = 32) -> trimesh.Trimesh:
    """A closed cylinder of ``radius_mm`` swept along ``points_mm`` with the given frames.

    Parameters
    ----------
    points_mm : (n, 3) array
        Centre line (world mm), n >= 2.
    frames : (n, 3, 3) array
        Frames whose columns 0 and 1 span each cross-section.
    radius_mm : float
    sides : int
        Vertices per ring.

    Returns
    -------
    trimesh.Trimesh
        Watertight, outward-facing mesh.
    """
    verts, faces = swept_rings(points_mm, frames, radius_mm, sides)
    return trimesh.Trimesh(vertices=verts, faces=faces, process=False)


def tube_meshes(
    backbone: Backbone, robot: Robot, joints: Joints, step_mm: float = 0.5, hidden_mm: float = 8.0, sides: int = 32,
    max_ring_step_mm: float = 2.0,
) -> list:
    """One closed mesh per tube, swept along ``backbone``: the backbone sampled every ``step_mm``, rings at
    the samples :func:`ring_samples` keeps (at most ``max_ring_step_mm`` apart), ``sides`` vertices each.

    The outermost tube starts ``hidden_mm`` inside the actuation unit (s < 0) so
    no gap shows at the pin vise; each inner tube starts 1 mm inside the tube
    around it (where it is hidden) and ends at its own extension.

    Returns
    -------
    list of (int, trimesh.Trimesh)
        Tube index (into ``robot.tubes``) and its mesh (world mm); tubes with no
        exposed length are left out.
    """
    out = []
    prev_end = -hidden_mm
    for i, (tube, ext) in enumerate(zip(robot.tubes, joints.extension_mm)):
        start = -hidden_mm if i == 0 else max(-hidden_mm, min(prev_end, ext) - 1.0)
        prev_end = ext
        if ext - start <= 1e-6 or (i > 0 and ext <= joints.extension_mm[i - 1]):
            continue
        n = max(2, int(np.ceil((ext - start) / step_mm)) + 1)
        p, R = sample_backbone(backbone, np.linspace(start, ext, n))
        keep = ring_samples(p, tube.outer_radius_mm * (1.0 - np.cos(np.pi / sides)), max_ring_step_mm)
        out.append((i, swept_tube(p[keep], R[keep], tube.outer_radius_mm, sides=sides)))
    return out


def ring_samples(points_mm: np.ndarray, tolerance_mm: float, max_step_mm: float) -> np.ndarray:
    """Indices of the samples ``points_mm`` (n, 3) that a swept tube needs as rings: the first, the last,
    the ones next to them, and in between as few as keep every dropped sample within ``tolerance_mm`` of the
    chord between the kept ones around it, at most ``max_step_mm`` apart.

    :func:`tube_meshes` passes the facets' own depth, ``r (1 - cos(pi / sides))``: the rings' chords then cut
    no deeper into a bend than the polygon already cuts into the tube's section. Where the tube is straight
    that is one ring every ``max_step_mm``: llvmpipe's time for a robot grows with its triangles.
    """
    pts = np.ascontiguousarray(points_mm, dtype=np.float64)
    keep = np.empty(len(pts), np.int64)
    return keep[:_ring_samples_nb(pts, float(tolerance_mm), float(max_step_mm), keep)].copy()


@njit(cache=True, nogil=True)
def _ring_samples_nb(pts, tol, max_step, keep):  # pragma: no cover - compiled
    """:func:`ring_samples` into ``keep``; returns how many. Greedy: from each kept sample, the chord is
    stretched one sample at a time while it stays within ``max_step`` and passes within ``tol`` of every
    sample it spans; the samples next to the ends always stay (the end rings' normals lean towards the caps,
    and the shading blends them into the tube's over the first ring step: a highlight stopped up to 2 mm
    short of a step)."""
    n = pts.shape[0]
    keep[0] = 0
    m, i = 1, 0
    while i < n - 1:
        j = i + 1
        while j + 1 < n and j != 1 and j != n - 2 and _chord_within_nb(pts, i, j + 1, tol, max_step):
            j += 1
        keep[m] = j
        m += 1
        i = j
    return m


@njit(cache=True, nogil=True, inline="always")
def _chord_within_nb(pts, a, b, tol, max_step):  # pragma: no cover - compiled
    """Whether the chord from sample ``a`` to ``b`` is at most ``max_step`` long and passes within ``tol`` of
    every sample between (mm)."""
    c0, c1, c2 = pts[b, 0] - pts[a, 0], pts[b, 1] - pts[a, 1], pts[b, 2] - pts[a, 2]
    ll = c0 * c0 + c1 * c1 + c2 * c2
    if ll > max_step * max_step:
        return False
    for k in range(a + 1, b):
        v0, v1, v2 = pts[k, 0] - pts[a, 0], pts[k, 1] - pts[a, 1], pts[k, 2] - pts[a, 2]
        t = (v0 * c0 + v1 * c1 + v2 * c2) / ll if ll > 0.0 else 0.0
        d0, d1, d2 = v0 - t * c0, v1 - t * c1, v2 - t * c2
        if d0 * d0 + d1 * d1 + d2 * d2 > tol * tol:
            return False
    return True


def box_mesh(lo_mm, hi_mm) -> trimesh.Trimesh:
    """Axis-aligned box between two world corners (mm)."""
    lo = np.asarray(lo_mm, float)
    hi = np.asarray(hi_mm, float)
    m = trimesh.creation.box(extents=hi - lo)
    m.apply_translation((lo + hi) / 2)
    return m


def cylinder_mesh(p0_mm, p1_mm, radius_mm: float, sections: int = 32) -> trimesh.Trimesh:
    """Closed cylinder between two world points (mm)."""
    return trimesh.creation.cylinder(radius=radius_mm, segment=np.array([p0_mm, p1_mm], float), sections=sections)


def plane_mesh(center_mm, u_axis, v_axis, size_u_mm: float, size_v_mm: float) -> tuple:
    """A rectangle (two triangles) with texture coordinates.

    Returns
    -------
    vertices (4, 3) mm, faces (2, 3), uv (4, 2), normal (3,)
    """
    c = np.asarray(center_mm, float)
    u = np.asarray(u_axis, float) / np.linalg.norm(u_axis)
    v = np.asarray(v_axis, float) / np.linalg.norm(v_axis)
    hu, hv = size_u_mm / 2, size_v_mm / 2
    verts = np.array([c - hu * u - hv * v, c + hu * u - hv * v, c + hu * u + hv * v, c - hu * u + hv * v])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    return verts, faces, uv, np.cross(u, v)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Smooth-shading normals (n, 3): each vertex's faces' unit normals weighted by their angle at it, normalized.

    trimesh's ``vertex_normals`` (the same weighting, to rounding) in one compiled
    pass: a tube's normals took 2.2 ms through trimesh's face angles and sparse sums,
    at every frame.

    Parameters
    ----------
    vertices : (n, 3) float array
    faces : (m, 3) int array, wound counter-clockwise seen from outside
    """
    out = np.zeros((len(vertices), 3))
    _angle_weighted_normals_nb(np.ascontiguousarray(vertices, dtype=np.float64), np.ascontiguousarray(faces, dtype=np.int64), out)
    return out


@njit(cache=True, nogil=True)
def _corner_angle(ax, ay, az, bx, by, bz):  # pragma: no cover - compiled
    """Angle (rad) between the edge vectors a and b at one corner."""
    la = np.sqrt(ax * ax + ay * ay + az * az)
    lb = np.sqrt(bx * bx + by * by + bz * bz)
    if la == 0.0 or lb == 0.0:
        return 0.0
    return np.arccos(min(max((ax * bx + ay * by + az * bz) / (la * lb), -1.0), 1.0))


@njit(cache=True, nogil=True)
def _angle_weighted_normals_nb(v, faces, out):  # pragma: no cover - compiled
    """Accumulate angle-weighted unit face normals into ``out`` (n, 3) and normalize its rows."""
    for f in range(faces.shape[0]):
        i, j, k = faces[f, 0], faces[f, 1], faces[f, 2]
        e1 = v[j] - v[i]
        e2 = v[k] - v[i]
        e3 = v[k] - v[j]
        nx = e1[1] * e2[2] - e1[2] * e2[1]
        ny = e1[2] * e2[0] - e1[0] * e2[2]
        nz = e1[0] * e2[1] - e1[1] * e2[0]
        ln = np.sqrt(nx * nx + ny * ny + nz * nz)
        if ln == 0.0:  # a degenerate face has no normal
            continue
        nx, ny, nz = nx / ln, ny / ln, nz / ln
        a_i = _corner_angle(e1[0], e1[1], e1[2], e2[0], e2[1], e2[2])
        a_j = _corner_angle(-e1[0], -e1[1], -e1[2], e3[0], e3[1], e3[2])
        a_k = _corner_angle(-e2[0], -e2[1], -e2[2], -e3[0], -e3[1], -e3[2])
        for idx, a in ((i, a_i), (j, a_j), (k, a_k)):
            out[idx, 0] += nx * a
            out[idx, 1] += ny * a
            out[idx, 2] += nz * a
    for r in range(out.shape[0]):
        ln = np.sqrt(out[r, 0] ** 2 + out[r, 1] ** 2 + out[r, 2] ** 2)
        if ln > 0.0:
            out[r] /= ln
    return out
