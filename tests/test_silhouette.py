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
