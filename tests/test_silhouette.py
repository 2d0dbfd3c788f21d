"""Silhouette extraction: largest region, and the frames it refuses."""
import numpy as np
import pytest

from recon.errors import FrameError
from recon.silhouette import SilhouetteParams, extract_silhouette

H, W = 120, 160


def blank(noise_seed=0):
    # Low-level noise everywhere: stays below the 0.25 threshold.
    return np.random.default_rng(noise_seed).uniform(0.0, 0.2, (H, W)).astype(np.float32)


def test_keeps_largest_region_only():
    d = blank()
    d[40:50, 20:120] = 1.0  # robot: 1000 px
    d[90:95, 60:70] = 0.9  # speck: 50 px
    d[10, 10] = 0.8  # single pixel
    sil = extract_silhouette(d, SilhouetteParams(min_area_px=100))
    assert sil.dtype == bool
    assert sil.sum() == 1000 and sil[40:50, 20:120].all()


def test_eight_connectivity():
    d = blank()
    d[30:40, 20:60] = 1.0
    d[40:50, 60:100] = 1.0  # touches the first block only at a corner
    sil = extract_silhouette(d, SilhouetteParams(min_area_px=100))
    assert sil.sum() == 800


def test_two_blobs_of_similar_size():
    d = blank()
    d[20:30, 20:120] = 1.0  # 1000 px
    d[70:79, 20:120] = 1.0  # 900 px
    with pytest.raises(FrameError, match=r"^side: two blobs of similar size \(1000 px and 900 px\)$"):
        extract_silhouette(d, SilhouetteParams(min_area_px=100), "side")


def test_no_region():
    with pytest.raises(FrameError, match=r"^top: no silhouette"):
        extract_silhouette(blank(), SilhouetteParams(), "top")


def test_region_too_small():
    d = blank()
    d[50:55, 50:60] = 1.0
    with pytest.raises(FrameError, match=r"no silhouette \(largest region 50 px < 200 px\)"):
        extract_silhouette(d, SilhouetteParams(min_area_px=200))


def test_low_contrast_frame_rejected():
    d = blank()
    d[40:50, 20:120] = 1.0  # normalized, but from a raw maximum of only 5 gray levels
    with pytest.raises(FrameError, match=r"^side: no silhouette \(max difference 5 < 12 gray levels\)$"):
        extract_silhouette(d, SilhouetteParams(min_contrast=12), "side", max_difference=5.0)
    assert extract_silhouette(d, SilhouetteParams(min_area_px=100), "side", max_difference=80.0).sum() == 1000


def test_region_touching_a_border():
    d = blank()
    d[40:50, 60:] = 1.0
    with pytest.raises(FrameError, match=r"^side: robot leaves the view at the right border$"):
        extract_silhouette(d, SilhouetteParams(min_area_px=100), "side")
    d = blank()
    d[40:50, :] = 1.0
    with pytest.raises(FrameError, match=r"at the left and right borders$"):
        extract_silhouette(d, SilhouetteParams(min_area_px=100), "side")


def test_allowed_border():
    d = blank()
    d[40:50, :100] = 1.0  # enters from the left, where the actuation unit is
    sil = extract_silhouette(d, SilhouetteParams(min_area_px=100, allowed_borders=("left",)))
    assert sil.sum() == 1000


def test_unknown_border_name():
    with pytest.raises(ValueError, match="unknown border"):
        SilhouetteParams(allowed_borders=("west",))


def test_cracks_and_holes_filled():
    # A tube 13 px wide with a specular crack along it, open at the left end,
    # and a closed hole: both belong to the tube.
    d = blank()
    d[40:53, 20:140] = 1.0
    d[45:47, 20:100] = 0.1  # crack, 2 px wide, from the left end
    d[48:50, 110:130] = 0.1  # hole
    sil = extract_silhouette(d, SilhouetteParams(min_area_px=100), tube_radii_px=(6.9, 4.3))
    assert sil[40:53, 20:140].all()
    assert sil.sum() == 13 * 120
    # Without tube radii (no closing) only the enclosed hole is filled.
    sil = extract_silhouette(d, SilhouetteParams(min_area_px=100))
    assert sil[48:50, 110:130].all() and not sil[45:47, 20:100].any()


def test_loop_keeps_the_background_it_encloses():
    d = blank()
    d[20:30, 20:140] = d[90:100, 20:140] = 1.0
    d[20:100, 20:30] = d[20:100, 130:140] = 1.0  # a ring around 60 x 100 px of background
    sil = extract_silhouette(d, SilhouetteParams(min_area_px=100), tube_radii_px=(6.9, 4.3))
    assert not sil[35:85, 35:125].any()


