"""Centerline extraction by two-disk erosion, with outer/inner labels."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from recon.camera import Camera
from recon.centerline import INNER, OUTER, CenterlineParams, centerline_params_for, extract_centerline
from recon.geometry import look_at

H, W = 300, 400
R_OUTER, R_INNER = 0.8 / 0.12, 0.5 / 0.12  # px: the paper's tubes at ~0.12 mm/px
PARAMS = CenterlineParams(outer_radius_px=5, inner_radius_px=3)


def segment_distance(a, b):
    """Distance (px) of every pixel centre to the segment a-b, and the position along it (0..1)."""
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    a, b = np.asarray(a, float), np.asarray(b, float)
    ab = b - a
    t = np.clip(((xx - a[0]) * ab[0] + (yy - a[1]) * ab[1]) / (ab @ ab), 0.0, 1.0)
    return np.hypot(xx - a[0] - t * ab[0], yy - a[1] - t * ab[1]), t


def two_tube(a, m, b):
    """Silhouette of an outer tube a-m continued by an inner tube m-b (pixel coordinates x, y)."""
    d_out, _ = segment_distance(a, m)
    d_in, _ = segment_distance(m, b)
    return (d_out <= R_OUTER) | (d_in <= R_INNER)


@pytest.mark.parametrize(
    "a, m, b",
    [((40, 150), (220, 150), (360, 150)), ((40, 40), (200, 160), (340, 265))],
    ids=["horizontal", "diagonal"],
)
def test_centerline_on_axis_with_labels(a, m, b):
    sil = two_tube(a, m, b)
    cl, labels = extract_centerline(sil, PARAMS)
    assert cl.dtype == bool and labels.dtype == np.uint8
    np.testing.assert_array_equal(cl, labels > 0)
    d_out, t_out = segment_distance(a, m)
    d_in, t_in = segment_distance(m, b)
    outer, inner = labels == OUTER, labels == INNER
    # The erosion leaves a band (tube radius - disk radius = 1.7 px on either
    # side of the axis); its middle lies within 1 px of the true axis.
    assert np.minimum(d_out, d_in)[cl].max() <= 2.0
    assert band_middle_offset(outer, a, m) <= 1.0
    assert band_middle_offset(inner, m, b) <= 1.0
    L_out = np.hypot(*np.subtract(m, a))
    L_in = np.hypot(*np.subtract(b, m))
    # Outer pixels lie along the outer tube (its capsule end included), inner
    # pixels beyond the step; no inner line runs alongside the outer tube.
    assert np.all(along_unclipped(a, m)[outer] <= L_out + R_OUTER)
    assert np.all(along_unclipped(m, b)[inner] >= 0.0)
    assert np.all(d_out[inner] > 2.5)
    # Both centerlines cover their tube, less the erosion at the ends.
    cover_out = np.ptp(t_out[outer]) * L_out
    cover_in = np.ptp(t_in[inner]) * L_in
    assert cover_out >= L_out - 2 * PARAMS.outer_radius_px - 2
    assert cover_in >= L_in - 2 * PARAMS.inner_radius_px - 8


def band_middle_offset(mask, a, b):
    """Largest |mean signed distance| (px) of ``mask``'s pixels to the line a->b, per 2-px slice along it."""
    ys, xs = np.nonzero(mask)
    u = np.subtract(b, a) / np.hypot(*np.subtract(b, a))
    rel = np.stack([xs - a[0], ys - a[1]], axis=1)
    offset = rel @ np.array([-u[1], u[0]])
    slices = np.floor(rel @ u / 2.0).astype(int)
    slices -= slices.min()
    counts, sums = np.bincount(slices), np.bincount(slices, offset)
    used = counts > 0
    return np.abs(sums[used] / counts[used]).max()


def along_unclipped(a, b):
    """Signed position (px) of every pixel centre along the line a->b, from a."""
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    u = np.subtract(b, a) / np.hypot(*np.subtract(b, a))
    return (xx - a[0]) * u[0] + (yy - a[1]) * u[1]


