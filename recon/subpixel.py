"""Sub-pixel tube centerline in one view, for the ``fast`` method (:mod:`recon.fast`).

The tube is found coarsely, then measured finely only where it is:

1. **Coarse** (1/4 resolution, the whole frame): the frame is area-averaged
   by ``coarse_factor``, its eigenbackground coefficients are fitted by least
   squares on those coarse pixels (a second pass leaves out the pixels the
   first pass calls foreground), and the coarse difference is thresholded
   against a per-pixel threshold learnt from the background frames (so the
   edges of static objects, which flicker with camera jitter, are not
   foreground); next to foreground pixels the mean *absolute* difference of
   each block's central 2x2 pixels is thresholded too, so that the dark rims
   and the bright highlight of a tube only a block or two wide, which cancel
   in the average, do not break the robot's region. The connected region at the robot's base is the robot; a
   geodesic (breadth-first) walk from the base through it gives the ordered path
   to the farthest point, the tip.
2. **Fine** (full resolution, ~1 % of the pixels): along the coarse path, at
   every pixel column (or row, where the tube runs more vertically than
   horizontally), a short profile across the tube is cut out of the frame and
   of the background, which is rebuilt on those pixels only
   (``mean + basis^T c``, with the basis stored pixel-major so a gather reads
   contiguous memory). On each profile the two silhouette edges are located to
   a fraction of a pixel by the partial-area (coverage) of the edge pixels:
   a pixel that the tube covers by a fraction ``a`` differs from the
   background by ``a`` times the tube's rim contrast, so an edge lies at the
   pixel boundary minus the summed coverage of the pixels before it. The
   midpoint of the two edges lies on the tube's axis (exactly, for a straight
   stretch with parallel edges, whatever the profile's slant) and their
   distance, times the slant, is the tube's width.
3. Centres are smoothed by a least-squares cubic B-spline (outliers, e.g.
   profiles through a specular highlight that reaches the rim, are rejected by
   their residual and the spline refitted; profiles much wider than their
   neighbours, e.g. cut through the end cap, are dropped). Where the coarse path
   stopped short of the tip, the tube is followed further at full resolution,
   profile by profile (:func:`_follow_tube`). The tip is measured along the
   tube's axis on lines parallel to it, each against its own interior contrast.

The per-pixel loops run compiled (:mod:`recon._kernels`, numba); this module
prepares their inputs and makes the decisions between them. Their NumPy
equivalents live on as test oracles (``tests/fast_oracles.py``). The
parameters are :class:`ViewParams`.

Pixel coordinates follow OpenCV: (0, 0) is the centre of the top-left pixel.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from ._kernels import (
    coarse_foreground_nb,
    coarse_foreground_tiles_nb,
    frame_coefficients_nb,
    median_nb,
    near_any_nb,
    profile_values_nb,
    profiles_at_seeds_nb,
    ridge_hits_nb,
    running_rank_nb,
    spline_basis_nb,
    spline_eval_nb,
    spline_fit_nb,
    spline_robust_nb,
    tip_along_axis_nb,
    traced_path_nb,
)
from .background import no_picture, to_gray
from .errors import FrameError
from .halflit import BASE_STRETCH, half_lit_moves, lit_side
from .jitter import ShiftModel, frame_shift, pixel_noise, prepare_shift, shifted
from .geometry import resample_arc

__all__ = [
    "ViewParams",
    "ViewModel",
    "ViewCenterline",
    "prepare_view",
    "frame_coefficients",
    "steady_frame",
    "coarse_path",
    "coarse_abs_difference",
    "background_difference",
    "edges_from_profiles",
    "fit_curve",
    "UniformSpline",
    "extract_view",
]

_BORDER_NAMES = ("left", "top", "right", "bottom")

#: How far (coarse px) from a coarse pixel whose 2x2 average differs from the background the coarse stage
#: also tests the 2x2 pixels' mean absolute difference (see coarse_path): bridges cancellations up to
#: 2 * 2 coarse px (16 px) along a tube.
_ABS_REACH = 2


# ----------------------------------------------------------------------------- parameters
@dataclass(frozen=True)
class ViewParams:
    """Parameters of one view's centerline extraction (:func:`extract_view`).

    Nested in :class:`recon.fast.FastParams` as ``view`` (a ``[view]`` table
    in a parameter file). Image quantities are in full-resolution pixels (px)
    and gray levels (DN) of the view's camera.

    Attributes
    ----------
    base_search_px : float
        The robot's region must come within this distance (px) of the
        projected base (or of where the insertion axis enters the image).
    profile_step_px : float
        Spacing of the measuring profiles across the tube along its path (px).
    edge_threshold_sigma, edge_min_dn : float
        A profile sample is tube when its difference exceeds this many sigmas
        (of the profile's noise: the pixel noise over the square root of the
        lines averaged) and gray levels.
    profile_half_lines : int
        Each profile averages ``2 profile_half_lines + 1`` parallel lines along
        the tube (fewer where the tube runs slanted to them), so that a tube
        little brighter or darker than the backdrop still has edges.
    single_line_rim_factor : float
        The middle line is tried alone first: where both its rims exceed this
        many times the single-line threshold (``edge_threshold_sigma`` sigmas,
        at least ``edge_min_dn``) its edges are used and the other lines are
        not cut (the averaging is ~5x the work per profile); inf: always
        average.
    min_width_fraction, max_width_fraction : float
        Profiles narrower than this fraction of the inner tube's width, or
        wider than this fraction of the outer tube's, are rejected.
    follow_gap_diameters : float
        Following the tube past the coarse path bridges stretches without
        edges (the tube in front of backdrop as bright as itself) up to this
        many outer-tube diameters, if the tube is found again beyond them
        (:func:`_follow_tube`).
    follow_energy : bool
        While following, a profile without a pair of edges still finds the
        tube where a window of its width differs from the background by half
        the edge threshold on average (a shiny tube whose rims match the
        backdrop, or one changing polarity along the way).
    outlier_sigma, outlier_min_px : float
        A centre farther than ``max(outlier_sigma * MAD, outlier_min_px)``
        (px) from the spline is rejected.
    spline_knot_px : float
        Knot spacing of the view's centerline spline (px of its curve
        parameter, the arc length along the coarse path).
    jitter_compensation : bool
        Measure each frame's image shift against the background's static
        edges (camera jitter, :func:`recon.jitter.frame_shift`), so that the caller can undo
        it before triangulating; False: ``ViewCenterline.shift_px`` is zero.
    """

    base_search_px: float = 24.0
    profile_step_px: float = 2.0
    edge_threshold_sigma: float = 5.0
    edge_min_dn: float = 8.0
    profile_half_lines: int = 2
    single_line_rim_factor: float = 3.0
    min_width_fraction: float = 0.2
    max_width_fraction: float = 1.3
    follow_gap_diameters: float = 3.0
    follow_energy: bool = True
    outlier_sigma: float = 4.0
    outlier_min_px: float = 0.5
    spline_knot_px: float = 40.0
    jitter_compensation: bool = True

    def __post_init__(self):
        # Zero would stall the profile walk or leave the spline without knot intervals.
        for name in ("profile_step_px", "spline_knot_px"):
            if not getattr(self, name) > 0:
                raise ValueError(f"ViewParams.{name} must be > 0, got {getattr(self, name)}")


# ----------------------------------------------------------------------------- model
@dataclass(frozen=True, eq=False)
class ViewModel:
    """Per-camera constants of the fast method (built once per session).

    Attributes
    ----------
    name : str
    shape : (H, W)
    stack : (H*W, k+1) float32
        Mean background and eigenbackgrounds, pixel-major: row ``p`` holds
        ``mean[p], basis[0, p], ..., basis[k-1, p]``.
    factor : int
        Coarse downsampling factor.
    coarse_mean : (Hc*Wc,) float32
    coarse_basis : (k, Hc*Wc) float32
    sample_index : (M, 4) int
        Full-resolution pixels whose mean is each of M fixed coarse pixels
        (a regular grid) on which the eigenbackground coefficients are fitted.
    sample_mean, sample_basis_t, sample_gram, sample_threshold, sample_prior
        Mean, basis (M, k), its Gram matrix, the foreground threshold at
        those coarse pixels, and the prior's diagonal (noise / eigenvalue).
    background_jitter_px : (2,) array or None
        The background frames' largest shift along u and along v against their
        mean, times the jitter margin (px; None: not measured): the coarse
        thresholds, learnt on those frames, hold a frame's flicker up to these
        shifts.
    shift : recon.jitter.ShiftModel or None
        The mean background's edges on which each frame's image shift (camera
        jitter) is measured; None when the background has too little texture.
    coarse_threshold : (Hc, Wc) float32
        Foreground threshold per coarse pixel (gray levels), learnt on
        :func:`coarse_abs_difference` (never below the absolute value of the
        2x2 average's difference, the other statistic it is applied to).
    coarse_stack : (Hc, Wc, 4, k+1) float32
        The rows of ``stack`` at the central 2x2 pixels of each coarse pixel's
        block, contiguous (the coarse stage reads them for every pixel of its
        region of interest).
    sigma_fine : float
        Noise of the fine background difference (gray levels).
    base_px, axis_px : (2,) arrays
        The robot base projected into the image, and the unit image direction
        of the insertion axis there.
    start_px : (2,) array or None
        Where the robot is looked for first: the projected base when it lies
        in the image, else where the projected insertion axis enters the
        image (the robot comes in across the border); None: ``base_px``.
    start_search_px : float
        Extra search radius around ``start_px`` (px): a fifth of the distance
        from the base to the entry point (a precurved tube can enter a little
        off the axis), 0 when the base is in view.
    outer_radius_px, inner_radius_px : float
        Tube radii in the image where the robot is seen (px): at the base, or
        where the insertion axis enters the image when the base is out of
        view (``width_at`` says which).
    peak, background_range : float
        Brightest gray level of the mean background and its spread (max -
        min), for :func:`recon.background.no_picture`.
    """

    name: str
    shape: tuple
    stack: np.ndarray
    factor: int
    coarse_mean: np.ndarray
    coarse_basis: np.ndarray
    coarse_threshold: np.ndarray
    sample_index: np.ndarray
    sample_mean: np.ndarray
    sample_basis_t: np.ndarray
    sample_gram: np.ndarray
    sample_threshold: np.ndarray
    sample_prior: np.ndarray
    sigma_fine: float
    base_px: np.ndarray
    axis_px: np.ndarray
    outer_radius_px: float
    inner_radius_px: float
    peak: float
    background_range: float = 0.0
    background_jitter_px: np.ndarray = None
    shift: ShiftModel = None
    coarse_stack: np.ndarray = None
    start_px: np.ndarray = None
    start_search_px: float = 0.0
    width_at: str = "at the robot base"

    @property
    def coarse_shape(self) -> tuple:
        """``(Hc, Wc)``: the coarse image's size (coarse px), ``shape`` floor-divided by ``factor``.

        Returns
        -------
        tuple of int
            Rows and columns of the coarse image (coarse px).
        """
        return (self.shape[0] // self.factor, self.shape[1] // self.factor)

    @property
    def starts_at_base(self) -> bool:
        """Whether the robot is looked for at its projected base (in view, or nothing is).

        Returns
        -------
        bool
            ``start_px`` is None or :func:`numpy.allclose` to ``base_px``
            (px), in plain floats: asked on every frame, where NumPy's
            version costs ~12 us.
        """
        if self.start_px is None:
            return True
        return all(abs(float(a) - float(b)) <= 1e-8 + 1e-5 * abs(float(b)) for a, b in zip(self.start_px, self.base_px))


def _downsample(img: np.ndarray, factor: int) -> np.ndarray:
    """Coarse image: each output pixel averages the central 2x2 pixels of its ``factor`` block.

    (OpenCV's bilinear resize at an integer ratio; a linear operator, applied
    alike to frames, the mean background and the eigenbackgrounds, so coarse
    coefficients are those of the full-resolution model. ~6x cheaper than an
    area average of the whole block.)
    """
    h, w = img.shape[0] // factor, img.shape[1] // factor
    if factor == 1:
        return img
    return cv2.resize(img[: h * factor, : w * factor], (w, h), interpolation=cv2.INTER_LINEAR)


def _central_offsets(factor: int) -> tuple[int, int]:
    """Offsets (px) of the central 2x2 pixels of a ``factor`` block (one pixel, twice, for odd factors)."""
    if factor % 2:
        return (factor - 1) // 2, (factor - 1) // 2
    return factor // 2 - 1, factor // 2


def _central_pixels(H: int, W: int, factor: int) -> np.ndarray:
    """(Hc, Wc, 4) flat indices of the central 2x2 pixels of each coarse pixel's block."""
    lo, hi = _central_offsets(factor)
    cy, cx = np.mgrid[0: H // factor, 0: W // factor]
    return np.stack([(cy * factor + a) * W + cx * factor + b for a in (lo, hi) for b in (lo, hi)], axis=-1)


def coarse_abs_difference(model: ViewModel, frame: np.ndarray, coeff: np.ndarray, roi: tuple) -> np.ndarray:
    """Mean absolute background difference of the central 2x2 pixels of each coarse pixel in ``roi``.

    The background is rebuilt at those pixels only (``ViewModel.stack @
    coeff``). Absolute values, not the difference of the averages: a tube
    one or two blocks wide often has dark rims and a highlight brighter than
    the backdrop, whose differences cancel in an average (an inner tube of
    4-6 px dropped out of the coarse mask for one or a few coarse pixels, and
    the path stopped there, short of the tip).

    Parameters
    ----------
    model : ViewModel
        The view's constants.
    frame : (H, W) uint8 array
        The frame (gray levels).
    coeff : (k+1,) float32 array
        The frame's background coefficients (:func:`frame_coefficients`).
    roi : (x0, y0, x1, y1)
        Coarse pixels (image frame, coarse px).

    Returns
    -------
    (y1-y0, x1-x0) float32 array
        The mean absolute difference (gray levels).
    """
    f = model.factor
    lo, hi = _central_offsets(f)
    x0, y0, x1, y1 = (int(v) for v in roi)
    # The four pixels in the order of ViewModel.coarse_stack's third axis.
    px = np.stack([frame[y0 * f + a: y1 * f: f, x0 * f + b: x1 * f: f] for a in (lo, hi) for b in (lo, hi)], axis=-1)
    bg = model.coarse_stack[y0:y1, x0:x1] @ coeff
    return np.abs(px.astype(np.float32) - bg).mean(axis=-1)


def background_difference(model: ViewModel, frame: np.ndarray, coeff: np.ndarray, box: tuple,
                          shift_px=(0.0, 0.0)) -> np.ndarray:
    """Frame minus background over a box of full-resolution pixels (gray levels).

    The background is rebuilt there (``ViewModel.stack @ coeff``) and moved by
    the frame's image shift (:func:`recon.jitter.frame_shift`), so the edges of a textured
    backdrop cancel under camera jitter.

    Parameters
    ----------
    model : ViewModel
    frame : (H, W) or (H, W, 3) array
        The frame (gray levels).
    coeff : (k+1,) float32 array
        The frame's background coefficients (:func:`frame_coefficients`).
    box : (x0, y0, x1, y1)
        Pixel bounds (image frame, px; x1, y1 exclusive), within the image.
    shift_px : (2,)
        The frame's shift against the background (px).

    Returns
    -------
    (y1-y0, x1-x0) float32 array
    """
    x0, y0, x1, y1 = (int(v) for v in box)
    H, W = model.shape
    idx = (np.arange(y0, y1)[:, None] * W + np.arange(x0, x1)[None, :]).ravel()
    bg = (model.stack[idx] @ np.asarray(coeff, np.float32)).reshape(y1 - y0, x1 - x0)
    if np.any(np.asarray(shift_px) != 0):
        move = np.float32([[1, 0, shift_px[0]], [0, 1, shift_px[1]]])
        bg = cv2.warpAffine(bg, move, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return _gray_frame(model, frame)[y0:y1, x0:x1].astype(np.float32) - bg


def _entry_point(camera, base_world_mm, axis_world, H: int, W: int, margin: float = 2.0, reach_mm: float = 400.0):
    """Where the robot is looked for: the projected base, or where the projected insertion axis enters the image.

    Returns ``(start_px, extra_search_px, point_world_mm)``; ``start_px`` is
    None when neither the base nor any point of the axis within ``reach_mm``
    projects into the image; ``point_world_mm`` is the axis point at
    ``start_px`` (the base when it is in view or nothing is).
    """
    base = np.asarray(base_world_mm, float)
    axis = np.asarray(axis_world, float)
    axis = axis / max(np.linalg.norm(axis), 1e-12)
    t = np.arange(0.0, reach_mm, 0.25)
    uv, z = camera.project(base[None] + t[:, None] * axis[None])
    inside = (z > 0) & (uv[:, 0] >= margin) & (uv[:, 0] <= W - 1 - margin) & (uv[:, 1] >= margin) & (uv[:, 1] <= H - 1 - margin)
    if inside[0]:
        return uv[0].copy(), 0.0, base
    if not inside.any():
        return None, 0.0, base
    k = int(np.argmax(inside))
    return uv[k].copy(), (0.2 * float(np.hypot(*(uv[k] - uv[0]))) if z[0] > 0 else 0.0), base + t[k] * axis


def prepare_view(name, eigen, camera, base_world_mm, axis_world, outer_radius_mm, inner_radius_mm, background_frames,
                 factor: int = 4, threshold_sigma: float = 6.0, threshold_min_dn: float = 6.0,
                 jitter_margin: float = 1.5, n_samples: int = 2048) -> ViewModel:
    """Build a :class:`ViewModel` from a fitted :class:`~recon.background.EigenBackground`.

    ``background_frames`` set the noise levels: the coarse threshold of each
    pixel is ``max(threshold_min_dn, threshold_sigma * sigma, jitter_margin *
    max residual)`` over the background frames, with sigma the noise of a 2x2
    mean and the residual the larger of the two statistics the live frames
    are thresholded on (:func:`coarse_abs_difference`), the maximum taken over
    the pixel's 3x3 neighbourhood (the residual of a static edge moves with
    the jitter).

    Parameters
    ----------
    name : str
        The camera's name (errors name it).
    eigen : recon.background.EigenBackground
        The view's eigenbackgrounds, (H, W) px, gray levels.
    camera : recon.camera.Camera
        The calibrated camera of the view (world frame, mm).
    base_world_mm : (3,) array_like
        The robot base (world frame, mm).
    axis_world : (3,) array_like
        The insertion axis' direction (world frame; need not be unit).
    outer_radius_mm, inner_radius_mm : float
        Tube radii (mm); turned into px where the view sees the robot.
    background_frames : (N, H, W) or (N, H, W, 3) array
        Background frames of the view (gray levels; RGB is converted).
    factor : int, optional
        Coarse downsampling factor (full-resolution px per coarse px).
    threshold_sigma, threshold_min_dn : float, optional
        Floor of the coarse threshold: noise sigmas of a 2x2 mean, and gray
        levels.
    jitter_margin : float, optional
        Factor on the background frames' largest coarse residual.
    n_samples : int, optional
        About how many coarse pixels the per-frame coefficients are fitted on.

    Returns
    -------
    ViewModel
        The view's constants; positions in the image's pixel frame (px,
        OpenCV convention).
    """
    H, W = eigen.shape
    k = eigen.k
    stack, coarse_mean, coarse_basis = _background_arrays(eigen, factor)
    hc, wc = H // factor, W // factor
    scoarse, sidx = _coefficient_samples(H, W, factor, n_samples)
    base_uv, axis_px = _image_axis(camera, base_world_mm, axis_world)
    start_px, start_search, seen_at = _entry_point(camera, base_world_mm, axis_world, H, W)
    # Tube widths where the robot is seen: at the base, or where it enters the view (an out-of-view base can
    # lie farther from the camera than any part of the robot in the image, and the tubes look thinner there).
    mm_px = camera.mm_per_pixel_at(seen_at)
    model = ViewModel(
        name=name, shape=(H, W), stack=stack, factor=factor, coarse_mean=coarse_mean, coarse_basis=coarse_basis,
        coarse_threshold=np.zeros((hc, wc), np.float32),
        sample_index=sidx, sample_mean=coarse_mean[scoarse], sample_basis_t=np.ascontiguousarray(coarse_basis[:, scoarse].T.astype(np.float64)),
        sample_gram=coarse_basis[:, scoarse].astype(np.float64) @ coarse_basis[:, scoarse].T.astype(np.float64),
        sample_threshold=np.zeros(scoarse.size, np.float32), sample_prior=np.zeros(k), sigma_fine=1.0,
        coarse_stack=np.ascontiguousarray(stack[_central_pixels(H, W, factor)]),
        base_px=base_uv[0], axis_px=axis_px, outer_radius_px=outer_radius_mm / mm_px,
        inner_radius_px=inner_radius_mm / mm_px, peak=float(eigen.mean.max()),
        background_range=float(eigen.mean.max() - eigen.mean.min()),
        start_px=start_px, start_search_px=start_search,
        width_at="at the robot base" if np.array_equal(seen_at, np.asarray(base_world_mm, float)) else "where the robot enters the image",
    )
    frames = to_gray(background_frames)
    sigma_pix = pixel_noise(frames)
    sigma_c = sigma_pix / 2.0  # a coarse pixel averages 2x2 pixels
    floor = max(threshold_min_dn, threshold_sigma * sigma_c)
    lam = np.maximum(np.asarray(eigen.eigenvalues, float), 1e-9)
    # The prior and the floor first: the background frames' residuals below are fitted with them, as live frames are.
    object.__setattr__(model, "sample_prior", sigma_c ** 2 / lam)
    object.__setattr__(model, "sample_threshold", np.full(scoarse.size, floor, np.float32))
    thr = _coarse_thresholds(model, frames, jitter_margin, floor)
    object.__setattr__(model, "coarse_threshold", thr.astype(np.float32))
    object.__setattr__(model, "sample_threshold", thr.reshape(-1)[scoarse].astype(np.float32))
    object.__setattr__(model, "sigma_fine", sigma_pix)
    object.__setattr__(model, "shift", prepare_shift(eigen.mean.reshape(H, W), sigma_pix))
    if model.shift is not None:
        shifts = np.array([frame_shift(model.shift, f) for f in frames])
        object.__setattr__(model, "background_jitter_px", np.float64(jitter_margin) * np.abs(shifts).max(axis=0))
    return model


def _background_arrays(eigen, factor: int) -> tuple:
    """``(stack, coarse_mean, coarse_basis)`` of :class:`ViewModel` from the eigenbackgrounds (gray levels)."""
    H, W = eigen.shape
    stack = np.empty((H * W, eigen.k + 1), np.float32)
    stack[:, 0] = eigen.mean
    stack[:, 1:] = eigen.basis.T
    coarse_mean = _downsample(eigen.mean.reshape(H, W), factor).ravel().astype(np.float32)
    coarse_basis = np.stack([_downsample(b.reshape(H, W), factor).ravel() for b in eigen.basis]).astype(np.float32)
    return stack, coarse_mean, coarse_basis


def _coefficient_samples(H: int, W: int, factor: int, n_samples: int) -> tuple:
    """The coarse pixels the per-frame coefficients are fitted on: a regular grid of about ``n_samples``.

    Returns ``(flat coarse indices (M,), the full-resolution pixels each averages (M, 4) flat indices)``.
    """
    hc, wc = H // factor, W // factor
    step = max(1, int(np.sqrt(hc * wc / n_samples)))
    gy, gx = np.mgrid[step // 2:hc:step, step // 2:wc:step]
    gy, gx = gy.ravel(), gx.ravel()
    return gy * wc + gx, _central_pixels(H, W, factor)[gy, gx]


def _image_axis(camera, base_world_mm, axis_world) -> tuple:
    """The base projected into the image (px) and the unit image direction of the insertion axis there."""
    base_uv, _ = camera.project(np.asarray(base_world_mm, float)[None])
    tip_uv, _ = camera.project(np.asarray(base_world_mm, float)[None] + 5.0 * np.asarray(axis_world, float)[None])
    axis_px = tip_uv[0] - base_uv[0]
    axis_px /= max(np.linalg.norm(axis_px), 1e-9)
    return base_uv, axis_px


def _coarse_thresholds(model: ViewModel, frames: np.ndarray, jitter_margin: float, floor: float) -> np.ndarray:
    """(Hc, Wc) float32 coarse threshold (gray levels): ``jitter_margin`` times the largest residual of (at
    most 12) background frames over each pixel's 3x3 neighbourhood (the static edges' flicker moves with the
    jitter), at least ``floor``."""
    hc, wc = model.coarse_shape
    pick = np.unique(np.linspace(0, len(frames) - 1, min(12, len(frames))).round().astype(int))
    maxabs = np.zeros((hc, wc), np.float32)
    for i in pick:
        f = frames[i]
        res = coarse_abs_difference(model, f, frame_coefficients(model, f), (0, 0, wc, hc))
        np.maximum(maxabs, res, out=maxabs)
    thr = cv2.dilate(maxabs, np.ones((3, 3), np.uint8)) * np.float32(jitter_margin)
    return np.maximum(thr, np.float32(floor))


def steady_frame(model: ViewModel, frame: np.ndarray) -> tuple:
    """The frame moved back onto the background by its image shift (camera jitter, :func:`recon.jitter.frame_shift`).

    Under jitter every edge of a textured backdrop differs from the background
    model by up to its gradient times the shift. The coarse thresholds, learnt
    on the background frames, hold that flicker as far as those frames jittered
    (:attr:`ViewModel.background_jitter_px`); a frame that jitters further
    along u or v has its backdrop's edges, as thin as a tube, pass for one
    (wide-2-23 frame 1, noise: 35 footprints off; moved back, 4.7). Only such a
    frame is moved: within that range resampling only blurs (the CI wide set's
    wide-21-3 frame 2, a faint tube under 4 px: moved back, both views lost its
    last 38 footprints). Cubic convolution (:func:`recon.jitter.shifted`): bilinear
    resampling at half a pixel halves a thin tube's end cap, and tips came
    out shorter.

    Parameters
    ----------
    model : ViewModel
        The view's constants.
    frame : (H, W) or (H, W, 3) array
        The frame (gray levels).

    Returns
    -------
    steady : (H, W) uint8 array
        The frame resampled at its pixels plus the shift: in the background's
        (the calibrated camera's) pixel frame. The gray frame as it is where
        the shift is within the background frames', or where the backdrop's
        flicker under it (its steepest 2 % of gradients,
        :attr:`recon.jitter.ShiftModel.texture_dn_per_px`, times the shift) stays below the
        pixel noise (``sigma_fine``): there resampling would buy nothing for
        its cost (~1 ms a megapixel) and blur (the paper scene: 1.2 gray
        levels per px, shifts up to 1.3 px, noise 3.7 gray levels).
    shift_px : (2,) float64 array
        The frame's shift measured ``(du, dv)`` px (:func:`recon.jitter.frame_shift`).
    moved : bool
        Whether ``steady`` was moved back by it (else it is the frame, whose
        shift ``shift_px`` still is).
    """
    gray = _gray_frame(model, frame)
    if model.shift is None:
        return gray, np.zeros(2), False  # no texture: nothing to measure on, nothing that flickers
    d = frame_shift(model.shift, gray)
    within = model.background_jitter_px is not None and bool(np.all(np.abs(d) <= model.background_jitter_px))
    if within or float(np.hypot(d[0], d[1])) * model.shift.texture_dn_per_px < model.sigma_fine:
        return gray, d, False
    # The whole frame: the eigenbackground coefficients are fitted on samples all over it, and the background
    # frames' jitter gave the eigenbackgrounds shift-like modes; fitted on a frame moved back in part, they
    # took up the shift outside and put it back inside (a brick test frame moved back around the last
    # frame's robot: every joint across the shift foreground there).
    return shifted(gray, d), d, True


# ----------------------------------------------------------------------------- coarse stage
@dataclass(frozen=True, eq=False)
class CoarseResult:
    """Output of :func:`coarse_path`.

    Attributes
    ----------
    coefficients : (k+1,) float32
        ``[1, c_1..c_k]``: multiplies the rows of ``ViewModel.stack``.
    path_px : (n, 2) float
        Ordered path base -> tip in full-resolution pixel coordinates.
    bbox : (x0, y0, x1, y1)
        The robot region's bounding box (full-resolution pixels).
    n_pixels : int
        Coarse pixels of the robot region.
    coarse_bbox : (x0, y0, x1, y1)
        The same box in coarse pixels (the next frame's ROI).
    """

    coefficients: np.ndarray
    path_px: np.ndarray
    bbox: tuple
    n_pixels: int
    coarse_bbox: tuple


def frame_coefficients(model: ViewModel, frame: np.ndarray) -> np.ndarray:
    """Eigenbackground coefficients ``[1, c_1..c_k]`` of a frame, fitted on the fixed coarse samples.

    Least squares on M (~2000) coarse pixels, regularized by the
    eigenbackgrounds' own variances (a Gaussian prior ``c_j ~ N(0, lambda_j)``
    against the pixel noise, so that directions the background frames hardly
    vary along, e.g. noise picked up from few frames, are not blown up by
    fitting them on a subset), then once more without the pixels the first
    fit calls foreground (the robot must not pull the background).

    Parameters
    ----------
    model : ViewModel
        The view's constants (its ``sample_*`` fields).
    frame : (H, W) uint8 array
        The frame (gray levels).

    Returns
    -------
    (k+1,) float32 array
        ``[1, c_1..c_k]``: multiplies the rows of ``ViewModel.stack`` to
        rebuild the background (gray levels).

    Raises
    ------
    FrameError
        A frame with no picture (:func:`recon.background.no_picture`, on the
        sampled pixels: all black, or one flat level).
    """
    # The samples' range comes out of the same pass (gathering them in NumPy first cost ~40 us a view).
    c, lo, hi = frame_coefficients_nb(frame.reshape(-1), model.sample_index, model.sample_mean, model.sample_basis_t,
                                      model.sample_gram + np.diag(model.sample_prior), model.sample_threshold)
    why = no_picture(np.array([lo, hi]), model.peak, model.background_range)
    if why:
        raise FrameError(why, model.name)
    return np.concatenate([[1.0], c]).astype(np.float32)


def _coarse_foreground(model: ViewModel, frame: np.ndarray, coeff: np.ndarray, box: tuple) -> tuple:
    """The coarse foreground mask (uint8, 1 = foreground) of ``box`` = (x0, y0, x1, y1) coarse px, whether
    any pixel is foreground, and the largest excess over the threshold (gray levels).

    Foreground: the 2x2 average's difference from the background over the
    threshold (cheap: coarse arrays), or, within :data:`_ABS_REACH` coarse
    pixels of such a pixel, the 2x2 pixels' mean absolute difference (the
    background rebuilt at 4 pixels): across a tube a coarse pixel or two wide,
    its dark rims and a highlight brighter than the backdrop can cancel in the
    average over a few coarse pixels along it.
    """
    f = model.factor
    hc, wc = model.coarse_shape
    rx0, ry0, rx1, ry1 = box
    k = model.coarse_basis.shape[0]
    lo, hi = _central_offsets(f)
    mask, peak = coarse_foreground_nb(frame, f, lo, hi, rx0, ry0, rx1, ry1, model.coarse_mean.reshape(hc, wc),
                                      model.coarse_basis.reshape(k, hc, wc), model.coarse_stack, model.coarse_threshold,
                                      coeff.astype(np.float64), _ABS_REACH)
    return mask, peak > 0.0, peak


#: Coarse px a side of the tiles :func:`_coarse_foreground_tiles` computes (64 px at the factor 4; 16 to 64 cost
#: 0.75-0.93 ms a view on seed 1's frames, the whole image 1.6).
_TILE = 16


def _coarse_foreground_tiles(model: ViewModel, frame: np.ndarray, coeff: np.ndarray, seed_box: tuple) -> tuple:
    """:func:`_coarse_foreground` of the whole image, computed only where a region meeting ``seed_box`` can reach
    (:func:`recon._kernels.coarse_foreground_tiles_nb`): the same mask in every region that meets it, and 0 in
    the tiles no foreground led to. A robot crossing a fifth of a 5 MP frame costs a fifth of the pass."""
    f = model.factor
    hc, wc = model.coarse_shape
    k = model.coarse_basis.shape[0]
    lo, hi = _central_offsets(f)
    mask, peak, _ = coarse_foreground_tiles_nb(frame, f, lo, hi, model.coarse_mean.reshape(hc, wc),
                                               model.coarse_basis.reshape(k, hc, wc), model.coarse_stack,
                                               model.coarse_threshold, coeff.astype(np.float64), _ABS_REACH, _TILE,
                                               np.asarray(seed_box, np.int64))
    return mask, bool(mask.any()), peak


def _traced_path(mask: np.ndarray, rect: tuple, origin: tuple, coarse_shape: tuple, base: tuple,
                 ahead=None) -> tuple:
    """The robot's path through its flood-filled region (``mask == 2``; ``rect`` = (sx, sy, sw, sh) in the
    coarse image, ``mask`` offset by ``origin`` = (rx0, ry0)), from the pixel nearest ``base`` (coarse px).
    With ``ahead`` = (axis, margin): only the region's pixels less than ``margin`` (coarse px) behind the
    base along the image ``axis`` (unit) of the insertion axis are traced (the robot leaves its base forward:
    an outline of the actuation unit joined to the region must not lead the path away).

    Returns ``(path, g, region, x0p, y0p)``: (n, 2) (y, x) pixels of the grid pooled ``g`` x ``g``, start
    first; the region (coarse px) from ``(x0p, y0p)``.
    """
    # The path is traced on the region pooled 2x2 (4x fewer graph nodes; the fine stage re-centres), compiled:
    # the ~25 NumPy calls on a region of a few hundred coarse px cost ~55 us a view.
    (sx, sy, sw, sh), (rx0, ry0), (hc, wc) = rect, origin, coarse_shape
    (ax0, ax1), margin = ((0.0, 0.0), 0.0) if ahead is None else ahead
    return traced_path_nb(mask, int(sx), int(sy), int(sw), int(sh), int(rx0), int(ry0), int(hc), int(wc),
                          float(base[0]), float(base[1]), float(ax0), float(ax1), float(margin), ahead is not None)


def _border_seed(mask: np.ndarray, base_c, min_region: int) -> tuple | None:
    """The coarse pixel (x, y) on the image border, in a foreground region of at least ``min_region`` pixels,
    nearest to the base ``base_c`` (coarse px, outside the image); None when no such region crosses the border."""
    n_lab, lab, stats, _ = cv2.connectedComponentsWithStats((mask > 0).view(np.uint8), connectivity=8)
    edge = np.zeros(mask.shape, bool)
    edge[0, :] = edge[-1, :] = edge[:, 0] = edge[:, -1] = True
    ys, xs = np.nonzero(edge & (lab > 0))
    big = stats[lab[ys, xs], cv2.CC_STAT_AREA] >= min_region
    if not big.any():
        return None
    ys, xs = ys[big], xs[big]
    k = int(np.argmin((xs - base_c[0]) ** 2 + (ys - base_c[1]) ** 2))
    return int(xs[k]), int(ys[k])


def coarse_path(model: ViewModel, frame: np.ndarray, roi=None, border_margin_px: int = 1,
                base_search_px: float = 24.0, min_region: int = 8) -> CoarseResult:
    """Coarse stage: background coefficients, robot region at the base, ordered path.

    Parameters
    ----------
    model : ViewModel
        The view's constants.
    frame : (H, W) uint8 array
        The frame (gray levels).
    roi : (x0, y0, x1, y1) or None, optional
        Coarse pixels to search for the robot in (e.g. around the previous
        frame's); when nothing is found there, or the robot's region reaches
        the ROI's edge, the whole frame is searched instead.
    border_margin_px : int, optional
        The robot's visible end within this many coarse px of the image
        border is partly out of view.
    base_search_px : float, optional
        The robot's region must come within this distance (full-resolution
        px) of the projected base, or of where the insertion axis enters the
        image (:attr:`ViewModel.start_px`).
    min_region : int, optional
        Smallest robot region (coarse px).

    Returns
    -------
    CoarseResult
        Coefficients, and the path in full-resolution pixel coordinates
        (image frame, px).

    Raises
    ------
    FrameError
        All-black frame, no foreground, nothing at the base, or the far end
        of the robot's path at the image border (partly out of view).
    """
    f = model.factor
    hc, wc = model.coarse_shape
    coeff = frame_coefficients(model, frame)
    (bx, by), bwin, box = _search_boxes(model, roi, base_search_px)
    rx0, ry0, rx1, ry1 = box
    mask = None
    if roi is None:
        # The robot's region at its base, in the tiles it crosses only; the whole image where nothing of the
        # robot's size lies at the base (a robot entering elsewhere, pieces to join, the error's figures).
        tiled, found, _ = _coarse_foreground_tiles(model, frame, coeff, bwin)
        if found:
            area, rect, (bx, by) = _robot_region(model, tiled, (bx, by), bwin, box, min_region, False)
            mask = tiled if area >= min_region else None
    if mask is None:
        mask, found, peak = _coarse_foreground(model, frame, coeff, box)
        if not found:
            if roi is not None:
                return coarse_path(model, frame, None, border_margin_px, base_search_px, min_region)
            raise FrameError(f"no silhouette (no coarse pixel above its threshold, closest by {-peak:.1f} gray levels)", model.name)
        area, rect, (bx, by) = _robot_region(model, mask, (bx - rx0, by - ry0), bwin, box, min_region, roi is None)
    if area < min_region:
        if roi is not None:
            return coarse_path(model, frame, None, border_margin_px, base_search_px, min_region)
        if model.starts_at_base:
            if _join_along_axis(model, mask, (bx, by)):
                area, rect, (bx, by) = _robot_region(model, mask, (bx, by), bwin, box, min_region, True)
    if area < min_region:
        n_lab, _, stats, _ = cv2.connectedComponentsWithStats((mask > 0).view(np.uint8), connectivity=8)
        biggest = int(stats[1:, cv2.CC_STAT_AREA].max()) if n_lab > 1 else 0
        raise FrameError(f"no robot at its base (largest foreground region, {biggest * f * f} px, is elsewhere)", model.name)
    sx, sy, sw, sh = (int(v) for v in rect)
    hr, wr = ry1 - ry0, rx1 - rx0
    if roi is not None and (sx == 0 and rx0 > 0 or sy == 0 and ry0 > 0 or sx + sw == wr and rx1 < wc or sy + sh == hr and ry1 < hc):
        return coarse_path(model, frame, None, border_margin_px, base_search_px, min_region)  # outgrew the ROI
    sx, sy = sx + rx0, sy + ry0
    ahead = None
    if model.starts_at_base:
        # The base in view: the path runs forward from it. Behind it by more than a tube diameter and 2 coarse
        # px lies only what joined the region there (the actuation unit's outline flickering with jitter:
        # wide-2-16 frame 1 followed it 300 px away from the tube).
        ahead = (model.axis_px, max(3.0, 2.0 * model.outer_radius_px / f + 2.0))
    path, g, region, x0p, y0p = _traced_path(mask, (sx, sy, sw, sh), (rx0, ry0), (hc, wc), (bx + rx0, by + ry0), ahead)
    path_c = _path_coarse_xy(path, g, x0p, y0p)
    if ahead is not None and float(np.max((path_c - [bx + rx0, by + ry0]) @ model.axis_px)) < _MIN_REACH_AHEAD:
        # A path that stays at the base followed what lies there (the tube's stub behind the base, a clamp),
        # not the robot, whose outer tube showed ahead only in pieces under the coarse threshold (wide-4-43
        # frame 1: a 3 px tube on a photo of coins; the path ran 19 px backwards and the frame was refused).
        if roi is not None:
            return coarse_path(model, frame, None, border_margin_px, base_search_px, min_region)
        joined = _joined_ahead(model, frame, coeff, (bx, by), bwin, min_region)
        if joined is not None:
            mask, area, (sx, sy, sw, sh) = joined
            path, g, region, x0p, y0p = _traced_path(mask, (sx, sy, sw, sh), (0, 0), (hc, wc), (bx, by), ahead)
            path_c = _path_coarse_xy(path, g, x0p, y0p)
    _check_end_in_view(model, path, g, region, (x0p, y0p), border_margin_px)
    path_px = (path_c + 0.5) * f - 0.5
    bbox = (sx * f, sy * f, (sx + sw) * f, (sy + sh) * f)
    return CoarseResult(coeff, path_px, bbox, area, (sx, sy, sx + sw, sy + sh))


def _path_coarse_xy(path: np.ndarray, g: int, x0p: int, y0p: int) -> np.ndarray:
    """A traced path's (y, x) cells of the grid pooled ``g`` x ``g`` from ``(x0p, y0p)`` (:func:`_traced_path`) as
    (n, 2) (x, y) coarse px, each cell's centre."""
    return (path[:, ::-1].astype(np.float64) + 0.5) * g + [x0p, y0p] - 0.5


#: How far (coarse px) ahead of the base along the insertion axis the traced path must reach for
#: :func:`coarse_path` to take it as it is (else it joins the pieces ahead, :func:`_joined_ahead`).
_MIN_REACH_AHEAD = 6.0
#: The most coarse pixels a joined region may cover per coarse px of its bounding box's diagonal, in outer tube
#: widths plus a coarse px: the joined tubes of wide-4-43 and wide-4-36 frame 1 cover 0.66 and 0.64, the sheet
#: of fabric texture of wide-2-22 frame 2 1.85 (a tube 1.5 times as long as its box's diagonal, about 1).
_MAX_FILL = 1.25


def _joined_ahead(model: ViewModel, frame: np.ndarray, coeff: np.ndarray, base: tuple, bwin: tuple, min_region: int):
    """The robot's region with the pieces ahead of the base joined to it (:func:`_join_along_axis`), over the
    whole image: ``(mask, area, rect)`` (coarse px, ``rect`` = (x, y, w, h)), or None where nothing was joined
    or the joined region is not as thin as a tube (``_MAX_FILL``).

    The whole image: the pieces ahead may lie in tiles the region at the base did not lead to. Pieces of a
    backdrop whose texture crosses the coarse threshold everywhere join a sheet of it (wide-2-22 frame 2,
    fabric: a path across the whole side view, 260 footprints off, where the frame had been refused).
    """
    f = model.factor
    hc, wc = model.coarse_shape
    mask = _coarse_foreground(model, frame, coeff, (0, 0, wc, hc))[0]
    if not _join_along_axis(model, mask, base):
        return None
    area, rect, _ = _robot_region(model, mask, base, bwin, (0, 0, wc, hc), min_region, True)
    width = max(1.5, 2.0 * model.outer_radius_px / f + 1.0)
    if rect is None or area < min_region or area > _MAX_FILL * np.hypot(rect[2], rect[3]) * width:
        return None
    return mask, area, tuple(int(v) for v in rect)


def _join_along_axis(model: ViewModel, mask: np.ndarray, base: tuple, gap_px: float = 48.0) -> bool:
    """Join the foreground pieces in a corridor ahead of the base along the insertion axis to the base (in place:
    a line of 1s from the base to the last piece reached in steps of at most ``gap_px`` along the axis;
    ``mask`` and ``base`` in coarse px of the whole image).

    The robot leaves its actuation unit along the insertion axis, and the outer tube is straight there; where
    its first stretch stands a few gray levels off the backdrop, only pieces of it pass the coarse threshold
    (wide-21-3 and wide-1-69: tubes of 3-5 px on mottled backdrops, every frame refused). The corridor is
    the outer tube's width and a coarse pixel either side. Returns whether a line was drawn.
    """
    f = model.factor
    ys, xs = np.nonzero(mask)
    d = np.column_stack([xs - base[0], ys - base[1]]).astype(np.float64)
    along = d @ model.axis_px
    across = np.abs(d @ np.array([-model.axis_px[1], model.axis_px[0]]))
    ahead = np.sort(along[(along > 0) & (across <= max(1.5, model.outer_radius_px / f + 1.0))])
    steps = np.diff(np.concatenate([[0.0], ahead]))
    n = int(np.argmax(steps > gap_px / f)) if np.any(steps > gap_px / f) else len(ahead)
    if n < 3:
        return False
    mask[mask > 1] = 1  # undo the fills of the pieces tried before
    end = np.asarray(base, np.float64) + ahead[n - 1] * model.axis_px
    cv2.line(mask, tuple(int(round(v)) for v in base), tuple(int(round(v)) for v in end), 1, 1)
    return True


def _search_boxes(model: ViewModel, roi, base_search_px: float) -> tuple:
    """Where :func:`coarse_path` looks (coarse px): ``((bx, by), bwin, box)``, the start (the projected base, or
    where the insertion axis enters the image), the window around it the robot's region must reach, and the
    box searched for foreground (``roi`` grown to hold that window; the whole image without one).

    Raises :class:`~recon.errors.FrameError` when the window lies outside the image.
    """
    f = model.factor
    hc, wc = model.coarse_shape
    start = model.base_px if model.start_px is None else model.start_px
    bx, by = (start + 0.5) / f - 0.5
    rad = max(2, int(np.ceil((base_search_px + min(model.start_search_px, 8.0 * base_search_px)) / f)))
    ix, iy = int(np.floor(bx)), int(np.floor(by))
    bwin = (max(0, ix - rad), max(0, iy - rad), min(wc, ix + rad + 2), min(hc, iy + rad + 2))
    if bwin[0] >= bwin[2] or bwin[1] >= bwin[3]:
        raise FrameError("neither the robot's base nor its insertion axis projects into the image (check the calibration)", model.name)
    if roi is None:
        return (bx, by), bwin, (0, 0, wc, hc)
    rx0, ry0 = max(0, min(int(roi[0]), bwin[0])), max(0, min(int(roi[1]), bwin[1]))
    rx1, ry1 = min(wc, max(int(roi[2]), bwin[2])), min(hc, max(int(roi[3]), bwin[3]))
    return (bx, by), bwin, (rx0, ry0, rx1, ry1)


def _robot_region(model: ViewModel, mask: np.ndarray, start: tuple, bwin: tuple, box: tuple, min_region: int,
                  whole_frame: bool) -> tuple:
    """Flood-fill (value 2, in place) the robot's region in the foreground ``mask`` of ``box``: the region of
    one of the 8 foreground pixels of ``bwin`` nearest to ``start`` (coarse px, relative to ``box``) that
    reaches ``min_region`` pixels, else the largest of them.

    With the base out of view and nothing of ``min_region`` pixels where its straight insertion axis enters
    (``whole_frame`` searches only), a robot bent before the border enters elsewhere: the region crossing the
    border nearest to the base is taken, and its border pixel becomes the start.

    Returns ``(area, rect, start)``: coarse pixels, ``(x, y, w, h)`` relative to ``box`` (None: nothing
    filled), and the start.
    """
    rx0, ry0 = box[0], box[1]
    bx, by = start
    x0, y0, x1, y1 = bwin[0] - rx0, bwin[1] - ry0, bwin[2] - rx0, bwin[3] - ry0
    wy, wx = np.nonzero(mask[y0:y1, x0:x1])
    area, rect = 0, None
    for k in np.argsort((wx + x0 - bx) ** 2 + (wy + y0 - by) ** 2)[:8]:
        px, py = int(wx[k] + x0), int(wy[k] + y0)
        if mask[py, px] != 1:
            continue  # already part of a filled (too small) region
        a, _, _, rc = cv2.floodFill(mask, None, (px, py), 2, 0, 0, 8)
        if a > area:
            area, rect = a, rc
        if a >= min_region:
            break
    if area < min_region and whole_frame and model.start_px is not None:
        seed = _border_seed(mask, (model.base_px + 0.5) / model.factor - 0.5, min_region)
        if seed is not None:
            area, _, _, rect = cv2.floodFill(mask, None, seed, 2, 0, 0, 8)
            bx, by = float(seed[0]), float(seed[1])
    return area, rect, (bx, by)


def _check_end_in_view(model: ViewModel, path: np.ndarray, g: int, region: np.ndarray, origin: tuple,
                       border_margin_px: int) -> None:
    """Raise :class:`~recon.errors.FrameError` when the far end of the traced ``path`` (pooled ``g`` x ``g``,
    :func:`_traced_path`; ``region`` from ``origin`` = (x0p, y0p) coarse px) is within ``border_margin_px``
    coarse px of the image border.

    Only the end counts: static edges flickering with camera jitter can join the region near the base and
    run to the border (the actuation unit's outline, when few background frames teach the threshold), which
    says nothing about the robot. (The fine stage checks again where it follows the tube past the path.)
    """
    hc, wc = model.coarse_shape
    x0p, y0p = origin
    ey, ex = int(path[-1, 0]) * g, int(path[-1, 1]) * g
    cy, cx = np.nonzero(region[ey: ey + g, ex: ex + g])
    cy, cx = cy + ey + y0p, cx + ex + x0p
    touched = [nm for nm, hit in zip(_BORDER_NAMES, (cx.min() < border_margin_px, cy.min() < border_margin_px,
                                                      cx.max() >= wc - border_margin_px, cy.max() >= hc - border_margin_px)) if hit]
    if touched:
        raise FrameError(f"robot partly out of view (its silhouette reaches the {' and '.join(touched)} image border)", model.name)


# ----------------------------------------------------------------------------- fine stage
def _smooth_path(path: np.ndarray, window: int) -> np.ndarray:
    if len(path) < 3 or window < 2:
        return path
    k = np.ones(window) / window
    pad = window // 2
    out = np.empty_like(path)
    for j in range(2):
        c = path[:, j]
        p = np.concatenate([np.full(pad, c[0]), c, np.full(pad, c[-1])])  # np.pad's "edge", at a tenth of its cost
        out[:, j] = np.convolve(p, k, mode="same")[pad: pad + len(path)]
    return out


@dataclass(eq=False)
class Profiles:
    """Profiles across the tube: centres, chords and geometry (full-resolution px)."""

    centers: np.ndarray  # (n, 2) sub-pixel centres
    chord: np.ndarray  # (n,) edge distance along the profile axis (px)
    axis: np.ndarray  # (n,) 0: profile along v (column), 1: along u (row)
    s: np.ndarray  # (n,) arc length of the seed along the coarse path (px)
    ok: np.ndarray  # (n,) bool


def edges_from_profiles(model: ViewModel, frame, coeff, seeds, tangents, s, half, threshold, nav: int = 0,
                        threshold1: float | None = None, strong: float = np.inf) -> Profiles:
    """Cut profiles at ``seeds`` across ``tangents`` and locate the edges on them.

    A profile runs along the pixel row (a tube running more vertically than
    horizontally) or column through the rounded seed, ``half`` px each way;
    each edge is the boundary between the pixels outside and those fully
    inside minus the summed coverage of the partial pixels (a pixel's
    difference over the rim contrast, the largest same-signed difference
    among the first three pixels inside). With ``nav`` > 0 each profile
    averages ``2 nav + 1`` parallel lines along the tube (noise down by their
    square root; the edges of a slanted tube are blurred symmetrically, so the
    summed coverage, hence the edge, is that of the middle line); ``nav`` is
    lowered where the tube runs slanted to the lines (their edges spread by at
    most ~2 px). The middle line is tried alone first: where both its rims
    exceed ``strong`` its edges are taken as they are and the other lines are
    not cut (most of a tube well off its backdrop; the averaging costs ~5x the
    background model's work per profile), nor where none of its samples
    exceeds ``threshold`` (no tube there: past the tip, while bridging a gap).
    Compiled: :func:`recon._kernels.profiles_at_seeds_nb`.

    Parameters
    ----------
    model : ViewModel
        The view's constants.
    frame : (H, W) uint8 array
        The frame (gray levels).
    coeff : (k+1,) float32 array
        The frame's background coefficients (:func:`frame_coefficients`).
    seeds : (n, 2) array
        Profile centres (image frame, px).
    tangents : (n, 2) array
        Unit image direction of the tube at each seed.
    s : (n,) array
        Curve parameter of each seed (px), passed through to the result.
    half : int
        Half-length of the profiles (px).
    threshold : float
        Edge threshold of an averaged profile (gray levels).
    nav : int, optional
        Parallel lines averaged on each side of the middle one.
    threshold1 : float or None, optional
        Edge threshold of the middle line alone (gray levels); None: ``threshold``.
    strong : float, optional
        Rim contrast (gray levels) above which the middle line's edges are
        taken as they are; inf: always average.

    Returns
    -------
    Profiles
        Centres (image frame, px), chords (px along the profile), profile
        axes, ``s``, and validity (edges found, window not moved to stay inside
        the image).
    """
    centers, chord, axis, ok = profiles_at_seeds_nb(
        frame, model.stack, coeff, np.ascontiguousarray(seeds, np.float64), np.ascontiguousarray(tangents, np.float64),
        int(half), float(threshold), int(nav), float(threshold if threshold1 is None else threshold1), float(strong))
    return Profiles(centers=centers, chord=chord, axis=axis, s=s, ok=ok)


# ----------------------------------------------------------------------------- curve fit
class UniformSpline:
    """Cubic B-spline with uniform knots: ``y(s) = sum_j coef[j] B((s - s0) / h - j + 3)``.

    Fitted by :func:`fit_curve` (penalized least squares, P-spline). Outside
    ``[s0, s1]`` the end polynomials are extrapolated.

    Parameters
    ----------
    s0 : float
        First knot, in the units of the curve parameter (px along a view's
        coarse path, or the summed parameters of a matched pair).
    h : float
        Knot spacing (same units).
    n_int : int
        Knot intervals; there are ``n_int + 3`` coefficients.
    coef : (n_int + 3, d) array
        Coefficients, in the units and frame of the values (image px, world mm).
    deriv : int, optional
        0: the curve; 1: its first derivative (values per unit of ``s``).
    """

    def __init__(self, s0: float, h: float, n_int: int, coef: np.ndarray, deriv: int = 0):
        self.s0, self.h, self.n_int, self.coef, self.deriv = float(s0), float(h), int(n_int), coef, deriv

    @staticmethod
    def basis(s: np.ndarray, s0: float, h: float, n_int: int, deriv: int = 0):
        """The four non-zero basis functions (or their derivatives) at each ``s``.

        Parameters
        ----------
        s : array
            Curve parameters (units of ``s0``).
        s0, h, n_int : float, float, int
            The knots, as for :class:`UniformSpline`.
        deriv : int, optional
            0: the basis functions; 1: their first derivatives (per unit of ``s``).

        Returns
        -------
        i : int64 array, shape of ``s``
            Index of the first of the four coefficients each ``s`` uses.
        b : float64 array, shape of ``s`` + (4,)
            Their weights.
        """
        s = np.asarray(s, np.float64)
        i, b = spline_basis_nb(np.ascontiguousarray(s.reshape(-1)), float(s0), float(h), int(n_int), int(deriv))
        return i.reshape(s.shape), b.reshape(s.shape + (4,))

    def __call__(self, s):
        """The curve (or its derivative) at ``s``.

        Parameters
        ----------
        s : float or (n,) array
            Curve parameters (units of ``s0``).

        Returns
        -------
        (d,) or (n, d) array
            Values, in the units and frame of ``coef``.
        """
        scalar = np.ndim(s) == 0
        i, b = spline_basis_nb(np.atleast_1d(np.asarray(s, np.float64)), self.s0, self.h, self.n_int, self.deriv)
        c = self.coef
        out = spline_eval_nb(i, b, c if c.ndim == 2 else c[:, None])
        out = out if c.ndim == 2 else out[:, 0]
        return out[0] if scalar else out

    def derivative(self) -> "UniformSpline":
        """The first derivative, ``dy/ds`` (units of ``coef`` per unit of ``s``).

        Returns
        -------
        UniformSpline

        Raises
        ------
        NotImplementedError
            For the derivative of a derivative.
        """
        if self.deriv:
            raise NotImplementedError("only the first derivative is implemented")
        return UniformSpline(self.s0, self.h, self.n_int, self.coef, deriv=1)


def fit_curve(s: np.ndarray, y: np.ndarray, spacing: float, w=None, smoothing: float = 1e-4) -> UniformSpline:
    """Penalized least-squares cubic spline of ``y`` over ``s`` with knots about ``spacing`` apart.

    A small second-difference penalty on the coefficients (relative weight
    ``smoothing``) keeps the fit well posed across gaps in the data. The
    normal equations are built from the banded design, compiled
    (:func:`recon._kernels.spline_fit_nb`).

    Parameters
    ----------
    s : (n,) array
        Curve parameters (any unit; the knots span ``[min s, max s]``).
    y : (n, d) array
        Values (their frame and units, e.g. world mm).
    spacing : float
        Largest knot spacing, in the units of ``s``.
    w : (n,) array or None, optional
        Row weights; None: all 1.
    smoothing : float, optional
        Weight of the penalty relative to the mean diagonal of the normal matrix.

    Returns
    -------
    UniformSpline
        ``y(s)``, in the frame and units of ``y``.
    """
    s = np.asarray(s, float)
    y = np.asarray(y, float)
    w = np.ones(s.size) if w is None else np.asarray(w, float)
    s0, s1 = float(s.min()), float(s.max())
    n_int = max(1, int(np.ceil((s1 - s0) / spacing - 1e-9)))
    h = max((s1 - s0) / n_int, 1e-9)
    idx, b = UniformSpline.basis(s, s0, h, n_int)
    coef = spline_fit_nb(idx, b, y, np.ones(s.size, np.bool_), w, _penalty(n_int + 3), smoothing)
    return UniformSpline(s0, h, n_int, coef)


def off_curve(s: np.ndarray, y: np.ndarray, spacing: float, min_off: float, n_sigma: float) -> np.ndarray:
    """Which points lie off the penalized spline through the others.

    The spline is fitted, points farther from it than ``max(n_sigma * MAD,
    min_off)`` (MAD: the median absolute deviation of the distances) are
    rejected and it is refitted (:meth:`_Fitter.robust`).

    Parameters
    ----------
    s : (n,) array
        Increasing curve parameters (e.g. px along a view's centerline).
    y : (n, d) array
        The points (e.g. image px).
    spacing : float
        Largest knot spacing, in the units of ``s``.
    min_off : float
        Distance from the fit (units of ``y``) below which no point is rejected.
    n_sigma : float
        Rejection threshold in MADs of the distances.

    Returns
    -------
    (n,) bool array
        True for the rejected points.
    """
    fitter = _Fitter(np.asarray(s, float), spacing)
    _, ok = fitter.robust(np.asarray(y, float), np.ones(len(s), np.bool_), min_off, n_sigma)
    return ~ok


_PENALTIES: dict = {}


def _penalty(m: int) -> np.ndarray:
    """(m, m) second-difference penalty ``D^T D`` of ``m`` spline coefficients (cached: one per knot count)."""
    P = _PENALTIES.get(m)
    if P is None:
        D = np.diff(np.eye(m), 2, axis=0)
        P = _PENALTIES[m] = D.T @ D
    return P


# ----------------------------------------------------------------------------- view result
@dataclass(frozen=True, eq=False)
class ViewCenterline:
    """Sub-pixel centerline of one view.

    Attributes
    ----------
    name : str
    curve : UniformSpline
        Centre (u, v) px as a function of the coarse-path arc length ``s`` (px).
    s_range : (s0, s1)
        Where the curve is supported by profiles.
    points_px : (n, 2)
        Accepted profile centres, base to tip (px).
    s : (n,)
        Their curve parameter.
    width_px : (n,)
        Tube width at each centre (px).
    end_px : (2,)
        Sub-pixel end of the silhouette along the tube's axis (px).
    end_s : float
        Curve parameter of the last accepted centre (``end_px`` lies
        beyond it along the tangent).
    tangent_end : (2,)
        Unit image tangent at the end.
    n_profiles, n_rejected : int
    coarse : CoarseResult
    shift_px : (2,) array
        The frame's image shift against the background (camera jitter,
        :func:`recon.jitter.frame_shift`; zeros when not measured). Positions above are as
        measured; subtract it for the calibrated (unjittered) camera.
    """

    name: str
    curve: UniformSpline
    s_range: tuple
    points_px: np.ndarray
    s: np.ndarray
    width_px: np.ndarray
    end_px: np.ndarray
    end_s: float
    tangent_end: np.ndarray
    n_profiles: int
    n_rejected: int
    coarse: CoarseResult
    shift_px: np.ndarray = None


def _tip_along_axis(model, frame, coeff, p_end, t_end, radius_px, threshold, back_px=8.0, ahead_px=20.0, step=0.5):
    """Silhouette end along the axis beyond ``p_end`` (px), from lines parallel to the axis.

    On each line the tube's difference is roughly constant (a cylinder's
    shading varies across it, not along it), so the end is located with the
    same coverage rule as the side edges, against that line's own interior
    contrast. The result is the median over the lines (NaN if none works;
    :func:`recon._kernels.tip_along_axis_nb`).
    """
    return float(tip_along_axis_nb(frame, model.stack, coeff, np.asarray(p_end, float), np.asarray(t_end, float),
                                   float(radius_px), float(threshold), float(back_px), float(ahead_px), float(step)))


class _Lap:
    """Accumulates wall time (ms) per stage into a dict (or does nothing)."""

    def __init__(self, timings):
        self.timings = timings
        self.t = time.perf_counter()

    def __call__(self, stage):
        if self.timings is not None:
            now = time.perf_counter()
            self.timings[stage] = self.timings.get(stage, 0.0) + 1e3 * (now - self.t)
            self.t = now


def _unit(v: np.ndarray) -> np.ndarray:
    return v / max(float(np.hypot(v[0], v[1])), 1e-12)


def _filled(shape, value) -> np.ndarray:
    """A new float64 array of ``shape`` with ``value`` broadcast into it: what the kernels take, ~4x cheaper for the
    follower's few seeds than ``np.ascontiguousarray(np.broadcast_to(value, shape), np.float64)``."""
    out = np.empty(shape)
    out[...] = value
    return out


def _unit_rows(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.hypot(v[:, 0], v[:, 1]), 1e-12)[:, None]


def _tangents(p: np.ndarray) -> np.ndarray:
    """Unit tangents (n, 2) of the points ``p`` (n, 2, px): :func:`numpy.gradient` along the rows (unit spacing,
    first-order ends), in three slices at a third of its cost (the same values; it raises below two points)."""
    if len(p) < 2:
        return _unit_rows(np.gradient(p, axis=0))
    g = np.empty(p.shape)
    g[1:-1] = (p[2:] - p[:-2]) / 2.0
    g[0] = p[1] - p[0]
    g[-1] = p[-1] - p[-2]
    return _unit_rows(g)


def _reparameterize(prof, seeds, tang):
    """Curve parameter of each centre: its seed's plus the centre's offset along the path, sorted.

    (A profile's centre can lie a few px along the tube from its seed, e.g. at 45 degrees.)
    """
    s = prof.s + np.einsum("ij,ij->i", prof.centers - seeds, tang)
    o = np.argsort(s, kind="stable")
    prof.chord, prof.axis = prof.chord[o], prof.axis[o]
    return s[o], prof.centers[o], prof.ok[o]


class _Fitter:
    """Penalized cubic spline fits of several data sets over the same increasing abscissae ``s``.

    One knot layout over all of them: the banded design (basis weights and
    their derivatives at ``s``) is built once, and every fit is a small solve.
    """

    def __init__(self, s: np.ndarray, spacing: float, smoothing: float = 1e-4):
        s0, s1 = float(s[0]), float(s[-1])
        self.n_int = max(1, int(np.ceil((s1 - s0) / spacing - 1e-9)))
        self.s0, self.h = s0, max((s1 - s0) / self.n_int, 1e-9)
        self.P = _penalty(self.n_int + 3)
        self.smoothing = smoothing
        self.idx, self.b = UniformSpline.basis(s, self.s0, self.h, self.n_int)
        _, self.db = UniformSpline.basis(s, self.s0, self.h, self.n_int, 1)

    def robust(self, y, ok, min_px, n_sigma):
        """Fit, reject points off the fit by more than max(n_sigma MAD, min_px), refit: ``(coef, new ok)``."""
        return spline_robust_nb(self.idx, self.b, y, ok, self.P, self.smoothing, float(min_px), float(n_sigma))

    def values(self, coef) -> np.ndarray:
        """The fit at every ``s``."""
        return spline_eval_nb(self.idx, self.b, coef)

    def value_at(self, coef, j: int) -> np.ndarray:
        """The fit at ``s[j]`` alone."""
        return spline_eval_nb(self.idx[j:j + 1], self.b[j:j + 1], coef)[0]

    def derivative_at(self, coef, j: int) -> np.ndarray:
        """The fit's derivative at ``s[j]`` alone."""
        return spline_eval_nb(self.idx[j:j + 1], self.db[j:j + 1], coef)[0]

    def derivatives(self, coef) -> np.ndarray:
        """The fit's derivative at every ``s``."""
        return spline_eval_nb(self.idx, self.db, coef)

    def spline(self, coef) -> UniformSpline:
        """The fit as a :class:`UniformSpline`."""
        return UniformSpline(self.s0, self.h, self.n_int, coef)


def _fit_centres(s, c, ok, prof, params, wmin, wmax):
    """Robust spline through the centres ``c`` (n, 2) over ``s``, and the tube width at each (px).

    Returns ``(fitter, coef, ok, unit_tangents, width)``; ``ok`` loses the
    outliers and the centres whose width is outside ``(wmin, wmax)``.
    """
    # One knot layout over all profiles: the design matrices are built once and every fit is a small solve.
    fitter = _Fitter(s, params.spline_knot_px)
    coef, ok = fitter.robust(c, ok, 4.0 * params.outlier_min_px, params.outlier_sigma)
    # Width across the tube: the chord times the slant of the profile to the tube.
    d = _unit_rows(fitter.derivatives(coef))
    width = prof.chord * np.where(prof.axis == 1, np.abs(d[:, 1]), np.abs(d[:, 0]))
    ok = ok & (width > wmin) & (width < wmax)
    # A profile cut through the end cap at a slant, or reaching clutter beside the tube, reads wider than the
    # tube around it, and its centre is off the axis: measured against the running median of the widths
    # (9 profiles, ~18 px: a step from the outer to the inner tube is kept).
    g = np.flatnonzero(ok)
    if g.size >= 9:
        ok[g[width[g] > 1.3 * running_rank_nb(width[g], 9, 4)]] = False
    return fitter, coef, ok, d, width


def _median_of_few(values) -> float:
    """The median of a few numbers, as :func:`numpy.median` gives it: sorted in Python, ~30x cheaper than
    ``np.median`` for the handful of widths the follower asks for in every batch."""
    v = sorted(float(x) for x in values)
    m = len(v) // 2
    return v[m] if len(v) % 2 else (v[m - 1] + v[m]) / 2.0


def _end_of(fitter, coef, s, good, d, width):
    """Curve parameter, position, unit tangent and half-width (px) of the tube at the last accepted centre."""
    j = int(good[-1])
    return (float(s[j]), fitter.value_at(coef, j), d[j], 0.5 * _median_of_few(width[good[-min(6, good.size):]]))


def _near(points_px, visited_px, radius_px: float) -> np.ndarray:
    """(n,) bool: which of ``points_px`` (n, 2) lie within ``radius_px`` of one of ``visited_px`` (m, 2)."""
    if len(visited_px) == 0 or len(points_px) == 0:
        return np.zeros(len(points_px), bool)
    return near_any_nb(np.ascontiguousarray(points_px, np.float64), np.ascontiguousarray(visited_px, np.float64), float(radius_px))


def _energy_hits(model, frame, coeff, seeds, t, half, nav, threshold, width_px, max_off):
    """Tube centres on profiles without an edge pair, from where their absolute difference is largest.

    A shiny tube in front of backdrop as bright as its rims, or changing
    polarity along the way, keeps a core that differs from the background
    although no pair of edges stands out. Across each profile (``seeds``,
    across the axis ``t``), the mean absolute difference over a window of the
    tube's width ``width_px`` is taken at every offset within ``max_off`` (px,
    per seed) of the seed; a profile finds the tube where that mean exceeds
    half the edge ``threshold`` (gray levels) and twice the profile's
    median: a ridge, where the residual of a textured backdrop is broad. The
    centre is the window's centroid of the absolute difference
    (:func:`recon._kernels.ridge_hits_nb`).

    Returns ``(found, centres)``: (n,) bool and (n, 2) px.
    """
    tangents = _filled((len(seeds), 2), t)
    d = np.abs(profile_values_nb(frame, model.stack, coeff, np.ascontiguousarray(seeds, np.float64), tangents, int(half), int(nav)))
    n, L = d.shape
    # np.clip(np.rint(w), 2, L - 2) on a Python float (the bounds are whole: clipping first rounds the same),
    # at a tenth of its cost.
    w = int(round(min(max(float(width_px), 2.0), L - 2.0)))
    centres = np.rint(seeds).astype(np.float64)
    axis = 1 if abs(t[0]) >= abs(t[1]) else 0  # profiles run along a pixel axis (see edges_from_profiles)
    found, off = ridge_hits_nb(np.ascontiguousarray(d, np.float64), w, _filled(n, max_off),
                               float(half), float(threshold))
    centres[:, axis] += off
    return found, centres


def _add_ridge_hits(model, frame, coeff, seeds, t, half, nav, threshold, wref, max_off, last_hit, seen, pr, width, hit):
    """Turn the misses among ``hit`` into hits where :func:`_energy_hits` finds the tube's core (in place).

    Only ahead of ``last_hit`` along ``t``, and never back onto the ``seen``
    centres (past the tip the ridge of the tube's own end can turn the
    prediction round); such a hit gets the width ``wref`` found so far.
    """
    miss = np.flatnonzero(~hit)
    e_hit, e_c = _energy_hits(model, frame, coeff, seeds[miss], t, half, nav, threshold, wref, max_off[miss])
    e_hit &= ((e_c - last_hit) @ t > 0.0) & ~_near(e_c, seen, max(4.0, wref))
    miss, e_c = miss[e_hit], e_c[e_hit]
    pr.centers[miss], width[miss], hit[miss] = e_c, wref, True
    pr.chord[miss] = wref / max(abs(t[0]), abs(t[1]))


@dataclass(eq=False)
class _Track:
    """What :func:`_follow_tube` knows so far: the centres found, those beyond a gap still to confirm, the misses."""

    recent: list  # the last <= 6 centres found ((2,) px each), for the predicted axis
    last_hit: np.ndarray  # (2,) last centre found (px)
    max_misses: int  # a run of this many misses ends the tube
    confirm: int  # hits beyond a gap that confirm it
    widths: list = field(default_factory=list)  # widths found (px)
    found: list = field(default_factory=list)  # (center, chord, axis, s, width)
    pending: list = field(default_factory=list)  # hits after a gap, not yet confirmed
    misses: int = 0

    @property
    def bridging(self) -> bool:
        """Across a gap (two misses or more), or confirming what lies beyond one."""
        return self.misses >= 2 or bool(self.pending)

    @property
    def on_tube(self) -> bool:
        """Fewer than two misses since the last hit, or confirming what lies beyond a gap."""
        return self.misses < 2 or bool(self.pending)

    def wref(self) -> float:
        """The width (px) found over the last centres."""
        return _median_of_few(self.widths[-6:])

    def take(self, item) -> bool:
        """Count a hit ``(center, chord, axis, s, width)``; True when it confirms the tube beyond a gap."""
        confirmed = False
        if self.bridging:
            self.pending.append(item)
            if len(self.pending) >= self.confirm:
                self.found.extend(self.pending)
                self.pending = []
                self.misses = 0
                confirmed = True
        else:
            self.found.append(item)
            self.misses = 0
        if not self.pending:
            self.widths.append(item[4])
            self.last_hit = item[0].copy()
            # A list: an array concatenated on every hit cost ~3 us a hit, ~50 hits a pair.
            self.recent.append(item[0])
            del self.recent[:-6]
        return confirmed

    def miss(self) -> bool:
        """Count a miss (unconfirmed hits beyond a gap become misses too); True when the run of misses ends the tube."""
        if self.pending:
            self.misses += len(self.pending)
            self.pending = []
        self.misses += 1
        return self.misses >= self.max_misses


def _principal_axis(points: np.ndarray) -> np.ndarray:
    """Unit direction of largest spread of a few image points (n, 2): the 2x2 scatter's leading eigenvector, in
    closed form (what the SVD of the centred points gives, at a tenth of its cost; sign arbitrary)."""
    x = points - points.mean(axis=0)
    a, b, c = float(x[:, 0] @ x[:, 0]), float(x[:, 0] @ x[:, 1]), float(x[:, 1] @ x[:, 1])
    theta = 0.5 * math.atan2(2.0 * b, a - c)
    return np.array([math.cos(theta), math.sin(theta)])


def _border_error(model: ViewModel, seed: np.ndarray, half: int) -> FrameError:
    """The error for a tube followed to within ``half`` px of the image border at ``seed`` (px).

    The message names both causes: on textured backdrops the follower also runs on along a backdrop line to
    the border while the robot is well inside (wide-2-49 frame 1, side: bricks' mortar, the tip 554 px from
    that border)."""
    H, W = model.shape
    u, v = seed
    out = [b for b, o in zip(_BORDER_NAMES, (u < half, v < half, u > W - 1 - half, v > H - 1 - half)) if o]
    return FrameError(f"robot partly out of view (the tube runs to within {half} px of the {' and '.join(out)} image border), "
                      "or the tube was followed onto the backdrop to that border", model.name)


def _follow_tube(model, frame, coeff, p, t, s, half, threshold, wmin, wmax, step, tolerance, batch: int = 4,
                 max_gap_px: float = 0.0, confirm: int = 4, nav: int = 0, threshold1=None, strong: float = np.inf,
                 energy: bool = False, visited=None):
    """Profiles beyond ``p`` (px) along the tube, at full resolution, for as long as they find it.

    Starting from a centre ``p`` with tangent ``t`` and curve parameter ``s``,
    profiles are cut every ``step`` px along the predicted axis, ``batch`` at
    a time; a profile finds the tube when its edges give a width in
    ``(wmin, wmax)`` (px) and a centre within ``tolerance`` (px, e.g. the
    thinner tube's radius) of the prediction, plus a quarter of its distance
    ahead of the last centre found (the tangent at the start, e.g. at the
    step from the outer to a bent inner tube, can be off by ~10 degrees).
    After each batch the axis is re-predicted from the last centres found.

    Where the tube crosses a stretch of backdrop as bright as itself its
    edges vanish for a while: misses are bridged along the predicted axis for
    up to ``max_gap_px`` (px), and what is found beyond such a gap counts only
    once ``confirm`` consecutive profiles find a tube of the width found
    before it (0.5-1.35 times: the step to the thinner tube may lie in the
    gap). Following stops at the first longer run of misses (at least two
    profiles). With ``energy``, a profile without an edge pair still finds
    the tube where its core stands out (:func:`_energy_hits`, at the width
    found so far but no narrower than ``tolerance``), ahead of the last centre and away from the ``visited``
    centres (m, 2) px.

    Returns
    -------
    Profiles or None
        The profiles that found the tube (``ok`` all true), or None if none did.

    Raises
    ------
    FrameError
        The tube was still being followed when the profiles reached the image
        border: the robot may continue out of view.
    """
    H, W = model.shape
    edge = 2.0
    p, t = np.asarray(p, np.float64), _unit(np.asarray(t, np.float64))
    seen = np.zeros((0, 2)) if visited is None else np.asarray(visited, np.float64)[::2]
    tr = _Track(recent=[p], last_hit=p.copy(), max_misses=max(2, int(np.floor(max_gap_px / step)) + 1), confirm=confirm)
    grow = 1
    for _ in range(int((H + W) / (step * batch)) + 1):
        if len(tr.recent) >= 3:
            # Direction of the last centres (principal axis), oriented along the previous tangent.
            ax = _principal_axis(np.array(tr.recent))
            t = ax if ax @ t > 0 else -ax
        # While bridging a gap the prediction stays put: the rest of the gap (and the profiles that would
        # confirm a tube beyond it) in one batch.
        # On a clean run the batches grow (x2 per batch of all hits, up to 4x): a tube the coarse path lost is
        # followed for hundreds of px, ~0.1 ms of Python per batch.
        nb = batch * grow if tr.on_tube else int(min(max(batch, tr.max_misses - tr.misses + confirm), 128))
        k = step * np.arange(1, nb + 1, dtype=np.float64)
        seeds = p + k[:, None] * t
        pr = edges_from_profiles(model, frame, coeff, seeds, _filled(seeds.shape, t), s + k, half, threshold, nav, threshold1, strong)
        width = pr.chord * max(abs(t[0]), abs(t[1]))  # the slant, as in extract_view (profiles run across the larger component)
        off = (pr.centers - seeds) @ np.array([-t[1], t[0]])
        max_off = tolerance + 0.25 * np.maximum((seeds - tr.last_hit) @ t, 0.0)
        hit = pr.ok & (width > wmin) & (width < wmax) & (np.abs(off) < max_off)
        if energy and tr.widths and not hit.all():
            # The window is never narrower than the thinnest tube's radius: just before a tip the profiles cut
            # the end cap (chords of 2-3 px), and a window that narrow finds a "core" in plain backdrop noise.
            wref = max(tr.wref(), tolerance)
            _add_ridge_hits(model, frame, coeff, seeds, t, half, nav, threshold, wref, max_off, tr.last_hit, seen, pr, width, hit)
        hit = hit.tolist()
        stop, confirmed = _count_batch(tr, model, seeds, pr, s + k + (pr.centers - seeds) @ t, hit, width.tolist(), edge)
        if stop:
            break
        grow = min(4, 2 * grow) if (not confirmed and tr.misses == 0 and all(hit)) else 1
        # Next batch from the last centre found, or along the prediction while bridging a gap.
        if tr.misses == 0 and tr.found:
            p = tr.found[-1][0]
            s = float(tr.found[-1][3])
        else:
            p = seeds[-1]
            s = float(s + k[-1])
    found = tr.found
    if not found:
        return None
    # A run of misses at the end is no part of the tube.
    return Profiles(centers=np.array([f[0] for f in found]), chord=np.array([f[1] for f in found]),
                    axis=np.array([f[2] for f in found], np.int8), s=np.array([f[3] for f in found]),
                    ok=np.ones(len(found), bool))


def _count_batch(tr: _Track, model: ViewModel, seeds: np.ndarray, pr: Profiles, s_c: np.ndarray, hit: list,
                 width: list, edge: float) -> tuple:
    """Count a batch of :func:`_follow_tube`'s profiles into ``tr``, in order along the tube.

    ``seeds`` (n, 2) px, their profiles ``pr``, the centres' curve parameters
    ``s_c`` (px), which found the tube (``hit``, a list: a hit beyond a gap
    whose ``width`` (px) is not the tube's so far becomes a miss, in place).
    Returns ``(stop, confirmed)``: the tube ends here (a run of misses, or
    the border after one), or a hit confirmed the tube beyond a gap (the
    rest of the batch is not counted: the axis is predicted again).

    Raises :class:`~recon.errors.FrameError` when the prediction reaches
    within ``edge`` px of the image border while on the tube.
    """
    H, W = model.shape
    # At the border when the prediction itself nearly leaves the image: a tip a few px inside it is in
    # view (profiles there keep their windows inside the image, recon._kernels._windows).
    border = ((seeds[:, 0] < edge) | (seeds[:, 1] < edge) | (seeds[:, 0] > W - 1 - edge) | (seeds[:, 1] > H - 1 - edge)).tolist()
    for i in range(len(hit)):
        if border[i]:
            if tr.on_tube:
                raise _border_error(model, seeds[i], int(edge))
            return True, False
        if hit[i] and tr.misses >= 2 and tr.widths and not 0.5 * tr.wref() < width[i] < 1.35 * tr.wref():
            hit[i] = False
        if hit[i]:
            if tr.take((pr.centers[i], pr.chord[i], pr.axis[i], s_c[i], width[i])):
                return False, True  # re-predict the axis from the centres beyond the gap
        elif tr.miss():
            return True, False
    return False, False


#: Rounds of following the tube and locating its tip in :func:`extract_view` (each round goes on from a
#: tip found well beyond the profiles, or from the refitted end of a stretch the last round added; a
#: round that adds nothing ends it).
_MAX_FOLLOWS = 8


def _merge_profiles(prof, s, c, ok, more):
    """The profiles ``prof`` (s, c, ok) with those of ``more`` added, sorted by curve parameter."""
    order = np.argsort(np.concatenate([s, more.s]), kind="stable")
    prof.chord = np.concatenate([prof.chord, more.chord])[order]
    prof.axis = np.concatenate([prof.axis, more.axis])[order]
    return (np.concatenate([s, more.s])[order], np.concatenate([c, more.centers])[order],
            np.concatenate([ok, more.ok])[order])


def _gray_frame(model: ViewModel, frame) -> np.ndarray:
    """The frame as (H, W) uint8 gray levels (RGB converted, other dtypes clipped to 0-255).

    Raises :class:`~recon.errors.FrameError` when its size is not the background model's.
    """
    frame = np.asarray(frame)
    if frame.ndim == 3:
        frame = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)
    if frame.shape != model.shape:
        raise FrameError(f"frame is {frame.shape[1]}x{frame.shape[0]} but the background model is {model.shape[1]}x{model.shape[0]}", model.name)
    if frame.dtype != np.uint8:
        frame = np.clip(frame, 0, 255).astype(np.uint8)
    return frame


#: A cross-section narrower than this fraction of the full-width ones near it shows part of the tube only.
RIM_NARROW_FRACTION = 0.8


def _rim_lit_centres(fitter, s, c, ok, d, width, params) -> tuple:
    """Centres ``c`` (n, 2, px) and widths (px) with the narrow cross-sections that show a lit rim only moved
    to the tube's middle.

    A shiny tube in front of a backdrop of its own gray shows, on some cross-sections, only the highlight
    along its lit rim: one edge found is the tube's, the other lies inside it, and the centre sits off the
    axis by half the width missing (wide-1-60's side view: 3.5-5 px narrow of 12-18 px, 2-5 px off, always
    towards the lit rim). Between cross-sections of full width (:data:`RIM_NARROW_FRACTION` of the
    running 80th percentile of widths, 41 profiles) at most two knot spacings apart, a narrow one whose
    centre is off their curve towards one side by 0.8-1.2 times half its missing width (at least 1 px)
    keeps its outer edge and takes the nearest full one's width (running median of 9). Any other narrow
    cross-section is left as it was (no full ones on both sides: which rim is lit is not known; full ones
    beside it more than 2 px off their curve: they may be the tube with backdrop beside it). ``d``: unit
    tangents (n, 2); ``ok``: the accepted cross-sections.
    """
    g = np.flatnonzero(ok)
    if g.size < 16:
        return c, width
    full = np.zeros(len(s), bool)
    full[g] = width[g] >= RIM_NARROW_FRACTION * running_rank_nb(width[g], 41, 32)  # 80th percentile
    f = np.flatnonzero(full)
    cand = _rim_lit_candidates(s, c, ok & ~full, f, d, width, 2.0 * params.spline_knot_px)
    if cand is None:
        return c, width
    narrow, before, after, near, normal = cand
    coef, _ = fitter.robust(c, full, 4.0 * params.outlier_min_px, params.outlier_sigma)
    ref = fitter.values(coef)
    off = np.sum((c[narrow] - ref[narrow]) * normal, axis=1)
    full_width = width.copy()
    full_width[f] = running_rank_nb(width[f], 9, 4)  # median: one odd full cross-section sets no width
    half_missing = 0.5 * (full_width[near] - width[narrow])
    # The full ones must lie near their curve (a wider cross-section can also be the tube with backdrop
    # beside it: wide-3-7's inner tube, 6 px, read 10-13 px, scattered 1-4 px off the axis; a full one can
    # itself miss a fifth of the width), and the narrow one's outer edge must be theirs.
    clean = np.maximum(np.linalg.norm(c[before] - ref[before], axis=1), np.linalg.norm(c[after] - ref[after], axis=1)) <= 2.0
    lit = (clean & (half_missing >= 1.0)
           & (np.abs(off) >= 0.8 * half_missing) & (np.abs(off) <= 1.2 * half_missing))
    i = narrow[lit]
    c, width = c.copy(), width.copy()
    c[i] -= (np.sign(off[lit]) * half_missing[lit])[:, None] * normal[lit]
    width[i] = full_width[near[lit]]
    return c, width


def _rim_lit_candidates(s, c, narrow, f, d, width, max_gap):
    """The narrow cross-sections (bool mask ``narrow``) that may show a lit rim only, screened cheaply
    against the chord between the full ones (indices ``f``) on either side, at most ``max_gap`` (px of ``s``)
    apart: ``(indices, full before, full after, the nearer of the two, unit normals)``, or None.

    Between full ones only: beyond the last, their curve is extrapolated (past the outer tube's end it
    leaves the inner tube, whose narrower cross-sections would seem off it). Off the chord by half to 1.5
    times half the missing width (the nearer full one's, at least 1 px): most frames have none, and the
    spline through the full ones is not fitted.
    """
    narrow = np.flatnonzero(narrow)
    if f.size < 8 or narrow.size == 0:
        return None
    k = np.searchsorted(s[f], s[narrow])
    inside = (k > 0) & (k < f.size)
    narrow, k = narrow[inside], k[inside]
    before, after = f[k - 1], f[k]
    gap = s[after] - s[before]
    near = np.where(s[narrow] - s[before] < s[after] - s[narrow], before, after)
    half_missing = 0.5 * (width[near] - width[narrow])
    chord = c[before] + ((s[narrow] - s[before]) / np.maximum(gap, 1e-9))[:, None] * (c[after] - c[before])
    normal = np.c_[-d[narrow, 1], d[narrow, 0]]
    off = np.abs(np.sum((c[narrow] - chord) * normal, axis=1))
    keep = (gap <= max_gap) & (half_missing >= 1.0) & (off >= 0.5 * half_missing) & (off <= 1.5 * half_missing)
    if not keep.any():
        return None
    return narrow[keep], before[keep], after[keep], near[keep], normal[keep]


def _half_lit_centres(model: ViewModel, c, ok, d, width) -> tuple:
    """Centres ``c`` (n, 2, px) and widths (px) with the cross-sections that show one side of the tube only
    moved to its axis, where the stretch at the base tells which side is lit (:mod:`recon.halflit`).

    :func:`_rim_lit_centres` mends narrow cross-sections between full ones. A view can show the highlight
    alone from the base on, or along all of the tube, and the centres then run off the axis by half the width
    missing (wide-2-34's side view: 3.3 px of a 10 px tube, 3.9 px off, the backbone 3.8 footprints off
    and ``ok``). The lit side is taken to be the base stretch's all along the view. ``ok``: the accepted
    cross-sections; ``d``: unit tangents (n, 2).
    """
    g = np.flatnonzero(ok)
    if g.size < 2 * BASE_STRETCH:
        return c, width
    head = g[:BASE_STRETCH]
    side, fraction = lit_side(model.base_px, model.axis_px, 2.0 * model.outer_radius_px, c[head], d[head], width[head])
    if side == 0.0:
        return c, width
    narrow, full, move = half_lit_moves(width[g], fraction, 2.0 * model.inner_radius_px, 2.0 * model.outer_radius_px)
    i = g[narrow]
    c, width = c.copy(), width.copy()
    c[i] -= (side * move)[:, None] * np.c_[-d[i, 1], d[i, 0]]
    width[i] = full
    return c, width


#: A tail cross-section wider than this many times the tube before it can be the end cap cut at a slant.
_WIDE_TAIL = 1.2


def _off_axis_tail(fitter, s, c, ok, width, params) -> np.ndarray:
    """``ok`` without the centres of the last tube diameter that read wide and lie off the line the centres
    before them run along.

    Near the tip a profile can cross the end cap at a slant, or reach the backdrop beside it where that is as
    dark as the tube: it reads wider and its centre lies off the axis. A few such centres at the end of the
    curve bend the spline's free end towards them (it has nothing beyond to hold it), the robust fit keeps
    them, and the tip is then measured along that bent tangent (wide-1-44's side view: the last centres read
    20-23 px of a 10-14 px tube, 4.6-6.1 px off the axis, and the backbone's tip ended 1.1 mm, 11
    footprints, off the truth; the frame was ``ok``). Over a diameter a tube bends off its tangent line by
    about a pixel (the material's strain limit). A tail centre is dropped where it is both wider than 1.2
    times the centres before it and more than a quarter of a width (at least 2 px) off the fitted curve's
    tangent line at the last of them. At least 8 centres must lie before the tail, and no gap longer than
    the tail between them; the widths set its length (the median of the last 40 accepted, robust against
    the few wide ones). Where the tail is as wide as the tube, its centres are the tube's, even off that
    line (a tube that bends at its end, seen at a slant).
    """
    g = np.flatnonzero(ok)
    if g.size < 16:
        return ok
    diameter = float(median_nb(width[g[-40:]]))
    in_tail = s[g] > s[g[-1]] - diameter
    tail, head = g[in_tail], g[~in_tail]
    if head.size < 8 or s[tail[0]] - s[head[-1]] > diameter:
        return ok
    wide = width[tail] > _WIDE_TAIL * float(median_nb(width[head[-20:]]))
    if not wide.any():
        return ok
    only_head = ok.copy()
    only_head[tail] = False
    coef, _ = fitter.robust(c, only_head, 4.0 * params.outlier_min_px, params.outlier_sigma)
    j = int(head[-1])
    p, t = fitter.value_at(coef, j), _unit(fitter.derivative_at(coef, j))
    rel = c[tail] - p
    off = np.abs(rel[:, 0] * t[1] - rel[:, 1] * t[0])
    bad = wide & (off > max(2.0, 0.25 * diameter))
    if not bad.any():
        return ok
    ok = ok.copy()
    ok[tail[bad]] = False
    return ok


def _final_curve(name: str, fitter, s, c, ok, end_px, params) -> tuple:
    """The robust spline through the accepted centres ``c[ok]`` and the tip ``end_px`` (px) moved onto its end tangent.

    Returns ``(spline, good indices, s_end, t_end, end_px)``; raises
    :class:`~recon.errors.FrameError` with fewer than 8 centres left.
    """
    if ok.sum() < 8:
        raise FrameError(f"too few valid tube profiles ({int(ok.sum())} of {len(ok)})", name)
    coef, ok = fitter.robust(c, ok, params.outlier_min_px, params.outlier_sigma)
    good = np.flatnonzero(ok)
    if good.size < 8:
        raise FrameError(f"too few valid tube profiles ({good.size})", name)
    spl = fitter.spline(coef)
    s_end = float(s[good[-1]])
    p_end = spl(s_end)
    t_end = _unit(spl.derivative()(s_end))
    return spl, good, s_end, t_end, p_end + float(np.dot(end_px - p_end, t_end)) * t_end


def _edge_limits(model: ViewModel, params) -> tuple:
    """The edge search's limits for a view: ``(rmax, nav, thr, thr_px, wmin, wmax, strong)``.

    ``rmax`` the largest tube radius (px); ``nav`` the parallel lines a
    profile averages on each side; ``thr`` the edge threshold of an averaged
    profile and ``thr_px`` of one line (gray levels); ``wmin``, ``wmax`` the
    accepted tube widths (px); ``strong`` the rim contrast (gray levels) above
    which a single line's edges are taken as they are.
    """
    rmax = model.outer_radius_px * params.max_width_fraction
    nav = int(params.profile_half_lines)
    thr = max(params.edge_threshold_sigma * model.sigma_fine / np.sqrt(2 * nav + 1), params.edge_min_dn)
    thr_px = max(params.edge_threshold_sigma * model.sigma_fine, params.edge_min_dn)  # one line, no averaging: the tip
    wmin = 2.0 * model.inner_radius_px * params.min_width_fraction
    strong = float(params.single_line_rim_factor) * thr_px
    return rmax, nav, thr, thr_px, wmin, 2.0 * rmax, strong


@dataclass(eq=False)
class _Fit:
    """The profiles' curve parameters ``s``, centres ``c`` (px) and accepted ``ok``, with their robust spline fit."""

    s: np.ndarray
    c: np.ndarray
    ok: np.ndarray
    fitter: object
    coef: np.ndarray
    d: np.ndarray
    width: np.ndarray

    def end(self) -> tuple:
        """:func:`_end_of` the fit: curve parameter, position, unit tangent and half-width (px) at its last centre."""
        return _end_of(self.fitter, self.coef, self.s, np.flatnonzero(self.ok), self.d, self.width)

    def drop_off_axis_tail(self, params) -> None:
        """Drop the tail centres :func:`_off_axis_tail` finds (an end cap cut at a slant) and refit, so that the
        end tangent the tube is followed along is the tube's (the paper scene's frame 0, top view: the last
        knot span turned 24 deg towards them, and following along it took edge pairs of the backdrop's noise
        for tube 20-28 px past a 5 mm tip, the tip 1.1 mm long)."""
        ok = _off_axis_tail(self.fitter, self.s, self.c, self.ok, self.width, params)
        if np.array_equal(ok, self.ok):
            return
        self.coef, self.ok = self.fitter.robust(self.c, ok, 4.0 * params.outlier_min_px, params.outlier_sigma)
        self.d = _unit_rows(self.fitter.derivatives(self.coef))

    def add(self, prof, more, params, widths) -> None:
        """Merge the followed profiles ``more`` and refit (``widths``: the accepted (min, max), px)."""
        self.s, self.c, self.ok = _merge_profiles(prof, self.s, self.c, self.ok, more)
        self.fitter, self.coef, self.ok, self.d, self.width = _fit_centres(self.s, self.c, self.ok, prof, params, *widths)


def _follow_options(model: ViewModel, params, visited: np.ndarray, follow_min_dn, bridge_gaps: bool) -> dict:
    """:func:`_follow_tube`'s keyword arguments for a view (see :func:`extract_view` for the second tries'
    ``follow_min_dn`` and ``bridge_gaps``); ``visited`` (m, 2) px: the centres found so far."""
    rmax, nav, thr, thr_px, wmin, wmax, strong = _edge_limits(model, params)
    gap_px = 2.0 * model.outer_radius_px * params.follow_gap_diameters if bridge_gaps else 0.0
    if follow_min_dn is not None:
        # More sensitive; callers then bridge no gaps: at this threshold a stretch of backdrop texture beyond
        # a gap passes for a tube often enough (seen: two hits 50 px on, 20 px off the tube).
        _, _, thr, thr_px, *_ = _edge_limits(model, replace(params, edge_min_dn=min(follow_min_dn, params.edge_min_dn)))
    return dict(half=int(np.ceil(rmax * 1.45 + 4)), threshold=thr, wmin=wmin, wmax=wmax, step=params.profile_step_px,
                tolerance=model.inner_radius_px, max_gap_px=gap_px, nav=nav, threshold1=thr_px, strong=strong,
                energy=bool(params.follow_energy), visited=visited)


def _follow_rounds(model, frame, coeff, prof, fit: _Fit, follow: dict, params, widths, lap) -> float:
    """Follow the tube beyond ``fit``'s last centre and locate its tip, in up to :data:`_MAX_FOLLOWS` rounds
    (``fit`` grows in place); returns the tip's distance (px) along the end tangent beyond the last centre
    (NaN where the tip stage found none)."""
    fit.drop_off_axis_tail(params)
    sb, p_end, t_end, r_end = fit.end()
    start, end_t = (p_end, t_end, sb), np.nan
    for round_ in range(_MAX_FOLLOWS):
        try:
            more = _follow_tube(model, frame, coeff, *start, **follow)
        except FrameError:
            if round_ == 0 or start[2] <= sb:
                raise
            # A round that goes on from beyond a tip the tip stage found (not from the tube itself) and runs
            # into the border followed backdrop (seen: a dark line from 10 px past the tip to the border):
            # the robot in view ends at that tip.
            break
        # What that finds within a diameter and 2 px is the end cap, which the tip stage measures and the
        # end-cap rule in extract_view drops anyway; only a longer stretch is added, and the centres refitted.
        added = more is not None and more.s[-1] > sb + 2.0 * r_end + 2.0
        if round_ > 0 and not added:
            break
        if added:
            fit.add(prof, more, params, widths)
            sb, p_end, t_end, r_end = fit.end()
        lap("follow")
        # Tip, along the axis from the last accepted centre.
        end_t = _tip_along_axis(model, frame, coeff, p_end, t_end, r_end, follow["threshold1"])
        lap("tip")
        # Where the tip stage walks on well beyond the profiles (lines along the axis see a tube whose edges
        # faded across a stretch of backdrop, or the step to a thinner tube whose core alone stands out),
        # the tube may go on: follow it again from there.
        if np.isfinite(end_t) and end_t > 2.0 * r_end + 3.0:
            start = (p_end + end_t * t_end, t_end, sb + end_t)
        elif added:
            # The follower predicts its axis from its last few centres; across textured backdrop they can
            # wander and the prediction leaves a bending tube. The refitted spline's end tangent is steadier:
            # go on from there (seen: 120 px of a tube left beyond such a stop).
            start = (p_end, t_end, sb)
        else:
            break
    return end_t


#: The tip stage is run again along the final curve where the two end tangents are this far apart (deg).
_TIP_RETRY_DEG = 10.0


def _tip_along_final_curve(model, frame, coeff, p_fit, t_fit, t_tip, end_px, radius_px, threshold) -> np.ndarray:
    """The tip (px), measured again from the final curve's last centre ``p_fit`` along its end tangent ``t_fit``
    where the tip stage walked along a tangent ``t_tip`` more than :data:`_TIP_RETRY_DEG` away; ``end_px`` as
    it is otherwise, or where the new end lies no more than 1 px beyond it.

    Profiles that cut the end cap at a slant read centres off the axis, and the last knot span turns towards
    them; the tip stage then walks off the tube at once and the tip lands on the last centre. The end-cap rule
    drops those centres from the final curve, which then points along the tube again (seen: the paper scene's
    top view under other noise draws, the tangents 25 deg apart, the tip 6 px short).
    """
    if float(t_tip @ t_fit) >= np.cos(np.radians(_TIP_RETRY_DEG)):
        return end_px
    before = float((end_px - p_fit) @ t_fit)
    # The end lies beyond the centres the end-cap rule dropped: look as far ahead of the old end as the stage does.
    again = _tip_along_axis(model, frame, coeff, p_fit, t_fit, radius_px, threshold, ahead_px=20.0 + max(before, 0.0))
    if not np.isfinite(again) or again <= before + 1.0:
        return end_px
    return p_fit + again * t_fit


def _fit_along_path(model: ViewModel, frame: np.ndarray, coarse: CoarseResult, params: ViewParams, lap) -> tuple:
    """Profiles along the coarse path, wide enough for its error (about a pooled cell), and the robust spline
    through their centres: ``(prof, fit, (wmin, wmax))``, the accepted widths (px) last.

    Raises :class:`~recon.errors.FrameError` with fewer than 8 valid profiles.
    """
    f = model.factor
    rmax, nav, thr, thr_px, wmin, wmax, strong = _edge_limits(model, params)
    seeds, s = resample_arc(_smooth_path(coarse.path_px, 3), params.profile_step_px, mode="steps")
    tang = _tangents(seeds)
    half = int(np.ceil(rmax * 1.45 + 1.5 * f + 2))
    prof = edges_from_profiles(model, frame, coarse.coefficients, seeds, tang, s, half, thr, nav, thr_px, strong)
    lap("profiles")
    s, c, ok = _reparameterize(prof, seeds, tang)
    ok &= (prof.chord > wmin) & (prof.chord < 1.45 * wmax)
    if ok.sum() < 8:
        raise FrameError(f"no tube edges found along the silhouette ({int(ok.sum())} of {len(ok)} profiles)", model.name)
    fitter, coef, ok, d, width = _fit_centres(s, c, ok, prof, params, wmin, wmax)
    good = np.flatnonzero(ok)
    if good.size < 8:
        raise FrameError(f"too few valid tube profiles ({good.size} of {len(ok)})", model.name)
    lap("fit")
    return prof, _Fit(s, c, ok, fitter, coef, d, width), (wmin, wmax)


def extract_view(model: ViewModel, frame: np.ndarray, params: ViewParams, roi=None, timings: dict | None = None,
                 follow_min_dn: float | None = None, bridge_gaps: bool = True, shift_px=None) -> ViewCenterline:
    """Coarse path, fine profiles, spline, tip: the sub-pixel centerline of one view.

    Parameters
    ----------
    model : ViewModel
        The view's constants (:func:`prepare_view`).
    frame : (H, W) or (H, W, 3) array
        The frame (gray levels; RGB is converted, other dtypes clipped to 0-255).
    params : ViewParams
        The extraction's parameters (``FastParams.view`` for the fast method).
    roi : (x0, y0, x1, y1) or None, optional
        Coarse pixels that narrow the search for the robot (see :func:`coarse_path`).
    timings : dict or None, optional
        Stage times (ms) are added to it: ``coarse``, ``profiles``, ``fit``,
        ``follow``, ``tip``.
    follow_min_dn : float or None, optional
        Second tries, when the other view's tip disagrees: lowers
        ``params.edge_min_dn`` (gray levels) for following the tube beyond the
        fitted profiles only.
    bridge_gaps : bool, optional
        False: following stops at the first gap (what lies beyond one may be
        backdrop that passes for the tube).
    shift_px : (2,) array or None, optional
        The frame's image shift (px) where it was measured on this very frame
        already (:func:`steady_frame`, leaving it as it was); None: measured
        here (zeros without ``params.jitter_compensation``).

    Returns
    -------
    ViewCenterline
        The curve and its points in the frame's pixel coordinates (image
        frame, px, as measured: ``shift_px`` not subtracted).

    Raises
    ------
    FrameError
        A frame of the wrong size, from :func:`coarse_path`, too few valid
        profiles, or the tip at the image border.
    """
    lap = _Lap(timings)
    frame = _gray_frame(model, frame)
    coarse = coarse_path(model, frame, roi, base_search_px=params.base_search_px)
    lap("coarse")
    if len(coarse.path_px) < 3:
        raise FrameError(f"robot too short in the image (~{len(coarse.path_px) * 2 * model.factor} px)", model.name)
    prof, fit, widths = _fit_along_path(model, frame, coarse, params, lap)
    # The coarse path can stop short of the tip (a tube only a coarse pixel or two wide can drop out of the
    # coarse mask): follow the tube's edges at full resolution beyond the last accepted centre.
    follow = _follow_options(model, params, fit.c[np.flatnonzero(fit.ok)], follow_min_dn, bridge_gaps)
    end_t = _follow_rounds(model, frame, coarse.coefficients, prof, fit, follow, params, widths, lap)
    s, c, ok, fitter, width = fit.s, fit.c, fit.ok, fit.fitter, fit.width
    sb, p_end, t_end, r_end = fit.end()
    if not np.isfinite(end_t):
        end_t = 0.0
    # Profiles within about a radius of the silhouette's end are cut by the end cap.
    ok &= s <= sb + end_t - 1.2 * r_end - 1.0
    c, width = _rim_lit_centres(fitter, s, c, ok, fit.d, width, params)
    c, width = _half_lit_centres(model, c, ok, fit.d, width)
    ok = _off_axis_tail(fitter, s, c, ok, width, params)
    spl, good, s_end, t_fit, end_px = _final_curve(model.name, fitter, s, c, ok, p_end + end_t * t_end, params)
    end_px = _tip_along_final_curve(model, frame, coarse.coefficients, spl(s_end), t_fit, t_end, end_px, r_end,
                                    follow["threshold1"])
    t_end = t_fit
    lap("fit")
    # Outside border check at full resolution: the tip must not be at the border.
    H, W = model.shape
    if not (1.0 <= end_px[0] <= W - 2.0 and 1.0 <= end_px[1] <= H - 2.0):
        raise FrameError("robot partly out of view (its tip is at the image border)", model.name)
    return ViewCenterline(
        name=model.name, curve=spl, s_range=(float(s[good[0]]), s_end), points_px=c[good], s=s[good],
        width_px=width[good], end_px=end_px, end_s=s_end, tangent_end=t_end, n_profiles=len(s),
        n_rejected=int(len(s) - good.size), coarse=coarse,
        shift_px=np.asarray(shift_px, np.float64) if shift_px is not None else (
            frame_shift(model.shift, frame) if params.jitter_compensation else np.zeros(2)),
    )
