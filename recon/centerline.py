"""Centerline of a two-tube robot's silhouette by erosion with two disks.

Section III-B of the paper: the silhouette is eroded with a large disk, which
leaves a thin line along the (wider) outer tube only; the outer tube is then
removed from the silhouette and the rest eroded with a small disk, which leaves
a line along the inner tube. Small regions are removed from both lines and the
two are added into the centerline image.

The paper gives no disk sizes. Here they are derived from the tube radii in
pixels and the silhouette's measured width (:func:`disk_radii`,
:func:`measure_edge_loss`); the other deviations (the outer tube's region is
subtracted, dashed lines survive small-region removal, stretches too thin for
either disk are bridged) are listed in :func:`extract_centerline` and
``docs/paper-method.md``.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .morphology import disk

__all__ = [
    "CenterlineParams",
    "centerline_params_for",
    "disk_radii",
    "measure_edge_loss",
    "extract_centerline",
    "remove_small_regions",
    "OUTER",
    "INNER",
    "THIN",
]

#: Label of outer-tube centerline pixels.
OUTER = 1
#: Label of inner-tube centerline pixels.
INNER = 2
#: Label of centerline pixels of a stretch too thin for either disk (tube unknown).
THIN = 3


@dataclass(frozen=True)
class CenterlineParams:
    """Structuring elements of :func:`extract_centerline`.

    The defaults are for the paper's tubes as this rig images them: outer and
    inner radii 0.8 mm and 0.5 mm at ~0.12 mm/px, i.e. 6.9 px and 4.3 px,
    with silhouettes ~0.5 px narrower per side (see :func:`disk_radii`).

    Attributes
    ----------
    outer_radius_px : int
        Radius of the large disk (px). Must exceed the inner tube's radius in
        the image, or the inner tube survives the first erosion as "outer".
        Used as is when ``outer_tube_px`` is 0.
    inner_radius_px : int
        Radius of the small disk (px). Used as is when ``outer_tube_px`` is 0.
    min_region_px : int
        Connected pieces of either centerline smaller than this are removed
        (px): corners of the outer tube's end, specks on the edges.
    min_region_gap_px : int
        For that removal, pieces less than this many pixels apart count as
        one (see :func:`remove_small_regions`).
    outer_tube_px, inner_tube_px : float
        Radii of the tubes in the image (px). When set (> 0), the disks are
        sized per frame from them and the silhouette's measured width
        (:func:`measure_edge_loss`, :func:`disk_radii`) and the two radius
        fields above are ignored.
    edge_loss_px : float
        How much narrower than the tube (px per side) the silhouette is taken
        to be when it cannot be measured (too little of it), and the centre
        of the measurement's search range.
    edge_loss_range_px : float
        The measured loss is searched within ``edge_loss_px`` plus or minus
        this (px).
    thin_min_width_px : float
        Stretches of the silhouette that neither erosion explains (too thin
        for the small disk: a tube whose specular side matched the backdrop
        and was thresholded away) get a centerline along their middle, the
        ridge of their distance transform, labelled ``THIN``, where they are
        at least this wide (px); 0 disables it (see :func:`extract_centerline`).
    outer_disk_position, inner_disk_margin_px : float
        How the disks are sized from the tube radii (see :func:`disk_radii`).
    """

    outer_radius_px: int = 5
    inner_radius_px: int = 3
    min_region_px: int = 10
    min_region_gap_px: int = 2
    outer_tube_px: float = 0.0
    inner_tube_px: float = 0.0
    edge_loss_px: float = 0.5
    edge_loss_range_px: float = 1.5
    thin_min_width_px: float = 3.0
    outer_disk_position: float = 0.5
    inner_disk_margin_px: float = 1.0

    def __post_init__(self):
        if not 1 <= int(self.inner_radius_px) <= int(self.outer_radius_px):
            raise ValueError(
                "CenterlineParams: need 1 <= inner_radius_px <= outer_radius_px, "
                f"got {self.inner_radius_px} and {self.outer_radius_px}"
            )
        if not 0.0 <= self.outer_disk_position <= 1.0:
            raise ValueError(f"CenterlineParams: outer_disk_position must be in [0, 1], got {self.outer_disk_position}")
        if self.inner_disk_margin_px < 0:
            raise ValueError(f"CenterlineParams: inner_disk_margin_px must be >= 0, got {self.inner_disk_margin_px}")
        if self.outer_tube_px > 0 and not 0 < self.inner_tube_px < self.outer_tube_px:
            raise ValueError(
                "CenterlineParams: need 0 < inner_tube_px < outer_tube_px, "
                f"got {self.inner_tube_px} and {self.outer_tube_px}"
            )

    @property
    def adaptive(self) -> bool:
        """Whether the disks are sized per frame from the tube radii and the measured width.

        Returns
        -------
        bool
            True when ``outer_tube_px > 0`` (tube radii in px are known); False: the fixed disk radii are used.
        """
        return self.outer_tube_px > 0


def disk_radii(
    outer_tube_px: float,
    inner_tube_px: float,
    edge_loss_px: float = 0.5,
    outer_disk_position: float = 0.5,
    inner_disk_margin_px: float = 1.0,
) -> tuple[int, int]:
    """Disk radii (px) for tubes of given image radii whose silhouettes lose ``edge_loss_px`` per side.

    A silhouette band of half-width ``h`` (px) has a distance transform of
    about ``h + 0.5`` on its axis, and an erosion with a disk of radius ``r``
    keeps the pixels whose distance exceeds ``r``. With ``h = tube radius -
    edge loss`` for each tube:

    * the large disk must remove the inner tube (``r >= h_inner + 0.5``) and
      leave a line on the outer one (``r <= h_outer - 0.5``); by default it
      is taken half-way, ``round((h_outer + h_inner) / 2)``, the most margin
      either way (the tubes' widths vary along the image with depth and
      anti-aliasing); ``outer_disk_position`` moves it between the two;
    * the small disk leaves a line ~3 px wide on the inner tube,
      ``round(h_inner - 1)``: one pixel (``inner_disk_margin_px``) of slack
      on either side of its axis.

    Parameters
    ----------
    outer_tube_px, inner_tube_px : float
        Tube radii in the image (px).
    edge_loss_px : float
        Silhouette narrower than the tube by this much per side (px).
    outer_disk_position : float
        Where the large disk's radius lies between the inner tube's
        half-width (0) and the outer tube's (1).
    inner_disk_margin_px : float
        The small disk is this much (px) smaller than the inner tube's
        half-width.

    Returns
    -------
    outer_radius_px, inner_radius_px : int
        At least 2 and 1, the large one larger than the small one.
    """
    h_out = float(outer_tube_px) - float(edge_loss_px)
    h_in = float(inner_tube_px) - float(edge_loss_px)
    inner = max(1, int(np.floor(h_in - float(inner_disk_margin_px) + 0.5)))
    t = float(outer_disk_position)
    outer = max(inner + 1, int(np.floor((1.0 - t) * h_in + t * h_out + 0.5)))
    return outer, inner


def centerline_params_for(
    camera,
    outer_tube_radius_mm: float,
    inner_tube_radius_mm: float,
    at_point_world_mm,
    min_region_px: int = CenterlineParams.min_region_px,
    *,
    edge_loss_px: float = CenterlineParams.edge_loss_px,
    adaptive: bool = False,
    outer_disk_position: float = CenterlineParams.outer_disk_position,
    inner_disk_margin_px: float = CenterlineParams.inner_disk_margin_px,
) -> CenterlineParams:
    """Structuring elements for tubes of given radii seen by ``camera``.

    Parameters
    ----------
    camera : recon.camera.Camera
    outer_tube_radius_mm, inner_tube_radius_mm : float
        Tube radii (mm).
    at_point_world_mm : (3,) array
        World point (mm) whose depth sets the pixel scale, typically the robot
        base.
    min_region_px : int
    edge_loss_px : float
        Silhouette narrower than the tube by this much per side (px).
    adaptive : bool
        Size the disks per frame from the silhouette's measured width (the
        tube radii in pixels are stored in the result) instead of once here.
    outer_disk_position, inner_disk_margin_px : float
        See :func:`disk_radii`.

    Returns
    -------
    CenterlineParams
        Disk radii from :func:`disk_radii`.
    """
    mmpp = camera.mm_per_pixel_at(at_point_world_mm)
    outer_px, inner_px = outer_tube_radius_mm / mmpp, inner_tube_radius_mm / mmpp
    if not inner_px < outer_px:
        raise ValueError(f"the inner tube ({inner_tube_radius_mm} mm) must be thinner than the outer one ({outer_tube_radius_mm} mm)")
    outer, inner = disk_radii(outer_px, inner_px, edge_loss_px, outer_disk_position, inner_disk_margin_px)
    return CenterlineParams(
        outer_radius_px=outer,
        inner_radius_px=inner,
        min_region_px=min_region_px,
        outer_tube_px=outer_px if adaptive else 0.0,
        inner_tube_px=inner_px if adaptive else 0.0,
        edge_loss_px=edge_loss_px,
        outer_disk_position=outer_disk_position,
        inner_disk_margin_px=inner_disk_margin_px,
    )


# Fewest ridge pixels for a width measurement: ~2 mm of robot at 0.12 mm/px.
_MIN_RIDGE_PX = 16


def measure_edge_loss(silhouette: np.ndarray, params: CenterlineParams) -> float | None:
    """How much narrower than the tubes (px per side) a silhouette is, measured on its ridge.

    The ridge is the set of local maxima of the silhouette's distance
    transform, whose values are the half-widths (+0.5 px) of the band along
    its axis: about ``tube radius + 0.5 - loss`` for one tube or the other.
    The loss is the one, within ``edge_loss_px +- edge_loss_range_px``, that
    puts the most ridge values near either tube's level (a robust fit: each
    value counts at most 1 px; ties go to the value nearest
    ``edge_loss_px``). Ends and junctions, where the ridge value is neither,
    barely weigh.

    Parameters
    ----------
    silhouette : (h, w) bool or uint8 array
        A silhouette (or a crop of one with a background border).
    params : CenterlineParams
        With the tube radii (``outer_tube_px``, ``inner_tube_px``) set.

    Returns
    -------
    float or None
        The loss (px); None when the ridge has fewer than 16 pixels.
    """
    sil = np.ascontiguousarray(silhouette).astype(np.uint8, copy=False)
    dist = cv2.distanceTransform(sil, cv2.DIST_L2, cv2.DIST_MASK_5)
    ridge = (dist >= 1.0) & (dist >= cv2.dilate(dist, np.ones((3, 3), np.uint8)))
    v = dist[ridge].astype(np.float64)
    if v.size < _MIN_RIDGE_PX:
        return None
    prior, span = float(params.edge_loss_px), float(params.edge_loss_range_px)
    losses = prior + np.linspace(-span, span, int(round(2 * span / 0.05)) + 1)
    # Histogram the values once (0.05 px bins): cost over the grid without an n x grid array.
    edges = np.arange(0.0, v.max() + 0.1, 0.05)
    counts, _ = np.histogram(v, bins=edges)
    centres = 0.5 * (edges[1:] + edges[:-1])
    lo, li = params.outer_tube_px + 0.5 - losses, params.inner_tube_px + 0.5 - losses
    r = np.minimum(np.abs(centres[None, :] - lo[:, None]), np.abs(centres[None, :] - li[:, None]))
    cost = (np.minimum(r, 1.0) * counts[None, :]).sum(axis=1)
    best = np.flatnonzero(cost <= cost.min() + 1e-9)
    return float(losses[best[np.argmin(np.abs(losses[best] - prior))]])


def remove_small_regions(mask: np.ndarray, min_region_px: int, gap_px: int = 0) -> np.ndarray:
    """Zero the regions of ``mask`` smaller than ``min_region_px``.

    Parameters
    ----------
    mask : (H, W) uint8 array
        Binary image (0 / nonzero).
    min_region_px : int
    gap_px : int
        Pieces less than this many pixels apart count as one region (0: plain
        8-connected regions). A centerline broken into a dotted line by a
        rough silhouette is then kept whole, while an isolated speck still
        goes.

    Returns
    -------
    (H, W) bool array
    """
    m = (mask > 0).view(np.uint8)
    grouped = cv2.dilate(m, disk((int(gap_px) + 1) // 2)) if gap_px > 0 else m
    n, labels, stats, _ = cv2.connectedComponentsWithStatsWithAlgorithm(grouped, 8, cv2.CV_32S, cv2.CCL_GRANA)
    area = stats[:, cv2.CC_STAT_AREA] if gap_px <= 0 else np.bincount(labels[m > 0], minlength=n)
    keep = area >= min_region_px
    keep[0] = False
    out = keep[labels]
    if gap_px > 0:
        out &= m > 0
    return out


def extract_centerline(
    silhouette: np.ndarray, params: CenterlineParams = CenterlineParams(), info: dict | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Centerline of a two-tube robot from its silhouette.

    Deviations from the paper (see ``docs/paper-method.md``):

    * The paper subtracts the outer tube's *centerline* from the silhouette
      before the second erosion. That leaves the outer tube's two halves,
      each wider than the small disk, which the second erosion would turn
      into two spurious lines flanking the outer centerline. Here the outer
      tube's *region* is subtracted instead: its centerline dilated back by
      the large disk, i.e. the morphological opening of the silhouette.
    * Small-region removal counts pieces less than ``min_region_gap_px``
      apart as one region, so that a centerline broken into dashes by a
      rough silhouette is not deleted dash by dash.
    * Gap bridging: what the two centerlines, dilated back by their disks, do
      not cover of the silhouette and is at least ``thin_min_width_px`` wide
      is a stretch of tube too thin for the small disk (half a tube, when
      its specular side matched the backdrop). Its middle line (the ridge of
      its distance transform) is added with the label ``THIN``, so that the
      centerline does not stop there. It lies off the tube's axis by up to
      half the missing width: a rough bridge, but a continuous one.
    * With tube radii in ``params`` (``outer_tube_px > 0``) the disks are
      sized per frame from the silhouette's measured width
      (:func:`measure_edge_loss`, :func:`disk_radii`) rather than fixed.

    Parameters
    ----------
    silhouette : (H, W) bool array
    params : CenterlineParams
    info : dict, optional
        Receives ``outer_radius_px``, ``inner_radius_px`` (the disks used) and
        ``edge_loss_px`` (measured, or None).

    Returns
    -------
    centerline : (H, W) bool array
        Outer and inner centerlines together.
    labels : (H, W) uint8 array
        ``OUTER`` (1) on the outer tube's centerline, ``INNER`` (2) on the
        inner tube's, ``THIN`` (3) on bridges over stretches too thin for
        either disk, 0 elsewhere.
    """
    sil = np.ascontiguousarray(silhouette, dtype=bool)
    H, W = sil.shape
    labels = np.zeros((H, W), np.uint8)
    sil_u8 = sil.view(np.uint8)
    x, y, w, h = cv2.boundingRect(sil_u8)
    r_out, r_in, loss = int(params.outer_radius_px), int(params.inner_radius_px), None
    if w == 0 or h == 0:
        if info is not None:
            info.update(outer_radius_px=r_out, inner_radius_px=r_in, edge_loss_px=loss)
        return labels.astype(bool), labels
    if params.adaptive:
        # Measured on the silhouette with a background border (the crop below
        # would cut it at the image border).
        m = 1
        crop = np.zeros((h + 2 * m, w + 2 * m), np.uint8)
        crop[m:-m, m:-m] = sil_u8[y : y + h, x : x + w]
        loss = measure_edge_loss(crop, params)
        r_out, r_in = disk_radii(
            params.outer_tube_px,
            params.inner_tube_px,
            params.edge_loss_px if loss is None else loss,
            params.outer_disk_position,
            params.inner_disk_margin_px,
        )
    if info is not None:
        info.update(outer_radius_px=r_out, inner_radius_px=r_in, edge_loss_px=loss)
    # Morphology on the silhouette's bounding box only (padded so that the
    # dilation back does not clip): the robot covers a small part of the image.
    pad = r_out + 2
    x0, y0, x1, y1 = max(x - pad, 0), max(y - pad, 0), min(x + w + pad, W), min(y + h + pad, H)
    crop = sil_u8[y0:y1, x0:x1]
    large = disk(r_out)
    # Default border (outside = foreground): a robot crossing an allowed image
    # border keeps its centerline up to the border.
    outer_line = cv2.erode(crop, large)
    gap = int(params.min_region_gap_px)
    outer_keep = remove_small_regions(outer_line, params.min_region_px, gap)
    outer_region = cv2.dilate(outer_line, large)
    rest = cv2.subtract(crop, outer_region)
    inner_line = cv2.erode(rest, disk(r_in))
    inner_keep = remove_small_regions(inner_line, params.min_region_px, gap)
    rest_kept = rest  # the silhouette less the region of the outer line as kept
    if not np.array_equal(outer_keep, outer_line.view(bool)):
        # Specks the large disk leaves where the inner tube is a little wider
        # than expected (a halo, nearer the camera) are dropped as small
        # regions, but their region took the inner tube's pixels with it and
        # its centerline stopped there. The inner line computed without them
        # is added where it continues the inner line found above (not where
        # it is an isolated blob's core).
        rest_kept = cv2.subtract(crop, cv2.dilate(outer_keep.view(np.uint8), large))
        more = remove_small_regions(cv2.erode(rest_kept, disk(r_in)), params.min_region_px, gap)
        if inner_keep.any() and more.any():
            n, lab = cv2.connectedComponents(more.view(np.uint8), connectivity=8)
            touch = np.zeros(n, bool)
            touch[lab[inner_keep & more]] = True
            touch[0] = False
            inner_keep = inner_keep | touch[lab]
    out = labels[y0:y1, x0:x1]
    if params.thin_min_width_px > 0:
        # Against the kept lines' regions: the dropped specks' region is not explained by any line, and
        # took the middle of a silhouette barely wider than the outer tube with it (wide-2-38 frame 0: 46 mm
        # of the top view's centerline missing, the carved robot in pieces).
        out[_thin_ridge(crop, rest_kept, inner_keep, r_in, params)] = THIN
    out[inner_keep] = INNER
    out[outer_keep] = OUTER
    return labels > 0, labels


def _thin_ridge(crop, rest, inner_keep, r_in, params) -> np.ndarray:
    """Middle line of the parts of the silhouette crop explained by neither centerline (bool)."""
    # ``rest`` is the silhouette less the outer tube's region; less the inner
    # tube's region too, what is left is edge slivers and too-thin stretches.
    inner_region = cv2.dilate(inner_keep.view(np.uint8), disk(r_in))
    left = cv2.subtract(rest, inner_region)
    if not left.any():
        return np.zeros(crop.shape, bool)
    dist = cv2.distanceTransform(left, cv2.DIST_L2, cv2.DIST_MASK_5)
    # Wide enough (slivers along the edges are 1-2 px), and a local maximum across.
    ridge = (dist >= 0.5 * params.thin_min_width_px + 0.5) & (dist >= cv2.dilate(dist, np.ones((3, 3), np.uint8)))
    return remove_small_regions(ridge.view(np.uint8), params.min_region_px, int(params.min_region_gap_px))
