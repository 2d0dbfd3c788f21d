"""Silhouette of the robot: binarized difference image, largest 1-region.

Section III-A of the paper: the normalized difference image is binarized at
0.25 and everything but the largest connected 1-region is removed. On top of
the paper, frames where that region is not trustworthy are rejected with a
:class:`~recon.errors.FrameError` instead of being reconstructed into
nonsense: no contrast, no region, two regions of similar size (unless just
one of them is joined to the robot base the camera sees), or a region running
off the image.

Deviation from the paper (see ``docs/paper-method.md``): the largest region is
closed with a small disk and its holes are filled. A shiny tube reflects
bands of the scene along its length whose brightness crosses the
background's, so the difference drops below the threshold in thin cracks
*inside* the tube; the centerline erosion that follows reads every crack as
the tube's edge and breaks up. The closing seals cracks open at an end of the
silhouette (it is no wider than half the thinner tube, so it joins nothing
that is apart by more than that); hole filling removes the rest, up to a
size: a hole wider than the widest tube is background enclosed by a robot
that crosses itself in the image, and is kept.

A second deviation: when the tube radii in the image are known, "the
largest region" is the largest one *as wide as a tube*. Camera jitter leaves
thin lines along high-contrast edges of the set (the actuation unit, the
camera mount) in the difference of every frame; in a frame without the robot,
the normalization stretches them over the threshold, and the largest of them
would be taken for the robot.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .errors import FrameError
from .morphology import disk

__all__ = ["SilhouetteParams", "extract_silhouette", "hysteresis_threshold", "BORDERS"]

#: Image borders by name, in the order they are reported.
BORDERS = ("left", "right", "top", "bottom")


@dataclass(frozen=True)
class SilhouetteParams:
    """Parameters of :func:`extract_silhouette`.

    Attributes
    ----------
    threshold : float
        Binarization threshold on the normalized difference (paper: 0.25).
    min_contrast : float
        Minimum raw ``max |frame - background|`` (gray levels). Below it the
        frame holds no robot: normalization would turn sensor noise into a
        silhouette.
    min_area_px : int
        Smallest acceptable silhouette (px). A 1.6 mm tube at 0.12 mm/px covers
        ~13 px per px of length, so 200 px is ~2 mm of robot.
    ambiguity_ratio : float
        The frame is rejected when the second-largest region has at least this
        fraction of the largest's area: which one is the robot is then a guess.
    border_margin_px : int
        A region within this many pixels of an image border touches it.
    allowed_borders : tuple of str
        Borders ("left", "right", "top", "bottom") the robot may cross, e.g.
        the one the actuation unit sits behind.
    fill_holes : bool
        Fill the region's holes (not in the paper; see the module docstring).
        Holes wider than ``max_hole_radius_px`` (argument of
        :func:`extract_silhouette`) are kept.
    min_width_fraction : float
        With ``tube_radii_px`` (argument of :func:`extract_silhouette`), a
        region is the robot only if its inscribed radius is at least this
        fraction of the thinner tube's radius in the image (not in the paper;
        see the module docstring). 0 disables the test. Half: a shiny tube
        whose shaded side is as gray as the backdrop shows about half its
        width (wide-2-47 frame 2: 7.4 px of an 11.1 px tube, refused at 0.7).
    close_tube_fraction : float
        Radius of the closing disk as a fraction of the thinnest tube's radius
        in the image (``tube_radii_px`` argument of
        :func:`extract_silhouette`; no closing without it), at least 1 px.
        0.5 on the paper's tubes: a 2 px disk, which seals cracks up to ~4 px
        wide in a 8.6 px inner tube.
    group_gap_fraction : float
        With ``tube_radii_px``, regions less than this many outer-tube
        diameters apart count as one region (not in the paper): a tube whose
        brightness matches the backdrop over a short stretch breaks the
        thresholded silhouette into pieces, and the largest piece alone would
        silently drop the rest of the robot. 0 disables it.
    hysteresis_sigma, hysteresis_floor : float
        The low threshold of the hysteresis (``low_threshold`` argument of
        :func:`extract_silhouette`, see :func:`hysteresis_threshold`): this
        many times the frame's robust noise level of the difference, and at
        least ``hysteresis_floor`` (normalized). ``hysteresis_sigma = 0``:
        none (the paper's single threshold).
    """

    threshold: float = 0.25
    min_contrast: float = 12.0
    min_area_px: int = 200
    ambiguity_ratio: float = 0.6
    border_margin_px: int = 1
    allowed_borders: tuple = ()
    fill_holes: bool = True
    close_tube_fraction: float = 0.5
    min_width_fraction: float = 0.5
    group_gap_fraction: float = 1.0
    hysteresis_sigma: float = 4.0
    hysteresis_floor: float = 0.05
    hysteresis_floor_dn: float = 4.0

    def __post_init__(self):
        bad = [b for b in self.allowed_borders if b not in BORDERS]
        if bad:
            raise ValueError(f"SilhouetteParams.allowed_borders: unknown border {bad[0]!r} (one of {', '.join(BORDERS)})")
        if not 0.0 < self.threshold < 1.0:
            raise ValueError(f"SilhouetteParams.threshold must be in (0, 1), got {self.threshold}")
        if not self.close_tube_fraction >= 0.0:
            raise ValueError(f"SilhouetteParams.close_tube_fraction must be >= 0, got {self.close_tube_fraction}")
        object.__setattr__(self, "allowed_borders", tuple(self.allowed_borders))


def hysteresis_threshold(diff: np.ndarray, params: SilhouetteParams, max_difference_dn: float | None = None) -> float | None:
    """Low threshold (normalized) for :func:`extract_silhouette`, or None (no hysteresis).

    ``hysteresis_sigma`` times the noise level of the normalized difference,
    estimated robustly as its median over the frame / 0.6745 (the robot covers
    a few percent of it), at least ``hysteresis_floor``, at most the
    threshold. Sampled every 7th pixel: the median of 5 megapixels costs more
    than the rest of the stage.

    With ``max_difference_dn`` (the difference that normalized to 1, gray
    levels), the low threshold is also at least ``hysteresis_floor_dn`` gray
    levels: in a frame without the robot the normalizing peak is a jitter edge of
    a few gray levels, and a purely relative low threshold would grow broad
    sub-noise ripples of the backdrop into a "robot" reaching the image border.

    Parameters
    ----------
    diff : (H, W) array
        The normalized difference image (0 to 1; 1 is the frame's largest difference).
    params : SilhouetteParams
        ``hysteresis_sigma``, ``hysteresis_floor`` (normalized), ``hysteresis_floor_dn``
        (gray levels) and ``threshold`` (normalized) are used.
    max_difference_dn : float, optional
        The difference (gray levels, 0-255 scale) that normalized to 1; None or <= 0: no
        gray-level floor.

    Returns
    -------
    float or None
        The low threshold (normalized, below ``params.threshold``), or None when
        ``hysteresis_sigma`` is 0 or the low threshold would reach the threshold itself.
    """
    if not params.hysteresis_sigma > 0:
        return None
    sample = np.ascontiguousarray(diff).reshape(-1)[::7]
    sigma = float(np.median(sample)) / 0.6745
    low = max(params.hysteresis_sigma * sigma, params.hysteresis_floor)
    if max_difference_dn is not None and max_difference_dn > 0:
        low = max(low, params.hysteresis_floor_dn / float(max_difference_dn))
    return low if low < params.threshold else None


def _touched_borders(x: int, y: int, w: int, h: int, shape, margin: int) -> list:
    H, W = shape
    touched = {
        "left": x <= margin,
        "right": x + w - 1 >= W - 1 - margin,
        "top": y <= margin,
        "bottom": y + h - 1 >= H - 1 - margin,
    }
    return [b for b in BORDERS if touched[b]]


def extract_silhouette(
    diff: np.ndarray,
    params: SilhouetteParams = SilhouetteParams(),
    camera_name: str | None = None,
    *,
    max_difference: float | None = None,
    tube_radii_px=None,
    max_hole_radius_px: float | None = None,
    low_threshold: float | None = None,
    attach_gap_px: float | None = None,
    base_px=None,
) -> np.ndarray:
    """Robot silhouette from a normalized difference image.

    Parameters
    ----------
    diff : (H, W) float array
        Normalized absolute difference in [0, 1] (see
        :func:`recon.background.difference_image`).
    params : SilhouetteParams
    camera_name : str, optional
        Prefix of error messages.
    max_difference : float, optional
        Raw maximum difference (gray levels) of the frame; when given, frames
        below ``params.min_contrast`` are rejected.
    tube_radii_px : sequence of float, optional
        Radii (px) of the tubes in the image; the thinnest sizes the closing
        (``params.close_tube_fraction``) and the narrowest region that can be
        the robot (``params.min_width_fraction``). Neither without it.
    max_hole_radius_px : float, optional
        Holes whose inscribed radius (px) exceeds this are not filled; default
        the largest of ``tube_radii_px`` plus 1 px (all holes without it).
    low_threshold : float, optional
        Hysteresis (not in the paper): pixels above this (normalized, below
        ``params.threshold``) belong to the silhouette when they are
        connected to a pixel above ``params.threshold``. Where a metallic
        tube crosses a backdrop of its own brightness its difference falls
        to a few noise levels; the paper's threshold alone cuts the tube
        into a highlight and a shadow band, each too thin for the erosions.
    attach_gap_px : float, optional
        Regions as wide as a tube and of at least ``min_area_px`` within this
        distance (px) of the largest join the silhouette (not in the paper):
        the rest of a tube beyond a stretch where it matched the backdrop.
        They are then no competitor in the "two blobs" test.
    base_px : (2,) array_like, optional
        Where the robot leaves its base in the image (px), when the camera
        sees it (not in the paper). Of two regions of similar size, the one
        that reaches within :func:`_base_reach_px` of it is the robot where
        the other does not: the robot is joined to its base, clutter whose
        edges jitter into a region as large is not (wide-3-20 frame 0).

    Returns
    -------
    (H, W) bool array
        The largest 8-connected region of ``diff > threshold``, closed and
        with its holes filled (see the module docstring).

    Raises
    ------
    FrameError
        No contrast, no region (as wide as a tube) or too small a one, two
        regions of similar size, or the region touching a border not in
        ``allowed_borders``.
    """
    if max_difference is not None and max_difference < params.min_contrast:
        raise FrameError(
            f"no silhouette (max difference {max_difference:.3g} < {params.min_contrast:g} gray levels)", camera_name
        )
    binary = np.greater(diff, params.threshold).view(np.uint8)
    if low_threshold is not None and low_threshold < params.threshold:
        binary = _hysteresis(diff, binary, low_threshold)
    # Grana's algorithm with stats is ~3x faster than the default on 1024x768.
    n, labels, stats, _ = cv2.connectedComponentsWithStatsWithAlgorithm(binary, 8, cv2.CV_32S, cv2.CCL_GRANA)
    if n <= 1:
        raise FrameError(f"no silhouette (no pixel above {params.threshold:g})", camera_name)
    group_of = None
    if tube_radii_px is not None and params.group_gap_fraction > 0 and n > 2:
        n, labels, stats, group_of = _group_pieces(binary, labels, stats, tube_radii_px, params, camera_name)
    areas = stats[1:, cv2.CC_STAT_AREA]
    order = [int(i) + 1 for i in np.argsort(areas, kind="stable")[::-1]]
    a0 = int(stats[order[0], cv2.CC_STAT_AREA])
    if a0 < params.min_area_px:
        raise FrameError(f"no silhouette (largest region {a0} px < {params.min_area_px} px)", camera_name)
    if tube_radii_px is not None and params.min_width_fraction > 0:
        # Only regions as wide as a tube can be the robot: the edges that
        # camera jitter leaves in the difference of a robot-free frame are
        # thin lines, however long or contrasted.
        need = params.min_width_fraction * float(min(tube_radii_px))
        widths = {i: _half_width(labels, stats[i], i, group_of) for i in order[:_WIDTH_CANDIDATES]}
        regions = [i for i, w in widths.items() if w >= need]
        if not regions:
            raise FrameError(
                f"no silhouette (largest region {a0} px, but no region as wide as a tube: "
                f"the widest is {2 * max(widths.values()):.1f} px across, the thinner tube {2 * float(min(tube_radii_px)):.1f} px)",
                camera_name,
            )
    else:
        regions, widths = order, {}
    largest = regions[0]
    a1 = int(stats[largest, cv2.CC_STAT_AREA])
    if a1 < params.min_area_px:
        raise FrameError(f"no silhouette (largest region {a1} px < {params.min_area_px} px)", camera_name)
    # An attached piece wider than a tube is clutter, not the rest of a tube (wide-8-38 frame 0).
    narrow = regions
    if tube_radii_px is not None:
        wide_px = _ATTACH_WIDTH_FACTOR * float(max(tube_radii_px)) + 1.0
        narrow = [i for i in regions if (widths[i] if i in widths else _half_width(labels, stats[i], i, group_of)) <= wide_px]

    def members_of(main: int) -> list:
        return _members(labels, stats, main, [main] + [i for i in narrow if i != main], attach_gap_px, params.min_area_px, group_of)

    members = members_of(largest)
    rest = [i for i in regions if i not in members]
    if rest:
        a2 = int(stats[rest[0], cv2.CC_STAT_AREA])
        if a2 >= params.ambiguity_ratio * a1:
            at_base = _at_base(labels, (largest, rest[0]), base_px, tube_radii_px, group_of)
            if at_base is None:
                raise FrameError(f"two blobs of similar size ({a1} px and {a2} px)", camera_name)
            if at_base != largest:
                largest = at_base
                members = members_of(largest)
    (x, y, w, h), off = _extent(stats, members, diff.shape, params)
    if off:
        at_base = _off_base_robot(labels, stats, largest, regions, base_px, tube_radii_px, params.min_area_px, group_of)
        if at_base is not None:
            base_members = members_of(at_base)
            base_extent, base_off = _extent(stats, base_members, diff.shape, params)
            if not base_off:
                largest, members, (x, y, w, h), off = at_base, base_members, base_extent, base_off
    if off:
        where = off[0] if len(off) == 1 else ", ".join(off[:-1]) + " and " + off[-1]
        raise FrameError(f"robot leaves the view at the {where} border{'s' if len(off) > 1 else ''}", camera_name)
    region = labels == largest if len(members) == 1 else np.isin(labels, members)
    if group_of is not None:
        region &= group_of.view(bool)
    close_px = 0
    if tube_radii_px is not None and params.close_tube_fraction > 0:
        close_px = max(1, int(round(params.close_tube_fraction * float(min(tube_radii_px)))))
    if max_hole_radius_px is None and tube_radii_px is not None:
        max_hole_radius_px = float(max(tube_radii_px)) + 1.0
    if close_px or params.fill_holes:
        region = _close_and_fill(region, (x, y, w, h), close_px, params.fill_holes, max_hole_radius_px)
    return region


def _extent(stats, members, shape, params: SilhouetteParams) -> tuple:
    """The bounding box ``(x, y, w, h)`` (px) of regions ``members`` and the borders it touches that the robot may not cross."""
    x0 = min(int(stats[i, 0]) for i in members)
    y0 = min(int(stats[i, 1]) for i in members)
    x1 = max(int(stats[i, 0] + stats[i, 2]) for i in members)
    y1 = max(int(stats[i, 1] + stats[i, 3]) for i in members)
    box = (x0, y0, x1 - x0, y1 - y0)
    return box, [b for b in _touched_borders(*box, shape, params.border_margin_px) if b not in params.allowed_borders]


def _off_base_robot(labels, stats, largest: int, regions, base_px, tube_radii_px, min_area_px: int, binary=None):
    """Where the largest region runs off the image away from the base the camera sees: the largest of ``regions``
    (of at least ``min_area_px``) that reaches the base instead (None where the largest reaches it, or no other does).

    The robot is joined to its base. A region that does not come near it and
    runs off the image is light or clutter (a brightening across a plain
    backdrop, wide-8-2 frame 2), not a robot leaving the view.
    """
    if base_px is None or _at_base(labels, (largest,), base_px, tube_radii_px, binary) is not None:
        return None
    for i in regions:
        if i != largest and stats[i, cv2.CC_STAT_AREA] >= min_area_px and _at_base(labels, (i,), base_px, tube_radii_px, binary) is not None:
            return i
    return None


def _hysteresis(diff: np.ndarray, strong: np.ndarray, low_threshold: float) -> np.ndarray:
    """Pixels above ``low_threshold`` connected (8-neighbours) to a pixel of ``strong`` (uint8 masks)."""
    weak = np.greater(diff, low_threshold).view(np.uint8)
    nw, wlab = cv2.connectedComponentsWithAlgorithm(weak, 8, cv2.CV_32S, cv2.CCL_GRANA)
    seeded = np.zeros(nw, bool)
    seeded[wlab[strong.view(bool)]] = True
    seeded[0] = False
    return seeded[wlab].view(np.uint8)


def _group_pieces(binary: np.ndarray, labels: np.ndarray, stats: np.ndarray, tube_radii_px, params: SilhouetteParams,
                  camera_name) -> tuple:
    """Regions less than ``group_gap_fraction`` tube diameters apart as one (see :func:`_group_regions`).

    Only pieces at least a tube's width square are grouped: noise specks of a low
    threshold, a few pixels each, would otherwise chain across the frame.
    """
    gap = params.group_gap_fraction * 2.0 * float(max(tube_radii_px))
    piece_px = max(4, int((2.0 * float(min(tube_radii_px))) ** 2))
    small = stats[:, cv2.CC_STAT_AREA] < piece_px
    small[0] = False
    if small.any():
        binary = (binary.view(bool) & ~small[labels]).view(np.uint8)
    n, labels, stats, group_of = _group_regions(binary, labels, stats, gap)
    if n <= 1:
        raise FrameError(f"no silhouette (only specks above {params.threshold:g}, none of {piece_px} px)", camera_name)
    return n, labels, stats, group_of


# Regions, largest first, whose width is checked (the robot is among the largest).
_WIDTH_CANDIDATES = 8
# An attached piece's inscribed radius may exceed the outer tube's by half (a tube crossing itself,
# blur and hysteresis at its rim) plus a pixel; clutter beyond the gap is wider.
_ATTACH_WIDTH_FACTOR = 1.5


def _members(labels, stats, main: int, regions, attach_gap_px, min_area_px: int, binary=None) -> list:
    """Region ``main`` and the pieces of the same tube beyond a stretch the threshold lost: every further region
    of ``regions`` (as wide as a tube, no wider than one) within ``attach_gap_px`` of it joins it (the backbone
    bridges such gaps in 3-D)."""
    others = [i for i in regions if i != main]
    if attach_gap_px is None or not others:
        return [main]
    return [main] + _attached(labels, stats, main, others, attach_gap_px, min_area_px, binary)


def _base_reach_px(tube_radii_px) -> float:
    """How near (px) the projected robot base a region must come to be the robot's: two outer tube widths (the
    base's own cross-section less what the threshold loses at its rim), at least 4 px."""
    return max(4.0, 4.0 * float(max(tube_radii_px))) if tube_radii_px is not None else 4.0


def _at_base(labels, candidates, base_px, tube_radii_px, binary=None):
    """The one of ``candidates`` (labels) with a pixel within :func:`_base_reach_px` of ``base_px``; None where no
    base is given, or where none or both reach it."""
    if base_px is None:
        return None
    H, W = labels.shape
    r = _base_reach_px(tube_radii_px)
    u, v = float(base_px[0]), float(base_px[1])
    x0, y0, x1, y1 = max(int(u - r), 0), max(int(v - r), 0), min(int(u + r) + 1, W), min(int(v + r) + 1, H)
    if x0 >= x1 or y0 >= y1:
        return None
    yy, xx = np.mgrid[y0:y1, x0:x1]
    near = (xx - u) ** 2 + (yy - v) ** 2 <= r * r
    if binary is not None:
        near &= binary[y0:y1, x0:x1].view(bool)
    found = [i for i in candidates if np.any(near & (labels[y0:y1, x0:x1] == i))]
    return found[0] if len(found) == 1 else None


def _attached(labels, stats, main: int, others, gap_px: float, min_area_px: int, binary=None) -> list:
    """Labels of ``others`` (area >= ``min_area_px``) whose pixels come within ``gap_px`` of region ``main``."""
    H, W = labels.shape
    x, y, w, h = (int(v) for v in stats[main, :4])
    g = int(np.ceil(gap_px)) + 1
    x0, y0, x1, y1 = max(x - g, 0), max(y - g, 0), min(x + w + g, W), min(y + h + g, H)
    crop = labels[y0:y1, x0:x1]
    not_main = crop != main
    if binary is not None:
        not_main |= ~binary[y0:y1, x0:x1].view(bool)
    dist = cv2.distanceTransform(not_main.view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5)
    out = []
    for i in others:
        if int(stats[i, cv2.CC_STAT_AREA]) < min_area_px:
            continue
        on = crop == i
        if binary is not None:
            on &= binary[y0:y1, x0:x1].view(bool)
        if on.any() and float(dist[on].min()) <= gap_px:
            out.append(i)
    return out


def _group_regions(binary: np.ndarray, labels: np.ndarray, stats: np.ndarray, gap_px: float):
    """Regions of ``binary`` less than ``gap_px`` apart merged into one label each.

    Returns ``(n, labels, stats, binary)`` as :func:`cv2.connectedComponentsWithStats`
    would for the merged regions: the labels cover the gaps between the
    pieces too (mask them with ``binary``), the areas count pixels of
    ``binary`` only.
    """
    r = max(1, int(np.ceil(0.5 * gap_px)))
    grown = cv2.dilate(binary, disk(r))
    n, glab, gstats, _ = cv2.connectedComponentsWithStatsWithAlgorithm(grown, 8, cv2.CV_32S, cv2.CCL_GRANA)
    on = binary.view(bool)
    area = np.bincount(glab[on], minlength=n)
    gstats = gstats.copy()
    gstats[:, cv2.CC_STAT_AREA] = area
    # Bounding boxes of the pieces (not of the grown region).
    for g in range(1, n):
        x, y, w, h = (int(v) for v in gstats[g, :4])
        sub = (glab[y : y + h, x : x + w] == g) & on[y : y + h, x : x + w]
        bx, by, bw, bh = cv2.boundingRect(sub.view(np.uint8))
        gstats[g, :4] = (x + bx, y + by, bw, bh)
    return n, glab, gstats, binary


def _half_width(labels: np.ndarray, stat, label: int, binary=None) -> float:
    """Inscribed radius (px) of one labelled region: its distance transform's maximum less half a pixel."""
    x, y, w, h = (int(v) for v in stat[:4])
    crop = np.zeros((h + 2, w + 2), np.uint8)
    crop[1:-1, 1:-1] = labels[y : y + h, x : x + w] == label
    if binary is not None:
        crop[1:-1, 1:-1] &= binary[y : y + h, x : x + w]
    return float(cv2.distanceTransform(crop, cv2.DIST_L2, cv2.DIST_MASK_5).max()) - 0.5


def _close_and_fill(region: np.ndarray, rect, close_px: int, fill: bool, max_hole_radius_px) -> np.ndarray:
    """Close ``region`` with a disk of ``close_px`` and fill its holes, on its bounding box only.

    The box is padded with background beyond the image too, so the closing
    only ever adds pixels and the flood fill from the padded corner reaches
    all the background around the region.
    """
    H, W = region.shape
    x, y, w, h = rect
    pad = close_px + 2
    canvas = np.zeros((h + 2 * pad, w + 2 * pad), np.uint8)
    canvas[pad : pad + h, pad : pad + w] = region[y : y + h, x : x + w]
    if close_px:
        canvas = cv2.morphologyEx(canvas, cv2.MORPH_CLOSE, disk(close_px), borderType=cv2.BORDER_CONSTANT, borderValue=0)
    if fill:
        # Background reached from outside is 2; the holes stay 0.
        reach = canvas.copy()
        cv2.floodFill(reach, None, (0, 0), 2)
        holes = (reach == 0).view(np.uint8)
        if max_hole_radius_px is not None and holes.any():
            # Keep holes wider than any tube: background enclosed by a loop of the robot.
            n, lab = cv2.connectedComponents(holes, connectivity=4)
            depth = cv2.distanceTransform(holes, cv2.DIST_L2, cv2.DIST_MASK_5)
            widest = np.zeros(n, np.float32)
            at = np.flatnonzero(holes)
            np.maximum.at(widest, lab.ravel()[at], depth.ravel()[at])
            fillable = widest <= np.float32(max_hole_radius_px)
            fillable[0] = False
            holes = fillable[lab].view(np.uint8)
        canvas |= holes
    out = np.zeros((H, W), bool)
    out[y : y + h, x : x + w] = canvas[pad : pad + h, pad : pad + w].view(bool)
    return out
