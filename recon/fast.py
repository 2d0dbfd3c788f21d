"""The ``fast`` method: sub-pixel centerlines, epipolar correspondence, triangulation (docs/fast-method.md).

Per view (:mod:`recon.subpixel`): a coarse (1/4 resolution) eigenbackground
difference finds the robot and its base-to-tip path; full-resolution profiles
across the tube, with the background rebuilt on their pixels only, give
sub-pixel edges, hence the tube's centre and width every pixel along it; a
least-squares B-spline smooths the centres (outliers rejected); the tip is
measured along the axis.

In 3D (:mod:`recon.epipolar`): the two ordered centerlines are matched by
their epipolar-plane angle (dynamic programming under the ordering constraint
when that angle is not monotonic), matched rays are triangulated, and a
weighted least-squares B-spline (weights from how well each match is
conditioned) gives the backbone, resampled by arc length. The backbone is
started at the base point along the insertion axis where the base is in view
(or continued straight back to the image border where the robot enters across
it) and continued forward to the tip measured in both views (allowing for the
tube's end cap seen at an angle). The
outer/inner transition is where the measured width steps down.

Across frames (:mod:`recon.temporal`): each backbone is compared with the
previous frame's; an implausible jump sets ``jump_flag`` and ``jump_reason``
on the result.

Everything runs on one core, the per-pixel loops and the ray computations
compiled (:mod:`recon._kernels`, numba); no per-pixel work is done outside
~1 % of the full-resolution pixels.
"""
from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from ._kernels import max_window_median_nb, median_nb, polyline_distances_nb, project_nb, rays_nb
from .background import EigenBackground, EigenBackgroundParams, fit_eigenbackground, to_gray
from .backbone import back_to_base_plane, back_to_border, from_base_point
from .carving import rig_center
from .distortion import undistort_normalized
from .epipolar import EpipolarFrame, align_dp, conditioning, monotonic, triangulate_rays
from .errors import FrameError
from .geometry import arc_length, interp_rows, resample_polyline
from .guided import best_path, ray_candidates, ray_points, strongest_candidates, tube_contrast
from .methods import Method, register_method
from .paper import camera_order
from .rigcal import RigCalibration
from .subpixel import (ViewCenterline, ViewModel, ViewParams, background_difference, extract_view, fit_curve, off_curve,
                       prepare_view, steady_frame)
from .temporal import JumpLimits, jump_check

__all__ = ["FastParams", "FastModel", "FastReconstruction", "prepare_fast", "FastReconstructor"]


@dataclass(frozen=True)
class FastParams:
    """Parameters of the fast method (defaults: the documented values, docs/fast-method.md).

    Attributes
    ----------
    background : EigenBackgroundParams
        Eigenbackgrounds (as the paper: 5).
    outer_tube_radius_mm, inner_tube_radius_mm : float
        Tube radii (mm): widths expected in the images, and the end cap.
    min_tube_width_px : float
        Every frame is refused (:class:`~recon.errors.FrameError`) when a
        tube is narrower than this in a camera's image at the robot base, or
        where the robot enters the image when the base is out of view
        (px). Was 4 (docs/envelope.md, "Tube too thin to resolve": a thinner
        tube was lost and the backbone stopped short of the tip); with the
        tip check (``max_tip_mismatch_px``) such frames are refused, and 3.1-4 px
        tubes of the wide suite reconstruct within 1.6 px mean
        (docs/fast-method.md, "Tubes too thin to resolve").
    coarse_factor : int
        Downsampling of the coarse stage.
    coarse_threshold_sigma, coarse_threshold_min_dn : float
        Coarse foreground threshold: at least this many noise sigmas and gray
        levels (and above the pixel's own background residual, see
        :func:`recon.subpixel.prepare_view`).
    roi_margin_px : float
        The robot is looked for within the previous frame's region plus this
        margin (px); the whole frame when it is lost or outgrows that.
    view : recon.subpixel.ViewParams
        Each view's centerline extraction (``[view]`` table): base search,
        profile spacing, edge thresholds and lines averaged, accepted widths,
        following the tube past the coarse path, outlier rejection, the
        per-view spline's knots and the jitter compensation.
    sample_step_px : float
        Sampling of the per-view curves for correspondence (px).
    knot_mm : float
        Knot spacing of the 3D backbone spline (mm).
    output_step_mm : float
        Spacing of the output backbone points (mm).
    max_ray_gap_mm : float
        Matched rays that pass farther apart than this are dropped.
    min_end_conditioning : float
        Where the tube's last stretch runs near an epipolar plane (the
        conditioning, the sine between the curve and the epipolar lines, under
        this in either view), the epipolar angle hardly changes along it and a
        fraction of a pixel across the tube moves the match far along it: one
        view's samples stall while the other's run on, and the depth wanders
        off between measured points (wide-3-48 frame 1: 15 mm before a right
        tip, 14 px footprints off, reported ``ok``). That stretch is paired by
        arc fraction instead, from its start to the two views' last samples
        (the tip, one point): every point stays on both views' curves and the
        depth goes evenly from the measured start to the measured tip
        (:func:`_end_by_fraction`).
    max_base_gap_mm : float
        The backbone is continued back to the base plane only if its first
        point is at most this far from it (mm).
    retry_min_dn : float
        A view whose end stops short of where the other view puts the tip is
        followed once more beyond its end with this lower edge threshold (gray
        levels; the inner tube can stand only 5-8 levels off a backdrop); the
        tip check then judges the result again.
    max_tip_mismatch_px : float
        The tip is one point, in one epipolar plane: when the two views'
        silhouette ends lie in planes farther apart than this plus the inner
        tube's diameter (each view's silhouette ends at the rim of the end
        face it sees; px along the tube, in the view where that distance is
        smaller), after the second tries (``retry_min_dn``), the views are
        cut to what both see (:func:`_tip_mismatch`): one view lost the tube
        short of its tip, or the other ran on into something else, and the
        backbone stops where the shorter view ends; the frame is ``suspect``
        (``suspect_reason``), never ``ok``.
    min_common_fraction : float
        Such a cut is made only while the longer view keeps at least this
        fraction of its curve (of its length in px); a view that lost the tube
        earlier than that refuses the frame (:class:`~recon.errors.FrameError`):
        a stub of the robot is no reconstruction of it.
    guided_tip_share, guided_tip_sigmas, guided_support : float
        Before the cut, the stretch the shorter view lost is looked for along
        the longer view's rays (:func:`_lost_stretch`, :mod:`recon.guided`).
        The path found is taken only where the shorter view shows the tube
        over its last ``guided_tip_share`` of candidates (median contrast at
        least ``guided_tip_sigmas`` robust sigmas) and over at least
        ``guided_support`` of its length; the frame stays ``suspect``. Set
        while looking at seed 1's wide-1-37 and wide-1-49 frames (max error
        50 and 142 px after the cut, 11 and 17 px with the path).
    tip_triangulate_px : float
        Where continuing the backbone straight along its end tangent leaves
        one view's silhouette end more than this (px) off, the end is
        triangulated from the two ends instead (:func:`_to_tip`). 3 px, from
        the tuning seeds (2 and 3): always triangulating made the median tip
        error 0.3 px worse (the ends are noisier than the curve); above 3 px
        it cut four tips 5-8 px short to 1-5 px and lengthened two by ~2 px.
    max_reprojection_px, reprojection_window_mm : float
        The backbone, projected into each view, must follow that view's own
        centerline: where the median distance (px) over any
        ``reprojection_window_mm`` of backbone exceeds ``max_reprojection_px``,
        the triangulation made a shape neither view shows and the frame is
        ``suspect`` (``suspect_reason``). Seen: wide-1-63 frame 0, a stretch
        matched across bricks 23 px off the top view's tube (that view's
        centerline within 6 px of the truth), reported ``ok``. 5 px: on the
        tuning seeds (2 and 3, 251 good frames) the largest figure of a good
        frame was 3.2 px.
    jump : JumpLimits
        Largest plausible change between consecutive frames.
    """

    background: EigenBackgroundParams = field(default_factory=EigenBackgroundParams)
    outer_tube_radius_mm: float = 0.8
    inner_tube_radius_mm: float = 0.5
    min_tube_width_px: float = 3.0
    coarse_factor: int = 4
    coarse_threshold_sigma: float = 6.0
    coarse_threshold_min_dn: float = 6.0
    roi_margin_px: float = 64.0
    view: ViewParams = field(default_factory=ViewParams)
    sample_step_px: float = 4.0
    knot_mm: float = 4.0
    output_step_mm: float = 0.5
    max_ray_gap_mm: float = 1.0
    min_end_conditioning: float = 0.2
    max_base_gap_mm: float = 6.0
    retry_min_dn: float = 3.0
    max_tip_mismatch_px: float = 8.0
    min_common_fraction: float = 0.5
    guided_tip_share: float = 0.1
    guided_tip_sigmas: float = 3.0
    guided_support: float = 0.4
    tip_triangulate_px: float = 3.0
    max_reprojection_px: float = 5.0
    reprojection_window_mm: float = 7.5
    jump: JumpLimits = field(default_factory=JumpLimits)

    def __post_init__(self):
        if int(self.coarse_factor) < 1:
            raise ValueError(f"FastParams.coarse_factor must be >= 1, got {self.coarse_factor}")
        if not 0 < self.inner_tube_radius_mm < self.outer_tube_radius_mm:
            raise ValueError("FastParams: need 0 < inner_tube_radius_mm < outer_tube_radius_mm")
        for name in ("sample_step_px", "knot_mm", "output_step_mm"):
            if not getattr(self, name) > 0:
                raise ValueError(f"FastParams.{name} must be > 0, got {getattr(self, name)}")


