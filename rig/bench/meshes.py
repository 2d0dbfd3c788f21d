"""Tube meshes of reconstructions (and ground truth) as PLY, OBJ and glTF (GLB) files.

The geometry comes from :func:`recon.tubemesh.tube_mesh` (circles along the backbone,
patched into a closed tube — the picture of Morimoto & Sketch); this module only
chooses radii and writes files with trimesh. Units are world mm.

Layout under ``OUT/meshes/`` (docs/outputs.md):

* ``NNNNNN.ply``, ``NNNNNN.obj``, ``NNNNNN.glb``: the reconstructed tube of frame NNNNNN;
* ``NNNNNN_both.glb`` (twin sessions): reconstruction (blue) and true tube (orange) in one
  glTF scene, nodes ``reconstruction`` and ``truth``, for a quick look in any glTF viewer.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from recon.geometry import arc_length
from recon.tubemesh import radii_along, tube_mesh

__all__ = ["recon_tube", "truth_tube", "to_trimesh", "export_mesh", "write_frame_meshes", "RECON_RGBA", "TRUTH_RGBA", "MESH_FORMATS"]

#: Colours of the two tubes (Okabe-Ito blue and orange), RGBA 0-255.
RECON_RGBA = (0, 114, 178, 255)
TRUTH_RGBA = (230, 159, 0, 255)
MESH_FORMATS = ("ply", "obj", "glb")


def recon_tube(points_mm, transition_s_mm=None, outer_radius_mm: float = 0.8, inner_radius_mm: float = 0.5, sides: int = 16) -> tuple:
    """Vertices and faces of a reconstructed backbone's tube.

    The outer tube's radius is used up to ``transition_s_mm`` (where the outer tube
    ends, when the method saw it) and the inner tube's after it.
    """
    P = np.asarray(points_mm, dtype=np.float64).reshape(-1, 3)
    r = radii_along(arc_length(P), transition_s_mm, outer_radius_mm, inner_radius_mm)
    return tube_mesh(P, r, sides=sides)


def truth_tube(backbone_world_mm, outer_radius_mm=None, step_mm: float = 0.5, sides: int = 16) -> tuple:
    """Vertices and faces of a true backbone's tube (radius per sample when given).

    The truth is sampled every <= 0.1 mm; it is thinned to ``step_mm`` (keeping the
    radius step between the tubes at the right place) to keep files small.
    """
    B = np.asarray(backbone_world_mm, dtype=np.float64).reshape(-1, 3)
    s = arc_length(B)
    if outer_radius_mm is None:
        r = np.full(len(B), 0.8)
    else:
        r = np.asarray(outer_radius_mm, dtype=np.float64).reshape(-1)
    n = max(2, int(np.ceil(s[-1] / step_mm)) + 1)
    s_new = np.linspace(0.0, s[-1], n)
    steps = np.nonzero(np.diff(r))[0]
    if steps.size:  # keep the samples on both sides of every radius step
        s_new = np.union1d(s_new, np.concatenate([s[steps], s[steps + 1]]))
    P = np.stack([np.interp(s_new, s, B[:, k]) for k in range(3)], axis=1)
    idx = np.clip(np.searchsorted(s, s_new, side="left"), 0, len(s) - 1)
    return tube_mesh(P, r[idx], sides=sides)


def to_trimesh(vertices, faces, rgba=RECON_RGBA) -> trimesh.Trimesh:
    """A trimesh with one colour on every face (kept by PLY and glTF)."""
    m = trimesh.Trimesh(vertices=np.asarray(vertices), faces=np.asarray(faces), process=False)
    m.visual.face_colors = np.tile(np.asarray(rgba, dtype=np.uint8), (len(m.faces), 1))
    return m


def export_mesh(mesh, path) -> Path:
    """Write a trimesh (or scene) to ``path``; the suffix picks the format (.ply, .obj, .glb)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
    if path.suffix.lower() == ".obj":  # plain geometry, 0.1 um: a third smaller than trimesh's default
        mesh.export(tmp, digits=4, include_color=False)
    else:
        mesh.export(tmp)
    tmp.replace(path)
    return path


def write_frame_meshes(mesh_dir, frame: int, recon_points_mm, transition_s_mm=None, truth: dict | None = None,
                       outer_radius_mm: float = 0.8, inner_radius_mm: float = 0.5, formats=MESH_FORMATS) -> list:
    """Write the meshes of one frame; returns the paths written.

    Parameters
    ----------
    mesh_dir : path
        ``OUT/meshes``.
    frame : int
    recon_points_mm : (n, 3) array
        Reconstructed backbone (world mm).
    transition_s_mm : float or None
        Arc length of the outer tube's end on the reconstruction.
    truth : dict, optional
        The frame's ground truth (``backbone_world_mm`` and ``outer_radius_mm``).
    """
    mesh_dir = Path(mesh_dir)
    written = []
    P = np.asarray(recon_points_mm, dtype=np.float64).reshape(-1, 3)
    if len(P) >= 2:
        rec = to_trimesh(*recon_tube(P, transition_s_mm, outer_radius_mm, inner_radius_mm), RECON_RGBA)
        for fmt in formats:
            written.append(export_mesh(rec, mesh_dir / f"{frame:06d}.{fmt}"))
    else:
        rec = None
    if truth is not None and "backbone_world_mm" in truth and "glb" in formats:
        tru = to_trimesh(*truth_tube(truth["backbone_world_mm"], truth.get("outer_radius_mm")), TRUTH_RGBA)
        if rec is not None:
            scene = trimesh.Scene()
            scene.add_geometry(rec, geom_name="reconstruction", node_name="reconstruction")
            scene.add_geometry(tru, geom_name="truth", node_name="truth")
            written.append(export_mesh(scene, mesh_dir / f"{frame:06d}_both.glb"))
    return written