def test_single_tube_is_all_outer():
    d, _ = segment_distance((50, 100), (350, 200))
    cl, labels = extract_centerline(d <= R_OUTER, PARAMS)
    assert cl.sum() > 250 and not np.any(labels == INNER)


def test_thin_tube_is_all_inner():
    d, _ = segment_distance((50, 100), (350, 200))
    cl, labels = extract_centerline(d <= R_INNER, PARAMS)
    assert cl.sum() > 250 and not np.any(labels == OUTER)


def test_small_regions_removed():
    sil = two_tube((40, 150), (220, 150), (360, 150))
    yy, xx = np.mgrid[0:H, 0:W]
    sil |= np.hypot(xx - 100, yy - 60) <= 5.5  # a blob that erodes to a speck
    _, labels = extract_centerline(sil, CenterlineParams(5, 3, min_region_px=10))
    assert not labels[50:70, 90:110].any()


def test_empty_silhouette():
    cl, labels = extract_centerline(np.zeros((H, W), bool), PARAMS)
    assert not cl.any() and not labels.any()


def test_params_from_tube_radii():
    K = np.array([[2580.0, 0, 511.5], [0, 2580.0, 383.5], [0, 0, 1]])
    cam = Camera("side", 1024, 768, K, T_cam_world=look_at([50, -300, 0], [50, 0, 0], [0, 0, -1]))
    p = centerline_params_for(cam, 0.8, 0.5, [50, 0, 0])
    # 0.8 mm and 0.5 mm at 300/2580 = 0.116 mm/px: 6.9 px and 4.3 px, one px less, floored.
    assert (p.outer_radius_px, p.inner_radius_px) == (5, 3)


def test_invalid_radii():
    with pytest.raises(ValueError):
        CenterlineParams(outer_radius_px=3, inner_radius_px=5)


def test_disk_radii_from_tube_radii():
    from recon.centerline import disk_radii

    # The paper's tubes at 0.116 mm/px, silhouettes 0.5 px narrower per side.
    assert disk_radii(6.9, 4.3, 0.5) == (5, 3)
    # Half-way between the tubes' half-widths (6.4 and 3.8 px): the large disk
    # fits in the outer silhouette and not in the inner one, with margin.
    r_out, r_in = disk_radii(6.9, 4.3, 0.5)
    assert 3.8 + 0.5 <= r_out <= 6.4 - 0.5 + 1e-9
    # Bigger images, bigger disks; never below 2 and 1.
    assert disk_radii(13.8, 8.6, 1.0) == (10, 7)
    assert disk_radii(1.5, 1.0, 0.5) == (2, 1)


def test_edge_loss_measured_from_the_silhouette():
    from recon.centerline import measure_edge_loss

    params = CenterlineParams(outer_tube_px=R_OUTER, inner_tube_px=R_INNER, edge_loss_px=0.5)
    a, m, b = (40, 150), (220, 150), (360, 150)
    d_out, _ = segment_distance(a, m)
    d_in, _ = segment_distance(m, b)
    for loss in (0.0, 1.0):
        sil = (d_out <= R_OUTER - loss) | (d_in <= R_INNER - loss)
        # Pixel rows quantize a band's width: within half a pixel.
        assert measure_edge_loss(sil, params) == pytest.approx(loss, abs=0.5)
    assert measure_edge_loss(np.zeros((H, W), bool), params) is None


def test_adaptive_disks_follow_the_measured_width():
    a, m, b = (40, 150), (220, 150), (360, 150)
    d_out, _ = segment_distance(a, m)
    d_in, _ = segment_distance(m, b)
    # Silhouettes 1.5 px narrower per side than the tubes: the fixed disks
    # (5 and 3) would leave almost nothing of the inner tube.
    sil = (d_out <= R_OUTER - 1.5) | (d_in <= R_INNER - 1.5)
    params = CenterlineParams(outer_tube_px=R_OUTER, inner_tube_px=R_INNER)
    info = {}
    cl, labels = extract_centerline(sil, params, info=info)
    assert info["edge_loss_px"] == pytest.approx(1.5, abs=0.5)
    assert (info["outer_radius_px"], info["inner_radius_px"]) == (4, 2)
    assert np.ptp(np.nonzero(labels == INNER)[1]) >= 140 - 2 * 2 - 8
    assert np.ptp(np.nonzero(labels == OUTER)[1]) >= 180 - 2 * 4 - 2


