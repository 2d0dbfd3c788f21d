"""The paper's method end to end (Morimoto & Sketch, Section III).

Per camera: eigenbackground subtraction, binarization at 0.25 and
largest-region extraction (silhouette), two-disk erosion (centerline). Then a
100^3 voxel volume around the robot is carved against the side camera's
centerline and the survivors against the top camera's. On top of the paper,
the voxels are ordered into a backbone curve (:mod:`recon.backbone`).

:func:`prepare_paper` does the once-per-session work (fitting the
eigenbackgrounds, converting tube radii to pixels); :func:`reconstruct_paper`
does one frame pair.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .backbone import BackboneParams, order_backbone
from .background import EigenBackgroundParams, difference_image, fit_eigenbackground
from .carving import CarvingParams, bounding_box, carve
from .centerline import CenterlineParams, centerline_params_for, extract_centerline
from .errors import FrameError
from .rigcal import RigCalibration
from .silhouette import SilhouetteParams, extract_silhouette

__all__ = ["PaperParams", "PaperModel", "Reconstruction", "prepare_paper", "reconstruct_paper", "camera_order"]


@dataclass(frozen=True)
class PaperParams:
    """Parameters of the paper's method, by stage.

    Attributes
    ----------
    background : EigenBackgroundParams
    silhouette : SilhouetteParams
    outer_tube_radius_mm, inner_tube_radius_mm : float
        Tube radii (mm); converted per camera into the centerline stage's disk
        radii (px) at the robot base (see
        :func:`recon.centerline.centerline_params_for`).
    centerline_min_region_px : int
        Small-region removal on the centerlines (px).
    carving : CarvingParams
    backbone : BackboneParams
    """

    background: EigenBackgroundParams = field(default_factory=EigenBackgroundParams)
    silhouette: SilhouetteParams = field(default_factory=SilhouetteParams)
    outer_tube_radius_mm: float = 0.8
    inner_tube_radius_mm: float = 0.5
    centerline_min_region_px: int = CenterlineParams.min_region_px
    carving: CarvingParams = field(default_factory=CarvingParams)
    backbone: BackboneParams = field(default_factory=BackboneParams)


@dataclass(frozen=True, eq=False)
class PaperModel:
    """What :func:`reconstruct_paper` needs besides the frames.

    Attributes
    ----------
    rig : RigCalibration
    camera_names : tuple of str
        Carving order: ``"side"`` first, then ``"top"``, then the others in
        rig order.
    backgrounds : dict
        Camera name -> :class:`~recon.background.EigenBackground`.
    centerline : dict
        Camera name -> :class:`~recon.centerline.CenterlineParams`.
    """

    rig: RigCalibration
    camera_names: tuple
    backgrounds: dict
    centerline: dict


@dataclass(frozen=True, eq=False)
class Reconstruction:
    """One reconstructed frame pair.

    Attributes
    ----------
    points_world_mm : (m, 3) array
        Backbone, base first, resampled by arc length (world, mm).
    tip_world_mm : (3,) array
        Backbone tip (world, mm).
    transition_s_mm : float
        Arc length of the outer tube's end (mm); NaN if not seen.
    transition_world_mm : (3,) array
        Its position (world, mm); NaN if not seen.
    length_mm : float
        Backbone arc length (mm).
    silhouettes : dict
        Camera name -> (H, W) bool silhouette.
    centerlines : dict
        Camera name -> (H, W) uint8 centerline labels (1 outer, 2 inner).
    box : tuple
        ``(lo_mm, hi_mm)``, the carving volume (world, mm).
    voxel_size_mm : (3,) array
        Voxel edge along world x, y, z (mm).
    n_voxels : int
        Voxels left after carving.
    timings_ms : dict
        Wall time per stage (ms): ``background``, ``silhouette``,
        ``centerline`` (all cameras), ``bounding_box``, ``carve``,
        ``backbone`` and ``total``.
    """

    points_world_mm: np.ndarray
    tip_world_mm: np.ndarray
    transition_s_mm: float
    transition_world_mm: np.ndarray
    length_mm: float
    silhouettes: dict
    centerlines: dict
    box: tuple
    voxel_size_mm: np.ndarray
    n_voxels: int
    timings_ms: dict


def camera_order(names) -> tuple:
    """Carving order of camera names: ``side``, ``top``, then the rest as given."""
    names = list(names)
    first = [n for n in ("side", "top") if n in names]
    return tuple(first + [n for n in names if n not in first])


def prepare_paper(rig: RigCalibration, background_frames: dict, params: PaperParams = PaperParams()) -> PaperModel:
    """Fit the eigenbackgrounds and size the structuring elements.

    Parameters
    ----------
    rig : RigCalibration
    background_frames : dict
        Camera name -> (N, H, W) frames of the empty scene (gray levels).
    params : PaperParams

    Returns
    -------
    PaperModel

    Raises
    ------
    ValueError
        A camera without background frames, too few frames, or frames whose
        size is not the camera's.
    """
    names = camera_order(rig.names)
    if len(names) < 2:
        raise ValueError(f"the paper's method needs two cameras, the rig has {len(names)}")
    backgrounds, centerline = {}, {}
    for name in names:
        cam = rig[name]
        if name not in background_frames:
            raise ValueError(f"{name}: no background frames")
        try:
            model = fit_eigenbackground(background_frames[name], params.background)
        except ValueError as exc:
            raise ValueError(f"{name}: {exc}") from None
        if model.shape != (cam.height, cam.width):
            raise ValueError(
                f"{name}: background frames are {model.shape[1]}x{model.shape[0]} but the camera is {cam.width}x{cam.height}"
            )
        backgrounds[name] = model
        centerline[name] = centerline_params_for(
            cam,
            params.outer_tube_radius_mm,
            params.inner_tube_radius_mm,
            rig.base_point_world_mm,
            min_region_px=params.centerline_min_region_px,
        )
    return PaperModel(rig=rig, camera_names=names, backgrounds=backgrounds, centerline=centerline)


def reconstruct_paper(model: PaperModel, frames: dict, params: PaperParams = PaperParams()) -> Reconstruction:
    """Reconstruct the backbone from one frame per camera.

    Parameters
    ----------
    model : PaperModel
        From :func:`prepare_paper` (with the same ``params``).
    frames : dict
        Camera name -> (H, W) uint8 frame.
    params : PaperParams

    Returns
    -------
    Reconstruction

    Raises
    ------
    FrameError
        With a one-line reason: a missing or malformed frame, no usable
        silhouette, an empty centerline, views that do not agree.
    """
    timings = {}
    t_start = t = time.perf_counter()

    def lap(stage):
        nonlocal t
        now = time.perf_counter()
        timings[stage] = timings.get(stage, 0.0) + 1e3 * (now - t)
        t = now

    names = model.camera_names
    cameras = [model.rig[n] for n in names]
    silhouettes, centerlines = {}, {}
    for name in names:
        if name not in frames or frames[name] is None:
            raise FrameError("no frame", name)
        diff, peak = difference_image(model.backgrounds[name], frames[name], name)
        lap("background")
        silhouettes[name] = extract_silhouette(diff, params.silhouette, name, max_difference=peak)
        lap("silhouette")
        mask, labels = extract_centerline(silhouettes[name], model.centerline[name])
        if not mask.any():
            raise FrameError("empty centerline (the silhouette is thinner than the tubes)", name)
        centerlines[name] = labels
        lap("centerline")
    box = bounding_box(cameras, [silhouettes[n] for n in names], params.carving)
    lap("bounding_box")
    carved = carve(
        cameras,
        [centerlines[n] > 0 for n in names],
        box,
        params.carving,
        centerline_labels=[centerlines[n] for n in names],
    )
    lap("carve")
    bb = order_backbone(
        carved.points_mm,
        carved.labels,
        model.rig.base_point_world_mm,
        model.rig.insertion_axis_world,
        params.backbone,
        voxel_size_mm=carved.voxel_size_mm,
    )
    lap("backbone")
    timings["total"] = 1e3 * (time.perf_counter() - t_start)
    return Reconstruction(
        points_world_mm=bb.points_mm,
        tip_world_mm=bb.tip_mm,
        transition_s_mm=bb.transition_s_mm,
        transition_world_mm=bb.transition_mm,
        length_mm=bb.length_mm,
        silhouettes=silhouettes,
        centerlines=centerlines,
        box=box,
        voxel_size_mm=carved.voxel_size_mm,
        n_voxels=int(carved.points_mm.shape[0]),
        timings_ms=timings,
    )
