"""Centerline of a two-tube robot's silhouette by erosion with two disks.

Section III-B of the paper: the silhouette is eroded with a large disk, which
leaves a thin line along the (wider) outer tube only; the outer tube is then
removed from the silhouette and the rest eroded with a small disk, which leaves
a line along the inner tube. Small regions are removed from both lines and the
two are added into the centerline image.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = [
    "CenterlineParams",
    "centerline_params_for",
    "extract_centerline",
    "remove_small_regions",
    "OUTER",
    "INNER",
]

#: Label of outer-tube centerline pixels.
OUTER = 1
#: Label of inner-tube centerline pixels.
INNER = 2


@dataclass(frozen=True)
class CenterlineParams:
    """Structuring elements of :func:`extract_centerline`.

    The defaults are for the paper's tubes as this rig images them: outer and
    inner radii 0.8 mm and 0.5 mm at ~0.12 mm/px, i.e. 6.7 px and 4.2 px,
    each disk one pixel smaller than its tube (see :func:`centerline_params_for`).

    Attributes
    ----------
    outer_radius_px : int
        Radius of the large disk (px). Must exceed the inner tube's radius in
        the image, or the inner tube survives the first erosion as "outer".
    inner_radius_px : int
        Radius of the small disk (px).
    min_region_px : int
        Connected pieces of either centerline smaller than this are removed
        (px): corners of the outer tube's end, specks on the edges.
    """

    outer_radius_px: int = 5
    inner_radius_px: int = 3
    min_region_px: int = 10

    def __post_init__(self):
        if not 1 <= int(self.inner_radius_px) <= int(self.outer_radius_px):
            raise ValueError(
                "CenterlineParams: need 1 <= inner_radius_px <= outer_radius_px, "
                f"got {self.inner_radius_px} and {self.outer_radius_px}"
            )


def _disk_radius_px(radius_mm: float, mm_per_px: float) -> int:
    # One pixel short of the tube's radius: the erosion then leaves a line
    # ~3 px wide, which survives the tube's width varying along the image.
    return max(1, int(np.floor(radius_mm / mm_per_px - 1.0)))


def centerline_params_for(
    camera,
    outer_tube_radius_mm: float,
    inner_tube_radius_mm: float,
    at_point_world_mm,
    min_region_px: int = CenterlineParams.min_region_px,
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

    Returns
    -------
    CenterlineParams
        Disk radii ``floor(radius_px - 1)`` (at least 1 px).
    """
    mmpp = camera.mm_per_pixel_at(at_point_world_mm)
    outer = _disk_radius_px(outer_tube_radius_mm, mmpp)
    inner = min(_disk_radius_px(inner_tube_radius_mm, mmpp), outer)
    return CenterlineParams(outer_radius_px=outer, inner_radius_px=inner, min_region_px=min_region_px)


def _disk(radius_px: int) -> np.ndarray:
    d = 2 * int(radius_px) + 1
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (d, d))


def remove_small_regions(mask: np.ndarray, min_region_px: int) -> np.ndarray:
    """Zero the 8-connected regions of ``mask`` smaller than ``min_region_px``.

    Parameters
    ----------
    mask : (H, W) uint8 array
        Binary image (0 / nonzero).
    min_region_px : int

    Returns
    -------
    (H, W) bool array
    """
    n, labels, stats, _ = cv2.connectedComponentsWithStatsWithAlgorithm(
        (mask > 0).view(np.uint8), 8, cv2.CV_32S, cv2.CCL_GRANA
    )
    keep = stats[:, cv2.CC_STAT_AREA] >= min_region_px
    keep[0] = False
    return keep[labels]


def extract_centerline(silhouette: np.ndarray, params: CenterlineParams = CenterlineParams()) -> tuple[np.ndarray, np.ndarray]:
    """Centerline of a two-tube robot from its silhouette.

    Deviation from the paper: the paper subtracts the outer tube's
    *centerline* from the silhouette before the second erosion. That leaves
    the outer tube's two halves, each wider than the small disk, which the
    second erosion would turn into two spurious lines flanking the outer
    centerline. Here the outer tube's *region* is subtracted instead: its
    centerline dilated back by the large disk, i.e. the morphological opening
    of the silhouette.

    Parameters
    ----------
    silhouette : (H, W) bool array
    params : CenterlineParams

    Returns
    -------
    centerline : (H, W) bool array
        Outer and inner centerlines together.
    labels : (H, W) uint8 array
        ``OUTER`` (1) on the outer tube's centerline, ``INNER`` (2) on the
        inner tube's, 0 elsewhere.
    """
    sil = np.ascontiguousarray(silhouette, dtype=bool)
    H, W = sil.shape
    labels = np.zeros((H, W), np.uint8)
    sil_u8 = sil.view(np.uint8)
    x, y, w, h = cv2.boundingRect(sil_u8)
    if w == 0 or h == 0:
        return labels.astype(bool), labels
    # Morphology on the silhouette's bounding box only (padded so that the
    # dilation back does not clip): the robot covers a small part of the image.
    pad = int(params.outer_radius_px) + 2
    x0, y0, x1, y1 = max(x - pad, 0), max(y - pad, 0), min(x + w + pad, W), min(y + h + pad, H)
    crop = sil_u8[y0:y1, x0:x1]
    large = _disk(params.outer_radius_px)
    # Default border (outside = foreground): a robot crossing an allowed image
    # border keeps its centerline up to the border.
    outer_line = cv2.erode(crop, large)
    outer_region = cv2.dilate(outer_line, large)
    rest = cv2.subtract(crop, outer_region)
    inner_line = cv2.erode(rest, _disk(params.inner_radius_px))
    outer_keep = remove_small_regions(outer_line, params.min_region_px)
    inner_keep = remove_small_regions(inner_line, params.min_region_px)
    out = labels[y0:y1, x0:x1]
    out[inner_keep] = INNER
    out[outer_keep] = OUTER
    return labels > 0, labels
