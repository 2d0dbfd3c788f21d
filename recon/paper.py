"""The paper's method end to end (Morimoto & Sketch, Section III).

Per camera: eigenbackground subtraction, binarization at 0.25 and
largest-region extraction (silhouette), two-disk erosion (centerline). Then a
100^3 voxel volume around the robot is carved against the side camera's
centerline and the survivors against the top camera's. On top of the paper,
the voxels are ordered into a backbone curve (:mod:`recon.backbone`).

:func:`prepare_paper` does the once-per-session work (fitting the
eigenbackgrounds, converting tube radii to pixels); :func:`reconstruct_paper`
does one frame pair.

Where this departs from the paper, and why, is listed in
``docs/paper-method.md``; in short: the silhouette is closed and its holes
filled (specular cracks), only regions as wide as a tube count as the robot
(jitter edges), the structuring elements are sized from the tube radii in
pixels and the silhouette's measured width, stretches too thin for either
disk are bridged by their middle line, the outer tube's region (not its
centerline) is subtracted before the second erosion, the voxels are ordered
along a spanning tree that bridges gaps, and a camera that does not see the
robot base lets the robot cross the image border on that side.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from .backbone import BackboneParams, back_to_base_plane, back_to_border, from_base_plane, from_base_point, order_backbone
from .background import EigenBackgroundParams, difference_image, fit_eigenbackground, to_gray
from .carving import CarvingParams, bounding_box, carve
from .centerline import CenterlineParams, centerline_params_for, extract_centerline
from .errors import FrameError
from .geometry import arc_length, resample_polyline
from .rigcal import RigCalibration
from .silhouette import BORDERS, SilhouetteParams, extract_silhouette, hysteresis_threshold
from .subvoxel import SubvoxelParams, refine_backbone

__all__ = ["PaperParams", "PaperModel", "Reconstruction", "prepare_paper", "reconstruct_paper", "camera_order",
           "check_tube_widths", "behind_base_pixels"]


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
    edge_loss_px : float
        How much narrower than the tube (px per side) a silhouette is expected
        to be: the starting point of the per-frame width measurement and the
        fallback when it cannot be made (see
        :func:`recon.centerline.measure_edge_loss`).
    measure_width : bool
        Size the structuring elements per frame from the tube radii in pixels
        and the silhouette's measured width (default); False: once per
        session from the tube radii and ``edge_loss_px``.
    outer_disk_position : float
        Where the large disk's radius lies between the inner tube's and the
        outer tube's half-width in the image (0 to 1; 0.5 the most margin
        either way). See :func:`recon.centerline.disk_radii`.
    inner_disk_margin_px : float
        The small disk's radius is the inner tube's half-width minus this (px).
    min_tube_width_px : float
        Every frame is refused (:class:`~recon.errors.FrameError`) when a
        tube is narrower than this in a camera's image at the robot base
        (px): below it the inner tube's centerline breaks up and the backbone
        silently stops short of the tip (see docs/envelope.md, "Tube too thin
        to resolve", for the measurement behind the default).
    cut_behind_base : bool
        Ignore the image behind the robot base (not in the paper): the
        half-plane beyond the line through the projected base, across the
        projected insertion axis, less the outer tube's radius and 2 px. The
        actuation unit and pin vise sit there; camera jitter leaves their
        edges in every difference image, and at a low threshold they join
        the robot's silhouette through the pin vise and run it off the image
        border. Assumes the robot never bends back behind its base plane.
        Not applied in a camera that sees the insertion axis foreshortened to
        less than a third.
    difference_blur_px : float
        Gaussian blur (px) of the signed difference image before its absolute
        value (not in the paper; 0 disables it). At 0.5 px it divides the
        sensor noise by ~1.8 while tubes a few pixels wide keep their
        contrast: where a tube is nearly the backdrop's brightness, 10-20 gray
        levels over noise of 4, the paper's per-pixel difference lost it.
        0.7 px did as well on the wide scenes but merged the jitter lines
        along the actuation unit's edges into a blob as wide as a tube, so a
        robot-free frame read as a robot leaving the view.
        Not applied to masks (background frames in [0, 1]): they have no
        noise, and a blurred mask only widens under the low threshold.
    max_tip_overrun_px : float
        The frame is reported suspect (``Reconstruction.suspect_reason``)
        when a view's centerline goes on beyond the reprojected tip for more
        than this (px; see :func:`centerline_beyond_tip_px`): the other view
        lost the tube there (a faint stretch its silhouette missed), and the
        carving, which keeps only what both views see, stopped short. Not in
        the paper; 0 disables it.
    max_base_gap_mm : float
        A backbone that starts up to this far (mm) in front of the base plane
        is continued straight back to it and then started at the base point
        along the insertion axis (not in the paper; as the fast method's
        ``max_base_gap_mm``).
    max_dropped_fraction : float
        The frame is refused (:class:`~recon.errors.FrameError`) when the
        backbone leaves out more than this fraction of the carved voxels:
        pieces it could not bridge to (farther than
        ``BackboneParams.max_gap_mm``, or the segment leaves a silhouette).
        On the twin scenes good frames leave out none; a frame that left out
        39 % was the distal half alone (not in the paper; 1 disables it).
    carving : CarvingParams
    backbone : BackboneParams
    subvoxel : SubvoxelParams or None
        The carved backbone moved onto the views' centerlines and its tip to
        where they end (:mod:`recon.subvoxel`; not in the paper). None: the
        backbone as the voxels give it, quantized to the grid.
    """

    background: EigenBackgroundParams = field(default_factory=EigenBackgroundParams)
    silhouette: SilhouetteParams = field(default_factory=SilhouetteParams)
    outer_tube_radius_mm: float = 0.8
    inner_tube_radius_mm: float = 0.5
    centerline_min_region_px: int = CenterlineParams.min_region_px
    edge_loss_px: float = CenterlineParams.edge_loss_px
    measure_width: bool = True
    outer_disk_position: float = CenterlineParams.outer_disk_position
    inner_disk_margin_px: float = CenterlineParams.inner_disk_margin_px
    min_tube_width_px: float = 3.0
    cut_behind_base: bool = True
    difference_blur_px: float = 0.5
    max_tip_overrun_px: float = 8.0
    max_dropped_fraction: float = 0.1
    max_base_gap_mm: float = 6.0
    carving: CarvingParams = field(default_factory=CarvingParams)
    backbone: BackboneParams = field(default_factory=BackboneParams)
    subvoxel: SubvoxelParams | None = field(default_factory=SubvoxelParams)


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
    tube_radii_px : dict
        Camera name -> (outer, inner) tube radius (px) at the robot base.
    behind_base : dict
        Camera name -> flat indices of the pixels behind the robot base
        (``cut_behind_base``), or None.
    full_scale : dict
        Camera name -> factor from the frames' gray levels to 8-bit ones for
        the contrast floor (``SilhouetteParams.min_contrast``): 255 for a
        camera whose background frames are all in [0, 1] (binary or [0, 1]
        float masks), else 1.
    attach_gap_px : dict
        Camera name -> the backbone's longest bridged gap
        (``BackboneParams.max_gap_mm``) in px at the robot base: regions as
        wide as a tube within it of the largest join the silhouette.
    base_px : dict
        Camera name -> the robot base's projection (px) where the camera sees
        it (inside the image, in front), else None: of two regions of similar
        size the one at the base is the robot (:func:`recon.silhouette.extract_silhouette`).
    silhouette : dict
        Camera name -> :class:`~recon.silhouette.SilhouetteParams`: the
        method's, with the border the robot base lies beyond (if it lies
        outside the image) added to ``allowed_borders``.
    """

    rig: RigCalibration
    camera_names: tuple
    backgrounds: dict
    centerline: dict
    tube_radii_px: dict = field(default_factory=dict)
    silhouette: dict = field(default_factory=dict)
    behind_base: dict = field(default_factory=dict)
    full_scale: dict = field(default_factory=dict)
    attach_gap_px: dict = field(default_factory=dict)
    base_px: dict = field(default_factory=dict)


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
    centerline_disks : dict
        Camera name -> ``{"outer_radius_px", "inner_radius_px",
        "edge_loss_px"}``: the structuring elements used and the measured
        silhouette edge loss (None when not measured).
    tip_overrun_px : dict
        Camera name -> length (px) of its centerline beyond the reprojected
        tip (:func:`centerline_beyond_tip_px`).
    suspect_reason : str or None
        Why the method itself cannot vouch for this shape (the frame is then
        reported ``suspect``): a view whose centerline goes on beyond the tip
        (``max_tip_overrun_px``).
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
    centerline_disks: dict = field(default_factory=dict)
    tip_overrun_px: dict = field(default_factory=dict)
    suspect_reason: object = None


def camera_order(names) -> tuple:
    """Carving order of camera names: ``side``, ``top``, then the rest as given.

    Parameters
    ----------
    names : iterable of str
        The rig's camera names (e.g. ``rig.names``).

    Returns
    -------
    tuple of str
        The same names, ``side`` and ``top`` (those present) first.
    """
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
    backgrounds, centerline, radii, sil, cut, scale, attach, base = {}, {}, {}, {}, {}, {}, {}, {}
    for name in names:
        cam = rig[name]
        if name not in background_frames:
            raise ValueError(f"{name}: no background frames")
        try:
            model = fit_eigenbackground(to_gray(background_frames[name]), params.background)
        except ValueError as exc:
            raise ValueError(f"{name}: {exc}") from None
        if model.shape != (cam.height, cam.width):
            raise ValueError(
                f"{name}: background frames are {model.shape[1]}x{model.shape[0]} but the camera is {cam.width}x{cam.height}"
            )
        backgrounds[name] = model
        # Masks (0/1 or [0, 1] floats): the contrast floor is in 8-bit gray levels.
        scale[name] = 255.0 if float(np.max(background_frames[name])) <= 1.0 else 1.0
        centerline[name] = centerline_params_for(
            cam,
            params.outer_tube_radius_mm,
            params.inner_tube_radius_mm,
            rig.base_point_world_mm,
            min_region_px=params.centerline_min_region_px,
            edge_loss_px=params.edge_loss_px,
            adaptive=params.measure_width,
            outer_disk_position=params.outer_disk_position,
            inner_disk_margin_px=params.inner_disk_margin_px,
        )
        mmpp = cam.mm_per_pixel_at(rig.base_point_world_mm)
        radii[name] = (params.outer_tube_radius_mm / mmpp, params.inner_tube_radius_mm / mmpp)
        attach[name] = params.backbone.max_gap_mm / mmpp
        # A base on the border, or inside it by less than the tube's radius, has the silhouette touch it too
        # (wide-3-14's side view: the base at u = 0, the robot entering there; every frame refused as leaving).
        near = params.silhouette.border_margin_px + radii[name][0] + 1.0
        behind = [b for b in base_borders(cam, rig.base_point_world_mm, near) if b not in params.silhouette.allowed_borders]
        base[name] = _seen_base_px(cam, rig.base_point_world_mm)
        sil[name] = replace(params.silhouette, allowed_borders=params.silhouette.allowed_borders + tuple(behind))
        cut[name] = (
            behind_base_pixels(cam, rig.base_point_world_mm, rig.insertion_axis_world, radii[name][0] + 2.0)
            if params.cut_behind_base
            else None
        )
    return PaperModel(
        rig=rig, camera_names=names, backgrounds=backgrounds, centerline=centerline, tube_radii_px=radii, silhouette=sil,
        behind_base=cut, full_scale=scale, attach_gap_px=attach, base_px=base,
    )


def behind_base_pixels(camera, base_point_world_mm, insertion_axis_world, margin_px: float):
    """Flat indices of the pixels behind the robot base as ``camera`` sees it, or None.

    The base plane (through the base, across the insertion axis) is seen as
    the line through the projected base across the projected axis; pixels
    farther than ``margin_px`` beyond it, on the side away from the robot, are
    behind the base. None when the camera sees the axis foreshortened to less
    than a third of its length (the plane is then not seen edge-on) or the
    base is behind the camera.

    Parameters
    ----------
    camera : recon.camera.Camera
        Its pose, intrinsics and distortion place the base line in the image.
    base_point_world_mm : (3,) array_like
        The robot base (world frame, mm).
    insertion_axis_world : (3,) array_like
        Insertion direction (world frame, unit vector), pointing from the base to the tip.
    margin_px : float
        Pixels within this distance (px) behind the base line are kept.

    Returns
    -------
    ndarray of int or None
        Flat indices ``v * width + u`` into the ``(height, width)`` image, or None (see above,
        or no pixel behind the line).
    """
    base = np.asarray(base_point_world_mm, float).reshape(3)
    axis = np.asarray(insertion_axis_world, float).reshape(3)
    step_mm = 10.0
    pc = camera.world_to_camera(np.stack([base, base + step_mm * axis]))
    if not np.all(pc[:, 2] > 0):
        return None
    # Foreshortening: the axis' image length against that of a step across the line of sight.
    uv = (camera.K[:2, :2] @ (pc[:, :2] / pc[:, 2:3]).T).T
    d = uv[1] - uv[0]
    full = float(np.sqrt(camera.K[0, 0] * camera.K[1, 1])) * step_mm / float(pc[0, 2])
    if np.linalg.norm(d) < full / 3.0:
        return None
    # The line through the distorted projection of the base, across the axis' direction there.
    (b_uv,), _ = camera.project(base[None])
    n = d / np.linalg.norm(d)
    v, u = np.mgrid[0 : camera.height, 0 : camera.width]
    along = (u - b_uv[0]) * n[0] + (v - b_uv[1]) * n[1]
    idx = np.flatnonzero(along.ravel() < -float(margin_px))
    return idx if idx.size else None


def check_tube_widths(camera: str, tube_radii_px, min_width_px: float) -> None:
    """Refuse a frame in which a tube is too thin for the method to resolve.

    Parameters
    ----------
    camera : str
        Camera name (prefixes the error).
    tube_radii_px : sequence of float or None
        Outer and inner tube radius in the camera's image at the robot base
        (px), outermost first; None: nothing to check.
    min_width_px : float
        The method's ``min_tube_width_px``.

    Raises
    ------
    FrameError
        One line naming the camera, the tube, its width (px) and the limit.
    """
    if tube_radii_px is None:
        return
    # Tubes of a known size: a too-thin one cannot be told from the images apart from a retracted one
    # (both end the silhouette at the outer tube), so the check is on the parameters, not on the frame.
    for name, r in zip(("outer", "inner"), tube_radii_px):
        if 2.0 * float(r) < min_width_px:
            raise FrameError(f"{name} tube is {2.0 * float(r):.1f} px wide at the robot base, less than "
                             f"min_tube_width_px = {min_width_px:g}: too thin to resolve", camera)


def silhouette_bridge_check(cameras, silhouettes, voxel_size_mm):
    """``check(p, q)``: whether the segment p-q (world mm) projects into every silhouette.

    Used by :func:`recon.backbone.order_backbone` to bridge a gap in the
    carved cloud longer than the pieces it joins (a stretch where a centerline
    broke up, e.g. a tube whose specular side matches the backdrop and whose
    silhouette is only half as wide there): the robot's silhouettes are
    continuous across a real gap. Points along the segment, every half voxel
    edge, may lie off a silhouette by a voxel's half-diagonal seen at their
    depth plus 1 px (the chord of a curved robot, the voxels' quantization).

    Parameters
    ----------
    cameras : sequence of recon.camera.Camera
        The cameras, in the order of ``silhouettes``.
    silhouettes : sequence of (H, W) bool arrays
        Each camera's silhouette (the camera's image size, px).
    voxel_size_mm : float or (3,) array_like
        The carving voxels' edge lengths (mm).

    Returns
    -------
    callable
        ``check(p, q) -> bool`` for two world points (3,) mm: False as soon as a sample of
        the segment is behind a camera, outside its image or too far off its silhouette.
        The distance transforms are computed on first use and kept.
    """
    voxel = np.broadcast_to(np.asarray(voxel_size_mm, float), (3,))
    half_diag = 0.5 * float(np.linalg.norm(voxel))
    step = 0.5 * float(voxel.min())
    dist = {}

    def check(p, q) -> bool:
        p, q = np.asarray(p, float), np.asarray(q, float)
        n = max(2, int(np.ceil(np.linalg.norm(q - p) / step)) + 1)
        pts = p + np.linspace(0.0, 1.0, n)[:, None] * (q - p)
        for k, (cam, sil) in enumerate(zip(cameras, silhouettes)):
            if k not in dist:
                # Distance (px) to the nearest silhouette pixel, computed on first use only.
                dist[k] = cv2.distanceTransform((~np.asarray(sil, bool)).view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5)
            uv, z = cam.project(pts)
            if not np.all(z > 0) or not np.all(np.isfinite(uv)):
                return False
            iu, iv = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
            if iu.min() < 0 or iv.min() < 0 or iu.max() >= cam.width or iv.max() >= cam.height:
                return False
            tol = np.sqrt(cam.K[0, 0] * cam.K[1, 1]) * half_diag / z + 1.0
            if np.any(dist[k][iv, iu] > tol):
                return False
        return True

    return check


def _chord_index(pts: np.ndarray, length_mm: float) -> int:
    """Index of the backbone point ~5 mm (at most a third of the robot) from its first: the chord to it
    gives the direction at the base. The first carved points can curl by a voxel, and a 2 mm chord ran a
    continuation off the tube (wide-1-63 frame 0: 28 px off in the top view); a precurved outer tube bends
    away from a 5 mm chord by ~0.1 mm."""
    step = float(np.median(np.linalg.norm(np.diff(pts, axis=0), axis=1)))
    return min(len(pts) - 1, max(2, int(np.ceil(min(5.0, length_mm / 3.0) / max(step, 1e-6)))))


def _continued_back(bb, back: np.ndarray):
    """The backbone with the points ``back`` (farthest first) put before its first point."""
    if not len(back):
        return bb
    ext = float(np.linalg.norm(back[0] - bb.points_mm[0]))
    return replace(bb, points_mm=np.concatenate([back, bb.points_mm]), length_mm=bb.length_mm + ext,
                   transition_s_mm=bb.transition_s_mm + ext)


def _onto_line(points, origin, other):
    """``points`` (world, mm) projected onto the line through ``origin`` and ``other``: the projections, their
    signed distances from ``origin`` (positive away from ``other``, mm) and the points' distances from the line (mm)."""
    d = origin - other
    d = d / max(float(np.linalg.norm(d)), 1e-12)
    along = (points - origin) @ d
    on_line = origin + along[:, None] * d
    return on_line, along, np.linalg.norm(points - on_line, axis=1)


