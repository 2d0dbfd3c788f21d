"""Triangle meshes of the twin: the tubes swept along the backbone, the backdrop and the clutter.

All vertices in world mm. Tube surfaces are closed (watertight) swept cylinders,
one per tube, so the step from the outer to the inner tube and both end caps
are real geometry.
"""
from __future__ import annotations

import numpy as np
import trimesh

from recon.tubemesh import swept_rings

from .robot import Backbone, Joints, Robot

__all__ = ["tube_meshes", "ring_arc_lengths", "ring_sides", "swept_tube", "sample_backbone", "box_mesh", "cylinder_mesh", "plane_mesh"]


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


def ring_arc_lengths(backbone: Backbone, start_mm: float, end_mm: float, tolerance_mm: float, max_step_mm: float = 4.0) -> np.ndarray:
    """Arc lengths (mm) of a tube's rings between ``start_mm`` and ``end_mm``, closer where it bends.

    A straight segment of length L across a bend of curvature k lies up to L^2 k / 8
    inside the true surface; rings are spread so that this sagitta stays within
    ``tolerance_mm`` (equal shares of the integral of sqrt(k / (8 tolerance))), and
    at most ``max_step_mm`` apart where the tube is straight. Fewer, longer triangles
    are what makes the software rasterizer fast: at a fixed 0.5 mm it shaded the
    same pixels once per sliver.
    """
    s, T = backbone.s_mm, backbone.R_world_body[:, :, 2]
    kappa = np.linalg.norm(np.gradient(T, s, axis=0), axis=1) if len(s) > 1 else np.zeros(len(s))
    grid = np.linspace(start_mm, end_mm, max(2, int(np.ceil((end_mm - start_mm) / 0.1)) + 1))
    # Outside the backbone (the part inside the actuation unit) the tube is straight.
    density = np.maximum(np.sqrt(np.interp(grid, s, kappa, left=0.0, right=0.0) / (8.0 * tolerance_mm)), 1.0 / max_step_mm)
    u = np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]) * np.diff(grid))])
    n = max(1, int(np.ceil(u[-1])))
    return np.interp(np.linspace(0.0, u[-1], n + 1), u, grid)


def ring_sides(radius_mm: float, tolerance_mm: float) -> int:
    """Vertices per ring (even, 12-64) so a polygon's flats lie within ``tolerance_mm`` of a circle of ``radius_mm``."""
    cos_half = 1.0 - min(tolerance_mm / radius_mm, 1.0)
    n = int(np.ceil(np.pi / max(np.arccos(cos_half), 1e-9)))
    return int(np.clip(n + n % 2, 12, 64))


def tube_meshes(backbone: Backbone, robot: Robot, joints: Joints, tolerance_mm: float = 0.01, hidden_mm: float = 8.0) -> list:
    """One closed mesh per tube, swept along ``backbone``.

    The outermost tube starts ``hidden_mm`` inside the actuation unit (s < 0) so
    no gap shows at the pin vise; each inner tube starts 1 mm inside the tube
    around it (where it is hidden) and ends at its own extension.

    Parameters
    ----------
    backbone, robot, joints
        The robot's shape, its tubes, and the extensions of this frame.
    tolerance_mm : float
        How far the triangles may depart from the true tube (mm): rings along the
        bends (:func:`ring_arc_lengths`) and sides round each ring (:func:`ring_sides`).
        The twin passes a tenth of the finest pixel footprint.
    hidden_mm : float
        Length of the outer tube drawn inside the actuation unit (mm).

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
        s = ring_arc_lengths(backbone, start, ext, tolerance_mm)
        p, R = sample_backbone(backbone, s)
        sides = ring_sides(tube.outer_radius_mm, tolerance_mm)
        # An inscribed polygon looks thinner than its circle: this radius gives it the
        # circle's mean width (perimeter / pi), so the silhouette errs both ways, not one.
        radius = tube.outer_radius_mm * np.pi / (sides * np.sin(np.pi / sides))
        out.append((i, swept_tube(p, R, radius, sides=sides)))
    return out


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