@dataclass(frozen=True, eq=False)
class FastModel:
    """What the fast method needs besides the frames (built by :func:`prepare_fast`).

    Attributes
    ----------
    rig : RigCalibration
    pair : tuple of str
        The two cameras used, in :func:`recon.paper.camera_order`.
    views : dict
        Camera name -> :class:`recon.subpixel.ViewModel`.
    epipolar : EpipolarFrame
        The pair's epipolar planes (world frame).
    epipoles : dict
        Camera name -> the other camera's centre in this camera's frame (mm).
    R_world_cam : dict
        Camera name -> (3, 3) rotation camera -> world.
    """

    rig: RigCalibration
    pair: tuple
    views: dict
    epipolar: EpipolarFrame
    epipoles: dict
    R_world_cam: dict


class _LazyImages(Mapping):
    """Camera name -> image, drawn on first access (the method itself never needs them)."""

    def __init__(self, names, draw):
        self._names = tuple(names)
        self._draw = draw
        self._cache = {}

    def __getitem__(self, name):
        if name not in self._names:
            raise KeyError(name)
        if name not in self._cache:
            self._cache[name] = self._draw(name)
        return self._cache[name]

    def __iter__(self):
        return iter(self._names)

    def __len__(self):
        return len(self._names)


@dataclass(frozen=True, eq=False)
class FastReconstruction:
    """One reconstructed frame pair (the attributes of :class:`recon.paper.Reconstruction`, and more).

    Attributes
    ----------
    points_world_mm : (m, 3)
        Backbone, base first, every ``output_step_mm`` of arc length (world, mm).
    tip_world_mm : (3,)
    transition_s_mm : float
        Arc length of the outer tube's end (mm); NaN if not seen.
    transition_world_mm : (3,)
    length_mm : float
    silhouettes : mapping name -> (H, W) bool
        The tube outline drawn from the measured centres and widths (drawn on
        first access).
    centerlines : mapping name -> (H, W) uint8
        Accepted centres rasterized, 1 outer tube, 2 inner (on first access).
    centerlines_px : dict name -> (n, 2)
        Sub-pixel centres, base to tip (px).
    widths_px : dict name -> (n,)
    box : tuple
        Bounds of the backbone (world, mm).
    voxel_size_mm : None
        No voxels (present for interface compatibility).
    n_voxels : int
        0.
    jump_flag : bool
        The shape jumped implausibly from the previous frame's
        (:mod:`recon.temporal`).
    jump_reason : str or None
    ray_gap_mm : float
        Median distance between matched rays (mm): calibration consistency.
    correspondence : str
        ``"epipolar-angle"``, or the fallback where a view's curve folds across an epipolar
        plane: ``"ordered-dp"`` (both views fold) or ``"ordered-dp-one-view"`` (one does; a doubt).
    timings_ms : dict
        ``steady`` (the frames moved back by their jitter, where they were),
        ``view_<name>`` per camera, ``triangulate``, ``total``, and the
        stages within them.
    suspect_reason : str or None
        Why the method itself cannot vouch for this shape (the frame is
        reported ``suspect``), e.g. a tube folding across an epipolar plane.
    check_answers_doubt : bool
        Whether ``suspect_reason`` is a doubt that an image check answers:
        the views' ends disagreed, and the backbone was cut to what both
        views see (:func:`_common_part`). Either view may have been the
        wrong one; where the longer view was right, its tube beyond the cut
        is foreground that the backbone leaves unexplained, or contrast that
        the tip probe reads (:mod:`recon.selfcheck`). A checker that passes
        the frame lifts the doubt (:func:`rig.rundir.record_doubt`); live,
        with no check, the frame stays suspect. False where another doubt
        stands (the order-matched fallback, a stretch off a centerline).
    alternative : FastReconstruction or None
        The same frame with the tip at the farther view's silhouette end,
        where the views' ends disagree by more than ``tip_triangulate_px``
        (None elsewhere). One view may have lost the tube's faint end, or
        the other run on past it: the ends alone do not tell which (wide
        seeds 2-5, docs/envelope.md rounds 25-26). A checker that reads the
        images takes it where it passes (:mod:`rig.bench.reconstruct`
        runs the self-check on it first).
    """

    points_world_mm: np.ndarray
    tip_world_mm: np.ndarray
    transition_s_mm: float
    transition_world_mm: np.ndarray
    length_mm: float
    silhouettes: Mapping
    centerlines: Mapping
    centerlines_px: dict
    widths_px: dict
    box: tuple
    voxel_size_mm: object
    n_voxels: int
    jump_flag: bool
    jump_reason: object
    ray_gap_mm: float
    correspondence: str
    timings_ms: dict
    suspect_reason: object = None
    check_answers_doubt: bool = False
    alternative: object = None


# ----------------------------------------------------------------------------- prepare
def _offset_only(eig: EigenBackground) -> EigenBackground:
    """A background that does not vary at all (binary masks, a uniform black or white backdrop, synthetic frames).

    The eigenbackgrounds drop every direction of zero variance, leaving none;
    the per-view stages need at least one. One uniform offset, with a prior
    variance of 1 gray level^2 per pixel, keeps the model what the frames
    say (the mean) while absorbing a small overall offset of the live frames.
    """
    P = int(eig.mean.size)
    basis = np.full((1, P), 1.0 / np.sqrt(P), np.float32)
    return EigenBackground(mean=eig.mean, basis=basis, eigenvalues=np.array([float(P)]), shape=eig.shape)


def prepare_fast(rig: RigCalibration, background_frames: dict, params: FastParams = FastParams()) -> FastModel:
    """Fit the eigenbackgrounds and the per-view constants.

    Parameters
    ----------
    rig : RigCalibration
        The calibrated cameras (world frame, mm), the robot base and its
        insertion axis; the first two cameras in :func:`recon.paper.camera_order`
        are used.
    background_frames : dict
        Camera name -> (N, H, W) or (N, H, W, 3) frames without the robot
        (gray levels; RGB is converted).
    params : FastParams, optional
        The method's parameters.

    Returns
    -------
    FastModel
        Per-view constants (:class:`recon.subpixel.ViewModel`) and the pair's
        epipolar geometry (world frame, mm).

    Raises
    ------
    ValueError
        Fewer than two cameras, a camera without background frames, or
        background frames of the wrong size.
    """
    names = camera_order(rig.names)
    if len(names) < 2:
        raise ValueError(f"the fast method needs two cameras, the rig has {len(names)}")
    pair = names[:2]
    views = {}
    for name in pair:
        cam = rig[name]
        if name not in background_frames:
            raise ValueError(f"{name}: no background frames")
        frames = to_gray(background_frames[name])
        try:
            eig = fit_eigenbackground(frames, params.background)
        except ValueError as exc:
            raise ValueError(f"{name}: {exc}") from None
        if eig.k == 0:
            eig = _offset_only(eig)
        if eig.shape != (cam.height, cam.width):
            raise ValueError(f"{name}: background frames are {eig.shape[1]}x{eig.shape[0]} but the camera is {cam.width}x{cam.height}")
        views[name] = prepare_view(
            name, eig, cam, rig.base_point_world_mm, rig.insertion_axis_world,
            params.outer_tube_radius_mm, params.inner_tube_radius_mm, frames,
            factor=int(params.coarse_factor), threshold_sigma=params.coarse_threshold_sigma,
            threshold_min_dn=params.coarse_threshold_min_dn,
        )
    ca, cb = rig[pair[0]], rig[pair[1]]
    ef = EpipolarFrame.from_cameras(ca, cb, rig_center([ca, cb]))
    epipoles = {
        pair[0]: ca.T_cam_world[:3, :3] @ (cb.center_world_mm - ca.center_world_mm),
        pair[1]: cb.T_cam_world[:3, :3] @ (ca.center_world_mm - cb.center_world_mm),
    }
    R = {n: rig[n].T_world_cam[:3, :3] for n in pair}
    return FastModel(rig=rig, pair=pair, views=views, epipolar=ef, epipoles=epipoles, R_world_cam=R)


# ----------------------------------------------------------------------------- 3D
@dataclass(frozen=True, eq=False)
class _ViewSamples:
    """A view's curve sampled for correspondence: curve parameters ``s`` (px), pixels ``uv`` (jitter removed),
    unnormalized world ray directions, epipolar-plane angles (rad) and conditioning (:func:`recon.epipolar.conditioning`)."""

    s: np.ndarray
    uv: np.ndarray
    dirs: np.ndarray
    phi: np.ndarray
    cond: np.ndarray