def _size_across_mm(directions: np.ndarray, voxel_size_mm) -> np.ndarray:
    """A voxel's size (mm) along each unit direction (n, 3): the norm of its edges weighted by the direction's
    components (world axes). One number for cubic voxels; for a long voxel, its short edge across it."""
    return np.linalg.norm(directions * np.broadcast_to(np.asarray(voxel_size_mm, float), (3,)), axis=1)


def _straight_start(bb, voxel_size_mm):
    """The backbone with its first ~5 mm put onto the line of the next ~5 mm, where they curl off it by more
    than the voxel's size in the direction they curl (the norm of the edges weighted by that direction).

    Where the robot enters across an image border at a shallow angle, that border's plane cuts the carved tube
    at a slant; the ordering's bins are geodesic distances from the cut's corner and stay slanted for a few
    diameters, so the backbone's first millimetres curl towards the corner (seen: wide-3-21 frame 1, 3.3 mm
    off over its first 5.5 mm; wide-3-46 frame 1, 1.8 mm over 3.5 mm). A precurved tube bends ~0.1 mm off
    5 mm of chord: a curl of more than a voxel is the cut's. The voxel is measured across the curl, not by its largest
    edge: a 100^3 grid over a long, thin robot has voxels 4x longer along the tube than across it
    (wide-2-1 frame 0: a 0.95 mm curl across 0.27 mm voxels, under the 1.09 mm edge along the tube,
    left the start 12 px footprints off). The points keep their distances along the line. Not for a base in
    view: there the line of the next 5 mm, extrapolated back, leaves a tube bent near its base (wide-2-14
    frame 0: 7 -> 14 px footprints).

    ``voxel_size_mm``: the voxel edge (mm), one number or one per world axis.
    """
    pts = bb.points_mm
    k = _chord_index(pts, bb.length_mm)
    if 2 * k >= len(pts):
        return bb
    on_line, _, off = _onto_line(pts[:k], pts[k], pts[2 * k])
    across = (pts[:k] - on_line) / np.maximum(off, 1e-12)[:, None]
    if np.all(off <= _size_across_mm(across, voxel_size_mm)):
        return bb
    new = np.concatenate([on_line, pts[k:]])
    length_mm = float(arc_length(new)[-1])
    return replace(bb, points_mm=new, length_mm=length_mm, transition_s_mm=bb.transition_s_mm - (bb.length_mm - length_mm))


