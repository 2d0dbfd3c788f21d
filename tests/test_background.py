"""Eigenbackground fitting, background estimation and difference images."""
import numpy as np
import pytest

from recon.background import (
    EigenBackgroundParams,
    background_estimate,
    difference_image,
    fit_eigenbackground,
    no_picture,
)
from recon.errors import FrameError

H, W = 60, 80
NOISE = 1.5


def clean_scene(gain=1.0, shift=0.0):
    """Textured background under a lighting gain, with a slight horizontal jitter (px)."""
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    return gain * (110 + 50 * np.sin((xx + shift) / 7.0) * np.cos(yy / 9.0) + 0.4 * xx)


def scene(rng, gain=1.0, shift=0.0):
    return clean_scene(gain, shift) + rng.normal(0.0, NOISE, (H, W))


def frames(rng, n=12):
    return np.stack([scene(rng, gain=rng.uniform(0.9, 1.1), shift=rng.uniform(-0.3, 0.3)) for _ in range(n)])


def test_held_out_frame_reconstructed_to_noise_level():
    rng = np.random.default_rng(0)
    model = fit_eigenbackground(frames(rng))
    truth = clean_scene(gain=1.07)
    est = background_estimate(model, truth + rng.normal(0.0, NOISE, (H, W)))
    assert est.dtype == np.float32 and est.shape == (H, W)
    # The estimate keeps the frame's lighting, to within the sensor noise.
    assert np.sqrt(np.mean((est - truth) ** 2)) <= NOISE
    # The mean image alone does not explain the gain change: the eigenspace does.
    assert np.sqrt(np.mean((model.mean.reshape(H, W) - truth) ** 2)) > 3 * NOISE


def test_basis_is_orthonormal_and_k_rows():
    model = fit_eigenbackground(frames(np.random.default_rng(1)), EigenBackgroundParams(k=5))
    assert model.basis.shape == (5, H * W) and model.basis.dtype == np.float32
    np.testing.assert_allclose(model.basis @ model.basis.T, np.eye(5), atol=1e-4)
    assert np.all(np.diff(model.eigenvalues) <= 0)


def test_foreground_object_stays_in_difference():
    rng = np.random.default_rng(2)
    model = fit_eigenbackground(frames(rng))
    frame = scene(rng, gain=0.95)
    frame[20:30, 30:60] = 20.0  # a dark object ~100 gray levels below the scene
    diff, peak = difference_image(model, np.clip(frame, 0, 255).astype(np.uint8))
    assert diff.dtype == np.float32 and diff.max() == pytest.approx(1.0)
    assert peak > 60
    inside = np.zeros((H, W), bool)
    inside[20:30, 30:60] = True
    assert np.mean(diff[inside] > 0.25) > 0.95
    assert np.mean(diff[~inside] > 0.25) < 0.01


def test_frame_without_object_has_low_raw_difference():
    rng = np.random.default_rng(3)
    model = fit_eigenbackground(frames(rng))
    _, peak = difference_image(model, scene(rng, gain=1.03))
    assert peak < 12  # below the silhouette stage's default min_contrast


def test_too_few_frames():
    rng = np.random.default_rng(4)
    with pytest.raises(ValueError, match=r"need at least k\+1=6 background frames, got 5"):
        fit_eigenbackground(frames(rng, 5))


def test_frames_of_different_sizes():
    rng = np.random.default_rng(5)
    fr = list(frames(rng, 6)) + [np.zeros((H + 1, W))]
    with pytest.raises(ValueError, match="different sizes"):
        fit_eigenbackground(fr)


def test_wrong_frame_size_names_both_sizes():
    model = fit_eigenbackground(frames(np.random.default_rng(6)))
    with pytest.raises(FrameError, match=r"^side: frame is 81x60 but the background model is 80x60$"):
        difference_image(model, np.full((H, W + 1), 100, np.uint8), "side")


def test_all_black_frame():
    model = fit_eigenbackground(frames(np.random.default_rng(7)))
    with pytest.raises(FrameError, match=r"^top: all-black frame$"):
        difference_image(model, np.zeros((H, W), np.uint8), "top")


@pytest.mark.parametrize("level", [255.0, 128.0])
def test_blank_frame(level):
    # A saturated or flat picture is named as such, not taken for a robot that fills the view.
    model = fit_eigenbackground(frames(np.random.default_rng(7)))
    with pytest.raises(FrameError, match=rf"^top: blank frame \(every pixel about {level:.0f} gray levels\)"):
        difference_image(model, np.full((H, W), level, np.uint8), "top")
    assert no_picture(np.array([0.0, 0.0]), 0.0, 0.0) is None  # a black mask background: no camera fault


def test_static_scene_drops_null_directions():
    # Identical frames span no variation: no eigenbackground, estimate = mean.
    rng = np.random.default_rng(8)
    f = scene(rng)
    model = fit_eigenbackground(np.stack([f] * 7))
    assert model.k == 0
    np.testing.assert_allclose(background_estimate(model, f), f, atol=1e-3)


def test_float_frames_on_any_scale():
    # Frames scaled to [0, 1] work the same (the all-black test is relative).
    rng = np.random.default_rng(9)
    model = fit_eigenbackground(frames(rng) / 255.0)
    frame = scene(rng, gain=0.95)
    frame[20:30, 30:60] = 20.0
    diff, peak = difference_image(model, frame / 255.0)
    assert np.mean(diff[20:30, 30:60] > 0.25) > 0.95 and 60 / 255 < peak < 1.0
    with pytest.raises(FrameError, match="all-black"):
        difference_image(model, np.zeros((H, W)))
