"""Method-independent self-check: does a reconstructed backbone explain the images?

A reconstruction method can return a plausible-looking but wrong shape: a
backbone that follows the tube half way and then runs straight to a wrong end,
or one that stops far short of the tip. This module judges any backbone (any
method, any peer) against the images alone, with its own foreground per view
that shares nothing with the method's silhouette:

* **Foreground.** Per view, the background frames are brought to one lighting
  (a gain and an offset, each with a ramp across the image: :class:`Lighting`) and
  reduced to a per-pixel band ``[erode(min), dilate(max)]`` over a small
  window (camera jitter of a pixel moves every texture edge), widened by
  ``noise_sigmas`` of the background's noise and ``margin_dn`` gray levels.
  Optionally (``align_jitter``), where the backdrop has edges to measure it
  on, every frame is moved back by its image shift first
  (:mod:`recon.jitter`) and the band, without the window, widened by the
  gradient times ``aligned_residual_px``. A frame, brought to the background
  mean's lighting the same way (lighting varies by +-20 %, with ramps), is
  foreground where it leaves that band.
* **Reprojection.** The backbone is projected into each view
  (:meth:`recon.camera.Camera.project`, with distortion) every ~1 px along
  the curve, with the tube radius in pixels from the focal length and depth.
* **Figures**, per view, on the in-image part only and in front of the robot
  base: (a) ``unexplained_fraction``, the share of the foreground connected to
  the reprojected tube that the tube (outermost radius plus a tolerance) does
  not cover (a backbone cut short, or one that left the tube); (b)
  ``off_foreground_fraction``, the share of centerline samples with no
  foreground within a pixel or two (a backbone that left the tube); (c)
  ``centerline_rms_px``, the RMS distance between the reprojected centerline
  and the middle of the foreground cross-section across it (a backbone that
  is offset in one view).
* **Shape figures**, from the backbone and the rig alone, which no view's
  foreground judges: a point behind the base plane (``behind_base_px``), a bend
  sharper than the innermost tube can take (``kink_px``), and a start away
  from where the robot enters the views (``start_gap_px``), a long stretch
  whose depth the views do not measure (``unmeasured_depth_mm``).

Everything runs in a region of interest around the reprojection, grown only
while the robot's foreground reaches its edge. Method and thresholds:
``docs/selfcheck.md``.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from .geometry import arc_length, points_at_arc_length, resample_polyline, transform_points
from .jitter import ShiftModel, frame_shift, pixel_noise, prepare_shift, shifted
from .morphology import near_mask
from .paper import behind_base_pixels
from .rigcal import RigCalibration

__all__ = ["SelfCheckParams", "SelfCheckModel", "SelfCheck", "FIGURE_LIMITS", "prepare_selfcheck", "check_backbone",
           "foreground_roi", "Lighting", "fit_lighting"]


@dataclass(frozen=True)
class SelfCheckParams:
    """Thresholds and tolerances of the self-check (defaults calibrated in docs/selfcheck.md).

    Attributes
    ----------
    jitter_window_px : int
        Half-size of the window over which the background's per-pixel minimum
        is eroded and maximum dilated (px) where the frames are not moved
        back (the default; ``align_jitter``). Camera
        jitter of up to 1 px moves every edge of a textured backdrop by that
        much; 1 covers it, since the background frames' own jitter already
        widens the band.
    align_jitter, aligned_residual_px : bool, float
        Where ``align_jitter`` is set and the backdrop has edges in two
        directions (:func:`recon.jitter.prepare_shift`) whose flicker under the
        background frames' jitter exceeds the pixel noise, the background
        frames and every judged frame are moved back by their image shift,
        and the band is widened by the mean background's gradient
        (gray levels per px) times this instead of the window: the shift's
        error and the resampling's. Over fabric and fine noise the window made
        the band the texture's whole local range, 65-90 gray levels wide, and
        a faint tube was foreground on 6-30 % of its length (wide-2-22 frame
        2, wide-2-23 frame 1: good frames flagged, 42-50 % of the tube off
        foreground); aligned, 33-45 levels and 42-66 %. Off by default: on the
        wide suite (seeds 1, 2, 3, 5, 6, fast and paper, 7fe1684) it took good
        frames flagged 24 -> 24 (fast) and 22 -> 17 (paper), but let two wrong
        frames of held-out seed 6 pass (wide-6-0 frame 2, fabric: the top view's
        backbone 4-9 px off a faint tube over 20 mm, 12.3 footprints, where the
        narrower band makes the fabric beside the tube foreground too;
        wide-6-43 frame 1, text, 10.6): fast's silent frames 1 -> 3
        (docs/envelope.md, round 37).
    noise_sigmas : float
        How many standard deviations of the background's temporal noise (per
        pixel, smoothed over 5x5 px) a pixel must lie beyond the band to be
        foreground. 3: the min/max of as few as 6 frames spans only about
        +-1.3 sigma, so 3 more keep false foreground below one pixel in ten
        thousand.
    margin_dn : float
        Further gray levels beyond the band: covers what neither the noise nor
        the gain model describes (quantization, a residual illumination ramp).
        Also the whole margin on noise-free inputs (binary masks).
    explain_tolerance_px : float
        The reprojected tube explains foreground within its outermost radius
        plus this (px): blur and anti-aliasing (about 1 px), calibration and
        camera jitter (up to 1 px), and the methods' own sub-voxel error.
    on_foreground_tolerance_px : float
        A centerline sample is on foreground when foreground lies within this
        distance (px): jitter plus rounding to the pixel grid.
    sample_step_px : float
        Spacing of the reprojected centerline samples (px).
    profile_search_px : float
        How far beyond the outermost radius the cross-section at a sample is
        searched for the tube (px); offsets up to about radius + this are
        measured, larger ones show as off-foreground samples.
    max_unexplained_fraction : float
        Limit of (a). A backbone 20 % short leaves about 20 % of the robot's
        area (less where the thinner inner tube is missing) unexplained; good
        frames stay below 5 % (shadow-free twin scenes) -- 0.10 between.
    max_unexplained_px : float
        Limit of (a) as a length (px of the innermost tube): a missing tip
        is a small fraction of a long robot. Good twin frames stay below 6 px.
    max_off_foreground_fraction : float
        Limit of (b): a backbone that leaves the tube for half its in-image
        length in scattered stretches. One that leaves it in one stretch is
        the run limit's; a thin tube over fine noise or fabric leaves 10-20
        px gaps in the foreground all along (wide-3-20 frame 0 of the fast
        method: 26 %, none over 4 % in one run, the backbone good;
        wide-2-22 frame 2: 49.5 %, 3.5 footprints). On wide seeds 2 and 3,
        0.20 flagged two good frames alone and every wrong frame between
        0.20 and 0.30 (five) was flagged by another figure too; 0.30 still
        flagged two good frames alone there (wide-2-22 frame 2, wide-2-23
        frame 1) and no wrong frame was flagged by this share alone on
        seeds 2 and 3 (round 38: 0.50).
    max_off_foreground_run_fraction : float
        Limit of (b) over its longest stretch: the longest run of reprojected
        samples with neither foreground nor tube contrast, as a share of the
        in-image length. A backbone that bulges off the tube where the tube
        crosses clutter of its own brightness leaves it in one piece.
    max_centerline_rms_px : float
        Limit of (c) (px). Good reconstructions reproject within about 1 px
        RMS; a backbone offset by 5 px in one view is far beyond 2.5.
    max_centerline_local_px, centerline_window_px : float
        Limit of (c'): the largest running median of the offsets over
        ``centerline_window_px`` of the curve (px): a stretch where the
        backbone leaves the tube, which the RMS of a long robot hides.
    min_section_width_share, section_width_window_px : float
        A clean cross-section narrower than this share of the median width
        of the clean cross-sections over ``section_width_window_px`` of the
        curve around it, or of the largest such median of the sections
        centred on the backbone (within ``on_foreground_tolerance_px``) from
        there on to the tip (widths in outer radii at each point's depth: the
        tubes only get thinner towards the tip) where the run reaches that
        section's edge (within ``on_foreground_tolerance_px`` + 1 px), is
        left out of (c) and (c'): it covers one side of the tube only (the
        other as bright as the backdrop), and its middle lies off the axis by
        up to a radius. The robot's tubes differ in width, so no fixed width
        (only ``1.5 r_in``) tells. 0: none left out.
    min_visible_px : float
        A view in which less than this length of the backbone (px) is in the
        image, in front of the base, is not judged.
    min_profile_fraction : float
        (c) is measured only when at least this fraction of the samples (and
        at least 10) have a clean cross-section (one run of foreground, no
        wider than the tube, bounded on both sides).
    roi_margin_px : int
        Margin of the region of interest around the reprojected tube (px).
    max_roi_growth : int
        How many times the region of interest may grow (each time doubling
        towards the sides where the robot's foreground reaches its edge).
    unseen_depths, unseen_slope, unseen_depth_mm, unseen_border_px, unseen_samples
        Robot foreground of one view that no other camera can see need not be
        explained (where the robot enters across a border of only this view,
        no method can triangulate it). An unexplained pixel ``d`` px from the
        nearest reprojected backbone sample (depth ``z``) is back-projected at
        ``unseen_depths`` depths across ``z +- (unseen_slope * d * z / f +
        unseen_depth_mm)`` (the tube between them inclined up to 45 deg out of
        the image plane, plus a few tube diameters) and is unseen when none of
        those points is inside another camera's image (``unseen_border_px`` in
        from its border: the methods crop the robot there). Near the base the
        depth comes from the line base -> first backbone point, so the
        stretch a method leaves out because only one view sees it is unseen.
        Up to ``unseen_samples`` pixels are tested.
    speck_reach : float
        A piece of unexplained foreground counts only when it reaches at least
        this many outermost tube diameters (plus ``explain_tolerance_px``) away
        from the band: noise specks clinging to the band (14 px on the paper
        scene's noisy rotated frame) do not, a tube left out does (40-180 px
        on the wide suite). Short tips are the tip probe's.
    contrast_window_px, contrast_min, contrast_ratio
        A centerline sample with no foreground near it is still *on the tube*
        when the frame's difference from the background mean (over the band's
        half-width), the most across the tube's middle, averaged over
        ``contrast_window_px`` along the curve, exceeds ``contrast_min`` and
        ``contrast_ratio`` times the same just beside the band (a tube as
        bright as a textured backdrop still changes it a little all along;
        bare backdrop does not differ from its side). Measured on the wide
        suite against the truth (window means, ratio 2): 97 % of such on-tube
        samples supported, 9 % of off-tube ones; now running medians and ratio
        3 (ratio 2 let a backbone with a 98 px detour pass on wide-2-7).
    tip_probe_start_px, tip_probe_px, tip_probe_radii, tip_probe_min_px, tip_probe_ratio, max_beyond_tip_contrast
        The tip probe: the same difference on the backbone's continuation
        beyond the reprojected tip (along the tip's tangent, from
        ``tip_probe_start_px`` for ``tip_probe_px`` or ``tip_probe_radii``
        outer radii, the longer), the largest mean over its first k >=
        ``tip_probe_min_px`` samples, over ``max(contrast_min, tip_probe_ratio
        * beside)`` (beside: the mean over the whole probe); above
        ``max_beyond_tip_contrast`` in any view the tube goes on: the backbone
        is short (a faint inner tube that the foreground does not show). The
        start (8 px) is the unexplained length's limit: a tip 8 footprints
        short is still good; it moves out by how far the tube's flat end face
        reaches beyond the tip, ``r_out |t . ray|`` px (a tube seen end on).
        The prefix means: a tube that goes on a few px past the start is
        diluted over the whole probe by the backdrop after it (paper,
        wide-2-3 frame 1: 13 footprints short, 1.12). The length in radii: a
        tube 9-13 px in radius (5 MP) has stretches of its own diameter as
        faint as the backdrop (wide-2-3 frame 0: 51 footprints short, the
        tube faint 7-23 px past the tip, 1.27 over 12 px).
    max_tip_off_foreground_px : float
        Limit of the length (px) of the judged curve's end with no foreground
        (nor contrast support) on it: a backbone that runs on beyond the tip
        (or leaves the tube just before the border). 8 px, as a tip cut short:
        the off-foreground share of a long robot hides a 20 px overrun.
    max_start_off_foreground_px : float
        The same at the judged curve's start, in a view whose image the base
        is not in (the robot enters across its border): a backbone that hooks
        off the tube there (wide-8-5 frame 2 of the paper method: the first
        10 px at the side view's border, 13 footprints, reported ok). 8 px, as
        at the tip. Stored backbones of wide seeds 1-3 and 5-8, both methods:
        good frames read at most 2 px; every frame over 8 px but that one was
        flagged already. With the base in view the tube is faint or hidden
        at the base (wide-3-23 frame 2 of the fast method: 11 px, 2.3
        footprints), and the start gap and behind-base figures judge it.
    tip_tangent_px, max_tip_overhang_px : float
        The *tip overhang*: how far (px) the foreground runs on beyond the
        reprojected tip, within the innermost radius plus
        ``on_foreground_tolerance_px`` of the tip's tangent (taken over the
        last ``tip_tangent_px``, as the tip probe's at least; a hook or a
        wiggle at the very end turns a shorter one off the tube), until a
        gap of 2 px, less the end face's reach
        ``r_in |t . ray|``. It is the tip's shortfall in that view. The
        unexplained length misses it where a thin inner tube ends inside a
        band drawn with a thick outer tube's radius: the band's square end
        swallows the first ``explain_tolerance_px`` and the rest clings to
        the band like a speck (wide-1-68 frame 2 of the paper method: 14
        footprints short, unexplained 0). Limit 8 px, as a tip cut short.
        Measured only where the tip probe does not run (binary masks, or
        ``tip_probe_px = 0``): on camera images the probe sees short tips,
        and there the overhang flagged two good frames of wide seed 3 (tips
        9.6 and 8.6 footprints short) and no wrong one of seeds 2/3.
    max_behind_base_px : float
        Limit of how far (pixel footprints: the cameras' mean mm per px there)
        from the base the backbone reaches behind the base plane, where no
        robot can be and no view judges it (the behind-base pixels are left
        out). Such a point is off the robot by its distance from the base: the
        figure is an error itself, so the limit is the 10 footprints that
        separate good frames from wrong ones.
    kink_chord_mm, max_strain, max_kink_px
        No view judges the backbone's shape between the samples it is on: a
        spike that leaves the tube for a few tube widths in one view and comes
        back reprojects mostly onto foreground (wide-1-14 frame 1 of the paper
        method: a 23-footprint V in the top view, reported ok). A tube cannot
        bend that sharply: past its material's strain limit it kinks or yields
        (superelastic Nitinol recovers about 8 %, the default ``max_strain``).
        The *kink* figure is the largest sagitta of the backbone over a
        chord ``kink_chord_mm`` either side of a point, less the sagitta of an
        arc of the tightest curvature the innermost tube allows,
        ``max_strain / r_in`` (``kappa * L**2 / 2``), in pixel footprints
        there; above ``max_kink_px`` the backbone is not a tube's shape. Where
        the frame's joint values say which tubes cover each point
        (``tube_sections_mm``), the radius is the outermost tube's there: the
        robot bends no more sharply than its outer surface allows (wide-6-32
        frame 2 of the paper method: a 1 mm zigzag 6-9 mm from the base, inside
        the outer tube, 17.6 footprints, read 2.1 against the inner tube's
        radius and 9.4 against the outer's). Stored backbones of wide seeds 1-3
        and 5-9, both methods: two more good paper frames read over 5
        (wide-7-6 frame 0, 8.4 footprints off, 5.19; wide-1-41 frame 2, 9.3,
        5.14), and no other frame's verdict moved.
    max_start_gap_px : float
        The robot is joined to its base. Where the base is outside a view, the
        robot enters that view at its border, so a backbone must start at (or
        beyond) the border of a view that does not see the base: the figure is
        the smallest distance (px) of its first point from the border of any
        such view. Where every view sees the base, it is the first point's
        distance from the base (pixel footprints). A backbone that starts
        further in left out the robot between (wide-1-63 frame 0 of the paper
        method: the tube's first 60 px in the top view, which the band did not
        touch). Both methods continue their backbones to the border and to the
        base plane, so the figure is about the start's error itself; 12 px
        keeps a margin over good frames just within the 10 footprints that
        make a frame wrong (seed 2: good frames up to 9.9).
    min_depth_visibility, max_unmeasured_depth_mm
        Where the tube runs near an epipolar plane the two views do not measure
        its depth: a displacement across it moves both reprojections along the
        tube, and every view figure passes whatever shape the method put there
        (wide-1-57 frame 0 of the fast method: 41 footprints off over a 54 mm
        stretch, flagged before only by a lighting misfit). Per point of the
        backbone (every mm), the *depth visibility* is the reprojection shift
        across the tube (px, the views in quadrature) of a displacement of one
        pixel footprint in the least visible direction across the tangent;
        under ``min_depth_visibility`` (0.3: a 10-footprint error shows as under
        3 px, inside the tolerances) the depth there is not measured. Neither
        the backbone nor the smoothest curve the views allow could be told from
        the truth there (docs/envelope.md, round 10), so a stretch longer than
        ``max_unmeasured_depth_mm`` between measured points is flagged: 20 mm,
        over which a bend of 1/50 mm^-1 (a CTR tube's precurvature) hides a
        1 mm sagitta, 10 footprints at 0.1 mm per px. Wide seed 2: one good
        frame of 206 reads more (wide-2-41 fast frame 0, 69 mm); seed 1: the
        wrong frames wide-1-24 fast 2 and wide-1-57 fast 0 read 68 and 55 mm.
        Stretches that reach an end of the backbone are left to the tip and
        start figures.
    max_length_mismatch_fraction, max_length_mismatch_px : float
        Where the frame's joint values are known, the robot's length is too:
        the innermost tube's tip is ``max(extension_mm)`` from the base along
        the backbone (docs/scenes.md, joint conventions), and tubes do not
        stretch. The *length mismatch* is ``|L + c - E|``, with ``L`` the
        backbone's arc length (over vertices 5 mm apart: a carved backbone's
        sub-mm wiggle added 4 % over its 0.5 mm vertices, wide-3-44 frame 1 of
        the paper method), ``c`` the straight distance from the base to its
        first point (the robot before a view's border, which no view sees) and
        ``E`` the joints' length. As a fraction of ``E``: a backbone that stops
        a third of the way along a faint tube, with every view figure in range
        because the rest of the tube is not foreground, reads 0.66 (wide-8-42
        frame 1 of the fast method: 85 mm off, reported ok); good frames of
        wide seeds 1-3 and 5-8 read up to 0.016 (fast) and 0.062 (paper, a 37
        mm robot) -- limit 0.10. In pixel footprints at the tip, where the
        base is in every view (elsewhere ``c`` is a chord of a robot that may
        bend out of view: good frames read up to 19 short): the length's error is the
        tip's along the tube, and good frames with the base in view read up
        to 7.1 (fast) and 8.9 (paper), while paper frames reported ok with
        their tips 12-18 footprints short read 11.8-18.3 (wide-1-7 frame 2,
        wide-7-44 frame 0, wide-8-27 frame 1) -- limit 10, the footprints that
        make a frame wrong. Where a view does not see the base, a backbone
        *longer* than the joints' length is judged in footprints all the same:
        the chord ``c`` is never longer than the robot it stands for, so what
        reaches beyond ``E`` is the backbone's own (the paper method with a base
        just outside the side view, wide-21-1 frame 0: its tip folded back along
        the views' lines of sight, 19 footprints over; good frames of seeds
        1-3 and 5-9 with the base out of a view read at most 3.3 (paper) and
        6.8 (fast) over). Both assume joint values calibrated to the tube's
        exposed length within about a millimetre; a rig whose are not should
        record none (or raise the limits).
    """

    jitter_window_px: int = 1
    align_jitter: bool = False
    aligned_residual_px: float = 0.2
    noise_sigmas: float = 3.0
    margin_dn: float = 4.0
    explain_tolerance_px: float = 3.0
    on_foreground_tolerance_px: float = 1.5
    sample_step_px: float = 1.0
    profile_search_px: float = 6.0
    max_unexplained_fraction: float = 0.10
    max_unexplained_px: float = 8.0
    max_off_foreground_fraction: float = 0.50
    max_off_foreground_run_fraction: float = 0.12
    max_centerline_rms_px: float = 2.5
    max_centerline_local_px: float = 7.0
    centerline_window_px: float = 15.0
    min_section_width_share: float = 0.8
    section_width_window_px: float = 63.0
    max_beyond_tip_contrast: float = 1.3
    max_tip_off_foreground_px: float = 8.0
    max_start_off_foreground_px: float = 8.0
    tip_tangent_px: float = 15.0
    max_tip_overhang_px: float = 8.0
    max_behind_base_px: float = 10.0
    min_visible_px: float = 10.0
    min_profile_fraction: float = 0.2
    roi_margin_px: int = 16
    max_roi_growth: int = 4
    unseen_depths: int = 16
    unseen_slope: float = 1.0
    unseen_depth_mm: float = 2.0
    unseen_samples: int = 400
    unseen_border_px: float = 6.0
    speck_reach: float = 1.0
    contrast_window_px: float = 15.0
    contrast_min: float = 0.4
    contrast_ratio: float = 3.0
    tip_probe_ratio: float = 2.0
    tip_probe_start_px: float = 8.0
    tip_probe_px: float = 12.0
    tip_probe_radii: float = 3.0
    tip_probe_min_px: float = 4.0
    kink_chord_mm: float = 3.0
    max_strain: float = 0.08
    max_kink_px: float = 5.0
    max_start_gap_px: float = 12.0
    min_depth_visibility: float = 0.3
    max_unmeasured_depth_mm: float = 20.0
    max_length_mismatch_fraction: float = 0.10
    max_length_mismatch_px: float = 10.0

    def __post_init__(self):
        if int(self.jitter_window_px) != self.jitter_window_px or self.jitter_window_px < 0:
            raise ValueError("SelfCheckParams: jitter_window_px must be an integer >= 0")
        for name in ("aligned_residual_px", "noise_sigmas", "margin_dn", "explain_tolerance_px", "on_foreground_tolerance_px", "profile_search_px",
                     "min_visible_px", "min_profile_fraction", "min_section_width_share", "section_width_window_px"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"SelfCheckParams: {name} must be >= 0")
        for name in ("sample_step_px", "max_unexplained_fraction", "max_unexplained_px", "max_off_foreground_fraction",
                     "max_off_foreground_run_fraction", "max_centerline_rms_px",
                     "tip_tangent_px", "max_tip_overhang_px", "kink_chord_mm", "max_strain", "max_kink_px", "max_start_gap_px", "max_unmeasured_depth_mm",
                     "max_length_mismatch_fraction", "max_length_mismatch_px"):
            if not getattr(self, name) > 0:
                raise ValueError(f"SelfCheckParams: {name} must be > 0")


@dataclass(frozen=True, eq=False)
class _ViewModel:
    """Per camera: the background mean and the foreground band (gray levels, normalized)."""

    mean: np.ndarray  # (H, W) float32, gain-normalized background mean
    lo: np.ndarray  # (H, W) float32, below this is foreground
    hi: np.ndarray  # (H, W) float32, above this is foreground
    behind: np.ndarray | None  # (H, W) bool, behind the robot base (ignored), or None
    binary: bool = False  # background frames are a mask (only 0 and 1, or only 0 and 255)
    keep: np.ndarray | None = None  # (H, W) uint8, 0 behind the robot base, 255 elsewhere; None: nothing behind
    shift: ShiftModel | None = None  # the backdrop's edges a frame's jitter is measured on; None: frames as they come
    contrast_half: np.ndarray | None = None  # (H, W) float32, the unmoved band's half-width where frames are moved


@dataclass(frozen=True, eq=False)
class SelfCheckModel:
    """What :func:`check_backbone` needs besides a frame: the rig and per-view background bands.

    Attributes
    ----------
    rig : RigCalibration
    views : dict
        Camera name -> background mean and foreground band.
    """

    rig: RigCalibration
    views: dict


@dataclass(frozen=True)
class SelfCheck:
    """The verdict on one backbone.

    Attributes
    ----------
    ok : bool
        False when a judged view exceeds a limit, or no view sees the backbone.
    reason : str or None
        One line naming the camera and the figure furthest beyond its limit,
        e.g. ``"top: 41 % of the reprojected tube is not on foreground (limit 30 %)"``.
    figures : dict
        Camera name -> ``{"unexplained_fraction", "unexplained_px",
        "off_foreground_fraction", "tip_off_foreground_px", "tip_overhang_px", "centerline_rms_px",
        "centerline_max_px", "beyond_tip_contrast", "behind_base_px", "kink_px", "start_gap_px",
        "unmeasured_depth_mm", "length_mismatch_fraction", "length_mismatch_px", "visible_px", "unseen_px"}``
        (None where not measured: view not judged, no clean cross-section for the RMS, no joint values
        for the length, ...). ``behind_base_px``, ``kink_px``, ``start_gap_px``, ``unmeasured_depth_mm``
        and the two length figures are the backbone's, the same in every view.
    ms : float
        Wall time of the check (ms).
    """

    ok: bool
    reason: str | None
    figures: dict = field(default_factory=dict)
    ms: float = 0.0

    def to_dict(self) -> dict:
        """JSON-ready (NaN as None, figures rounded).

        Returns
        -------
        dict
            ``ok`` (bool), ``reason`` (str or None), ``ms`` (wall time, ms, 3 decimals) and
            ``views``: camera name -> the ``figures`` (px, fractions 0-1, contrast) rounded to
            4 decimals, None where not measured or not finite.
        """
        def r(v):
            return None if v is None or not math.isfinite(v) else round(float(v), 4)

        return {"ok": bool(self.ok), "reason": self.reason, "ms": round(float(self.ms), 3),
                "views": {c: {k: r(v) for k, v in f.items()} for c, f in self.figures.items()}}


# ----------------------------------------------------------------------------- images
#: Pixels sampled (on a regular grid) for a gain/offset fit: a few thousand pin both to
#: well under 1 % and keep the fit's medians cheap.
_GAIN_SAMPLES = 2000.0


def _gray(image: np.ndarray, name: str) -> np.ndarray:
    """(H, W) or (H, W, 3) uint8 -> (H, W) uint8; a one-line error otherwise."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        raise ValueError(f"{name}: expected 8-bit images, got {img.dtype}")
    if img.ndim == 3 and img.shape[2] == 3:
        return cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2GRAY)
    if img.ndim != 2:
        raise ValueError(f"{name}: expected an (H, W) or (H, W, 3) image, got shape {img.shape}")
    return img


@dataclass(frozen=True)
class Lighting:
    """A frame's lighting against the background mean: ``frame ~ gain(u, v) * background + offset(u, v)`` (gray levels).

    ``gain(u, v) = gain + gain_u * x + gain_v * y`` and ``offset(u, v) = offset_dn + offset_u_dn * x +
    offset_v_dn * y``, with ``x = u / width - 0.5`` and ``y = v / height - 0.5`` (image frame, px): an
    illumination ramp across the image. On a textured backdrop the ramp is fitted as a gain plane (light
    scales what it falls on), on a uniform one as an offset plane (a gain cannot be told from an offset
    there).
    """

    gain: float = 1.0
    gain_u: float = 0.0
    gain_v: float = 0.0
    offset_dn: float = 0.0
    offset_u_dn: float = 0.0
    offset_v_dn: float = 0.0
    width: int = 1
    height: int = 1

    def _planes(self, u, v) -> tuple:
        """``(gain, offset)`` at pixels ``(u, v)`` (broadcast; float32 arrays, or float32 scalars where flat)."""
        x, y = _unit_coords(u, v, self.width, self.height, np.float32)
        return (_plane(self.gain, self.gain_u, self.gain_v, x, y),
                _plane(self.offset_dn, self.offset_u_dn, self.offset_v_dn, x, y))

    def relight(self, background_dn, u, v) -> np.ndarray:
        """Background gray levels at pixels ``(u, v)`` as this lighting shows them: ``gain * background + offset``.

        Parameters
        ----------
        background_dn : array
            Gray levels of the background mean.
        u, v : arrays
            Their pixels (image frame, px; broadcast against ``background_dn``).

        Returns
        -------
        float32 array
            The background under this frame's lighting.
        """
        g, o = self._planes(u, v)
        return np.asarray(background_dn, np.float32) * g + o

    def normalize(self, values_dn, u, v) -> np.ndarray:
        """Gray levels at pixels ``(u, v)`` brought to the background's lighting: ``(value - offset) / gain``.

        Parameters
        ----------
        values_dn : array
            Gray levels of the frame.
        u, v : arrays
            Their pixels (image frame, px; broadcast against ``values_dn``).

        Returns
        -------
        float32 array
            The gray levels under the background mean's lighting.
        """
        g, o = self._planes(u, v)
        return (np.asarray(values_dn, np.float32) - o) / g

    def normalize_roi(self, image_dn: np.ndarray, x0: int, y0: int) -> np.ndarray:
        """:meth:`normalize` of an image region.

        Parameters
        ----------
        image_dn : (h, w) array
            The region's gray levels.
        x0, y0 : int
            Its top-left pixel in the image (px).

        Returns
        -------
        (h, w) float32 array
            The region under the background mean's lighting.
        """
        h, w = image_dn.shape
        g, o = self._planes(np.arange(x0, x0 + w)[None, :], np.arange(y0, y0 + h)[:, None])
        out = image_dn.astype(np.float32)
        out -= o
        if np.ndim(g) or g != 1.0:  # a flat unit gain (uniform backdrops) divides by nothing
            out /= g
        return out


def _unit_coords(u, v, width: int, height: int, dtype) -> tuple:
    """Pixels ``(u, v)`` (image frame, px) as the coordinates the lighting planes are written in: ``u / width - 0.5``
    and ``v / height - 0.5`` (-0.5 to 0.5 across the image), in ``dtype``."""
    return (np.asarray(u, dtype) / dtype(width) - dtype(0.5), np.asarray(v, dtype) / dtype(height) - dtype(0.5))


def _plane(c0: float, cu: float, cv: float, x: np.ndarray, y: np.ndarray):
    """``c0 + cu x + cv y`` in float32 (broadcast): a scalar where the plane is flat, and where ``x`` and ``y``
    are a row and a column, their outer sum (one (h, w) array, not three)."""
    c0, cu, cv = np.float32(c0), np.float32(cu), np.float32(cv)
    if cu == 0.0 and cv == 0.0:
        return c0
    return np.add(c0 + cu * x, cv * y, dtype=np.float32)


def fit_lighting(image_dn: np.ndarray, background_dn: np.ndarray, u: np.ndarray, v: np.ndarray, shape: tuple,
                 iterations: int = 2) -> Lighting:
    """Robust :class:`Lighting` of a frame over sample pixels.

    Least squares, re-fitted on the samples within 3 robust sigmas (the robot
    and its neighbourhood are a minority of the samples and drop out). Where the
    background has contrast (a standard deviation of 2 gray levels or more over
    the samples), a gain plane and an offset; else an offset plane with the
    gain 1 (a uniform backdrop, binary masks). A gain plane leaving 0.3-3 over
    the samples means the fit follows something other than lighting: the
    offset plane is fitted instead.

    Parameters
    ----------
    image_dn, background_dn : (n,) arrays
        The frame's and the background mean's gray levels at the same pixels.
    u, v : (n,) arrays
        The pixels (image frame, px).
    shape : (height, width)
        The image's size (px).

    Returns
    -------
    Lighting
    """
    i = np.asarray(image_dn, np.float64).ravel()
    b = np.asarray(background_dn, np.float64).ravel()
    u, v = np.asarray(u).ravel(), np.asarray(v).ravel()
    h, w = shape
    x, y = _unit_coords(u, v, w, h, np.float64)
    light = Lighting(offset_dn=float(np.median(i - b)) if i.size else 0.0, width=w, height=h)
    if i.size < 8:
        return light
    keep = np.ones(i.size, bool)
    for _ in range(iterations):
        if keep.sum() < 8:
            break
        light = _lighting_lsq(i[keep], b[keep], x[keep], y[keep], w, h)
        res = i - light.relight(b, u, v)
        mad = float(np.median(np.abs(res[keep] - np.median(res[keep]))))
        keep = np.abs(res) <= 3.0 * max(1.4826 * mad, 1.0) + 2.0
    return light


def _lighting_lsq(i: np.ndarray, b: np.ndarray, x: np.ndarray, y: np.ndarray, w: int, h: int) -> Lighting:
    """One least-squares :class:`Lighting` fit (normalized coordinates ``x``, ``y``); see :func:`fit_lighting`."""
    ones = np.ones_like(i)
    if float(np.std(b)) >= 2.0:
        A = np.stack([b, b * x, b * y, ones], axis=1)
        c = np.linalg.lstsq(A, i, rcond=None)[0]
        gain = c[0] + c[1] * x + c[2] * y
        if np.all(np.isfinite(c)) and gain.min() > 0.3 and gain.max() < 3.0:
            return Lighting(gain=float(c[0]), gain_u=float(c[1]), gain_v=float(c[2]), offset_dn=float(c[3]), width=w, height=h)
    c = np.linalg.lstsq(np.stack([ones, x, y], axis=1), i - b, rcond=None)[0]
    return Lighting(offset_dn=float(c[0]), offset_u_dn=float(c[1]), offset_v_dn=float(c[2]), width=w, height=h)


def _normalized_stack(stack: np.ndarray) -> np.ndarray:
    """Background frames (N, H, W) as float32, each brought to the stack mean's lighting (:func:`fit_lighting`).

    A frame's lighting ramp left in would widen the band by its amplitude (up to
    15-30 gray levels at the border of a plain backdrop), hiding a faint tube.
    """
    f = stack.astype(np.float32)
    mean = f.mean(axis=0)
    H, W = mean.shape
    step = max(1, int(math.sqrt(mean.size / _GAIN_SAMPLES)))
    vs, us = np.mgrid[0:H:step, 0:W:step]
    ms = mean[::step, ::step]
    out = np.empty_like(f)
    for k in range(f.shape[0]):
        out[k] = fit_lighting(f[k, ::step, ::step], ms, us, vs, (H, W)).normalize_roi(f[k], 0, 0)
    return out


def prepare_selfcheck(rig: RigCalibration, background_frames: dict, params: SelfCheckParams = SelfCheckParams()) -> SelfCheckModel:
    """Build the per-view background bands from robot-free frames.

    Parameters
    ----------
    rig : RigCalibration
        Cameras (image sizes, poses) and robot base.
    background_frames : dict
        Camera name -> (N, H, W) or (N, H, W, 3) uint8 robot-free frames,
        N >= 2. Binary masks (all-0 or all-255 frames) work: the band is then
        the value itself plus ``margin_dn``.
    params : SelfCheckParams

    Returns
    -------
    SelfCheckModel

    Raises
    ------
    ValueError
        One line naming the camera: missing, wrong size, fewer than 2 frames.
    """
    views = {}
    for name in rig.names:
        cam = rig[name]
        if name not in background_frames:
            raise ValueError(f"{name}: no background frames")
        stack = np.asarray(background_frames[name])
        if stack.dtype != np.uint8:
            raise ValueError(f"{name}: expected 8-bit background frames, got {stack.dtype}")
        if stack.ndim == 4 and stack.shape[3] == 3:
            stack = np.stack([_gray(s, name) for s in stack])
        if stack.ndim != 3 or stack.shape[0] < 2:
            raise ValueError(f"{name}: need at least 2 background frames as (N, H, W), got shape {stack.shape}")
        if stack.shape[1:] != (cam.height, cam.width):
            raise ValueError(f"{name}: background frames are {stack.shape[2]}x{stack.shape[1]} but the camera is {cam.width}x{cam.height}")
        # Masks come as 0/1 or 0/255: a 0/1 mask is brought to 0/255 here and per frame
        # (check_backbone), else the robot (1) would lie within the band of a 0 background.
        binary = bool(stack.max() <= 1 or np.all((stack == 0) | (stack == 255)))
        if binary:
            stack = np.where(stack > 0, 255, 0).astype(np.uint8)
        mean, lo, hi, shift, contrast_half = _band(stack, binary, params)
        idx = behind_base_pixels(cam, rig.base_point_world_mm, rig.insertion_axis_world, 0.0)
        behind = None
        if idx is not None:
            behind = np.zeros(cam.height * cam.width, bool)
            behind[idx] = True
            behind = behind.reshape(cam.height, cam.width)
        keep = None if behind is None else np.where(behind, 0, 255).astype(np.uint8)
        views[name] = _ViewModel(mean.astype(np.float32), lo.astype(np.float32), hi.astype(np.float32), behind, binary, keep,
                                 shift, contrast_half)
    return SelfCheckModel(rig, views)


def _band(stack: np.ndarray, binary: bool, params: SelfCheckParams) -> tuple:
    """``(mean, lo, hi, shift, contrast_half)``: the background frames' (N, H, W) mean and foreground band (gray
    levels, at the mean's lighting), the :class:`~recon.jitter.ShiftModel` judged frames are moved back by, and
    the half-width contrast is measured in (None: the band's own; ``SelfCheckParams.align_jitter``)."""
    raw = _normalized_stack(stack)
    shift, shifts = _jitter_model(stack) if params.align_jitter and not binary else (None, None)
    if shift is None:
        return (raw.mean(axis=0),) + _window_band(raw, params) + (None, None)
    f = _normalized_stack(np.stack([shifted(s.astype(np.float32), d) for s, d in zip(stack, shifts)]))
    mean = f.mean(axis=0)
    margin = _noise_margin(f, params) + np.float32(params.aligned_residual_px) * _gradient_dn_per_px(mean)
    # Contrast stays in the unmoved band's units: the tip probe's and the contrast support's limits were set
    # there, and in the narrower band's the backdrop just past a tip read as tube (wide-2-39 frame 0, a brick
    # joint just past a right tip: 1.4 over the 1.3 limit).
    lo0, hi0 = _window_band(raw, params)
    return mean, f.min(axis=0) - margin, f.max(axis=0) + margin, shift, 0.5 * (hi0 - lo0)


def _noise_margin(f: np.ndarray, params: SelfCheckParams) -> np.ndarray:
    """(H, W) float32: ``noise_sigmas`` temporal deviations of normalized frames (N, H, W), smoothed over 5x5 px
    (6 frames give a poor per-pixel estimate), plus ``margin_dn`` (gray levels)."""
    sigma = np.sqrt(cv2.blur(f.var(axis=0), (5, 5)))
    return (params.noise_sigmas * sigma + params.margin_dn).astype(np.float32)


def _window_band(f: np.ndarray, params: SelfCheckParams) -> tuple:
    """``(lo, hi)`` of normalized frames (N, H, W): their minimum eroded and maximum dilated over the jitter window
    (``jitter_window_px``), less and plus :func:`_noise_margin` (gray levels)."""
    margin = _noise_margin(f, params)
    lo, hi = f.min(axis=0), f.max(axis=0)
    w = int(params.jitter_window_px)
    if w:
        kernel = np.ones((2 * w + 1, 2 * w + 1), np.uint8)
        lo, hi = cv2.erode(lo, kernel), cv2.dilate(hi, kernel)
    return lo - margin, hi + margin


def _jitter_model(stack: np.ndarray) -> tuple:
    """``(model, shifts)``: the edges of the background frames' mean that a frame's jitter is measured on
    (:func:`recon.jitter.prepare_shift`) and the frames' shifts (N, 2) px; ``(None, None)`` where there are too
    few, or where the backdrop's flicker under the frames' jitter (its steepest gradients times the largest
    shift) stays under the pixel noise: there the window holds it and resampling would only blur (the paper
    scene: a plain backdrop with a few static edges)."""
    noise = pixel_noise(stack)
    model = prepare_shift(stack.astype(np.float32).mean(axis=0), noise)
    if model is None:
        return None, None
    shifts = np.array([frame_shift(model, f) for f in stack])
    if float(np.abs(shifts).max()) * model.texture_dn_per_px < noise:
        return None, None
    return model, shifts


def _gradient_dn_per_px(image: np.ndarray) -> np.ndarray:
    """(H, W) float32 gradient magnitude (gray levels per px, 3x3 Sobel)."""
    gx = cv2.Sobel(image, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(image, cv2.CV_32F, 0, 1, ksize=3)
    return cv2.magnitude(gx, gy) / np.float32(8.0)


def foreground_roi(view: _ViewModel, gray: np.ndarray, roi: tuple, exclude: np.ndarray | None = None) -> np.ndarray:
    """Foreground of a gray image in a region of interest, against the background band.

    Parameters
    ----------
    view : the camera's background model
    gray : (H, W) uint8
        The frame, full size; moved back by its jitter first where the view measures it.
    roi : (x0, y0, x1, y1)
        Pixel bounds, x1 and y1 exclusive.
    exclude : (h, w) bool, optional
        Pixels of the region left out of the gain fit (where the robot is claimed to be).

    Returns
    -------
    (h, w) bool
        Foreground (in the background's pixel frame); False behind the robot base.
    """
    return _foreground_u8(view, _steadied(view, gray), roi, None if exclude is None else np.asarray(exclude, np.uint8))[0] > 0


def _steadied(view: _ViewModel, gray: np.ndarray) -> np.ndarray:
    """``gray`` moved back by its image shift onto the background frames, moved back alike, where the view
    measures the jitter (``SelfCheckParams.align_jitter``); else as it is."""
    return gray if view.shift is None else shifted(gray, frame_shift(view.shift, gray))


def _foreground_u8(view: _ViewModel, gray: np.ndarray, roi: tuple, exclude: np.ndarray | None = None) -> tuple:
    """:func:`foreground_roi` as a (h, w) uint8 mask (255 foreground), in OpenCV passes; ``exclude`` nonzero = left out.

    Returns ``(mask, lighting)``: the mask and the fitted :class:`Lighting`.
    """
    x0, y0, x1, y1 = roi
    img = gray[y0:y1, x0:x1]
    mean = view.mean[y0:y1, x0:x1]
    h, w = img.shape
    step = max(1, int(math.sqrt(h * w / _GAIN_SAMPLES)))
    sub = np.ones((len(range(0, h, step)), len(range(0, w, step))), bool)
    if exclude is not None:
        sub &= exclude[::step, ::step] == 0
    if view.behind is not None:
        sub &= ~view.behind[y0:y1:step, x0:x1:step]
    vs, us = np.mgrid[y0:y1:step, x0:x1:step]
    light = fit_lighting(img[::step, ::step][sub], mean[::step, ::step][sub], us[sub], vs[sub], gray.shape)
    norm = light.normalize_roi(img, x0, y0)
    fg = cv2.bitwise_not(cv2.inRange(norm, view.lo[y0:y1, x0:x1], view.hi[y0:y1, x0:x1]))
    if view.keep is not None:
        fg = cv2.bitwise_and(fg, view.keep[y0:y1, x0:x1])
    return fg, light


_CLOSE_KERNEL = np.ones((3, 3), np.uint8)

#: Development aid: set to a dict and each judged view's intermediates (region, foreground, band) are kept in it.
_DEBUG = None

# ----------------------------------------------------------------------------- reprojection
def _dense_projection(camera, points_world_mm: np.ndarray, step_px: float) -> tuple:
    """Backbone points subdivided so that consecutive projections are <= step_px apart.

    Returns
    -------
    uv : (m, 2) pixels (NaN behind the camera); depth_mm : (m,)
    """
    uv, _ = camera.project(points_world_mm)
    seg = np.linalg.norm(np.diff(uv, axis=0), axis=1)
    seg = np.where(np.isfinite(seg), seg, 0.0)
    n_sub = np.clip(np.ceil(seg / step_px).astype(int), 1, 10000)
    i0 = np.append(np.repeat(np.arange(n_sub.size), n_sub), n_sub.size - 1)
    start = np.repeat(np.cumsum(n_sub) - n_sub, n_sub)
    t = np.append((np.arange(start.size) - start) / np.repeat(n_sub, n_sub), 1.0)
    p = points_world_mm[i0] * (1.0 - t[:, None]) + points_world_mm[i0 + 1] * t[:, None]
    return camera.project(p)


def _normals(uv: np.ndarray) -> np.ndarray:
    """Unit normals (m, 2) of a densely sampled image curve."""
    d = np.gradient(uv, axis=0) if len(uv) > 1 else np.array([[1.0, 0.0]])
    n = np.stack([-d[:, 1], d[:, 0]], axis=1)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(norm > 1e-9, n / np.where(norm > 1e-9, norm, 1.0), np.array([0.0, 1.0]))


def _cut_tip_cap(band: np.ndarray, uv_roi: np.ndarray, r_band_px: float, tol_px: float) -> None:
    """Square off the band at the tip: a thick line's round cap would explain a missing tip as long as the radius.

    Pixels within the band's radius of the reprojected tip and more than
    ``tol_px`` beyond it along the tip's tangent are removed from ``band`` (in place).
    """
    tip = uv_roi[-1]
    back = uv_roi[max(0, len(uv_roi) - 4)]
    d = tip - back
    n = float(np.hypot(*d))
    if n < 1e-6:
        return
    d = d / n
    h, w = band.shape
    r = int(math.ceil(r_band_px)) + 2
    x0, x1 = max(0, int(tip[0]) - r), min(w, int(tip[0]) + r + 1)
    y0, y1 = max(0, int(tip[1]) - r), min(h, int(tip[1]) + r + 1)
    if x0 >= x1 or y0 >= y1:
        return
    yy, xx = np.mgrid[y0:y1, x0:x1]
    beyond = (xx - tip[0]) * d[0] + (yy - tip[1]) * d[1] > tol_px
    band[y0:y1, x0:x1][beyond] = 0


def _longest_run(mask: np.ndarray) -> int:
    """The length (samples) of the longest run of True in a 1-D bool array (0 when none)."""
    edges = np.diff(np.concatenate([[0], np.asarray(mask, np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return int(np.max(ends - starts)) if starts.size else 0


def _profile_offsets(fg: np.ndarray, uv_roi: np.ndarray, normals: np.ndarray, r_out_px: np.ndarray, r_in_px: np.ndarray,
                     params: SelfCheckParams) -> tuple:
    """Signed distance (px) from each sample to the middle of the foreground run across it, and the run's width (px); NaN where unclean.

    The run is the one nearest the sample along the normal, within the
    outermost radius plus ``profile_search_px``; it must be bounded by
    background on both sides inside the region, no wider than the tube plus
    the explain tolerance on each side, and at least 1.5 inner radii wide (a
    run that covers only one side of the tube would bias the middle). Gaps up
    to the outer radius inside a run are bridged first.
    """
    dt = 0.5
    half = float(np.max(r_out_px)) + params.profile_search_px
    t = np.arange(-half, half + 1e-9, dt)
    K = t.size
    pts = uv_roi[:, None, :] + t[None, :, None] * normals[:, None, :]
    u = np.rint(pts[..., 0]).astype(np.int64)
    v = np.rint(pts[..., 1]).astype(np.int64)
    h, w = fg.shape
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    P = np.zeros(u.shape, bool)
    P[inside] = fg[v[inside], u[inside]]
    out = np.full(len(uv_roi), np.nan)
    has = P.any(axis=1)
    if not has.any():
        return out, out.copy()
    ar = np.arange(K)[None, :]
    # Bridge gaps up to the outer radius: a metallic tube often has a stripe as bright as
    # the backdrop along it, which splits its cross-section into two runs.
    prev_fg = np.maximum.accumulate(np.where(P, ar, -1), axis=1)
    next_fg = np.minimum.accumulate(np.where(P, ar, K)[:, ::-1], axis=1)[:, ::-1]
    gap = (next_fg - prev_fg - 1) * dt
    P = P | ((prev_fg >= 0) & (next_fg < K) & (gap <= r_out_px[:, None]))
    j0 = np.argmin(np.where(P, np.abs(t)[None, :], np.inf), axis=1)
    left_bg = np.maximum.accumulate(np.where(~P, ar, -1), axis=1)
    right_bg = np.minimum.accumulate(np.where(~P, ar, K)[:, ::-1], axis=1)[:, ::-1]
    rows = np.arange(len(uv_roi))
    lb = left_bg[rows, j0]
    rb = right_bg[rows, j0]
    bounded = (lb >= 0) & (rb < K)
    lb_c = np.clip(lb, 0, K - 1)
    rb_c = np.clip(rb, 0, K - 1)
    # A run that ends at the region's (or image's) edge has an unknown extent.
    bounded &= inside[rows, lb_c] & inside[rows, rb_c]
    width = (rb - lb - 1) * dt
    good = has & bounded & (width <= 2.0 * (r_out_px + params.explain_tolerance_px)) & (width >= 1.5 * r_in_px)
    mid = 0.5 * (t[np.clip(lb + 1, 0, K - 1)] + t[np.clip(rb - 1, 0, K - 1)])
    out[good] = mid[good]
    widths = np.full(len(uv_roi), np.nan)
    widths[good] = width[good]
    return out, widths


def _contrast_profiles(view: _ViewModel, gray: np.ndarray, lighting: Lighting, uv: np.ndarray, normals: np.ndarray,
                       r_out_px: np.ndarray, r_in_px: np.ndarray, params: SelfCheckParams) -> tuple:
    """Per point: the image's difference from the background across the tube's middle, and just beside the band.

    The difference is ``|frame - background mean|`` over the band's half-width
    (gain-normalized frame; the unmoved band's where frames are moved back by
    their jitter), the most of 5 samples across ``+- r_in`` of the
    point (``centre``), and the most of 5 samples over ``2 r_in`` just outside
    the band, on the quieter of the two sides (``beside``).
    """
    ri = np.maximum(r_in_px, 1.0)

    h, w = gray.shape

    def excess(pts):  # nearest pixel, NaN outside the image; indices computed once for the four arrays
        u = np.rint(pts[..., 0]).astype(np.int64)
        v = np.rint(pts[..., 1]).astype(np.int64)
        ins = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        ui, vi = u[ins], v[ins]
        half = 0.5 * (view.hi[vi, ui] - view.lo[vi, ui]) if view.contrast_half is None else view.contrast_half[vi, ui]
        half = np.maximum(half, 1.0)
        out = np.full(u.shape, np.nan, np.float32)
        out[ins] = np.abs(lighting.normalize(gray[vi, ui], ui, vi) - view.mean[vi, ui]) / half
        return out

    def most(x):  # max across, -inf where all outside the image
        return np.max(np.where(np.isnan(x), -np.inf, x), axis=1)

    k = np.linspace(-1.0, 1.0, 5)[None, :]
    centre = most(excess(uv[:, None, :] + (k * ri[:, None])[..., None] * normals[:, None, :]))
    t = (r_out_px + params.explain_tolerance_px + 1.0)[:, None] + (0.5 * (k + 1.0)) * (2.0 * ri[:, None])
    side_p = most(excess(uv[:, None, :] + t[..., None] * normals[:, None, :]))
    side_m = most(excess(uv[:, None, :] - t[..., None] * normals[:, None, :]))
    beside = np.minimum(np.where(np.isfinite(side_p), side_p, np.inf), np.where(np.isfinite(side_m), side_m, np.inf))
    return centre, beside


def _contrast_support(view: _ViewModel, gray: np.ndarray, lighting: Lighting, uv: np.ndarray, normals: np.ndarray,
                      r_out_px: np.ndarray, r_in_px: np.ndarray, params: SelfCheckParams) -> np.ndarray:
    """(m,) bool: centerline samples where the image differs from the background along the tube more than beside it.

    A tube as bright as a textured backdrop leaves stretches with no pixel out
    of the band, yet it still changes the image a little all along: the
    difference from the background across the tube's middle
    (:func:`_contrast_profiles`), the median over ``contrast_window_px`` samples
    along the curve, against the same taken just outside the band. A sample is
    supported when the average along the tube exceeds ``contrast_min`` and
    ``contrast_ratio`` times that beside it; a backbone over bare backdrop is
    not (the two are alike there).
    """
    centre, beside = _contrast_profiles(view, gray, lighting, uv, normals, r_out_px, r_in_px, params)
    centre = np.where(np.isfinite(centre), centre, 0.0)
    beside = np.where(np.isfinite(beside), beside, centre)
    win = max(1, int(round(params.contrast_window_px / params.sample_step_px)))
    along, ref = _running_median(centre, win), _running_median(beside, win)
    return (along > params.contrast_min) & (along > params.contrast_ratio * ref)


def _running_median(x: np.ndarray, win: int) -> np.ndarray:
    """Median over ``win`` consecutive samples centred on each (the ends padded by reflection).

    A median, not a mean: one dark speck on the line would carry a mean alone. Reflected, not
    repeated, at the ends: repeated, the last sample filled half of the last window, and one
    noisy sample at the end of a backbone that ran on past the tip carried the median there.
    """
    if win <= 1 or len(x) == 0:
        return x.copy()
    h = win // 2
    xp = np.pad(x, (h, win - 1 - h), mode="reflect" if len(x) > 1 else "edge")
    return np.median(np.lib.stride_tricks.sliding_window_view(xp, win), axis=1)


def _tip_direction(uv_curve: np.ndarray, n_back: int) -> tuple | None:
    """``(tip, unit direction)`` of a densely sampled image curve's end, over its last ``n_back`` samples; None where it has fewer or they coincide."""
    if n_back < 1 or len(uv_curve) <= n_back:
        return None
    tip = uv_curve[-1]
    d = tip - uv_curve[-1 - n_back]
    nd = float(np.hypot(*d))
    return None if nd < 1e-6 else (tip, d / nd)


def _beyond_tip(view: _ViewModel, gray: np.ndarray, lighting: Lighting, uv_curve: np.ndarray, r_out_tip: float,
                r_in_tip: float, params: SelfCheckParams, end_face_px: float = 0.0, across: float = 1.0) -> float | None:
    """Tube contrast on the backbone's continuation beyond its reprojected tip, over what would flag it (> 1: the tube goes on).

    Samples every px from ``tip_probe_start_px * across + end_face_px``
    (``across``: the tip tangent's sine to the viewing ray, the image length
    of a footprint along the tube there) to that plus
    ``max(tip_probe_px, tip_probe_radii * r_out)`` beyond the tip along the
    tip's tangent (taken over the last ``max(2 r_out, tip_tangent_px)`` px);
    their difference from
    the background across the middle against beside
    (:func:`_contrast_profiles`): ``best_centre / max(contrast_min,
    tip_probe_ratio * mean_beside)``, ``best_centre`` the largest mean over
    the probe's first k >= ``tip_probe_min_px`` samples (means, not medians: a
    faint tube's difference is spotty, and medians or the weaker half of the
    probe left the faint short tips of the wide suite silent); None when less than
    half of the probe is in the image.
    """
    # The tangent over tip_tangent_px at least, as the overhang takes it: over the last few px the
    # tangent of a backbone that wiggles or hooks at its end points off a thin tube, and the probe
    # missed it (paper, wide-3-35 frame 1: 127 footprints short, the side view's tube plain beyond).
    n_back = max(2.0 * r_out_tip, params.tip_tangent_px) / params.sample_step_px
    end = _tip_direction(uv_curve, min(len(uv_curve) - 1, max(2, int(math.ceil(n_back)))))
    if end is None:
        return None
    tip, d = end
    # The start is 8 footprints short along the tube, 8 |sin| px in this view: a tube pointing partly at the
    # camera shows a tip 14 footprints short as 8 px (paper, wide-3-6 frame 2, top view: reported ok).
    start = params.tip_probe_start_px * across + end_face_px
    dist = np.arange(start, start + max(params.tip_probe_px, params.tip_probe_radii * r_out_tip) + 1e-9, 1.0)
    pts = tip[None, :] + dist[:, None] * d[None, :]
    h, w = gray.shape
    inside = (pts[:, 0] >= 0) & (pts[:, 0] <= w - 1) & (pts[:, 1] >= 0) & (pts[:, 1] <= h - 1)
    if inside.mean() < 0.5:
        return None
    pts = pts[inside]
    nrm = np.repeat(np.array([[-d[1], d[0]]]), len(pts), axis=0)
    centre, beside = _contrast_profiles(view, gray, lighting, pts, nrm, np.full(len(pts), r_out_tip),
                                        np.full(len(pts), r_in_tip), params)
    ok = np.isfinite(centre) & np.isfinite(beside)
    if ok.sum() < 0.5 * len(dist):
        return None
    # A tube that goes on a little past the start is diluted by the bare backdrop after it in the whole probe's mean.
    c = centre[ok]
    k_min = min(len(c), max(1, int(round(params.tip_probe_min_px))))
    best = float(np.max((np.cumsum(c) / np.arange(1, len(c) + 1))[k_min - 1:]))
    return best / max(params.contrast_min, params.tip_probe_ratio * float(np.mean(beside[ok])))


def _end_face_share(camera, points_world_mm: np.ndarray, chord_mm: float) -> float:
    """How far the tube's end face reaches beyond the reprojected tip, in tube radii: ``|t . ray|`` (0-1).

    The flat end face of a tube is a disk across its tangent ``t`` (over the last
    ``chord_mm``); seen along the viewing ray to the tip it projects to an ellipse
    whose half-extent along the projected tangent is the radius times ``|t . ray|``:
    none for a tube across the view, the whole radius for one pointing at the
    camera (wide-2-14 frame 2, side view: a 17 px radius, the end face 15 px beyond
    the tip, where the probe starting 8 px out read the face as tube going on).
    """
    s = arc_length(points_world_mm)
    back = points_at_arc_length(points_world_mm, [max(0.0, s[-1] - chord_mm)])[0]
    return camera.ray_cosine(points_world_mm[-1], points_world_mm[-1] - back)


def _unseen_share(camera, others: list, ys: np.ndarray, xs: np.ndarray, uv_bb: np.ndarray, depth_bb: np.ndarray,
                  params: SelfCheckParams) -> float:
    """Share of pixels (ys, xs) of ``camera`` that no camera of ``others`` can see at any plausible depth.

    The tube is continuous: a pixel of robot foreground ``d`` px from the
    nearest reprojected backbone sample (depth ``z``) lies at a depth within
    ``z +- (unseen_slope * d * z / f + unseen_depth_mm)`` -- the tube between
    them inclined at most ``atan(unseen_slope)`` out of the image plane. Each
    pixel is back-projected at ``unseen_depths`` depths across that range and
    the points projected into the other cameras; a pixel is unseen when none
    of its points lands in front of, and inside the image of (``unseen_border_px``
    in from the border), any of them. Up to ``unseen_samples`` pixels (every
    k-th) stand for all.
    """
    n = ys.size
    if n == 0 or not others:
        return 0.0
    k = max(1, int(math.ceil(n / params.unseen_samples)))
    uv = np.stack([xs[::k], ys[::k]], axis=1).astype(np.float64)
    # Nearest backbone sample of each pixel (the backbone subsampled to at most 128 samples:
    # the depth changes little between them, and the distance is rounded up by the spacing).
    step = max(1, int(math.ceil(len(uv_bb) / 128)))
    bb, zb = uv_bb[::step], depth_bb[::step]
    du = uv[:, 0:1] - bb[None, :, 0]
    dv = uv[:, 1:2] - bb[None, :, 1]
    d2 = du * du + dv * dv
    j = np.argmin(d2, axis=1)
    z0 = zb[j]
    f_px = math.sqrt(camera.K[0, 0] * camera.K[1, 1])
    dz = params.unseen_slope * np.sqrt(d2[np.arange(len(uv)), j]) * z0 / f_px + params.unseen_depth_mm
    t = np.linspace(-1.0, 1.0, int(params.unseen_depths))
    z = np.maximum(z0[:, None] + dz[:, None] * t[None, :], 1e-3)
    xy = camera.pixels_to_normalized(uv)
    pc = np.concatenate([xy[:, None, :] * z[:, :, None], z[:, :, None]], axis=2)
    pw = transform_points(camera.T_world_cam, pc.reshape(-1, 3))
    seen = np.zeros(pw.shape[0], bool)
    for cam in others:
        uvo, d = cam.project(pw)
        ok = np.all(np.isfinite(uvo), axis=1) & (d > 1e-6)
        seen |= ok & cam.in_image(np.where(ok[:, None], uvo, -1e9), params.unseen_border_px)
    return float(np.mean(~seen.reshape(len(xy), z.shape[1]).any(axis=1)))


def _band_and_foreground(view: _ViewModel, camera, gray: np.ndarray, uv_curve: np.ndarray, roi: list, r_band: float,
                         params: SelfCheckParams) -> tuple:
    """The reprojected tube's band and the foreground in a region of interest, grown until the robot's foreground fits.

    Returns ``(roi, band, fg, labels, stats, band_lab, touching, lighting)``: the final
    region ``[x0, y0, x1, y1]`` (px), the band and foreground masks (uint8, region
    coordinates), the foreground's connected components with their stats, the
    component labels under the band, the labels touching it, and the fitted
    :class:`Lighting`.
    """
    W, H = camera.width, camera.height
    thickness = 2 * int(math.ceil(r_band)) + 1
    # The band's outline: every 4th dense sample is close enough to the curve for a thick line.
    poly = uv_curve
    poly = np.concatenate([poly[:-1:4], poly[-1:]])
    for _ in range(int(params.max_roi_growth) + 1):
        x0, y0, x1, y1 = roi
        band = np.zeros((y1 - y0, x1 - x0), np.uint8)
        # Sub-pixel polyline (4 fractional bits); the tube drawn with its outermost radius plus the tolerance.
        pl = np.rint((poly - [x0, y0]) * 16).astype(np.int32)
        cv2.polylines(band, [pl.reshape(-1, 1, 2)], False, 1, thickness=thickness, lineType=cv2.LINE_8, shift=4)
        _cut_tip_cap(band, uv_curve - [x0, y0], r_band, params.explain_tolerance_px)
        fg, lighting = _foreground_u8(view, gray, tuple(roi), exclude=band)
        # Close 1-px cracks (specular highlights as bright as the backdrop) before measuring runs and regions.
        fg = cv2.morphologyEx(fg, cv2.MORPH_CLOSE, _CLOSE_KERNEL)
        if view.keep is not None:
            fg = cv2.bitwise_and(fg, view.keep[y0:y1, x0:x1])
        n_lab, labels, stats, _ = cv2.connectedComponentsWithStats(fg, connectivity=8)
        band_px = cv2.findNonZero(band)
        band_px = np.zeros((0, 2), np.int32) if band_px is None else band_px.reshape(-1, 2)
        band_lab = labels[band_px[:, 1], band_px[:, 0]]
        band_lab = band_lab[band_lab > 0]
        touching = np.unique(band_lab)
        grow = [False] * 4
        for lab in touching:
            lx, ly, lw, lh = stats[lab, :4]
            grow[0] |= lx == 0 and x0 > 0
            grow[1] |= ly == 0 and y0 > 0
            grow[2] |= lx + lw == x1 - x0 and x1 < W
            grow[3] |= ly + lh == y1 - y0 and y1 < H
        if not any(grow):
            break
        # Robot foreground runs out of the region: double it towards those sides and look again.
        dx, dy = x1 - x0, y1 - y0
        roi = [max(0, x0 - dx) if grow[0] else x0, max(0, y0 - dy) if grow[1] else y0,
               min(W, x1 + dx) if grow[2] else x1, min(H, y1 + dy) if grow[3] else y1]
    return roi, band, fg, labels, stats, band_lab, touching, lighting


def _drop_specks(band: np.ndarray, labels: np.ndarray, stats: np.ndarray, touching: np.ndarray, n_unexplained: int,
                 r_out_median_px: float, params: SelfCheckParams) -> tuple:
    """Unexplained foreground less the specks clinging to the band: ``(n_unexplained, ys, xs)`` (pixel count, kept pixels in region coordinates)."""
    # Only what reaches well away from the band can be tube: noise specks clinging to it (a
    # frame noisier than its backgrounds) reach a few px, a tube the band left out (a tip
    # cut short, a backbone that left the tube) runs on. Pieces of the unexplained foreground
    # that reach less than ``speck_reach`` tube diameters (plus the tolerance) from the band
    # are dropped. Measured only where the length could fail (distance transform).
    ys, xs = [], []
    not_band = (band == 0).view(np.uint8)
    dist = cv2.distanceTransform(not_band, cv2.DIST_L2, 3)
    reach = params.speck_reach * 2.0 * r_out_median_px + params.explain_tolerance_px
    # A piece with the area of max_unexplained_px of the whole tube's width is tube, however near the band
    # it stays: a thick tube's 20 px beyond a backbone that hooked away from it (wide-2-15 frame 0, 577 px)
    # reaches less than a diameter from the band.
    big = params.max_unexplained_px * 2.0 * r_out_median_px
    for lab in touching:
        lx, ly, lw, lh = (int(v) for v in stats[lab, :4])
        m = (labels[ly:ly + lh, lx:lx + lw] == lab).view(np.uint8)
        m[band[ly:ly + lh, lx:lx + lw] != 0] = 0
        n_p, lab_p, st_p, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
        dsub = dist[ly:ly + lh, lx:lx + lw]
        for q in range(1, n_p):
            qx, qy, qw, qh = (int(v) for v in st_p[q, :4])
            mq = lab_p[qy:qy + qh, qx:qx + qw] == q
            if float(dsub[qy:qy + qh, qx:qx + qw][mq].max()) < reach and st_p[q, cv2.CC_STAT_AREA] < big:
                n_unexplained -= int(st_p[q, cv2.CC_STAT_AREA])
                continue
            py, px = np.nonzero(mq)
            xs.append(px + qx + lx)
            ys.append(py + qy + ly)
    ys = np.concatenate(ys) if ys else np.zeros(0, int)
    xs = np.concatenate(xs) if xs else np.zeros(0, int)
    return n_unexplained, ys, xs


def _unseen_share_of(camera, others, ys: np.ndarray, xs: np.ndarray, uvv: np.ndarray, depth_vis: np.ndarray,
                     points_world_mm: np.ndarray, base_world_mm, params: SelfCheckParams) -> float:
    """Share of the unexplained pixels (image rows ``ys``, columns ``xs``) that no other camera can see."""
    # Foreground no other camera can see (the robot entering across a border of only this
    # view) cannot be triangulated by any method: it is not required. Measured only where
    # it could matter (it is the costly part).
    uv_g, depth_g = uvv, depth_vis
    if base_world_mm is not None:
        # The robot leaves the base: a backbone that starts where both cameras first see the
        # robot continues, unreconstructed, on the line back to the base (near it the tube is
        # straight). Its samples (in the image or not) pin the depth of the foreground there,
        # where the distance to the reconstructed samples alone would allow any inclination.
        lead = np.stack([np.asarray(base_world_mm, np.float64), points_world_mm[0]])
        if np.linalg.norm(lead[1] - lead[0]) > 1e-6:
            uvl, dl = _dense_projection(camera, lead, params.sample_step_px)
            okl = np.all(np.isfinite(uvl), axis=1) & (dl > 1e-6)
            uv_g, depth_g = np.concatenate([uvl[okl], uvv]), np.concatenate([dl[okl], depth_g])
    return _unseen_share(camera, list(others), ys, xs, uv_g, depth_g, params)


def _unsupported_end_px(on: np.ndarray, r_out_end: float, params: SelfCheckParams) -> float | None:
    """Length (px) of the run of unsupported samples that ends ``on`` (judged samples in order), or None.

    None unless the foreground or the tube's contrast shows the tube just before
    that run (at least half of the ``2 r_out_end`` px there, at least 5 px): where
    neither does, the tube is too faint to tell where it ends.
    """
    n_tail = int(np.argmax(on[::-1])) if on.any() else on.size
    n_pre = max(5, int(math.ceil(2.0 * r_out_end / params.sample_step_px)))
    pre = on[max(0, on.size - n_tail - n_pre):on.size - n_tail]
    return n_tail * params.sample_step_px if pre.size and pre.mean() >= 0.5 else None


def _tip_figures(view: _ViewModel, gray: np.ndarray, lighting: Lighting, uv: np.ndarray, finite: np.ndarray,
                 vis: np.ndarray, on: np.ndarray, r_out: np.ndarray, r_in: np.ndarray,
                 face_share: float | None, params: SelfCheckParams) -> tuple:
    """``(tip_off_foreground_px, beyond_tip_contrast)`` of one view, each None where not measured.

    ``uv`` the dense reprojection, ``finite`` and ``vis`` its finite and judged samples,
    ``on`` per judged sample: supported (foreground or contrast),
    ``r_out`` / ``r_in`` the radii (px) per dense sample, ``face_share`` the end face's
    reach beyond the tip in tube radii (:func:`_end_face_share`), None where the tip probe
    does not run.
    """
    # The end of the judged curve with nothing on it: a backbone that runs on beyond the tip
    # (the share above hides a 20 px overrun of a long robot). Only where the foreground or the
    # tube's contrast shows the tube just before (at least half of the 2 r_out px, >= 5 px): where
    # neither does, the tube is too faint to tell where it ends (the tip probe's case). A faint tube
    # that its contrast alone shows ends where that contrast ends (wide-3-48 frame 1 of the fast
    # method: a side view followed 67 px of fabric on past the tip, 47 footprints, no foreground before).
    tip_off = _unsupported_end_px(on, float(r_out[vis][-1]), params)
    beyond = None
    if face_share is not None:
        # The tip itself is in view (not behind the base): does the tube go on beyond it?
        r_tip = float(r_out[finite][-1])
        beyond = _beyond_tip(view, gray, lighting, uv[finite], r_tip, float(r_in[finite][-1]), params, r_tip * face_share,
                             math.sqrt(max(0.0, 1.0 - face_share ** 2)))
    return tip_off, beyond


def _tip_overhang_px(fg: np.ndarray, uv_roi: np.ndarray, r_in_tip: float, end_face_px: float, params: SelfCheckParams) -> float | None:
    """How far (px) the foreground runs on beyond the reprojected tip (``SelfCheckParams.max_tip_overhang_px``); None where not measured.

    ``fg`` the region's foreground, ``uv_roi`` the judged samples in region coordinates
    (tip last, in the image), ``r_in_tip`` the innermost radius there (px),
    ``end_face_px`` how far the tube's end face reaches beyond the tip (px).
    """
    end = _tip_direction(uv_roi, min(len(uv_roi) - 1, max(1, int(math.ceil(params.tip_tangent_px / params.sample_step_px)))))
    if end is None:
        return None
    tip, d = end
    dt = 0.5
    half = r_in_tip + params.on_foreground_tolerance_px
    across = np.arange(-half, half + 1e-9, dt)
    # Far enough to read a tip well beyond the limit, never beyond the region.
    along = np.arange(0.0, min(8.0 * params.max_tip_overhang_px + end_face_px, float(np.hypot(*fg.shape))), dt)
    pts = tip + along[:, None, None] * d + across[None, :, None] * np.array([-d[1], d[0]])
    u, v = np.rint(pts[..., 0]).astype(np.int64), np.rint(pts[..., 1]).astype(np.int64)
    h, w = fg.shape
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    hit = np.zeros(u.shape, bool)
    hit[inside] = fg[v[inside], u[inside]] != 0
    has = hit.any(axis=1)
    # The run ends at the first gap of 2 px (a 1-px crack of a specular tube does not end it).
    gap = int(round(2.0 / dt))
    blocked = np.convolve(~has, np.ones(gap, int), mode="valid") == gap
    end = int(np.argmax(blocked)) if blocked.any() else along.size
    run = float(along[np.flatnonzero(has[:end])[-1]]) if has[:end].any() else 0.0
    return max(0.0, run - end_face_px)


def _one_sided(offs: np.ndarray, widths: np.ndarray, r_out_px: np.ndarray, params: SelfCheckParams) -> np.ndarray:
    """(m,) bool: clean cross-sections (offsets and widths px, base first) that cover one side of the tube only.

    A run much narrower than its neighbours covers one side of the tube only (the other side as bright as
    the backdrop): its middle is off the axis by up to a radius (wide-3-3 frame 2 of the fast method, wood
    grain across a three-tube robot: 2.5 px RMS, the backbone 0.9 footprints off). So does one narrower
    than the widest stretch from there on to the tip, however long it is: the tubes only get thinner
    towards the tip (wide-2-4: the outer tube's shaded half as dark as the backdrop over its first 84 px,
    both methods' backbones flagged 10.4 px off its middle). Only stretches centred on the backbone set
    that width: a run merged with clutter is wide and off centre (wide-5-25 frame 0 of the paper method:
    84 px of them at the tip). And only a run that reaches the edge of a section of that width centred on
    the backbone is a side of it: a narrower run inside is measured (a thinner tube off the backbone; left
    out, wide-6-43 frame 1 of the fast method lost the figure that flagged it). Widths in outer radii
    (``r_out_px`` per section): depth changes them.
    """
    w = widths / r_out_px
    n_win = max(1, int(round(params.section_width_window_px / (3 * params.sample_step_px))))
    narrow = w < params.min_section_width_share * _running_median(w, min(n_win, w.size))
    centred = np.flatnonzero(np.abs(offs) <= params.on_foreground_tolerance_px)
    if centred.size:
        tipward = np.maximum.accumulate(_running_median(w[centred], min(n_win, centred.size))[::-1])[::-1]
        after = np.searchsorted(centred, np.arange(w.size))  # the first centred section at or after each
        ref = np.where(after < centred.size, tipward[np.minimum(after, centred.size - 1)], 0.0)
        reach = np.abs(offs) + 0.5 * widths  # the run's far edge from the sample (px)
        side = np.abs(reach - 0.5 * ref * r_out_px) <= params.on_foreground_tolerance_px + 1.0
        narrow |= (w < params.min_section_width_share * ref) & side
    return narrow


def _centerline_figures(fg: np.ndarray, uv_roi: np.ndarray, normals: np.ndarray, r_out_px: np.ndarray, r_in_px: np.ndarray,
                        params: SelfCheckParams) -> tuple:
    """``(centerline_rms_px, centerline_max_px)`` of one view's judged samples (region coordinates), None where too few clean sections."""
    # (c) centerline offset across the tube, on every third sample (the RMS needs no more).
    sub = slice(None, None, 3)
    offs, widths = _profile_offsets(fg, uv_roi[sub], normals[sub], r_out_px[sub], r_in_px[sub], params)
    good = np.isfinite(offs)
    if params.min_section_width_share > 0 and good.sum() >= 3:
        idx = np.flatnonzero(good)
        good[idx[_one_sided(offs[good], widths[good], r_out_px[sub][good], params)]] = False
    enough = good.sum() >= max(10.0, params.min_profile_fraction * offs.size)
    rms = float(np.sqrt(np.mean(offs[good] ** 2))) if enough else None
    # (c') the largest offset over a stretch: a bump where the method's centerline left the tube for
    # a few tube widths hardly moves the RMS of a long robot.
    win = max(1, int(round(params.centerline_window_px / (3 * params.sample_step_px))))
    local = float(np.max(np.abs(_running_median(offs[good], win)))) if enough and good.sum() >= win else None
    return rms, local


def _judge_view(view: _ViewModel, camera, gray: np.ndarray, points_world_mm: np.ndarray, radii_mm: tuple,
                params: SelfCheckParams, others: list = (), base_world_mm=None) -> dict:
    """The three figures of one view (None where not measured).

    ``others``: the rig's other cameras; robot foreground that none of them can
    see (outside their images at every plausible depth) need not be explained.
    ``base_world_mm``: the robot base; the straight line from it to the
    backbone's first point guides the depth of that test for the stretch a
    method leaves out because only this view sees it.
    """
    none = {"unexplained_fraction": None, "unexplained_px": None, "off_foreground_fraction": None, "off_foreground_run_fraction": None,
            "centerline_rms_px": None, "centerline_max_px": None,
            "visible_px": 0.0, "unseen_px": None, "beyond_tip_contrast": None, "tip_off_foreground_px": None,
            "start_off_foreground_px": None, "tip_overhang_px": None}

    uv, depth = _dense_projection(camera, points_world_mm, params.sample_step_px)
    finite = np.all(np.isfinite(uv), axis=1) & (depth > 1e-6)
    vis = finite & camera.in_image(np.where(finite[:, None], uv, -1e9))
    if view.behind is not None and vis.any():
        iu = np.clip(np.rint(uv[vis, 0]).astype(int), 0, camera.width - 1)
        iv = np.clip(np.rint(uv[vis, 1]).astype(int), 0, camera.height - 1)
        vis[np.flatnonzero(vis)[view.behind[iv, iu]]] = False
    n_vis = int(vis.sum())
    none["visible_px"] = n_vis * params.sample_step_px
    if n_vis * params.sample_step_px < params.min_visible_px:
        return none
    f_px = math.sqrt(camera.K[0, 0] * camera.K[1, 1])
    r_out = f_px * radii_mm[0] / np.where(finite, depth, np.inf)
    r_in = f_px * radii_mm[1] / np.where(finite, depth, np.inf)
    r_band = float(np.max(r_out[vis])) + params.explain_tolerance_px
    pad = int(math.ceil(r_band + params.profile_search_px)) + int(params.roi_margin_px)
    W, H = camera.width, camera.height
    uvv = uv[vis]
    roi = [max(0, int(np.floor(uvv[:, 0].min())) - pad), max(0, int(np.floor(uvv[:, 1].min())) - pad),
           min(W, int(np.ceil(uvv[:, 0].max())) + pad + 1), min(H, int(np.ceil(uvv[:, 1].max())) + pad + 1)]
    roi, band, fg, labels, stats, band_lab, touching, lighting = _band_and_foreground(view, camera, gray, uv[finite], roi,
                                                                                          r_band, params)
    x0, y0 = roi[0], roi[1]
    if _DEBUG is not None:
        _DEBUG[camera.name] = dict(roi=tuple(roi), fg=fg > 0, band=band > 0, labels=labels, touching=touching, gray=gray, uv=uv,
                                   uvv=uvv, normals=_normals(uv[finite])[vis[finite]], r_out=r_out[vis], r_in=r_in[vis])
    # (a) as tube length: unexplained area over the innermost tube's width (the
    # thinnest reading, so a missing tip counts fully), against the length drawn.
    # Every foreground pixel in the band belongs to a touching component, so the
    # unexplained area is theirs less those.
    n_unexplained = int(stats[touching, cv2.CC_STAT_AREA].sum()) - int(band_lab.size)
    px_width = 2.0 * max(float(np.median(r_in[vis])), 0.5)
    unexplained_px = n_unexplained / px_width
    unseen_px = None
    if unexplained_px > 0.5 * params.max_unexplained_px:
        n_unexplained, ys, xs = _drop_specks(band, labels, stats, touching, n_unexplained, float(np.median(r_out[vis])), params)
        unexplained_px = n_unexplained / px_width
    if others and unexplained_px > 0.5 * params.max_unexplained_px:
        share = _unseen_share_of(camera, others, ys + y0, xs + x0, uvv, depth[vis], points_world_mm, base_world_mm, params)
        unseen_px = share * unexplained_px
        unexplained_px -= unseen_px
    unexplained = unexplained_px / (unexplained_px + none["visible_px"])
    # (b) is there foreground within the tolerance of each in-image sample?
    uvr = uvv - [x0, y0]
    on = near_mask(fg, uvr, params.on_foreground_tolerance_px)
    normals = _normals(uv[finite])[vis[finite]]
    if params.contrast_window_px > 0 and not view.binary and not on.all():
        on = on | _contrast_support(view, gray, lighting, uvv, normals, r_out[vis], r_in[vis], params)
    off = float(np.mean(~on))
    # The longest stretch off it: scattered misses are specks and faint spots; one long run is a backbone
    # that left the tube where this view cannot see it (wide-5-32 frame 0 of the fast method: a 14 px bulge
    # over a disk of clutter as bright as the tube, 16 % in one run, 16 % in all).
    off_run = _longest_run(~on) / on.size
    if _DEBUG is not None:
        _DEBUG[camera.name].update(on=on, lighting=lighting)
    ends = _end_figures(view, camera, gray, lighting, points_world_mm, radii_mm, base_world_mm, uv, finite, vis, on, fg, uvr,
                        r_out, r_in, params)
    rms, local = _centerline_figures(fg, uvr, normals, r_out[vis], r_in[vis], params)
    return {"unexplained_fraction": unexplained, "unexplained_px": unexplained_px, "off_foreground_fraction": off,
            "off_foreground_run_fraction": off_run,
            "centerline_rms_px": rms, "centerline_max_px": local, "visible_px": none["visible_px"], "unseen_px": unseen_px, **ends}


def _end_figures(view: _ViewModel, camera, gray: np.ndarray, lighting: Lighting, points_world_mm: np.ndarray, radii_mm: tuple,
                 base_world_mm, uv: np.ndarray, finite: np.ndarray, vis: np.ndarray, on: np.ndarray, fg: np.ndarray,
                 uvr: np.ndarray, r_out: np.ndarray, r_in: np.ndarray, params: SelfCheckParams) -> dict:
    """The figures of the judged curve's ends in one view: ``beyond_tip_contrast``, ``tip_off_foreground_px``,
    ``tip_overhang_px`` and ``start_off_foreground_px`` (None where not measured).

    ``uv`` the dense reprojection, ``finite`` / ``vis`` its finite and judged samples, ``on`` per judged
    sample: supported; ``fg`` the foreground and ``uvr`` the judged samples in its region's coordinates;
    ``r_out`` / ``r_in`` the radii (px) per dense sample.
    """
    # The tip itself in view (not behind the base): the probe looks beyond it; the overhang stands in for the
    # probe where that cannot run (masks have no contrast to probe): on camera images near the 10-footprint
    # line it only traded good frames for wrong ones (wide seeds 2/3).
    tip_seen = bool(vis[np.flatnonzero(finite)[-1]])
    face = _end_face_share(camera, points_world_mm, 2.0 * radii_mm[0]) if tip_seen else 0.0
    probe = tip_seen and params.tip_probe_px > 0 and not view.binary
    tip_off, beyond = _tip_figures(view, gray, lighting, uv, finite, vis, on, r_out, r_in, face if probe else None, params)
    r_in_tip = float(r_in[finite][-1])
    overhang = _tip_overhang_px(fg, uvr, r_in_tip, r_in_tip * face, params) if tip_seen and not probe else None
    # The same at the judged curve's start where the robot enters across the border: a backbone that hooks
    # off the tube there (paper, wide-8-5 frame 2: the first 10 px curl away at the side view's border, 13
    # footprints). A base in view is the start gap's and the behind-base figure's: the tube is faint or
    # hidden at the base (wide-3-23 frame 2, fast: 11 px unsupported there, 2.3 footprints).
    start_off = None
    if base_world_mm is not None and not _sees(camera, base_world_mm):
        start_off = _unsupported_end_px(on[::-1], float(r_out[vis][0]), params)
    return {"beyond_tip_contrast": beyond, "tip_off_foreground_px": tip_off, "start_off_foreground_px": start_off,
            "tip_overhang_px": overhang}


def _footprints_mm(rig: RigCalibration, points_world_mm: np.ndarray) -> np.ndarray:
    """The cameras' mean pixel footprint (mm per px: depth over focal length) at each point (n,); NaN where no camera has it in front."""
    fp = []
    for name in rig.names:
        cam = rig[name]
        z = cam.world_to_camera(points_world_mm)[:, 2]
        fp.append(np.where(z > 1e-6, z, np.nan) / math.sqrt(cam.K[0, 0] * cam.K[1, 1]))
    fp = np.stack(fp)
    n = np.sum(np.isfinite(fp), axis=0)
    return np.where(n > 0, np.nansum(fp, axis=0) / np.maximum(n, 1), np.nan)


def _behind_base_px(rig: RigCalibration, points_world_mm: np.ndarray) -> float:
    """How far the backbone reaches behind the base plane: the largest distance from the base of a point behind it, or from the axis of one on it to within a footprint (pixel footprints).

    The robot leaves its base along the insertion axis: no backbone point can
    lie behind the plane through the base across the axis, and what does is off
    the robot by (about) its distance from the base. No view judges it (the
    behind-base pixels are left out). In pixel footprints: the distance over
    the cameras' mean footprint at that point (mm per px, depth / focal length).
    """
    b = np.asarray(rig.base_point_world_mm, np.float64)
    fp = _footprints_mm(rig, points_world_mm)
    ok = np.isfinite(fp) & (fp > 0)
    # On the plane counts too, to within a footprint: a backbone continued back to (or cut at) the base
    # plane starts there, and whether that point is behind it is up to rounding and the sub-pixel
    # refinement (wide-1-65 frame 1: 1.34 mm, 12 footprints, from the base). The tube leaves the base
    # along the axis: a point that close in front of the plane is off the robot by its distance from the axis.
    axis = np.asarray(rig.insertion_axis_world, np.float64)
    h = (points_world_mm - b) @ axis
    on = ok & (h <= 1e-6 + np.where(ok, fp, 0.0))
    if not on.any():
        return 0.0
    off = points_world_mm[on] - b - np.maximum(h[on], 0.0)[:, None] * axis
    return float(np.max(np.linalg.norm(off, axis=1) / fp[on]))


def _radius_along_mm(rig: RigCalibration, points_world_mm: np.ndarray, s_mm: np.ndarray, r_in_mm: float, tube_sections_mm) -> np.ndarray:
    """The radius (mm) of the outermost tube at backbone arc lengths ``s_mm``: ``r_in_mm`` without ``tube_sections_mm``.

    ``tube_sections_mm``: ``(extension_mm, radius_mm)`` per tube, outermost first (tube i covers the
    backbone out to its extension from the base). The backbone's arc lengths are counted from the
    base: its own plus the straight distance from the base to its first point.
    """
    if not tube_sections_mm:
        return np.full(s_mm.shape, r_in_mm)
    s_base = s_mm + float(np.linalg.norm(points_world_mm[0] - np.asarray(rig.base_point_world_mm, np.float64)))
    r = np.full(s_mm.shape, min(r for _, r in tube_sections_mm))
    for ext_mm, r_mm in reversed(tube_sections_mm):  # outer tubes last: where they cover, they set the radius
        r = np.where(s_base <= ext_mm, r_mm, r)
    return r


def _kink_px(rig: RigCalibration, points_world_mm: np.ndarray, r_in_mm: float, params: SelfCheckParams, tube_sections_mm=None) -> float:
    """How much more sharply the backbone bends than its tubes can (pixel footprints; 0 when it does not).

    The largest sagitta (mm) of the backbone over the chord from ``kink_chord_mm``
    before to as far after each point, less ``kappa L**2 / 2`` of the tightest
    bend ``kappa = max_strain / r`` (1/mm), ``r`` the outermost tube's radius there
    (:func:`_radius_along_mm`; the innermost's, ``r_in_mm``, without tube sections),
    over the cameras' mean footprint there. Points nearer an end than the chord are not measured.
    """
    L = float(params.kink_chord_mm)
    s = arc_length(points_world_mm)
    mid = (s >= L) & (s <= s[-1] - L)
    if not mid.any():
        return 0.0
    p = points_world_mm[mid]
    a = points_at_arc_length(points_world_mm, s[mid] - L)
    ab = points_at_arc_length(points_world_mm, s[mid] + L) - a
    t = np.clip(np.sum((p - a) * ab, axis=1) / np.maximum(np.sum(ab * ab, axis=1), 1e-12), 0.0, 1.0)
    sagitta_mm = np.linalg.norm(p - a - t[:, None] * ab, axis=1)
    r_mm = _radius_along_mm(rig, points_world_mm, s[mid], r_in_mm, tube_sections_mm)
    excess_px = (sagitta_mm - 0.5 * params.max_strain / r_mm * L * L) / _footprints_mm(rig, p)
    excess_px = excess_px[np.isfinite(excess_px)]
    return float(max(0.0, excess_px.max())) if excess_px.size else 0.0


def _depth_visibility(rig: RigCalibration, points_world_mm: np.ndarray, h_mm: float = 1e-3) -> np.ndarray:
    """Per point (n,): px of reprojection shift across the tube, over the views in quadrature, per footprint of displacement
    in the least visible direction across the tangent (``SelfCheckParams.min_depth_visibility``)."""
    p = np.asarray(points_world_mm, np.float64)
    t = np.gradient(p, axis=0)
    t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-12)
    helper = np.where(np.abs(t[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = np.cross(t, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(t, e1)
    M = np.zeros((len(p), 2, 2))
    for name in rig.names:
        cam = rig[name]
        J = cam.project_jacobian(p, h_mm)[1]  # (n, 2, 3) px per mm
        u = np.einsum("nij,nj->ni", J, t)
        nrm = np.stack([-u[:, 1], u[:, 0]], axis=1) / np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
        g = np.einsum("nij,ni->nj", J, nrm)  # px per mm of displacement, across the tube in this view
        ge = np.stack([np.sum(g * e1, axis=1), np.sum(g * e2, axis=1)], axis=1)
        M += ge[:, :, None] * ge[:, None, :]
    M = np.nan_to_num(M)
    a, b, c = M[:, 0, 0], M[:, 0, 1], M[:, 1, 1]
    lam = 0.5 * (a + c) - np.sqrt(0.25 * (a - c) ** 2 + b * b)
    return np.sqrt(np.maximum(lam, 0.0)) * np.nan_to_num(_footprints_mm(rig, p))


def _unmeasured_depth_mm(rig: RigCalibration, points_world_mm: np.ndarray, params: SelfCheckParams) -> float:
    """The longest stretch (mm) of the backbone, between two points whose depth the views measure, whose depth they do not.

    The backbone is resampled every mm; a point's depth is unmeasured where its
    :func:`_depth_visibility` is under ``min_depth_visibility``. Stretches that
    reach an end of the backbone are left to the tip and start figures. 0 when
    there is none.
    """
    pts = resample_polyline(np.asarray(points_world_mm, np.float64), 1.0)
    if len(pts) < 3:
        return 0.0
    low = _depth_visibility(rig, pts) < params.min_depth_visibility
    # Runs of unmeasured points: starts where low rises, ends where it falls (a run touching an end does not count).
    edges = np.diff(np.concatenate([[0], low.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    inner = (starts > 0) & (ends < len(pts))
    return float(np.max(ends[inner] - starts[inner] + 1)) if inner.any() else 0.0


def _sees(cam, point_world_mm: np.ndarray) -> bool:
    """Whether ``point_world_mm`` (3,) projects into ``cam``'s image, in front of it."""
    uv, z = cam.project(np.asarray(point_world_mm, np.float64)[None])
    return bool(z[0] > 1e-6 and np.all(np.isfinite(uv)) and cam.in_image(uv)[0])


def _start_gap_px(rig: RigCalibration, points_world_mm: np.ndarray) -> float:
    """How far in from where the robot must enter the backbone starts (px; see ``SelfCheckParams.max_start_gap_px``).

    The smallest distance of the first point's projection from the border of a
    view whose image the base is not in (0 where the point itself is outside
    that image); with the base in every image, the first point's distance from
    the base in pixel footprints.
    """
    base = np.asarray(rig.base_point_world_mm, np.float64)
    first = points_world_mm[:1]
    gaps = []
    for name in rig.names:
        cam = rig[name]
        if _sees(cam, base):
            continue
        if not _sees(cam, first[0]):
            return 0.0
        u, v = cam.project(first)[0][0] + 0.5  # from the image's outer edge, half a pixel beyond the border pixels' centres
        gaps.append(min(u, v, cam.width - u, cam.height - v))
    if gaps:
        return float(max(0.0, min(gaps)))
    fp = _footprints_mm(rig, first)[0]
    return float(np.linalg.norm(first[0] - base) / fp) if np.isfinite(fp) and fp > 0 else 0.0


#: Arc-length step (mm) over which the backbone's length is compared with the joints' (see
#: ``SelfCheckParams.max_length_mismatch_fraction``); a 1/20 mm^-1 arc measures under 0.3 % short.
_LENGTH_STEP_MM = 5.0


def _length_mismatch(rig: RigCalibration, points_world_mm: np.ndarray, expected_length_mm: float | None) -> tuple:
    """How far the backbone's length is off the joints': ``(fraction of it, pixel footprints at the tip or None)``.

    See ``SelfCheckParams.max_length_mismatch_fraction``. ``(None, None)`` when
    ``expected_length_mm`` (mm from the base along the backbone) is None; the
    footprints are None where a view does not see the base and the backbone is
    shorter than the joints' length.
    """
    if expected_length_mm is None:
        return None, None
    base = np.asarray(rig.base_point_world_mm, np.float64)
    reach_mm = arc_length(resample_polyline(points_world_mm, _LENGTH_STEP_MM, "spread"))[-1] + np.linalg.norm(points_world_mm[0] - base)
    off_mm = abs(reach_mm - expected_length_mm)
    fp = _footprints_mm(rig, points_world_mm[-1:])[0]
    # Out of a view, the chord from the base is no longer than the robot before the border: only an overrun counts.
    judged = reach_mm > expected_length_mm or all(_sees(rig[name], base) for name in rig.names)
    return float(off_mm / expected_length_mm), (float(off_mm / fp) if judged and np.isfinite(fp) and fp > 0 else None)


#: Each figure and the :class:`SelfCheckParams` limit it is judged against (figure > limit: the frame is
#: suspect), with the reason it then gives (``cam``, the figure ``x`` and the limit ``lim``).
FIGURE_LIMITS = {
    "off_foreground_fraction": ("max_off_foreground_fraction",
                                "{cam}: {pct:.0f} % of the reprojected tube is not on foreground (limit {pct_lim:.0f} %)"),
    "off_foreground_run_fraction": ("max_off_foreground_run_fraction",
                                    "{cam}: {pct:.0f} % of the reprojected tube, in one stretch, is on neither foreground nor tube "
                                    "contrast (limit {pct_lim:.0f} %)"),
    "unexplained_fraction": ("max_unexplained_fraction",
                             "{cam}: {pct:.0f} % of the foreground along the robot is not explained by the backbone (limit {pct_lim:.0f} %)"),
    "unexplained_px": ("max_unexplained_px", "{cam}: {x:.0f} px of tube along the robot are not explained by the backbone (limit {lim:.0f} px)"),
    "tip_off_foreground_px": ("max_tip_off_foreground_px", "{cam}: the reprojected tube's last {x:.0f} px are on neither foreground nor tube contrast (limit {lim:.0f} px)"),
    "start_off_foreground_px": ("max_start_off_foreground_px",
                                "{cam}: the reprojected tube's first {x:.0f} px are on neither foreground nor tube contrast (limit {lim:.0f} px)"),
    "tip_overhang_px": ("max_tip_overhang_px", "{cam}: the tube's foreground runs on {x:.0f} px beyond the reprojected tip (limit {lim:.0f} px)"),
    "behind_base_px": ("max_behind_base_px", "the backbone reaches {x:.0f} px (pixel footprints) behind the robot base (limit {lim:.0f} px)"),
    "kink_px": ("max_kink_px", "the backbone bends {x:.0f} px (pixel footprints) more sharply than a tube can (limit {lim:.0f} px)"),
    "start_gap_px": ("max_start_gap_px",
                     "the backbone starts {x:.0f} px in from where the robot enters the views (limit {lim:.0f} px): the robot before it is missing"),
    "unmeasured_depth_mm": ("max_unmeasured_depth_mm",
                            "over {x:.0f} mm the tube runs near an epipolar plane: the views do not measure its depth there (limit {lim:.0f} mm)"),
    "length_mismatch_fraction": ("max_length_mismatch_fraction",
                                 "the backbone's length is {pct:.0f} % off the robot's length from the joint values (limit {pct_lim:.0f} %)"),
    "length_mismatch_px": ("max_length_mismatch_px", "the backbone's length is {x:.0f} px (pixel footprints) off the robot's length "
                           "from the joint values (limit {lim:.0f} px)"),
    "beyond_tip_contrast": ("max_beyond_tip_contrast", "{cam}: the tube goes on beyond the reprojected tip (contrast {x:.1f}, limit {lim:.1f})"),
    "centerline_rms_px": ("max_centerline_rms_px", "{cam}: the reprojected centerline is {x:.1f} px RMS off the tube's middle (limit {lim:.1f} px)"),
    "centerline_max_px": ("max_centerline_local_px",
                          "{cam}: the reprojected centerline leaves the tube's middle by {x:.1f} px over a stretch (limit {lim:.1f} px)"),
}


def _verdict(figures: dict, params: SelfCheckParams) -> str | None:
    """The reason of the figure furthest beyond its limit (one line), or None."""
    worst, reason = 1.0, None
    for cam, f in figures.items():
        for key, (limit, text) in FIGURE_LIMITS.items():
            x, lim = f.get(key), getattr(params, limit)
            if x is not None and x / lim > worst:
                worst, reason = x / lim, text.format(cam=cam, x=x, lim=lim, pct=100 * x, pct_lim=100 * lim)
    return reason


def check_backbone(model: SelfCheckModel, images: dict, points_world_mm, tube_radii_mm, params: SelfCheckParams = SelfCheckParams(),
                   expected_length_mm: float | None = None, tube_sections_mm=None) -> SelfCheck:
    """Judge a backbone against the frame it was reconstructed from.

    Parameters
    ----------
    model : SelfCheckModel
        From :func:`prepare_selfcheck` on the same rig.
    images : dict
        Camera name -> (H, W) or (H, W, 3) uint8 frame.
    points_world_mm : (n, 3) array
        Backbone, base first (world, mm), n >= 2.
    tube_radii_mm : (outermost, innermost)
        Tube radii (mm): the band that explains foreground uses the outermost;
        a cross-section must be at least the innermost radius wide.
    params : SelfCheckParams
    expected_length_mm : float, optional
        The robot's length from the frame's joint values (mm from the base to
        the tip along the backbone, ``max(extension_mm)``); None where the
        frame has none (the length is then not judged).
    tube_sections_mm : sequence of (extension_mm, radius_mm), optional
        Per tube, outermost first: how far it reaches from the base along the
        backbone (the frame's joint values) and its outer radius (mm). The kink
        figure then allows each point the bend of the outermost tube there; without
        them, of the innermost tube everywhere.

    Returns
    -------
    SelfCheck

    Raises
    ------
    ValueError
        One line: a camera's image missing or of the wrong size, a backbone
        that is not (n >= 2, 3) finite, radii or an expected length that are
        not positive.
    """
    t0 = time.perf_counter()
    pts = np.asarray(points_world_mm, np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 2 or not np.all(np.isfinite(pts)):
        raise ValueError(f"self-check: the backbone must be (n >= 2, 3) finite points, got shape {pts.shape}")
    try:
        r_out, r_in = (float(r) for r in tube_radii_mm)
    except (TypeError, ValueError):
        raise ValueError("self-check: tube_radii_mm must be (outermost, innermost) in mm") from None
    if not (r_out > 0 and r_in > 0):
        raise ValueError(f"self-check: tube radii must be > 0 mm, got ({r_out}, {r_in})")
    r_in = min(r_in, r_out)
    if expected_length_mm is not None and not (math.isfinite(expected_length_mm) and expected_length_mm > 0):
        raise ValueError(f"self-check: the expected robot length must be > 0 mm, got {expected_length_mm}")
    if tube_sections_mm is not None:
        tube_sections_mm = tuple((float(e), float(r)) for e, r in tube_sections_mm)
        if not all(math.isfinite(e) and math.isfinite(r) and r > 0 for e, r in tube_sections_mm):
            raise ValueError(f"self-check: tube sections must be finite (extension_mm, radius_mm > 0) pairs, got {tube_sections_mm}")
    figures = {}
    for name, view in model.views.items():
        cam = model.rig[name]
        if name not in images:
            raise ValueError(f"{name}: no image for the self-check")
        gray = _gray(images[name], name)
        if gray.shape != (cam.height, cam.width):
            raise ValueError(f"{name}: image is {gray.shape[1]}x{gray.shape[0]} but the camera is {cam.width}x{cam.height}")
        if view.binary and gray.max() <= 1:
            gray = gray * np.uint8(255)  # a 0/1 mask
        gray = _steadied(view, gray)
        others = [model.rig[o] for o in model.rig.names if o != name]
        figures[name] = _judge_view(view, cam, gray, pts, (r_out, r_in), params, others, model.rig.base_point_world_mm)
    shape = {"behind_base_px": _behind_base_px(model.rig, pts), "kink_px": _kink_px(model.rig, pts, r_in, params, tube_sections_mm),
             "start_gap_px": _start_gap_px(model.rig, pts), "unmeasured_depth_mm": _unmeasured_depth_mm(model.rig, pts, params)}
    shape["length_mismatch_fraction"], shape["length_mismatch_px"] = _length_mismatch(model.rig, pts, expected_length_mm)
    for f in figures.values():
        f.update(shape)
    reason = _verdict(figures, params)
    if reason is None and not any(f["unexplained_fraction"] is not None for f in figures.values()):
        reason = "the reprojected backbone is in no camera's image"
    return SelfCheck(ok=reason is None, reason=reason, figures=figures, ms=1e3 * (time.perf_counter() - t0))