def _straight_end(bb, voxel_size_mm):
    """The backbone with its last 2.5 voxels (the longest edge) put onto the line of the 5 mm before, where they
    hook off it by more than half the voxel's size across the hook beyond what that stretch's own bend predicts.

    The carved tip ends where the two views' silhouette ends cut it, two planes at a slant to the tube; the
    last bins lean towards the longer corner and the backbone hooks (seen: wide-2-1 frame 2, the last 2.5 mm
    0.6 mm off the tube, 0.87 mm after the refinement). A tube bent to radius R leaves that line by
    ((L/2 + e)^2 - (L/2)^2) / 2R at a distance e past a chord of length L, 0.4 mm for R = 30 mm over
    these lengths; R is taken from the stretch's sagitta h (1/2R = 4h/L^2), so a curved end keeps its
    bend (wide-1-38 frame 1: straightened, 0.6 mm off at a 1.2 mm voxel). As for the start
    (:func:`_straight_start`), the voxel is measured across the hook: half the longest edge let hooks across
    thin voxels stay (seeds 2/3: tip error median 2.76 -> 2.42 and 3.24 -> 3.16 px footprints). The points
    keep their distances along the line.

    ``voxel_size_mm``: the voxel edge (mm), one number or one per world axis.
    """
    edges_mm = np.broadcast_to(np.asarray(voxel_size_mm, float), (3,))
    voxel_mm = float(np.max(edges_mm))
    pts = bb.points_mm
    s = arc_length(pts)
    a = int(np.searchsorted(s, s[-1] - 2.5 * voxel_mm))
    b = int(np.searchsorted(s, s[a] - 5.0))
    if a >= len(pts) - 1 or b >= a or a < 2:
        return bb
    on_line, along, off = _onto_line(pts[a:], pts[a], pts[b])
    chord = float(np.linalg.norm(pts[a] - pts[b]))
    sag = float(np.max(_onto_line(pts[b:a], pts[a], pts[b])[2]))
    bend = 4.0 * sag / chord ** 2 * ((chord / 2 + along) ** 2 - chord ** 2 / 4)
    across = (pts[a:] - on_line) / np.maximum(off, 1e-12)[:, None]
    if np.all(off <= 0.5 * _size_across_mm(across, edges_mm) + bend):
        return bb
    new = np.concatenate([pts[:a], on_line])
    return replace(bb, points_mm=new, tip_mm=new[-1].copy(), length_mm=float(arc_length(new)[-1]))