#: Most fixed-point steps of the undistortion; they stop once no point moves (1e-14). Each shrinks the
#: error by about ``3 |k1| r^2``: ~1 % at the paper rig's corners (5 steps reach 1e-10), but near 1 at the
#: corners of a wide lens with |k1| ~ 0.25, where 5 steps had left up to 23 px (8 % of the wide suite's
#: cameras more than 0.01 px); 100 leave < 1e-11 px on all 280 cameras of seeds 1-3.
_UNDISTORT_STEPS = 100


def _pixels_to_normalized(cam, uv: np.ndarray, iterations: int = _UNDISTORT_STEPS) -> np.ndarray:
    """:meth:`Camera.pixels_to_normalized`, stopping once converged (at most ``iterations`` steps)."""
    K = cam.K
    y = (uv[:, 1] - K[1, 2]) / K[1, 1]
    x = (uv[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    return undistort_normalized(np.stack([x, y], axis=1), cam.dist, max_iterations=iterations)


def _rays(model: FastModel, name: str, uv: np.ndarray) -> tuple:
    """Unnormalized world ray directions, epipolar-plane angles (rad) and conditioning of the pixels ``uv``
    (m, 2) of a view (distortion undone): :func:`recon._kernels.rays_nb`, or :func:`_rays_in_python` where
    its fixed-point steps did not settle."""
    cam = model.rig[name]
    ef = model.epipolar
    d, phi, cond = rays_nb(uv, cam.K, cam.dist14, cam.tilt[1], model.R_world_cam[name], ef.baseline, ef.e1, ef.e2,
                           model.epipoles[name], _UNDISTORT_STEPS)
    if np.isfinite(phi).all():  # NaN: a pixel the fixed-point steps did not solve (strong pincushion)
        return d, phi, cond
    return _rays_in_python(model, name, uv)


def _rays_in_python(model: FastModel, name: str, uv: np.ndarray) -> tuple:
    """:func:`_rays` by :func:`recon.distortion.undistort_normalized` (its Newton steps solve what the fixed-point
    steps leave)."""
    xy = _pixels_to_normalized(model.rig[name], uv)
    R = model.R_world_cam[name]
    d = xy @ R[:, :2].T + R[:, 2]
    return d, model.epipolar.phi(d), conditioning(xy, model.epipoles[name])


def _view_samples(model: FastModel, name: str, vc: ViewCenterline, step: float) -> _ViewSamples:
    """A view's curve every ``step`` px (at least 4 samples) of its parameter, jitter removed, with its rays."""
    s0, s1 = vc.s_range
    n = max(4, int(np.ceil((s1 - s0) / step)) + 1)
    s = np.linspace(s0, s1, n)
    uv = vc.curve(s) - vc.shift_px
    d, phi, cond = _rays(model, name, uv)
    return _ViewSamples(s=s, uv=uv, dirs=d, phi=phi, cond=cond)


def _check_tube_widths(name: str, vm, min_width_px: float) -> None:
    """:func:`recon.paper.check_tube_widths`, with the widths where the view sees the robot (``vm.width_at``)."""
    for tube, r in (("outer", vm.outer_radius_px), ("inner", vm.inner_radius_px)):
        if 2.0 * float(r) < min_width_px:
            raise FrameError(f"{tube} tube is {2.0 * float(r):.1f} px wide {vm.width_at}, less than "
                             f"min_tube_width_px = {min_width_px:g}: too thin to resolve", name)


def _phi_at(model: FastModel, name: str, uv: np.ndarray) -> np.ndarray:
    """Epipolar-plane angle (rad) of the rays through undistorted-by-calibration pixels ``uv`` (m, 2) of a view."""
    return _rays(model, name, np.ascontiguousarray(np.asarray(uv, float).reshape(-1, 2)))[1]


def _tip_mismatch(model: FastModel, views: dict, sa: _ViewSamples, sb: _ViewSamples):
    """How far (px along the tube) each view's tip stops short of the other's, through the epipolar planes.

    The tip is one point: its epipolar-plane angle is the same in both views.
    For each view, the other view's tip angle is mapped onto this view's
    curve; returns ``{name: px}`` (positive: this view's measured tip lies
    short of where the other view puts it), 0 where the angle cannot tell
    (the tube runs along the epipolar lines near the tip).
    """
    a, b = model.pair
    out = {}
    ends = {}
    for n, smp in ((a, sa), (b, sb)):
        vc = views[n]
        e = vc.end_px - vc.shift_px
        ph = _phi_at(model, n, np.stack([e, e - vc.tangent_end]))
        ends[n] = (float(ph[0]), float(ph[0] - ph[1]))  # angle at the tip, change per px along the tube (outward)
    for n, m in ((a, b), (b, a)):
        phi_n, rate_n = ends[n]
        phi_m, _ = ends[m]
        if abs(rate_n) < 1e-9:
            out[n] = 0.0
            continue
        out[n] = float((phi_m - phi_n) / rate_n)
    return out


def _project(cam, P: np.ndarray):
    """:meth:`recon.camera.Camera.project` compiled: world points (n, 3) mm -> pixels (n, 2), depths (n,) mm."""
    return project_nb(P, cam.K, cam.dist14, cam.tilt[0], cam.T_cam_world)


def _unit3(d: np.ndarray) -> np.ndarray:
    return d / np.sqrt(np.einsum("ij,ij->i", d, d))[:, None]


def _strictly_increasing(x: np.ndarray) -> np.ndarray:
    x = np.maximum.accumulate(x)
    return x + np.arange(x.size) * 1e-12


def _correspond(a: _ViewSamples, b: _ViewSamples, tol: float, min_end_cond: float = 0.0):
    """Matched (s_a, s_b, dir_a, dir_b, cond_a, cond_b) and the method used; the trailing stretch conditioned
    under ``min_end_cond`` paired by arc fraction (:func:`_end_by_fraction`)."""
    ma, mb = monotonic(a.phi, tol), monotonic(b.phi, tol)
    if ma != 0 and ma == mb:
        pa = _strictly_increasing(ma * a.phi)
        pb = _strictly_increasing(ma * b.phi)
        lo, hi = max(pa[0], pb[0]), min(pa[-1], pb[-1])
        if not hi > lo:
            raise FrameError("the two views do not overlap along the epipolar lines (calibration or wrong region)")
        q = np.concatenate([pa[(pa >= lo) & (pa <= hi)], pb[(pb >= lo) & (pb <= hi)]])
        q = np.unique(q)
        sa = np.interp(q, pa, a.s)
        sb = np.interp(q, pb, b.s)
        da = _unit3(interp_rows(q, pa, a.dirs))
        db = _unit3(interp_rows(q, pb, b.dirs))
        ca = np.interp(q, pa, a.cond)
        cb = np.interp(q, pb, b.cond)
        return _end_by_fraction(a, b, (sa, sb, da, db, ca, cb), min_end_cond) + ("epipolar-angle",)
    # Not monotonic in both views: ordered alignment. A fold both views show pairs up along the tube;
    # a fold in one view only is a shape the other view does not see.
    how = "ordered-dp" if ma == mb == 0 else "ordered-dp-one-view"
    ka = np.unique(np.linspace(0, a.s.size - 1, min(a.s.size, 160)).round().astype(int))
    kb = np.unique(np.linspace(0, b.s.size - 1, min(b.s.size, 160)).round().astype(int))
    fa = (a.s[ka] - a.s[0]) / max(a.s[-1] - a.s[0], 1e-9)
    fb = (b.s[kb] - b.s[0]) / max(b.s[-1] - b.s[0], 1e-9)
    ia, ib = align_dp(a.phi[ka], b.phi[kb], fa, fb, phi_scale=4.0 * tol)
    ia, ib = ka[ia], kb[ib]
    return a.s[ia], b.s[ib], _unit3(a.dirs[ia]), _unit3(b.dirs[ib]), a.cond[ia], b.cond[ib], how


def _end_by_fraction(a: _ViewSamples, b: _ViewSamples, matched: tuple, min_cond: float) -> tuple:
    """The matched ``(s_a, s_b, dir_a, dir_b, cond_a, cond_b)`` with the trailing run conditioned under
    ``min_cond`` (in either view) paired by arc fraction from its first match to both views' last samples
    (``FastParams.min_end_conditioning``); unchanged where the last match is conditioned well enough."""
    sa, sb = matched[0], matched[1]
    low = np.minimum(matched[4], matched[5]) < min_cond
    if sa.size < 2 or not low[-1]:
        return matched
    k0 = max(0, sa.size - int(np.argmin(low[::-1])) - 1) if not low.all() else 0
    n = max(2, int(np.sum(a.s > sa[k0])), int(np.sum(b.s > sb[k0])))
    f = np.linspace(0.0, 1.0, n + 1)[1:]
    ta, tb = sa[k0] + f * (a.s[-1] - sa[k0]), sb[k0] + f * (b.s[-1] - sb[k0])
    new = (ta, tb, _unit3(interp_rows(ta, a.s, a.dirs)), _unit3(interp_rows(tb, b.s, b.dirs)),
           np.interp(ta, a.s, a.cond), np.interp(tb, b.s, b.cond))
    return tuple(np.concatenate([old[: k0 + 1], add]) for old, add in zip(matched, new))


#: Where a view's curve is not monotonic in the epipolar angle the tube folds across an epipolar plane:
#: the points are matched by their order along the tube. Every point of the tube lies in the same
#: epipolar plane for both cameras, so a real fold turns back in both views at once; where only one
#: view's curve turns back, the views disagree on the shape there and the order-matched depth is a
#: guess (wide-3-48 frame 2: the side view missed a faint hook at the tip, 18 px footprints off).
#: A fold that both views show is matched along it and left to the self-check (its unmeasured-depth
#: figure judges the stretch within the plane): on wide seeds 1-3 and 5-9, the 9 such frames that
#: the self-check passed were within 7.2 px footprints (docs/envelope.md, round 41).
_ORDERED_REASON = ("one view's curve folds back across the epipolar planes and the other's does not: matched by "
                   "order along the tube, the views disagree on its shape there")


def _transition_s(vc: ViewCenterline, model: ViewModel) -> float:
    """Curve parameter where the measured width steps from outer to inner tube; NaN if no step."""
    w = vc.width_px
    if w.size < 8:
        return np.nan
    outer = w > (model.outer_radius_px + model.inner_radius_px)
    # k: first inner sample; cost = inner before k + outer from k on.
    c_in = np.concatenate([[0], np.cumsum(~outer)])
    c_out = np.concatenate([[0], np.cumsum(outer)])
    cost = c_in + (c_out[-1] - c_out)
    k = int(np.argmin(cost))
    if k < 3 or k > w.size - 3:
        return np.nan
    return 0.5 * (vc.s[k - 1] + vc.s[k])


def _draw_silhouette(vc: ViewCenterline, shape) -> np.ndarray:
    img = np.zeros(shape, np.uint8)
    p = vc.points_px
    sh = 4
    pts = np.rint(p * (1 << sh)).astype(np.int32)
    for i in range(len(p) - 1):
        th = max(1, int(round(0.5 * (vc.width_px[i] + vc.width_px[i + 1]))))
        cv2.line(img, tuple(pts[i]), tuple(pts[i + 1]), 1, th, cv2.LINE_8, sh)
    return img.astype(bool)


def _draw_centerline(vc: ViewCenterline, shape, s_trans: float) -> np.ndarray:
    img = np.zeros(shape, np.uint8)
    p = np.rint(vc.points_px * 16).astype(np.int32)
    lab = np.where(np.isfinite(s_trans) & (vc.s > s_trans), 2, 1) if np.isfinite(s_trans) else np.ones(len(p), int)
    for i in range(len(p) - 1):
        cv2.line(img, tuple(p[i]), tuple(p[i + 1]), int(lab[i]), 1, cv2.LINE_8, 4)
    return img


def _to_base(model: FastModel, params: FastParams, dense: np.ndarray, t0: np.ndarray, fine: float) -> tuple:
    """The dense curve (world, mm) started at the base point where it reaches the base plane within
    ``max_base_gap_mm`` along its start tangent ``t0`` (:func:`recon.backbone.from_base_point`: the base is
    in view), or, where the robot enters across the image border, continued straight back to where the
    first camera loses it; and the arc length (mm) gained before the dense curve's points (0 for the border)."""
    rig = model.rig
    t0 = t0 / np.linalg.norm(t0)
    back = back_to_base_plane(dense[0], t0, rig.base_point_world_mm, rig.insertion_axis_world, params.max_base_gap_mm, fine)
    if len(back):
        return from_base_point(dense, rig.base_point_world_mm, rig.insertion_axis_world, fine)
    if any(model.views[n].start_px is not None for n in model.pair):
        # The profiles stop short of the border by about their window.
        return np.concatenate([back_to_border(rig, model.pair, dense[0], t0, fine), dense]), 0.0
    return dense, 0.0


def _cap_mm(cam, x_end: np.ndarray, t1: np.ndarray, tip_radius: float) -> float:
    """The end cap's extent (mm): the tube's radius times the cosine between the tube (``t1``) and the line
    of sight from ``cam`` to the end ``x_end`` (world, mm); the silhouette ends at the end face's rim."""
    dv = x_end - cam.center_world_mm
    return tip_radius * abs(float(t1 @ dv)) / float(np.linalg.norm(dv))


def _triangulated_tip(model: FastModel, views: dict, x_end: np.ndarray, t1: np.ndarray, tip_radius: float,
                      max_gap_mm: float):
    """The backbone's end (world, mm) from the two silhouette ends' rays, less the end cap; None when the
    rays pass farther apart than ``max_gap_mm`` (the ends are not one point)."""
    a, b = model.pair
    (ca, da), (cb, db) = (model.rig[n].rays((views[n].end_px - views[n].shift_px)[None]) for n in (a, b))
    x, gap = triangulate_rays(ca, da, cb, db)
    if not gap[0] < max_gap_mm:
        return None
    return x[0] - 0.5 * sum(_cap_mm(model.rig[n], x_end, t1, tip_radius) for n in (a, b)) * t1


def _tip_radius(model: FastModel, views: dict, params: FastParams, s_tr: dict) -> float:
    """The radius (mm) of the tube the tip belongs to: the inner one, unless neither view found the step to
    it and the last widths are the outer tube's."""
    if any(np.isfinite(v) for v in s_tr.values()):
        return params.inner_tube_radius_mm
    wend = np.median(np.concatenate([views[n].width_px[-10:] / (2 * model.views[n].outer_radius_px) for n in model.pair]))
    if wend > 0.5 * (1 + params.inner_tube_radius_mm / params.outer_tube_radius_mm):
        return params.outer_tube_radius_mm
    return params.inner_tube_radius_mm


def _to_tip(model: FastModel, views: dict, params: FastParams, dense: np.ndarray, t1: np.ndarray, s_tr: dict,
            fine: float) -> tuple:
    """The dense curve (world, mm) continued, or cut, along its end tangent ``t1`` to the silhouette ends
    seen in both views, less the end cap's extent (the views weighted by the square of their px per mm).

    Where that straight continuation leaves one view's end more than ``params.tip_triangulate_px`` off (the
    tube bends over its last mm, and the end tangent points the views' ends apart), the end is triangulated
    from the two silhouette ends instead and joined by a straight piece.

    Returns ``(dense, farther)``: ``farther`` is the curve continued to the farther view's end where the
    views disagree (None where they agree). Either view may be the wrong one there: one may have lost
    the tube's faint end, or the other run on past it, and only the images can tell
    (:attr:`FastReconstruction.alternative`)."""
    t1 = t1 / np.linalg.norm(t1)
    x_end = dense[-1]
    tip_radius = _tip_radius(model, views, params, s_tr)
    per_view = []  # (lam, px per mm along t1) of each view
    for n in model.pair:
        cam = model.rig[n]
        uv, z = _project(cam, np.stack([x_end, x_end + t1]))
        g_vec = uv[1] - uv[0]
        g = float(np.linalg.norm(g_vec))
        if g < 1e-6:
            continue
        off = float((views[n].end_px - views[n].shift_px - uv[0]) @ (g_vec / g))
        per_view.append(((off - _cap_mm(cam, x_end, t1, tip_radius) * cam.K[0, 0] / z[0]) / g, g))
    den = sum(g * g for _, g in per_view)
    lam = sum(g * g * l for l, g in per_view) / den if den > 0 else 0.0
    if not (per_view and max(abs(l - lam) * g for l, g in per_view) > params.tip_triangulate_px):
        return _along_tangent(dense, t1, lam, fine), None
    farther = _along_tangent(dense, t1, max(l for l, _ in per_view), fine)
    tip = _triangulated_tip(model, views, x_end, t1, tip_radius, params.max_ray_gap_mm)
    if tip is not None:
        lam = float((tip - x_end) @ t1)
        if lam > 0:
            k = max(1, int(np.ceil(np.linalg.norm(tip - x_end) / fine)))
            return np.concatenate([dense, x_end + np.linspace(1.0 / k, 1.0, k)[:, None] * (tip - x_end)]), farther
    return _along_tangent(dense, t1, lam, fine), farther


def _along_tangent(dense: np.ndarray, t1: np.ndarray, lam: float, fine: float) -> np.ndarray:
    """The dense curve (world, mm) continued straight along its unit end tangent ``t1`` by ``lam`` mm, or cut
    ``-lam`` mm of arc short where ``lam`` is negative (unchanged where that would leave under two points)."""
    x_end = dense[-1]
    if lam > 0:
        k = max(1, int(np.ceil(lam / fine)))
        return np.concatenate([dense, x_end + np.linspace(lam / k, lam, k)[:, None] * t1])
    if lam < 0:
        s_d = arc_length(dense)
        keep_d = s_d <= s_d[-1] + lam
        if keep_d.sum() >= 2:
            cut = interp_rows(np.array([s_d[-1] + lam]), s_d, dense)
            return np.concatenate([dense[keep_d], cut])
    return dense


def _transition(matched, s_tr: dict, q: np.ndarray, spl, base_ext: float, points: np.ndarray) -> tuple:
    """Arc length (mm) and world point of the outer tube's end: the views' estimates combined through the
    matched parameters (``matched``: per view ``(name, s, confidence)``); NaN when no view has one."""
    trans = []
    for n, s_n, c_n in matched:
        st = s_tr[n]
        if np.isfinite(st) and s_n[0] < st < s_n[-1]:
            qt = float(np.interp(st, _strictly_increasing(s_n), q))
            trans.append((qt, float(np.interp(st, _strictly_increasing(s_n), c_n)) + 1e-3))
    if not trans:
        return float("nan"), np.full(3, np.nan)
    qt = sum(v * wt for v, wt in trans) / sum(wt for _, wt in trans)
    transition_s = float(base_ext + arc_length(spl(np.linspace(q[0], qt, 64)))[-1])
    return transition_s, interp_rows(np.array([transition_s]), arc_length(points), points)[0]


def _short_view(model: FastModel, views: dict, sa_: _ViewSamples, sb_: _ViewSamples, params: FastParams) -> str | None:
    """The view whose end lies short of where the other view's tip puts it by more than ``max_tip_mismatch_px``
    plus a tube diameter; None when the views agree. Raises :class:`~recon.errors.FrameError` when both overshoot
    each other (a view followed something else)."""
    a, b = model.pair
    short = _tip_mismatch(model, views, sa_, sb_)
    # Each view's silhouette ends at the rim of the end face that view sees: up to a tube diameter apart.
    cap_px = 2.0 * max(model.views[n].inner_radius_px for n in (a, b))
    if min(abs(v) for v in short.values()) <= params.max_tip_mismatch_px + cap_px:
        return None
    n_short = [n for n in (a, b) if short[n] > 0]
    if len(n_short) != 1:
        raise FrameError(f"the views disagree on the tip by {min(abs(v) for v in short.values()):.0f} px along the tube "
                         "(epipolar planes of the two silhouette ends): a view followed something else")
    return n_short[0]


def _cut_at_angle(model: FastModel, name: str, vc: ViewCenterline, phi_tip: float, min_fraction: float):
    """View ``name``'s centerline cut where its epipolar-plane angle first reaches ``phi_tip`` (rad: the other
    view's tip), going from the base; None where it never does, or keeps less than ``min_fraction`` of the curve.

    The tip lies in one epipolar plane, so where the other view's tube ends, this view's tube, as far as both
    views see it, ends in the same plane."""
    smp = _view_samples(model, name, vc, 1.0)
    i = _beyond_angle(smp, phi_tip)
    if i is None:
        return None
    d = smp.phi - phi_tip
    s_cut = float(smp.s[i - 1] + d[i - 1] / (d[i - 1] - d[i]) * (smp.s[i] - smp.s[i - 1]))
    s0, s1 = vc.s_range
    keep = vc.s <= s_cut
    if (s_cut - s0) < min_fraction * (s1 - s0) or keep.sum() < 4:
        return None
    tangent = vc.curve.derivative()(np.array([s_cut]))[0]
    return replace(vc, s_range=(s0, s_cut), points_px=vc.points_px[keep], s=vc.s[keep], width_px=vc.width_px[keep],
                   end_px=vc.curve(np.array([s_cut]))[0], end_s=s_cut, tangent_end=tangent / np.linalg.norm(tangent))


def _beyond_angle(smp: _ViewSamples, phi_tip: float) -> int | None:
    """Index of the first sample, from the base, past the epipolar-plane angle ``phi_tip`` (None: none is)."""
    d = smp.phi - phi_tip
    beyond = np.flatnonzero(np.sign(d) != np.sign(d[0]))
    return None if d[0] == 0.0 or beyond.size == 0 else int(beyond[0])


def _unit_rays(model: FastModel, name: str, uv: np.ndarray) -> np.ndarray:
    d = _rays(model, name, uv)[0]
    return d / np.linalg.norm(d, axis=1, keepdims=True)


# The guided search (recon.guided): candidates per ray; at most so many rays, spread evenly over the stretch; how
# far a step in 3D may stretch beyond what the other view sees of it (x12: the view sees the stretch nearly end-on),
# what that costs per unit of stretch, and the tube contrast (robust sigmas) that scores nothing (1.5), counts as
# support (2) and stops counting (4, so that one bright edge does not buy a detour). Set while looking at seed 1's
# wide-1-37 and wide-1-49 (tips lost on a textured backdrop); on seed 2 they changed one frame, wide-2-3 frame 0
# (max 190 -> 48 px, still suspect).
_GUIDED_CANDIDATES = 240
_GUIDED_MAX_RAYS = 120
# The tube's crossing of a ray falls between evenly spaced candidates where the stretch is long (their spacing grows
# with the reach: wide-2-21 frame 2, a 1.2 mm tube, candidates 2-11 mm apart on its last rays, the tube hit on about one
# ray in four). So the candidates are first read densely, every half tube radius in the lost view (at most so many per
# ray), and the search looks at the evenly spaced ones plus each ray's strongest local maxima.
_GUIDED_PEAKS = 48
_GUIDED_DENSE_MAX = 4096
_GUIDED_STRETCH = 12.0
_GUIDED_STRETCH_COST = 0.25
_GUIDED_BIAS, _GUIDED_SUPPORT, _GUIDED_CAP = 1.5, 2.0, 4.0


def _lost_stretch(model: FastModel, params: FastParams, views: dict, frame, n: str, other: str):
    """View ``n``'s centerline continued along the stretch of tube it lost and view ``other`` sees
    (:mod:`recon.guided`), or None where view ``n``'s image does not show that stretch's end.

    The candidates lie on ``other``'s rays beyond ``n``'s end (:func:`_guided_candidates`); the path through
    them is scored by :func:`recon.guided.tube_contrast` in ``n``. It is taken only where ``n`` sees the tube
    over the path's last ``guided_tip_share`` (median contrast at least ``guided_tip_sigmas``) and over at least
    ``guided_support`` of its length: the tip both views see, joined through a stretch one view shows faintly;
    a path that ends on bare backdrop (``other`` ran on onto something else) is not.
    """
    found = _guided_candidates(model, views, n, other, params.sample_step_px / 2)
    if found is None:
        return None
    pts, step, x0 = found
    uv, contrast = _guided_contrast(model, views[n], frame, n, pts)
    pick = strongest_candidates(contrast, _GUIDED_CANDIDATES, _GUIDED_PEAKS)
    pts, uv = (np.take_along_axis(a, pick[..., None], axis=1) for a in (pts, uv))
    contrast = np.take_along_axis(contrast, pick, axis=1)
    path = best_path(np.minimum(contrast, _GUIDED_CAP) - _GUIDED_BIAS, pts, step, x0,
                     stretch_cost=_GUIDED_STRETCH_COST, max_stretch=_GUIDED_STRETCH)
    if path is None:
        return None
    k = np.arange(len(path))
    on = contrast[k, path]
    tip = on[-max(4, int(np.ceil(params.guided_tip_share * len(on)))):]
    if np.median(tip) < params.guided_tip_sigmas or np.mean(on >= _GUIDED_SUPPORT) < params.guided_support:
        return None
    # Only where the view shows the tube: across its faint stretches the refitted curve interpolates.
    return _extended(views[n], uv[k, path][on >= params.guided_tip_sigmas], model.views[n].inner_radius_px, params)


def _guided_candidates(model: FastModel, views: dict, n: str, other: str, step_px: float):
    """Candidates for view ``n``'s lost stretch on ``other``'s rays beyond ``n``'s end: ``(points_mm (K, m, 3),
    step_mm (K,), start_mm (3,))`` in world mm, or None where ``other`` does not run on beyond it.

    The path starts where ``n``'s end ray passes ``other``'s first ray beyond the end; each step is at least
    what ``other`` sees of it at that depth (``step_mm``)."""
    vs, vl = views[n], views[other]
    smp = _view_samples(model, other, vl, step_px)
    end = (vs.end_px - vs.shift_px)[None]
    i = _beyond_angle(smp, float(_phi_at(model, n, end)[0]))
    if i is None or len(smp.s) - i < 8:
        return None
    ep = model.epipolar
    c_l, c_s = (ep.center_a, ep.center_b) if other == model.pair[0] else (ep.center_b, ep.center_a)
    uv = smp.uv[i - 1:]
    if len(uv) > _GUIDED_MAX_RAYS + 1:  # the search's time grows with its rays: about 1.3 s at 450
        uv = uv[np.round(np.linspace(0, len(uv) - 1, _GUIDED_MAX_RAYS + 1)).astype(int)]
    dirs = _unit_rays(model, other, uv)
    x0 = triangulate_rays(c_l, dirs[:1], c_s, _unit_rays(model, n, end))[0][0]
    depth_mm = float(np.linalg.norm(x0 - c_l))
    step_mm = depth_mm * np.arccos(np.clip(np.einsum("ij,ij->i", dirs[1:], dirs[:-1]), -1.0, 1.0))
    reach_mm = _GUIDED_STRETCH * np.cumsum(step_mm) + 1.0
    coarse = ray_candidates(c_l, dirs[1:], x0, reach_mm, 4 * _GUIDED_CANDIDATES)
    return _dense_in_view(model, n, c_l, dirs[1:], coarse), step_mm, x0


def _in_image(model: FastModel, n: str, uv: np.ndarray, z: np.ndarray) -> np.ndarray:
    """(m,) bool: projections ``uv`` (m, 2) px at depths ``z`` (m,) mm in front of camera ``n`` and inside its image."""
    H, W = model.views[n].shape
    return np.isfinite(uv).all(axis=1) & (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= W - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= H - 1)


def _dense_in_view(model: FastModel, n: str, center_mm: np.ndarray, dirs: np.ndarray, coarse: np.ndarray) -> np.ndarray:
    """Candidates on the rays ``dirs`` (K, 3) from ``center_mm``, on one depth grid over the depths at which view
    ``n`` sees any of the ``coarse`` ones (K, m, 3), spaced about half the inner tube's radius apart in view ``n``
    (at most ``_GUIDED_DENSE_MAX`` per ray): (K, N, 3) world mm; ``coarse`` itself where view ``n`` sees none.

    One grid for all rays: a candidate's neighbours on the next rays lie at its depth
    (:func:`_guided_contrast` reads the tube's direction from them)."""
    K, m = coarse.shape[:2]
    uv, z = _project(model.rig[n], coarse.reshape(-1, 3))
    ins = _in_image(model, n, uv, z).reshape(K, m)
    rows = np.flatnonzero(ins.any(axis=1))
    if rows.size == 0:
        return coarse
    depth = np.einsum("kmd,kd->km", coarse - center_mm, dirs)
    first, last = ins[rows].argmax(axis=1), m - 1 - ins[rows, ::-1].argmax(axis=1)
    uv = uv.reshape(K, m, 2)
    span_px = np.linalg.norm(uv[rows, last] - uv[rows, first], axis=1)
    span_mm = depth[rows, last] - depth[rows, first]
    lo, hi = float(depth[ins].min()), float(depth[ins].max())
    px_per_mm = float(np.max(span_px / np.maximum(span_mm, 1e-9)))
    spacing_px = 0.5 * max(model.views[n].inner_radius_px, 1.0)
    count = int(np.clip(np.ceil(px_per_mm * (hi - lo) / spacing_px), _GUIDED_CANDIDATES, _GUIDED_DENSE_MAX))
    return ray_points(center_mm, dirs, lo, hi, count)


def _guided_contrast(model: FastModel, vc: ViewCenterline, frame, n: str, pts_mm: np.ndarray) -> tuple:
    """Candidates ``pts_mm`` (K, m, 3) projected into view ``n`` (px, in the frame's shift) and their tube
    contrast there (:func:`recon.guided.tube_contrast`; 0 outside the image): ``(uv (K, m, 2), contrast (K, m))``."""
    uv, z = _project(model.rig[n], pts_mm.reshape(-1, 3))
    uv = uv + vc.shift_px
    H, W = model.views[n].shape
    r_px = max(model.views[n].inner_radius_px, 1.0)
    ins = _in_image(model, n, uv, z)
    contrast = np.zeros(len(uv), np.float32)
    grid = uv.reshape(*pts_mm.shape[:2], 2)
    if ins.any():
        m = int(np.ceil(4 * r_px)) + 2
        x_lo, y_lo = np.maximum(np.floor(uv[ins].min(axis=0)) - m, 0).astype(int)
        x_hi, y_hi = np.minimum(np.ceil(uv[ins].max(axis=0)) + m + 1, (W, H)).astype(int)
        diff = background_difference(model.views[n], frame, vc.coarse.coefficients, (x_lo, y_lo, x_hi, y_hi), vc.shift_px)
        along = np.gradient(grid, axis=0)  # the tube's direction near each candidate: its neighbours on the next rays
        nrm = np.stack([-along[..., 1], along[..., 0]], axis=-1)
        nrm /= np.maximum(np.linalg.norm(nrm, axis=-1, keepdims=True), 1e-9)
        contrast[ins] = tube_contrast(diff, (x_lo, y_lo), uv[ins], nrm.reshape(-1, 2)[ins], r_px)
    return grid, contrast.reshape(pts_mm.shape[:2])


def _extended(vc: ViewCenterline, more_px: np.ndarray, radius_px: float, params: FastParams) -> ViewCenterline:
    """A view's centerline with centres ``more_px`` (m, 2) px added beyond its end, its curve refitted.

    Centres more than ``radius_px`` (and 4 MADs of the distances) off the curve through the others are left out:
    the search along the other view's rays can take a stretch of backdrop beside the faint tube on one ray,
    and the curve refitted through it hooked off the tube (wide-1-49 frame 0, top view: 2 mm before the tip).
    """
    s1 = vc.s_range[1]
    start = vc.curve(np.array([s1]))[0]

    def s_of(more):  # curve parameters (px) of the added centres: chords on from the curve's end
        return s1 + np.cumsum(np.linalg.norm(np.diff(np.vstack([start, more]), axis=0), axis=1))

    off = off_curve(np.concatenate([vc.s, s_of(more_px)]), np.vstack([vc.points_px, more_px]),
                    params.view.spline_knot_px, radius_px, params.view.outlier_sigma)[len(vc.s):]
    if off.any() and not off.all():
        more_px = more_px[~off]
    s = np.concatenate([vc.s, s_of(more_px)])
    pts = np.vstack([vc.points_px, more_px])
    curve = fit_curve(s, pts, params.view.spline_knot_px)
    tangent = curve.derivative()(s[-1:])[0]
    tangent = tangent / np.linalg.norm(tangent)
    return replace(vc, curve=curve, s_range=(vc.s_range[0], float(s[-1])), points_px=pts, s=s,
                   width_px=np.concatenate([vc.width_px, np.full(len(more_px), 2.0 * radius_px)]),
                   end_px=pts[-1] + radius_px * tangent, end_s=float(s[-1]), tangent_end=tangent)


def _common_part(model: FastModel, views: dict, sa_: _ViewSamples, sb_: _ViewSamples, params: FastParams) -> tuple:
    """The pair's samples cut to what both views see where their tips still disagree after the second tries:
    ``(sa_, sb_, reason)``, ``views`` updated in place; reason None where the tips agree.

    Raises :class:`~recon.errors.FrameError` when each view overshoots the other, or the longer one would keep
    less than ``params.min_common_fraction`` of its curve."""
    n = _short_view(model, views, sa_, sb_, params)
    if n is None:
        return sa_, sb_, None
    a, b = model.pair
    other = b if n == a else a
    short = _tip_mismatch(model, views, sa_, sb_)[n]
    what = (f"the views disagree on the tip: {n}'s ends {short:.0f} px along the tube short of where {other}'s tip "
            "puts it (one view lost the tube before its tip, or the other followed something else)")
    end = views[n].end_px - views[n].shift_px
    cut = _cut_at_angle(model, other, views[other], float(_phi_at(model, n, end[None])[0]), params.min_common_fraction)
    if cut is None:
        raise FrameError(what)
    views[other] = cut
    smp = _view_samples(model, other, cut, params.sample_step_px)
    sa_, sb_ = (smp, sb_) if other == a else (sa_, smp)
    return sa_, sb_, f"{what}: the backbone stops where both views see the tube"


@dataclass(frozen=True)
class _Matched:
    """The views' samples matched through the epipolar planes (kept where the rays meet) and the smoothing
    spline through their triangulated points: parameters ``s_a, s_b`` (px), confidences ``ca, cb``,
    ``q = s_a + s_b``, ray gaps (mm), the correspondence used, the spline X(q) (mm) and its chord (mm)."""

    s_a: np.ndarray
    s_b: np.ndarray
    ca: np.ndarray
    cb: np.ndarray
    q: np.ndarray
    gap: np.ndarray
    how: str
    spline: object
    chord: float


def _matched_curve(model: FastModel, params: FastParams, sa_: _ViewSamples, sb_: _ViewSamples, tol: float) -> _Matched:
    """Correspond, triangulate, drop rays that miss each other, fit the weighted spline (:class:`_Matched`)."""
    s_a, s_b, da, db, ca, cb, how = _correspond(sa_, sb_, tol, params.min_end_conditioning)
    X, gap = triangulate_rays(model.epipolar.center_a, da, model.epipolar.center_b, db)
    keep = gap < params.max_ray_gap_mm
    if keep.sum() < 6:
        raise FrameError(f"the two views disagree: matched rays pass {np.median(gap):.2f} mm apart (more than {params.max_ray_gap_mm:g})")
    X, s_a, s_b, ca, cb, gap = X[keep], s_a[keep], s_b[keep], ca[keep], cb[keep], gap[keep]
    q = s_a + s_b
    order = np.argsort(q, kind="stable")
    X, q, s_a, s_b, ca, cb = X[order], q[order], s_a[order], s_b[order], ca[order], cb[order]
    w = np.clip(np.minimum(ca, cb), 0.03, 1.0) ** 2
    chord = float(np.sum(np.linalg.norm(np.diff(X[:: max(1, len(X) // 40)], axis=0), axis=1)))
    q_per_mm = (q[-1] - q[0]) / max(chord, 1e-6)
    spl = fit_curve(q, X, params.knot_mm * q_per_mm, w)
    return _Matched(s_a, s_b, ca, cb, q, gap, how, spl, chord)


class FastReconstructor:
    """The per-frame callable of the fast method (keeps the previous frame for the jump check).

    Parameters
    ----------
    model : FastModel
        From :func:`prepare_fast`.
    params : FastParams, optional
        The parameters the model was prepared with.
    """

    def __init__(self, model: FastModel, params: FastParams = FastParams()):
        self.model = model
        self.params = params
        self._prev = None
        self._roi = {}

    def reset(self) -> None:
        """Forget the previous frame (e.g. at a cut in the sequence)."""
        self._prev = None
        self._roi = {}

    def _steady(self, frames: dict, detail: dict) -> tuple:
        """The pair's frames moved back onto their backgrounds by their image shifts (camera jitter,
        :func:`recon.subpixel.steady_frame`) where ``params.view.jitter_compensation`` and they jitter beyond
        the background frames over a textured backdrop, and the shifts of those left as they were (None: not
        measured, or moved): ``(frames, shifts)``; the wall time (ms) into ``detail["steady"]``. Every later stage (and its second
        tries) reads these frames: what they find is in the calibrated cameras' pixel frames, up to the shift
        left (``ViewCenterline.shift_px``)."""
        if not self.params.view.jitter_compensation:
            return frames, {}
        t = time.perf_counter()
        steady, shifts = {}, {}
        for n in self.model.pair:
            steady[n], shift, moved = steady_frame(self.model.views[n], frames[n])
            shifts[n] = None if moved else shift
        detail["steady"] = 1e3 * (time.perf_counter() - t)
        return steady, shifts

    def _extract_views(self, frames: dict, timings: dict, detail: dict, shifts: dict) -> dict:
        """Each view's sub-pixel centerline (:func:`recon.subpixel.extract_view`), from last frame's region of
        interest, with the frame's shift where ``shifts`` holds it (:meth:`_steady`); ``view_<name>`` wall
        times (ms) into ``timings``, the stages' into ``detail``."""
        model, params = self.model, self.params
        views = {}
        t = time.perf_counter()
        for name in model.pair:
            stages = {}
            roi = self._roi.get(name)
            try:
                views[name] = extract_view(model.views[name], frames[name], params.view, roi=roi, timings=stages,
                                           shift_px=shifts.get(name))
            except FrameError:
                self._roi.pop(name, None)
                raise
            m = max(1, int(np.ceil(params.roi_margin_px / model.views[name].factor)))
            x0, y0, x1, y1 = views[name].coarse.coarse_bbox
            self._roi[name] = (x0 - m, y0 - m, x1 + m, y1 + m)
            now = time.perf_counter()
            timings[f"view_{name}"] = 1e3 * (now - t)
            for k, v in stages.items():
                detail[f"{name}_{k}"] = v
            t = now
        return views

    def _again(self, frames: dict, views: dict, samples: tuple, name: str, **kw) -> tuple:
        """View ``name`` extracted once more (:func:`recon.subpixel.extract_view` keywords ``kw``) into ``views``;
        returns the pair's samples with that view's replaced."""
        model, params = self.model, self.params
        views[name] = extract_view(model.views[name], frames[name], params.view, **kw)
        smp = _view_samples(model, name, views[name], params.sample_step_px)
        return (smp, samples[1]) if name == model.pair[0] else (samples[0], smp)

    def _retry(self, frames: dict, views: dict, samples: tuple, name: str, better, **kw) -> tuple:
        """:meth:`_again`, kept only where ``better(samples)`` says the second try improves on the first (else
        ``views`` and the samples are as they were, as they are where it raises :class:`FrameError`):
        ``(samples, rejected)``, the second try's centerline where it was not kept (else None)."""
        kept = views[name], samples
        try:
            samples = self._again(frames, views, samples, name, **kw)
            if better(samples):
                return samples, None
        except FrameError:
            pass
        rejected = views[name] if views[name] is not kept[0] else None
        views[name] = kept[0]
        return kept[1], rejected

    def _agreeing(self, frames: dict, views: dict, sa_: _ViewSamples, sb_: _ViewSamples, n: str) -> tuple:
        """The samples of a pair whose tips disagree (view ``n`` ends short), after second tries, and why the
        method cannot vouch for the shape (None: the tips now agree): ``(sa_, sb_, reason)``.

        One view lost a faint stretch of tube before its tip: it is followed once more, more sensitively (kept
        where it then ends nearer the other's tip). If it still ends short, the other view may have bridged a
        gap onto backdrop beyond the tip: that one is followed again without bridging (kept unless it then ends
        short of the first). Where they still disagree, the lost stretch is looked for along the other view's
        rays (:meth:`_found_again`), and failing that both are cut to what both see (:func:`_common_part`).
        """
        model, params = self.model, self.params
        a, b = model.pair
        other = b if n == a else a
        short = _tip_mismatch(model, views, sa_, sb_)[n]
        (sa_, sb_), sensitive = self._retry(frames, views, (sa_, sb_), n,
                                            lambda s: _tip_mismatch(model, views, *s)[n] < short,
                                            follow_min_dn=params.retry_min_dn, bridge_gaps=False)
        if _short_view(model, views, sa_, sb_, params) == n:
            # Without its bridges the other view must not end short of this one: then what it bridged was tube
            # (a faint stretch it crossed), not backdrop beyond the tip (wide-2-6 frame 0: the side view fell
            # back to its first 98 of 587 centres), and this view is looked for along its bridged centerline.
            (sa_, sb_), _ = self._retry(frames, views, (sa_, sb_), other,
                                        lambda s: _short_view(model, views, *s, params) != other, bridge_gaps=False)
        m = _short_view(model, views, sa_, sb_, params)
        if m is not None:
            # The search starts at the short view's end; the sensitive try's end, where it was not kept, is a
            # second start (wide-2-6 frame 0: the first end lies on a speck of clutter on the tube).
            starts = [views[m]] + ([sensitive] if m == n and sensitive is not None else [])
            found = self._found_again(frames, views, (sa_, sb_), m, starts)
            if found is not None:
                return found
        return _common_part(model, views, sa_, sb_, params)

    def _found_again(self, frames: dict, views: dict, samples: tuple, n: str, starts: list):
        """The pair's samples with view ``n``'s lost stretch found along the other view's rays
        (:func:`_lost_stretch`) from the first of ``starts`` (view ``n``'s centerlines) it is found from,
        ``views`` updated in place, and the reason the frame is suspect where the tips still disagree
        (:func:`_common_part`): ``(sa_, sb_, reason)``; None where it is found from none."""
        model, params = self.model, self.params
        a, b = model.pair
        other = b if n == a else a
        for start in starts:
            found = _lost_stretch(model, params, {**views, n: start}, frames[n], n, other)
            if found is None:
                continue
            views[n] = found
            smp = _view_samples(model, n, found, params.sample_step_px)
            sa_, sb_ = (smp, samples[1]) if n == a else (samples[0], smp)
            # The stretch found along the rays is judged as any other stretch is, by the reprojection against
            # both views (here and in the self-check). Flagged here as well, it was 21 frames of wide seeds 1,
            # 2, 3 and 5: 20 good, one 10.1 px footprints off at its base, not in the stretch (docs/envelope.md,
            # round 34).
            return _common_part(model, views, sa_, sb_, params)
        return None

    def _matched(self, frames: dict, views: dict, detail: dict) -> tuple:
        """The views' samples, after second tries where their tips disagree (:meth:`_agreeing`), matched and
        triangulated (:func:`_matched_curve`), and the :meth:`_agreeing` reason (None: the tips agree):
        ``(matched, reason)``; stage times (ms) into ``detail``: ``rays``, ``retry``, ``match_fit``."""
        model, params = self.model, self.params
        a, b = model.pair
        t = time.perf_counter()
        sa_, sb_ = (_view_samples(model, n, views[n], params.sample_step_px) for n in (a, b))
        lap = time.perf_counter()
        detail["rays"] = 1e3 * (lap - t)
        tol = 2.0 / float(model.rig[a].K[0, 0])  # ~2 px of epipolar angle
        n_short = _short_view(model, views, sa_, sb_, params)
        reason = None
        if n_short is not None:
            sa_, sb_, reason = self._agreeing(frames, views, sa_, sb_, n_short)
            detail["retry"] = 1e3 * (time.perf_counter() - lap)
        m = _matched_curve(model, params, sa_, sb_, tol)
        detail["match_fit"] = 1e3 * (time.perf_counter() - lap)
        return m, reason

    def __call__(self, frames: dict) -> FastReconstruction:
        """Reconstruct one frame pair.

        Parameters
        ----------
        frames : dict
            Camera name -> (H, W) or (H, W, 3) image (gray levels) of each
            camera of ``model.pair``; other cameras are ignored.

        Returns
        -------
        FastReconstruction
            The backbone (world frame, mm), its tip and outer/inner
            transition, the views' centres (image frame, px), and
            ``jump_flag`` against the previous frame's backbone.

        Raises
        ------
        FrameError
            A view's frame is missing, unusable or shows no (or not all of
            the) robot, a tube is too thin to resolve, or the two views
            disagree (rays, tips); the message names the camera where one is
            to blame.
        """
        model, params = self.model, self.params
        timings = {}
        t_start = time.perf_counter()
        detail = {}
        for name in model.pair:
            if name not in frames or frames[name] is None:
                raise FrameError("no frame", name)
            _check_tube_widths(name, model.views[name], params.min_tube_width_px)
        frames, shifts = self._steady(frames, detail)
        views = self._extract_views(frames, timings, detail, shifts)
        t = time.perf_counter()
        m, doubt = self._matched(frames, views, detail)
        lap = time.perf_counter()
        s_tr = {n: _transition_s(views[n], model.views[n]) for n in model.pair}
        backbones = _backbone(model, params, views, m, s_tr)
        now = time.perf_counter()
        detail["ends"] = 1e3 * (now - lap)
        timings["triangulate"] = 1e3 * (now - t)
        lap = time.perf_counter()
        judged = [self._judged(views, bb, doubt) for bb in backbones]
        self._prev = backbones[0][:2]  # (points, tip) of the own reading
        detail["reprojection"] = 1e3 * (time.perf_counter() - lap)
        timings["total"] = 1e3 * (time.perf_counter() - t_start)
        timings.update(detail)
        out = [_reconstruction(model, views, m, s_tr, bb, reason, timings, why, answerable)
               for bb, (reason, why, answerable) in zip(backbones, judged)]
        return replace(out[0], alternative=out[1]) if len(out) > 1 else out[0]

    def _judged(self, views: dict, backbone: tuple, doubt: str | None) -> tuple:
        """``(jump reason, doubt, answerable)`` of a backbone ``(points, tip, transition)``: the jump check
        against the previous frame's backbone, why the method cannot vouch for it (``doubt``: the views'
        disagreement on the tip, or the reprojection's), and whether that is the tips' doubt alone, which
        an image check answers (:attr:`FastReconstruction.check_answers_doubt`)."""
        points, tip, _ = backbone
        reason = None
        if self._prev is not None:
            reason = jump_check(self._prev[0], self._prev[1], points, tip, self.params.jump)
        off = _off_centerline(self.model, self.params, views, points)
        return reason, doubt or off, doubt is not None and off is None


def _backbone(model: FastModel, params: FastParams, views: dict, m: _Matched, s_tr: dict) -> list:
    """The matched curve ``m`` started at the base point (or continued straight back to the border,
    :func:`_to_base`) and continued to the tip seen in both views, resampled every ``output_step_mm``: a list
    of ``(points (n, 3) world mm, tip (3,) world mm, (transition_s_mm, transition_world_mm))``, a second one
    with the tip at the farther view's end where the views disagree on it (:func:`_to_tip`; ``s_tr``: each
    view's curve parameter of the outer tube's end, px)."""
    a, b = model.pair
    q, spl = m.q, m.spline
    fine = 0.5 * params.output_step_mm
    dense = spl(np.linspace(q[0], q[-1], max(8, int(m.chord / fine))))
    dense, base_ext = _to_base(model, params, dense, spl.derivative()(q[0]), fine)
    out = []
    for d in _to_tip(model, views, params, dense, spl.derivative()(q[-1]), s_tr, fine):
        if d is not None:
            points = resample_polyline(d, params.output_step_mm, mode="spread")
            out.append((points, points[-1].copy(), _transition(((a, m.s_a, m.ca), (b, m.s_b, m.cb)), s_tr, q, spl, base_ext, points)))
    return out


def _off_centerline(model: FastModel, params: FastParams, views: dict, points: np.ndarray) -> str | None:
    """Why the backbone ``points`` (world mm) cannot be vouched for, None where it can: a stretch of
    ``reprojection_window_mm`` whose projection into a view lies more than ``max_reprojection_px`` (median) from
    that view's centerline. Backbone points nearest either end segment of a centerline (the stretches continued
    to the base and the tip beyond it) are not judged."""
    # Every other backbone point and every fourth centre (~8 px chords, off a curve of 50 px radius by 0.2 px):
    # a tenth of the time, for a figure judged against 5 px.
    pts = points[::2]
    k = max(1, int(round(params.reprojection_window_mm / (2.0 * params.output_step_mm))))
    for name in model.pair:
        vc = views[name]
        line = np.concatenate([vc.points_px[:-1:4], vc.points_px[-1:]]) - vc.shift_px
        if len(line) < 4:
            continue
        uv, _ = _project(model.rig[name], pts)
        d, seg = polyline_distances_nb(uv, line)
        d = d[(seg > 0) & (seg < len(line) - 2)]
        if d.size < k:
            continue
        worst = float(max_window_median_nb(d, k))
        if worst > params.max_reprojection_px:
            return (f"{name}: the backbone leaves this view's centerline by {worst:.1f} px over "
                    f"{params.reprojection_window_mm:g} mm (limit {params.max_reprojection_px:g} px)")
    return None


def _reconstruction(model: FastModel, views: dict, m: _Matched, s_tr: dict, backbone: tuple, reason,
                    timings: dict, doubt: str | None = None, answerable: bool = False) -> FastReconstruction:
    """The :class:`FastReconstruction` of a pair: ``backbone`` = (points (n, 3) world mm, tip (3,) world mm,
    (transition_s_mm, transition_world_mm)), the jump check's ``reason`` (None: plausible), why the method
    cannot vouch for the shape (``doubt``; the order-matched fallback gives one of its own), and whether an
    image check answers that doubt (``answerable``, not where the fallback's stands too)."""
    points, tip, (transition_s, transition_world) = backbone
    pair = model.pair
    shapes = {n: model.views[n].shape for n in pair}
    return FastReconstruction(
        points_world_mm=points,
        tip_world_mm=tip,
        transition_s_mm=transition_s,
        transition_world_mm=transition_world,
        length_mm=float(arc_length(points)[-1]),
        silhouettes=_LazyImages(pair, lambda n: _draw_silhouette(views[n], shapes[n])),
        centerlines=_LazyImages(pair, lambda n: _draw_centerline(views[n], shapes[n], s_tr[n])),
        centerlines_px={n: views[n].points_px for n in pair},
        widths_px={n: views[n].width_px for n in pair},
        box=(points.min(axis=0), points.max(axis=0)),
        voxel_size_mm=None,
        n_voxels=0,
        jump_flag=reason is not None,
        jump_reason=reason,
        ray_gap_mm=float(median_nb(np.asarray(m.gap, np.float64))),
        correspondence=m.how,
        timings_ms=timings,
        suspect_reason=doubt or (_ORDERED_REASON if m.how == "ordered-dp-one-view" else None),
        check_answers_doubt=bool(answerable and doubt and m.how != "ordered-dp-one-view"),
    )


def _warm_up(rec: FastReconstructor, background_frames: dict, length_mm: float = 40.0) -> None:
    """Reconstruct one synthetic pair, so that the first real frame does not pay for loading the compiled
    kernels (~200 ms): a background frame of each view with a straight tube drawn from the base along the
    insertion axis, 60 gray levels off it. What it gives is thrown away, errors included."""
    model = rec.model
    rig = model.rig
    axis = np.asarray(rig.insertion_axis_world, float)
    pts = np.asarray(rig.base_point_world_mm, float) + np.linspace(0.0, length_mm, 40)[:, None] * axis / np.linalg.norm(axis)
    frames = {}
    for name in model.pair:
        img = np.array(to_gray(background_frames[name])[0], dtype=np.uint8)
        uv, z = rig[name].project(pts)
        good = np.all(np.isfinite(uv), axis=1) & (z > 0)
        shade = -60 if float(np.median(img)) > 100 else 60
        width = max(2, int(round(2 * model.views[name].outer_radius_px)))
        line = np.zeros_like(img)
        cv2.polylines(line, [np.round(uv[good]).astype(np.int32).reshape(-1, 1, 2)], False, 255, width)
        frames[name] = np.clip(img.astype(np.int16) + np.where(line > 0, shade, 0), 0, 255).astype(np.uint8)
    try:
        rec(frames)
    except (FrameError, ValueError, np.linalg.LinAlgError):
        pass
    rec.reset()
    # The guided search's compiled path (second tries only: the synthetic pair never needs it).
    best_path(np.zeros((2, 2)), np.zeros((2, 2, 3)), np.ones(2), np.zeros(3))


def _prepare(rig, background_frames, params):
    rec = FastReconstructor(prepare_fast(rig, background_frames, params), params)
    _warm_up(rec, background_frames)
    return rec


register_method(
    Method(
        "fast",
        FastParams,
        _prepare,
        "sub-pixel edge-midpoint centerlines from a coarse-to-fine eigenbackground, epipolar correspondence, "
        "triangulation and a smoothing spline; ~ms per pair on one core",
    )
)
