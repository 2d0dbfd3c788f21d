"""Scoring a reconstructed frame against its ground truth: one function, used by every command.

``reconstruct`` (and so ``run`` and ``bench --suite``), ``bench``, ``tune`` and ``experiment``
score through :func:`score_frame`, so their figures agree.
"""
from __future__ import annotations

from recon.metrics import backbone_errors
from rig.rundir import finite_or_none

__all__ = ["score_frame"]


def score_frame(result_or_points, truth, rig) -> dict:
    """A reconstructed frame's errors (mm) against its ground truth, over what every camera of ``rig`` sees.

    The one scoring of a frame: ``reconstruct`` (and so ``run`` and ``bench --suite``),
    ``bench``, ``tune`` and ``experiment`` all score through it, so that their figures
    agree. Only what every camera sees counts (:func:`recon.metrics.seen_by_all`): a
    part of the robot outside a view cannot be triangulated by any method.

    Parameters
    ----------
    result_or_points : a method's result (its ``points_world_mm``) or (n, 3) array
        The reconstructed backbone, base first (world frame, mm).
    truth : dict or (m, 3) array
        A frame's ground truth (:meth:`rig.session.Session.truth`, a twin camera
        pair's ``truth``: its ``backbone_world_mm``) or the true backbone itself,
        base first (world frame, mm).
    rig : recon.rigcal.RigCalibration
        The cameras the frame was seen with.

    Returns
    -------
    dict
        :func:`recon.metrics.backbone_errors`'s ``mean_error_mm``, ``max_error_mm``,
        ``tip_error_mm``, ``length_error_mm`` (mm) and ``scored_fraction``, as a
        record holds them: an unknown (non-finite) figure is None.

    Raises
    ------
    ValueError
        ``truth`` has no ``backbone_world_mm``, a backbone is empty, or no part of
        one is seen by every camera: the frame cannot be scored.
    """
    if rig is None:  # scoring every point would judge what no camera pair can see
        raise TypeError("score_frame: the rig is needed (errors count what every camera sees)")
    pts = getattr(result_or_points, "points_world_mm", result_or_points)
    if isinstance(truth, dict):
        if truth.get("backbone_world_mm") is None:
            raise ValueError("the ground truth has no backbone_world_mm array")
        truth = truth["backbone_world_mm"]
    return {k: finite_or_none(v) for k, v in backbone_errors(pts, truth, rig).items()}