def _continue_to_border(rig: RigCalibration, names, bb):
    """The backbone continued straight back to where the first camera loses it (robot entering across the border).

    Carving keeps only what every view sees, and the centerlines end a disk
    short of the border: on the wide suite such backbones started 2-3 mm
    (10-16 px footprints) in from where both views still see the robot.
    """
    pts = bb.points_mm
    if len(pts) < 3:
        return bb
    step = float(np.median(np.linalg.norm(np.diff(pts, axis=0), axis=1)))
    return _continued_back(bb, back_to_border(rig, names, pts[0], pts[_chord_index(pts, bb.length_mm)] - pts[0], step))


def _continue_to_base(rig: RigCalibration, bb, max_gap_mm: float):
    """The backbone continued straight back to the base plane (:func:`recon.backbone.back_to_base_plane`).

    The images are cut behind the base (``cut_behind_base``) and the
    centerlines end a disk short of the cut: on the wide suite such backbones
    started 14-24 px (pixel footprints) in front of the base, the frames'
    largest errors.
    """
    pts = bb.points_mm
    if len(pts) < 3:
        return bb
    step = float(np.median(np.linalg.norm(np.diff(pts, axis=0), axis=1)))
    return _continued_back(bb, back_to_base_plane(pts[0], pts[_chord_index(pts, bb.length_mm)] - pts[0], rig.base_point_world_mm,
                                                  rig.insertion_axis_world, max_gap_mm, step))


