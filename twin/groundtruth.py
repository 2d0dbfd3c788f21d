"""Checks that the twin's ground truth agrees with what it rendered."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

__all__ = ["projected_tube_area_px", "extend_to_mesh_start", "inside_fraction"]


def projected_tube_area_px(camera, backbone) -> float:
    """Analytic image area (px) of the tubes: projected length times projected diameter.

    The diameter is measured by projecting two surface points across the tube,
    perpendicular to both the tangent and the viewing ray, so perspective and lens
    distortion are included.
    """
    p = backbone.p_world_mm
    r = backbone.outer_radius_mm
    t = backbone.R_world_body[:, :, 2]
    n = np.cross(t, p - camera.center_world_mm)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    a, _ = camera.project(p + r[:, None] * n)
    b, _ = camera.project(p - r[:, None] * n)
    width = np.linalg.norm(a - b, axis=1)
    c, _ = camera.project(p)
    seg = np.linalg.norm(np.diff(c, axis=0), axis=1)
    return float(np.sum(seg * 0.5 * (width[1:] + width[:-1])))


def extend_to_mesh_start(backbone, hidden_mm: float = 8.0):
    """The backbone continued straight back ``hidden_mm`` into the base, as the tube mesh is."""
    t0 = backbone.R_world_body[0][:, 2]
    s_back = np.linspace(-hidden_mm, 0.0, int(hidden_mm * 10) + 1)[:-1]
    n = len(s_back)
    return replace(
        backbone,
        s_mm=np.concatenate([s_back, backbone.s_mm]),
        p_world_mm=np.concatenate([backbone.p_world_mm[0] + s_back[:, None] * t0, backbone.p_world_mm]),
        R_world_body=np.concatenate([np.repeat(backbone.R_world_body[:1], n, 0), backbone.R_world_body]),
        outer_radius_mm=np.concatenate([np.full(n, backbone.outer_radius_mm[0]), backbone.outer_radius_mm]),
        outermost_tube=np.concatenate([np.zeros(n, int), backbone.outermost_tube]),
    )


def inside_fraction(frame) -> dict:
    """Per camera: fraction of backbone points inside the rendered silhouette."""
    out = {}
    for name, labels in frame.labels.items():
        uv = np.rint(frame.centerline_px[name]).astype(int)
        h, w = labels.shape
        ok = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
        inside = np.zeros(len(uv), bool)
        inside[ok] = labels[uv[ok, 1], uv[ok, 0]] > 0
        out[name] = float(inside.mean())
    return out
