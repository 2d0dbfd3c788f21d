"""Errors of a reconstructed backbone against a reference backbone.

Both backbones are polylines ordered base to tip, in the same frame and unit
(world, mm). Distances are from points to the other polyline's *segments*,
so the result does not depend on how densely either curve is sampled.
"""
from __future__ import annotations

import numpy as np

from .geometry import arc_length

__all__ = ["backbone_errors", "point_to_polyline_distances", "seen_by_all"]

# Point-segment pairs evaluated at once: bounds memory at ~50 MB of float64.
_PAIRS_PER_CHUNK = 2_000_000


def point_to_polyline_distances(points, polyline) -> np.ndarray:
    """Distance from each point to the nearest point of a polyline.

    Parameters
    ----------
    points : (n, d) array
    polyline : (m, d) array
        Vertices in order; a single vertex is a point.

    Returns
    -------
    (n,) array
        Distances, in the unit of the inputs.
    """
    P = np.asarray(points, dtype=np.float64)
    V = np.asarray(polyline, dtype=np.float64)
    if V.shape[0] == 1:
        return np.linalg.norm(P - V[0], axis=1)
    A = V[:-1]
    AB = V[1:] - A
    ab2 = np.einsum("ij,ij->i", AB, AB)
    ab2 = np.where(ab2 > 0.0, ab2, 1.0)  # zero-length segments: t = 0 below
    out = np.empty(P.shape[0])
    rows = max(1, _PAIRS_PER_CHUNK // A.shape[0])
    for i in range(0, P.shape[0], rows):
        AP = P[i : i + rows, None, :] - A[None, :, :]
        t = np.clip(np.einsum("ijk,jk->ij", AP, AB) / ab2, 0.0, 1.0)
        AP -= t[:, :, None] * AB[None, :, :]
        out[i : i + rows] = np.sqrt(np.einsum("ijk,ijk->ij", AP, AP).min(axis=1))
    return out


def seen_by_all(rig, points_world_mm) -> np.ndarray:
    """Which world points (n, 3) mm project inside the image of every camera of ``rig`` (n,) bool.

    Only those can be triangulated: where the robot's base is outside a view, the
    part of the backbone beyond the image border is seen by at most one camera
    and no method can recover it from the images.

    Parameters
    ----------
    rig : RigCalibration
        Every camera of it is checked (``rig.names``).
    points_world_mm : array_like
        Points (world frame, mm), any shape reshaped to ``(n, 3)``.

    Returns
    -------
    (n,) bool ndarray
        True where the point lies in front of every camera (z > 0 in its frame) and
        projects inside its image.
    """
    P = np.asarray(points_world_mm, dtype=np.float64).reshape(-1, 3)
    seen = np.ones(len(P), bool)
    for name in rig.names:
        cam = rig[name]
        uv, z = cam.project(P)
        seen &= (z > 0) & cam.in_image(np.nan_to_num(uv, nan=-1e9))
    return seen


def backbone_errors(recon_points_mm, true_points_mm, rig=None) -> dict:
    """Shape, tip and length errors of a reconstructed backbone.

    Parameters
    ----------
    recon_points_mm : (n, 3) array
        Reconstructed backbone, base first (mm).
    true_points_mm : (m, 3) array
        Reference backbone, base first (mm).
    rig : RigCalibration, optional
        When given, only what both cameras see is scored (:func:`seen_by_all`):
        true points outside a view need not be reconstructed, and reconstructed
        points outside a view (an extrapolation to a base beyond the image
        border) are not judged. Without it every point counts.

    Returns
    -------
    dict
        ``mean_error_mm``: mean of the point-to-polyline distances of the
        reconstructed points to the true curve and of the true points to the
        reconstructed curve, pooled (a reconstruction that is too short or
        too long is penalized by the second direction);
        ``max_error_mm``: symmetric Hausdorff distance (point to polyline);
        ``tip_error_mm``: distance between the last points;
        ``length_error_mm``: reconstructed minus true arc length (signed), over the scored parts;
        ``scored_fraction``: the fraction of the true backbone's points scored (1 without ``rig``).
    """
    R = np.asarray(recon_points_mm, dtype=np.float64).reshape(-1, 3)
    T = np.asarray(true_points_mm, dtype=np.float64).reshape(-1, 3)
    if R.shape[0] == 0 or T.shape[0] == 0:
        raise ValueError("backbone_errors: empty backbone")
    r_keep = np.ones(len(R), bool) if rig is None else seen_by_all(rig, R)
    t_keep = np.ones(len(T), bool) if rig is None else seen_by_all(rig, T)
    if not r_keep.any() or not t_keep.any():
        raise ValueError("backbone_errors: no part of the backbone is seen by every camera")
    # Distances go to the whole other curve: a point on the true curve is right even where the
    # other curve's points are not scored.
    d = np.concatenate([point_to_polyline_distances(R[r_keep], T), point_to_polyline_distances(T[t_keep], R)])
    return {
        "mean_error_mm": float(d.mean()),
        "max_error_mm": float(d.max()),
        "tip_error_mm": float(np.linalg.norm(R[-1] - T[-1])),
        "length_error_mm": float(_kept_length(R, r_keep) - _kept_length(T, t_keep)),
        "scored_fraction": float(t_keep.mean()),
    }


def _kept_length(points: np.ndarray, keep: np.ndarray) -> float:
    """Arc length (mm) from the first to the last kept point."""
    idx = np.flatnonzero(keep)
    return float(arc_length(points[idx[0] : idx[-1] + 1])[-1])