def _started_at_base(rig: RigCalibration, bb, max_gap_mm: float):
    """The backbone started at the base point, along the insertion axis (:func:`recon.backbone.from_base_point`),
    where it starts on the base plane or at most ``max_gap_mm`` in front of it (the base in view).

    The carved start is where the images' cut behind the base and the disks' ends leave it: continued
    straight back along a 5 mm chord, or cut at the plane, it started up to 5-7 px footprints off the
    base on ok frames of wide seeds 2 and 3 (wide-2-8 frame 0: 6.5 -> 1.9 px footprints, round 34).
    """
    pts = bb.points_mm
    h = float((pts[0] - np.asarray(rig.base_point_world_mm, np.float64)) @ np.asarray(rig.insertion_axis_world, np.float64))
    if len(pts) < 4 or not -1e-6 <= h <= max_gap_mm:
        return bb
    step = float(np.median(np.linalg.norm(np.diff(pts, axis=0), axis=1)))
    new, added_mm = from_base_point(pts, rig.base_point_world_mm, rig.insertion_axis_world, step)
    return replace(bb, points_mm=new, length_mm=float(arc_length(new)[-1]), transition_s_mm=bb.transition_s_mm + added_mm)


def _from_base(rig: RigCalibration, bb):
    """The backbone cut where it crosses the base plane (:func:`recon.backbone.from_base_plane`), and how far
    (mm) from the base the cut part reached (0 where nothing was cut).

    Carving keeps what lies within ``radius + 2`` px of the cut behind the
    base, and the refinement follows the centerlines' ends there: on seeds
    2-5 of the wide suite backbones started behind the plane, their first
    points up to 2.4 mm from the base, most in-view frames' largest errors
    (wide-2-9 frame 0: 9.7 -> 3.9 px footprints once cut).
    """
    pts = from_base_plane(bb.points_mm, rig.base_point_world_mm, rig.insertion_axis_world)
    if len(pts) == len(bb.points_mm) and np.array_equal(pts, bb.points_mm):
        return bb, 0.0
    base = np.asarray(rig.base_point_world_mm, np.float64)
    h = (bb.points_mm - base) @ np.asarray(rig.insertion_axis_world, np.float64)
    lead = bb.points_mm[:int(np.argmax(h >= 0.0))]
    length_mm = float(arc_length(pts)[-1])
    bb = replace(bb, points_mm=pts, length_mm=length_mm, transition_s_mm=bb.transition_s_mm - (bb.length_mm - length_mm))
    return bb, float(np.max(np.linalg.norm(lead - base, axis=1)))


