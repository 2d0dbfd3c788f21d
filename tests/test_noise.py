"""The twin's sensor model: expose() is its NumPy form, bit for bit, and its noise is shot + read noise.

The compiled per-pixel pass of :func:`twin.noise.expose` is checked against the NumPy
form of the same model (the oracle below, hashing the same keys into the same normal
levels), and its noise against the variance the model predicts (shot noise in
proportion to the signal, plus read noise) and against the independence of its draws.
No OpenGL: these tests run anywhere.
"""
from dataclasses import replace

import cv2
import numpy as np
import pytest

from twin.noise import _NORMAL_LEVELS, LUMA, expose, frame_rng, lighting_field
from twin.scene import NoiseModel

SHAPE = (96, 128)


def _hashed_normals(key: int, shape: tuple) -> np.ndarray:
    """The sensor's standard normals for image ``key``: SplitMix64 of key + counter * golden picks a level."""
    with np.errstate(over="ignore"):
        h = np.uint64(key) + np.arange(int(np.prod(shape)), dtype=np.uint64) * np.uint64(0x9E3779B97F4A7C15)
        h = (h ^ (h >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        h = (h ^ (h >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        h ^= h >> np.uint64(31)
    return _NORMAL_LEVELS[h & np.uint64(len(_NORMAL_LEVELS) - 1)].reshape(shape)


def _oracle(radiance, noise, t_frames, rng):
    """expose() of a mono signal (H, W) or RGB radiance (H, W, 3) as NumPy array passes, with the same normals."""
    gain, offset = lighting_field(noise, radiance.shape[:2], t_frames, rng)
    gain = gain * np.float32(255.0)
    img = radiance * (gain if radiance.ndim == 2 else gain[..., None]) + np.float32(offset)
    if noise.blur_px > 0:  # the lens blurs the lit image, the sensor's noise comes after
        img = cv2.GaussianBlur(img, (0, 0), noise.blur_px)
    img = np.clip(img, 0.0, 255.0)
    var = img * np.float32(255.0 / noise.photons_full_scale) + np.float32(noise.read_noise_dn**2)
    img += np.sqrt(var) * _hashed_normals(int(rng.integers(0, 2**63)), img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def _flat(level_dn: float) -> np.ndarray:
    return np.full(SHAPE, level_dn / 255.0, np.float32)


@pytest.mark.parametrize("color", ["mono", "rgb"])
@pytest.mark.parametrize("blur_px", [0.0, 0.8])
def test_expose_is_its_numpy_model_bit_for_bit(paper_scene, color, blur_px):
    # With blur the gain is applied before it, so the compiled pass runs its uniform-gain loop.
    shape = SHAPE if color == "mono" else SHAPE + (3,)
    radiance = np.random.default_rng(0).uniform(0.0, 1.0, shape).astype(np.float32)
    noise = replace(paper_scene.noise, blur_px=blur_px)
    for t in (0.0, 17.0):
        got = expose(radiance, noise, t, frame_rng(5, "expose-frame", 2, "side"), color)
        want = _oracle(radiance, noise, t, frame_rng(5, "expose-frame", 2, "side"))
        assert np.array_equal(got, want)


def test_mono_signal_and_rgb_radiance_expose_alike(paper_scene):
    rgb = np.random.default_rng(1).uniform(0.0, 1.0, SHAPE + (3,)).astype(np.float32)
    a = expose(rgb, paper_scene.noise, 3.0, frame_rng(5, "x", 1, "top"))
    b = expose(rgb @ LUMA, paper_scene.noise, 3.0, frame_rng(5, "x", 1, "top"))
    assert np.array_equal(a, b)


@pytest.mark.parametrize("photons, read_dn", [(4000.0, 1.2), (4000.0, 0.0), (0.0, 2.0)])
def test_noise_variance_is_shot_plus_read(photons, read_dn):
    noise = NoiseModel(photons_full_scale=photons, read_noise_dn=read_dn)
    for level in (20.0, 120.0, 230.0):
        frames = np.stack([expose(_flat(level), noise, 0.0, frame_rng(3, "flat", i, "c")) for i in range(8)]).astype(float)
        shot = level * 255.0 / photons if photons > 0 else 0.0
        expected = shot + read_dn**2 + 1.0 / 12.0  # + rounding to whole DN
        assert frames.mean() == pytest.approx(level, abs=0.05)
        assert frames.var() == pytest.approx(expected, rel=0.03), f"level {level}"


def test_noise_free_exposure_is_the_lit_signal_rounded():
    noise = NoiseModel(gradient=0.03, offset_dn=1.5, flicker=0.01)
    radiance = np.random.default_rng(2).uniform(0.0, 1.05, SHAPE).astype(np.float32)
    gain, offset = lighting_field(noise, SHAPE, 5.0, frame_rng(9, "e", 0, "c"))
    want = np.clip(np.rint(radiance * (gain * np.float32(255.0)) + np.float32(offset)), 0, 255).astype(np.uint8)
    assert np.array_equal(expose(radiance, noise, 5.0, frame_rng(9, "e", 0, "c")), want)


def test_frames_differ_and_repeat(paper_scene):
    flat = _flat(150.0)
    a = expose(flat, paper_scene.noise, 0.0, frame_rng(2016, "expose-frame", 0, "top"))
    b = expose(flat, paper_scene.noise, 0.0, frame_rng(2016, "expose-frame", 1, "top"))
    again = expose(flat, paper_scene.noise, 0.0, frame_rng(2016, "expose-frame", 0, "top"))
    assert np.array_equal(a, again)
    assert np.abs(a.astype(int) - b).mean() > 1.0


def test_blur_and_rgb_keep_shape_and_level():
    noise = NoiseModel(blur_px=1.0, photons_full_scale=4000.0, read_noise_dn=1.2)
    rgb = np.full(SHAPE + (3,), 100.0 / 255.0, np.float32)
    out = expose(rgb, noise, 0.0, frame_rng(1, "b", 0, "c"), color="rgb")
    assert out.shape == SHAPE + (3,) and out.dtype == np.uint8
    assert out.mean() == pytest.approx(100.0, abs=0.2)


def test_noise_draws_are_standard_normal_and_independent():
    """The hashed draws: mean 0, unit variance, the normal's share within 1 and 2 sigma, no correlation
    between neighbouring pixels, rows, channels or frames (a weak hash or a shared key fails these)."""
    z = _hashed_normals(int(frame_rng(7, "n", 0, "c").integers(0, 2**63)), (480, 640, 3)).astype(float)
    other = _hashed_normals(int(frame_rng(7, "n", 1, "c").integers(0, 2**63)), (480, 640, 3)).astype(float)
    assert abs(z.mean()) < 0.01 and z.var() == pytest.approx(1.0, abs=0.01)
    assert np.mean(np.abs(z) < 1) == pytest.approx(0.6827, abs=0.005)
    assert np.mean(np.abs(z) < 2) == pytest.approx(0.9545, abs=0.003)
    pairs = [(z[:, :-1], z[:, 1:]), (z[:-1], z[1:]), (z[..., 0], z[..., 1]), (z, other)]
    for a, b in pairs:
        assert abs(np.corrcoef(a.ravel(), b.ravel())[0, 1]) < 0.01