def test_a_tube_showing_one_side_only_is_as_wide_as_a_tube():
    """A shiny tube whose shaded side is as gray as the backdrop shows about half its width (wide-2-47 frame 2:
    7.4 px of an 11.1 px inner tube, refused as no silhouette); a jitter line of 2 px still is not a tube."""
    d = blank()
    d[60:62, 5:155] = 1.0  # a jitter line (300 px)
    d[20:25, 40:100] = 1.0  # 5 px of a 8.6 px tube (300 px)
    sil = extract_silhouette(d, SilhouetteParams(min_area_px=100), tube_radii_px=(6.9, 4.3))
    assert sil[20:25, 40:100].all() and not sil[60:62].any()


def test_of_two_blobs_of_similar_size_the_one_at_the_base_is_the_robot():
    """Clutter whose edges jitter into a region as large as the robot: where the camera sees the base, the
    region joined to it is the robot; without a base, or with both (or neither) at it, the frame is refused."""
    d = blank()
    d[20:29, 10:70] = 1.0  # the robot, from its base at (10, 24)
    d[80:89, 90:145] = 1.0  # clutter, 495 px against 540
    kw = dict(tube_radii_px=(6.9, 4.3))
    sil = extract_silhouette(d, SilhouetteParams(min_area_px=100), base_px=(10.0, 24.0), **kw)
    assert sil[20:29, 10:70].all() and not sil[80:89].any()
    sil = extract_silhouette(d, SilhouetteParams(min_area_px=100), base_px=(92.0, 84.0), **kw)
    assert sil[80:89, 90:145].all() and not sil[20:29].any()
    for base in (None, (150.0, 10.0)):
        with pytest.raises(FrameError, match=r"^side: two blobs of similar size \(540 px and 495 px\)$"):
            extract_silhouette(d, SilhouetteParams(min_area_px=100), "side", base_px=base, **kw)


def test_only_regions_as_wide_as_a_tube():
    d = blank()
    d[60:62, 5:155] = 1.0  # a long thin edge line (300 px), like camera jitter leaves
    d[20:29, 40:70] = 1.0  # a 9 px wide tube (270 px)
    sil = extract_silhouette(d, SilhouetteParams(min_area_px=100), tube_radii_px=(6.9, 4.3))
    assert sil[20:29, 40:70].all() and not sil[60:62].any()
    d[20:29, 40:70] = 0.0
    with pytest.raises(FrameError, match=r"^side: no silhouette \(largest region 300 px, but no region as wide as a tube"):
        extract_silhouette(d, SilhouetteParams(min_area_px=100), "side", tube_radii_px=(6.9, 4.3))


def test_a_region_running_off_the_image_away_from_the_base_is_not_the_robot():
    """Light brightening one side of a plain backdrop (wide-8-2 frame 2) makes the largest region, and it runs
    off the image: where the camera sees the base, the region joined to the base is the robot. Without the
    base, or where the largest region reaches it, the frame is refused as before."""
    d = blank()
    d[20:29, 10:70] = 1.0  # the robot, from its base at (10, 24): 540 px
    d[40:100, 130:160] = 1.0  # light at the right border: 1800 px
    kw = dict(tube_radii_px=(6.9, 4.3))
    sil = extract_silhouette(d, SilhouetteParams(min_area_px=100), base_px=(10.0, 24.0), **kw)
    assert sil[20:29, 10:70].all() and not sil[60:120, 130:].any()
    for base in (None, (140.0, 90.0)):
        with pytest.raises(FrameError, match=r"^side: robot leaves the view at the right border$"):
            extract_silhouette(d, SilhouetteParams(min_area_px=100), "side", base_px=base, **kw)


def test_a_piece_wider_than_a_tube_beyond_a_gap_is_not_the_rest_of_the_tube():
    """Pieces within ``attach_gap_px`` of the robot join it (a tube beyond a stretch the threshold lost), but
    not a blob wider than the tube: clutter that runs off the image (wide-8-38 frame 0, 53 px below the robot)
    would make the robot "leave the view". A piece of the tube's own width still joins."""
    d = blank()
    d[20:29, 10:70] = 1.0  # the robot, 540 px
    d[90:120, 20:34] = 1.0  # a blob 61 px below it, 14 px wide, to the bottom border: 420 px
    d[20:29, 80:100] = 1.0  # the tube beyond a 10 px gap
    kw = dict(tube_radii_px=(3.0, 2.0), attach_gap_px=70.0)
    sil = extract_silhouette(d, SilhouetteParams(min_area_px=100, ambiguity_ratio=10.0), "side", **kw)
    assert sil[20:29, 10:70].all() and sil[20:29, 80:100].all() and not sil[90:].any()