#: What a start behind the base plane is allowed, in voxel diagonals beyond the cut's margin (see
#: :func:`_behind_base_doubt`).
_BEHIND_BASE_VOXEL_DIAGONALS = 1.0


def _behind_base_doubt(rig: RigCalibration, names, reached_mm: float, outer_radius_mm: float, voxel_size_mm):
    """The doubt (str or None) on a backbone whose carved start reached ``reached_mm`` from the base, behind
    its plane, before :func:`_from_base` cut it.

    The images are cut ``radius + 2`` px behind the base (``cut_behind_base``), so the carving reaches up to
    about the outer tube's radius plus 2 px (at the base, in the camera with the largest footprint) behind
    the plane, rounded to the voxel grid: one voxel diagonal more. On seeds 2-5 of the wide suite the
    starts reached at most 0.77 of that; a start beyond it was carved from something other than the tube's
    end at the base, and the backbone after the cut cannot be vouched for (seed 6, wide-6-32 frame 1:
    2.6 mm, 1.9 times the allowance, 46 px footprints off at the start and 21 at the tip).
    """
    if reached_mm <= 0.0:
        return None
    footprint_mm = max(rig[n].mm_per_pixel_at(rig.base_point_world_mm) for n in names)
    diagonal_mm = float(np.linalg.norm(np.broadcast_to(np.asarray(voxel_size_mm, float), (3,))))
    allowed_mm = outer_radius_mm + 2.0 * footprint_mm + _BEHIND_BASE_VOXEL_DIAGONALS * diagonal_mm
    if reached_mm <= allowed_mm:
        return None
    return (f"the carved backbone started {reached_mm:.1f} mm from the base, behind its plane (more than the "
            f"{allowed_mm:.1f} mm the cut behind the base and a voxel explain): cut there, not vouched for")


#: A view's centerline within the outer tube's image radius plus this (px) of the reprojected
#: backbone is explained by it: voxel rounding (a third of a voxel, about 1 px) plus the
#: centerline's own wander on a tube a few pixels wide.
_EXPLAINED_TOL_PX = 3.0


def centerline_beyond_tip_px(camera, centerline: np.ndarray, points_world_mm: np.ndarray, outer_radius_px: float) -> float:
    """How far (px of centerline) a view's centerline goes on beyond the reprojected backbone's tip.

    The carving keeps only what every view sees: where one view's silhouette
    loses a faint stretch of tube, the backbone stops there, and it
    reprojects onto the tube in both views. The view that did see the
    stretch still has it in its centerline, beyond the reprojected tip.

    Parameters
    ----------
    camera : recon.camera.Camera
    centerline : (H, W) array
        The view's centerline (nonzero on it).
    points_world_mm : (n, 3) array
        The backbone, base to tip (world, mm).
    outer_radius_px : float
        The outer tube's radius in this image (px).

    Returns
    -------
    float
        Pixels of centerline farther than ``outer_radius_px +
        _EXPLAINED_TOL_PX`` from the reprojected backbone, in pieces that
        start at its tip (pieces less than a tube diameter apart count as
        one); 0 when the tip is outside the image.
    """
    uv = camera.project(np.asarray(points_world_mm, float))[0]
    uv = uv[np.all(np.isfinite(uv), axis=1)]
    h, w = centerline.shape
    if len(uv) < 2 or not (0 <= uv[-1, 0] <= w - 1 and 0 <= uv[-1, 1] <= h - 1):
        return 0.0
    reach = int(math.ceil(outer_radius_px + _EXPLAINED_TOL_PX))
    on = (np.asarray(centerline) > 0).astype(np.uint8)
    x, y, bw, bh = cv2.boundingRect(on)  # only where the centerline is: a 5 MP frame costs as a small one
    if bw == 0:
        return 0.0
    on = on[y:y + bh, x:x + bw]
    uv = uv - (x, y)
    explained = np.zeros_like(on)
    cv2.polylines(explained, [np.round(uv * 16).astype(np.int32)], False, 1, thickness=2 * reach + 1, shift=4)
    beyond = on & (explained == 0)
    # A faint tube's centerline comes in pieces: gaps up to a tube diameter join them.
    gap = 2 * int(math.ceil(outer_radius_px)) + 1
    n, labels = cv2.connectedComponents(cv2.dilate(beyond, np.ones((gap, gap), np.uint8)), connectivity=8)
    if n <= 1:
        return 0.0
    near_tip = np.zeros_like(on)
    cv2.circle(near_tip, (int(round(uv[-1, 0])), int(round(uv[-1, 1]))), reach + 3, 1, -1)
    ids = np.unique(labels[(near_tip > 0) & (labels > 0)])
    return float((np.isin(labels, ids) & (beyond > 0)).sum()) if len(ids) else 0.0