def test_dashed_line_kept_speck_removed():
    from recon.centerline import remove_small_regions

    m = np.zeros((40, 100), np.uint8)
    m[20, 10:90:4] = 1  # dashes of 2 px, 2 px apart: 40 px in all
    m[20, 11:90:4] = 1
    m[5, 50:53] = 1  # a 3 px speck
    kept = remove_small_regions(m, 10, gap_px=2)
    assert kept[20].sum() == 40 and not kept[5].any()
    assert not remove_small_regions(m, 10).any()


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), density=st.floats(0.05, 0.6), min_px=st.integers(1, 30))
def test_small_regions_removed_as_skimage_removes_them(seed, density, min_px):
    """With no gap, remove_small_regions (OpenCV's labels, kept for speed: docs/libraries.md) keeps
    exactly the 8-connected regions that scikit-image's remove_small_objects keeps."""
    from skimage.morphology import remove_small_objects

    from recon.centerline import remove_small_regions

    m = (np.random.default_rng(seed).random((60, 80)) < density).astype(np.uint8)
    expected = remove_small_objects(m.astype(bool), max_size=min_px - 1, connectivity=2)
    assert np.array_equal(remove_small_regions(m, min_px), expected)


def test_thin_stretch_bridged():
    from recon.centerline import THIN

    a, m, b = (40, 150), (220, 150), (360, 150)
    d_out, _ = segment_distance(a, m)
    d_in, _ = segment_distance(m, b)
    sil = (d_out <= R_OUTER) | (d_in <= R_INNER)
    yy, xx = np.mgrid[0:H, 0:W]
    sil &= ~((xx >= 270) & (xx < 310) & (yy < 150))  # the inner tube's upper half lost over 40 px
    cl, labels = extract_centerline(sil, PARAMS)
    cols = np.unique(np.nonzero(cl)[1])
    # No gap along the robot wider than a voxel footprint bridges (~2 x 4.7 px).
    assert np.diff(cols[cols >= 230]).max() <= 8
    thin = labels == THIN
    assert thin.any() and np.all((xx[thin] >= 262) & (xx[thin] < 318))
    assert np.abs(yy[thin] - 150).max() <= 3  # within the lower half of the tube


def test_a_silhouette_barely_wider_than_the_outer_tube_keeps_a_line_through_the_specks():
    # wide-2-38 frame 0 (top view, fabric): a silhouette about as wide as the outer tube, ragged at its
    # edges. The large disk fits only at the bumps: specks, dropped as small regions, whose region still
    # took the band's middle with it, so neither line nor bridge survived along 46 mm of robot.
    from recon.centerline import THIN

    params = CenterlineParams(outer_radius_px=3, inner_radius_px=2)
    d, _ = segment_distance((30, 150), (370, 150))
    yy, xx = np.mgrid[0:H, 0:W]
    phase, span = (xx - 30) % 16, (xx >= 30) & (xx <= 370)
    above = (phase < 7) & (yy >= 146) & (yy < 150) & span  # 2 px more on top over 7 px, every 16 px
    below = (phase >= 8) & (phase < 15) & (yy > 150) & (yy <= 154) & span  # and below, in between
    sil = (d <= 2.6) | above | below  # 5 px wide, 7 px at the bumps: the large disk fits only there
    assert _pieces_after_erosion(sil, 3) > 20
    cl, labels = extract_centerline(sil, params)
    cols = np.unique(np.nonzero(cl)[1])
    assert cols.min() <= 40 and cols.max() >= 360
    assert np.diff(cols).max() <= 8, "a gap in the centerline wider than a voxel footprint bridges"
    assert np.abs(yy[labels == THIN] - 150).max() <= 1


def _pieces_after_erosion(sil, r):
    """Connected pieces left by eroding ``sil`` with a disk of radius ``r``."""
    import cv2

    from recon.morphology import disk

    n, _ = cv2.connectedComponents(cv2.erode(sil.astype(np.uint8), disk(r)), connectivity=8)
    return n - 1