def _tip_overrun(model: PaperModel, names, centerlines: dict, points_world_mm, params: PaperParams) -> tuple:
    """Per view the centerline beyond the tip (px), and the doubt it raises (str or None)."""
    overrun = {}
    for n in names:
        radii = model.tube_radii_px.get(n)
        overrun[n] = centerline_beyond_tip_px(model.rig[n], centerlines[n], points_world_mm,
                                              radii[0] if radii else _EXPLAINED_TOL_PX)
    worst = max(names, key=lambda n: overrun[n])
    reason = None
    if params.max_tip_overrun_px > 0 and overrun[worst] > params.max_tip_overrun_px:
        reason = (f"{worst}: the centerline goes on {overrun[worst]:.0f} px beyond the reconstructed tip "
                  f"(limit {params.max_tip_overrun_px:g} px): another view lost the tube there")
    return overrun, reason


def _on_silhouettes(cameras, silhouettes: list, points_world_mm: np.ndarray) -> np.ndarray:
    """(n,) bool: the points project within a pixel of the silhouette in every view (outside an image: not judged)."""
    ok = np.ones(len(points_world_mm), bool)
    for cam, sil in zip(cameras, silhouettes):
        h, w = sil.shape
        uv = np.rint(cam.project(points_world_mm)[0])
        inside = np.all(np.isfinite(uv), axis=1) & (uv[:, 0] >= 1) & (uv[:, 1] >= 1) & (uv[:, 0] < w - 1) & (uv[:, 1] < h - 1)
        iu, iv = uv[inside, 0].astype(int), uv[inside, 1].astype(int)
        near = np.zeros(int(inside.sum()), bool)
        for dv in (-1, 0, 1):
            for du in (-1, 0, 1):
                near |= sil[iv + dv, iu + du] > 0
        ok[np.flatnonzero(inside)[~near]] = False
    return ok


def _trim_tip(cameras, silhouettes: list, bb, max_trim_mm: float):
    """The backbone's end cut back to its last point on every view's silhouette, by at most ``max_trim_mm``.

    Voxels at the tip that both centerlines' ends carve can smear along an
    epipolar line: the backbone's end hooks off the tube in one view while
    it lies along the other's ray (wide-3-21 frame 0, a mask session: 8 px
    off the top view's mask, 24 footprints of error). No robot point lies
    off a silhouette.
    """
    pts = bb.points_mm
    s = arc_length(pts)
    near_end = s >= s[-1] - max_trim_mm
    ok = _on_silhouettes(cameras, silhouettes, pts[near_end])
    if ok.all() or not ok.any():
        return bb
    last = int(np.flatnonzero(near_end)[0] + np.flatnonzero(ok)[-1])
    if last < 1:
        return bb
    pts = pts[:last + 1]
    return replace(bb, points_mm=pts, tip_mm=pts[-1].copy(), length_mm=float(arc_length(pts)[-1]))


def _refined(cameras, centerlines: list, disks: list, bb, voxel_size_mm, params: PaperParams, silhouettes=None):
    """The backbone moved onto the views' centerlines (:func:`recon.subvoxel.refine_backbone`), resampled.

    ``disks``: per camera, :func:`recon.centerline.extract_centerline`'s info (the small disk made the tip's centerline).
    """
    pts = refine_backbone(cameras, centerlines, bb.points_mm, voxel_size_mm, params.subvoxel,
                          erosion_radii_px=[d.get("inner_radius_px") for d in disks], silhouettes=silhouettes,
                          tip_radius_mm=params.inner_tube_radius_mm)
    pts = resample_polyline(pts, params.backbone.step_mm)
    s = arc_length(pts)
    tr = bb.transition_s_mm
    at = np.array([np.interp(tr, s, pts[:, k]) for k in range(3)]) if np.isfinite(tr) and tr <= s[-1] else bb.transition_mm
    return replace(bb, points_mm=pts, tip_mm=pts[-1].copy(), length_mm=float(s[-1]), transition_mm=at)


def _seen_base_px(camera, base_point_world_mm):
    """The base's projection (2,) px where ``camera`` sees it (in front, inside the image), else None."""
    uv, z = camera.project(np.asarray(base_point_world_mm, float).reshape(1, 3))
    if not (z[0] > 0 and np.all(np.isfinite(uv)) and camera.in_image(uv)[0]):
        return None
    return uv[0]


def base_borders(camera, base_point_world_mm, margin_px: float = 0.0) -> list:
    """Image borders the robot base lies beyond (or within ``margin_px`` of), as ``camera`` sees it.

    When the camera does not see where the tubes leave the actuation unit, the
    robot enters the image across the border on that side: its silhouette
    touching that border is expected, not the robot leaving the view. So it is
    where the base lies on the border or just inside it: the tube's silhouette
    is as wide as the tube there.

    Parameters
    ----------
    camera : recon.camera.Camera
    base_point_world_mm : (3,) array_like
        The robot base (world frame, mm).
    margin_px : float, optional
        A base within this many px inside a border counts for that border too
        (0: beyond the image's outer pixel edges only).

    Returns
    -------
    list of str
        Among ``"left"``, ``"right"``, ``"top"``, ``"bottom"`` (in :data:`recon.silhouette.BORDERS`
        order): where the base's projection, with or without distortion, lies beyond the
        image's outer pixel edges (less ``margin_px``); empty when it is well inside or behind the camera.
    """
    p = np.asarray(base_point_world_mm, float).reshape(1, 3)
    pc = camera.world_to_camera(p)[0]
    if not pc[2] > 0:
        return []
    # With and without the lens distortion: far outside the field of view the
    # distortion polynomial can fold a point back into the image.
    ideal = camera.K[:2, :2] @ (pc[:2] / pc[2]) + camera.K[:2, 2]
    uv, _ = camera.project(p)
    out = set()
    for u, v in (ideal, uv[0]):
        if np.isfinite(u) and np.isfinite(v):
            m = float(margin_px)
            for b, beyond in (("left", u < m - 0.5), ("right", u > camera.width - 0.5 - m), ("top", v < m - 0.5),
                              ("bottom", v > camera.height - 0.5 - m)):
                if beyond:
                    out.add(b)
    return [b for b in BORDERS if b in out]


def _backbone(model: PaperModel, names, carved, silhouettes: dict, centerlines: dict, disks: dict, params: PaperParams):
    """The carved voxels ordered into a backbone, continued to the base (plane or image border), refined, cut
    at the base plane: ``(backbone, doubt)``, the doubt from :func:`_behind_base_doubt` (str or None).

    Raises :class:`~recon.errors.FrameError` when the backbone leaves out more
    than ``max_dropped_fraction`` of the voxels.
    """
    cameras = [model.rig[n] for n in names]
    sils = [silhouettes[n] for n in names]
    bb = order_backbone(carved.points_mm, carved.labels, model.rig.base_point_world_mm, model.rig.insertion_axis_world,
                        params.backbone, voxel_size_mm=carved.voxel_size_mm,
                        bridge_check=silhouette_bridge_check(cameras, sils, carved.voxel_size_mm))
    total = int(carved.points_mm.shape[0])
    voxel_mm = float(np.max(carved.voxel_size_mm))  # the largest edge: what the tip trim allows for
    if params.max_dropped_fraction < 1.0 and bb.n_dropped > params.max_dropped_fraction * total:
        # A piece of the robot the backbone could not bridge to: which piece
        # is the robot, and what joins them, is a guess (wide-5-1: the distal
        # half alone, 27 mm off).
        raise FrameError(f"the carved robot is in pieces the backbone cannot join: {bb.n_dropped} of {total} voxels "
                         f"({100.0 * bb.n_dropped / total:.0f} %) left out")
    border = any(base_borders(model.rig[n], model.rig.base_point_world_mm) for n in names)
    if border:
        bb = _continue_to_border(model.rig, names, _straight_start(bb, carved.voxel_size_mm))
    else:
        bb = _continue_to_base(model.rig, bb, params.max_base_gap_mm)
    if params.subvoxel is not None:
        bb = _refined(cameras, [centerlines[n] for n in names], [disks[n] for n in names], bb, carved.voxel_size_mm, params, sils)
        bb = _straight_end(bb, carved.voxel_size_mm)
        bb = _trim_tip(cameras, sils, bb, 4.0 * voxel_mm)
    bb, reached_mm = _from_base(model.rig, bb)
    if not border:
        bb = _started_at_base(model.rig, bb, params.max_base_gap_mm)
    return bb, _behind_base_doubt(model.rig, names, reached_mm, params.outer_tube_radius_mm, carved.voxel_size_mm)


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
        With a one-line reason: a missing or malformed frame, a tube too thin
        to resolve (``min_tube_width_px``), no usable silhouette, an empty
        centerline, views that do not agree, a carved robot in pieces the
        backbone cannot join (``max_dropped_fraction``).
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
    silhouettes, centerlines, disks = {}, {}, {}
    for name in names:
        if name not in frames or frames[name] is None:
            raise FrameError("no frame", name)
        check_tube_widths(name, model.tube_radii_px.get(name), params.min_tube_width_px)
        diff, peak = difference_image(model.backgrounds[name], to_gray(frames[name]), name, ignore=model.behind_base.get(name),
                                     blur_sigma_px=0.0 if model.full_scale.get(name, 1.0) > 1.0 else params.difference_blur_px)
        lap("background")
        sp = model.silhouette.get(name, params.silhouette)
        peak_dn = peak * model.full_scale.get(name, 1.0)
        silhouettes[name] = extract_silhouette(
            diff, sp, name, max_difference=peak_dn, tube_radii_px=model.tube_radii_px.get(name),
            low_threshold=hysteresis_threshold(diff, sp, peak_dn), attach_gap_px=model.attach_gap_px.get(name),
            base_px=model.base_px.get(name),
        )
        lap("silhouette")
        disks[name] = {}
        mask, labels = extract_centerline(silhouettes[name], model.centerline[name], info=disks[name])
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
    bb, base_doubt = _backbone(model, names, carved, silhouettes, centerlines, disks, params)
    lap("backbone")
    overrun, doubt = _tip_overrun(model, names, centerlines, bb.points_mm, params)
    doubt = doubt or base_doubt
    lap("tip_check")
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
        centerline_disks=disks,
        tip_overrun_px=overrun,
        suspect_reason=doubt,
    )
