"""Per-frame disturbances of the twin: lighting, camera jitter, sensor noise, blur.

Every draw comes from a generator seeded by (scene seed, stream, frame, camera),
so the same scene renders the same images bit for bit, whatever order frames
are rendered in.
"""
from __future__ import annotations

import zlib

import cv2
import numpy as np
from numba import njit
from scipy.special import ndtri

from recon.camera import Camera
from recon.geometry import rotation_matrix

from .scene import NoiseModel

__all__ = ["LUMA", "frame_rng", "jitter_camera", "lighting_field", "vignetting_field", "expose", "jpeg_roundtrip"]

#: Weights of R, G, B in a mono sensor's signal (ITU-R BT.601 luma).
LUMA = np.array([0.299, 0.587, 0.114], np.float32)


def frame_rng(seed: int, stream: str, frame: int, camera: str) -> np.random.Generator:
    """Independent, reproducible generator for one (stream, frame, camera)."""
    key = [seed, zlib.crc32(stream.encode()), frame, zlib.crc32(camera.encode())]
    return np.random.default_rng(np.random.SeedSequence(key))


def jitter_camera(camera: Camera, noise: NoiseModel, rng: np.random.Generator) -> Camera:
    """The camera after this frame's jitter: a small rotation about its own axes and a shift.

    The shift's standard deviation is ``noise.jitter_px`` expressed as image motion at
    the camera's working distance (the optical-axis distance to the world origin's
    depth), i.e. ``jitter_px * z / f`` mm across the optical axis.
    """
    if noise.jitter_px == 0 and noise.jitter_rotation_deg == 0:
        return camera
    z = max(float(np.linalg.norm(camera.center_world_mm)), 1.0)
    f = float(np.sqrt(camera.K[0, 0] * camera.K[1, 1]))
    shift_mm = rng.normal(0.0, noise.jitter_px * z / f, 2)
    angles = np.deg2rad(rng.normal(0.0, noise.jitter_rotation_deg, 3))
    R = np.eye(3)
    for ax, a in zip(np.eye(3), angles):
        R = rotation_matrix(ax, a) @ R
    D = np.eye(4)
    D[:3, :3] = R
    D[:2, 3] = shift_mm
    return camera.with_pose(D @ camera.T_cam_world)


def lighting_field(noise: NoiseModel, shape: tuple, t_frames: float, rng: np.random.Generator) -> tuple:
    """Gain image (H, W) and offset (DN) for this frame.

    Gain = (1 + slow drift (sinusoid over ``lighting_period_frames``) + flicker + a linear
    ramp in a random direction (the ``gradient`` amplitude at the image border)) times
    the static ``gain`` and the lens's vignetting.
    """
    h, w = shape
    gain = 1.0 + noise.lighting_drift * np.sin(2 * np.pi * t_frames / noise.lighting_period_frames)
    gain += rng.normal(0.0, noise.flicker) if noise.flicker else 0.0
    offset = rng.normal(0.0, noise.offset_dn) if noise.offset_dn else 0.0
    if noise.gain != 1.0 or noise.vignetting > 0:
        # Applied only when set, so scenes without these keys draw and compute exactly as before.
        field, offset = _ramped(noise, (h, w), gain, offset, rng)
        field *= np.float32(noise.gain)
        if noise.vignetting > 0:
            field *= vignetting_field((h, w), noise.vignetting)
        return field, offset
    return _ramped(noise, (h, w), gain, offset, rng)


def vignetting_field(shape: tuple, amount: float) -> np.ndarray:
    """Relative illumination (H, W) float32 of a lens: 1 at the centre, ``1 - amount`` at the corners.

    Natural vignetting falls as cos^4 of the field angle; over a camera's field this
    is close to a quadratic-quartic falloff in the radius normalised to the corner.
    """
    h, w = shape
    y = (np.arange(h, dtype=np.float32) - (h - 1) / 2) / np.float32(max(h - 1, 1) / 2)
    x = (np.arange(w, dtype=np.float32) - (w - 1) / 2) / np.float32(max(w - 1, 1) / 2)
    r2 = (y[:, None] ** 2 * h * h + x[None, :] ** 2 * w * w) / np.float32(h * h + w * w)  # 1 at the corners
    return (1.0 - np.float32(amount) * (0.6 * r2 + 0.4 * r2 * r2)).astype(np.float32)


def _ramped(noise: NoiseModel, shape: tuple, gain: float, offset: float, rng: np.random.Generator) -> tuple:
    """The gain field (uniform ``gain`` plus the per-frame ramp) and the offset (DN)."""
    h, w = shape
    if noise.gradient:
        theta = rng.uniform(0, 2 * np.pi)
        amp = noise.gradient * rng.uniform(0.5, 1.0)
        # A linear ramp is separable: an outer sum of a column and a row profile.
        col = (2.0 * amp * np.sin(theta)) * (np.arange(h, dtype=np.float32) / (h - 1) - 0.5)
        row = (2.0 * amp * np.cos(theta)) * (np.arange(w, dtype=np.float32) / (w - 1) - 0.5)
        # Summed in float64 (theta and amp are float64) and stored as float32, without an extra pass.
        field = np.empty((h, w), np.float32)
        return np.add.outer(np.float32(gain) + col, row, out=field, casting="same_kind"), offset
    return np.full((h, w), gain, np.float32), offset


def _normal_levels(bits: int) -> np.ndarray:
    """The standard normal's quantiles at ``2**bits`` equally likely levels, scaled to unit variance (float32)."""
    n = 1 << bits
    q = ndtri((np.arange(n) + 0.5) / n)
    return (q / q.std()).astype(np.float32)


#: The sensor noise's draws: 65536 equally likely normal levels (|z| <= 4.3), a 256 kB
#: table that stays in cache; a hash of (image key, pixel, channel) picks one.
_NORMAL_LEVELS = _normal_levels(16)


@njit(cache=True, nogil=True, inline="always")
def _lit_nb(s, g, offset):  # pragma: no cover - compiled
    """``clip(s * g + offset, 0, 255)`` (float32 DN)."""
    return min(max(s * g + offset, np.float32(0.0)), np.float32(255.0))


@njit(cache=True, nogil=True, inline="always")
def _noisy_nb(x, shot_per_dn, read_var, i, key, levels):  # pragma: no cover - compiled
    """``x`` (DN) plus the shot and read noise of flat sample ``i`` (see :func:`_sensor_nb`)."""
    h = key + np.uint64(i) * np.uint64(0x9E3779B97F4A7C15)
    h = (h ^ (h >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    h = (h ^ (h >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    h ^= h >> np.uint64(31)
    return x + np.sqrt(x * shot_per_dn + read_var) * levels[h & np.uint64(levels.shape[0] - 1)]


@njit(cache=True, nogil=True, inline="always")
def _dn_nb(x):  # pragma: no cover - compiled
    """``x`` (DN) rounded half to even and saturated to uint8."""
    return np.uint8(min(max(np.rint(x), np.float32(0.0)), np.float32(255.0)))


@njit(cache=True, nogil=True)
def _sensor_nb(signal, channels, gain, offset, shot_per_dn, read_var, key, levels, out):  # pragma: no cover - compiled
    """The per-pixel sensor model of :func:`expose`, fused into one pass (float32 throughout).

    ``signal`` and ``out`` are flat (pixels x ``channels``). Sample ``i`` (pixel ``i // channels``):
    ``x = clip(signal[i] * gain[pixel] + offset, 0, 255)`` DN, plus ``sqrt(x * shot_per_dn + read_var) * z``
    when ``levels`` is not empty, rounded half to even and saturated into ``out[i]`` (uint8). ``z`` is
    ``levels[h & (len - 1)]`` with ``h`` SplitMix64's output for the counter ``key + i * golden``, so every
    (image, pixel, channel) has its own independent draw, the same in any order. A ``gain`` of length 1
    applies to every pixel.

    Each case has a loop of its own without branches in it, the gain read at ``i`` where it can be: LLVM
    vectorizes those, a third of the time of one general loop (the same values, bit for bit).
    """
    n = signal.shape[0]
    noisy = levels.shape[0] > 0
    if gain.shape[0] == 1 or channels == 1:
        step = 0 if gain.shape[0] == 1 else 1
        if noisy:
            for i in range(n):
                x = _lit_nb(signal[i], gain[i * step], offset)
                out[i] = _dn_nb(_noisy_nb(x, shot_per_dn, read_var, i, key, levels))
        else:
            for i in range(n):
                out[i] = _dn_nb(_lit_nb(signal[i], gain[i * step], offset))
        return out
    for p in range(n // channels):
        g = gain[p]
        if noisy:
            for i in range(p * channels, (p + 1) * channels):
                out[i] = _dn_nb(_noisy_nb(_lit_nb(signal[i], g, offset), shot_per_dn, read_var, i, key, levels))
        else:
            for i in range(p * channels, (p + 1) * channels):
                out[i] = _dn_nb(_lit_nb(signal[i], g, offset))
    return out


def _sensor(signal: np.ndarray, gain: np.ndarray, offset: float, noise: NoiseModel, rng: np.random.Generator) -> np.ndarray:
    """Shot and read noise on ``clip(signal * gain + offset, 0, 255)`` DN, quantized to uint8 (``signal``'s shape).

    Shot noise (Poisson in photo-electrons) and read noise (Gaussian in DN) add in
    variance; with thousands of electrons at full scale the Poisson law is Gaussian to
    within a fraction of a DN. Each pixel's standard normal is one of 65536 equally
    likely levels (:data:`_NORMAL_LEVELS`), picked by a hash of the pixel and a key drawn
    from ``rng``: a fifth of the time of drawing a normal field with ``rng`` and reading
    it back (2.0 against 9.6 ms for a 1024x768 image, one core).

    Parameters
    ----------
    signal : (H, W) or (H, W, 3) float32
    gain : (H, W) float32 (DN per unit of signal), or (1,) for all pixels
    offset : float
        DN.
    """
    flat = np.ascontiguousarray(signal, dtype=np.float32).reshape(-1)
    channels = 1 if signal.ndim == 2 else signal.shape[2]
    shot = np.float32(255.0 / noise.photons_full_scale) if noise.photons_full_scale > 0 else np.float32(0.0)
    read_var = np.float32(noise.read_noise_dn**2) if noise.read_noise_dn > 0 else np.float32(0.0)
    noisy = shot > 0 or read_var > 0
    key = np.uint64(rng.integers(0, 2**63)) if noisy else np.uint64(0)
    levels = _NORMAL_LEVELS if noisy else _NORMAL_LEVELS[:0]
    out = np.empty(flat.shape, np.uint8)
    _sensor_nb(flat, channels, np.ascontiguousarray(gain, dtype=np.float32).ravel(), np.float32(offset), shot, read_var, key, levels, out)
    return out.reshape(signal.shape)


def expose(radiance: np.ndarray, noise: NoiseModel, t_frames: float, rng: np.random.Generator, color: str = "mono") -> np.ndarray:
    """Sensor model: lighting, blur, shot and read noise, 8-bit quantization.

    Parameters
    ----------
    radiance : (H, W, 3) float32 in [0, 1], or (H, W) for a mono sensor's signal (already weighted by :data:`LUMA`)
    noise : NoiseModel
    t_frames : float
        Time of this exposure in frames since the session started (drives the drift).
    rng : Generator
    color : {"mono", "rgb"}

    Returns
    -------
    (H, W) or (H, W, 3) uint8
    """
    img = radiance @ LUMA if color == "mono" and radiance.ndim == 3 else radiance
    gain, offset = lighting_field(noise, img.shape[:2], t_frames, rng)
    gain *= np.float32(255.0)  # a fresh field: scaled in place
    if noise.blur_px > 0:
        # The lens blurs the lit image; the sensor's noise comes after.
        lit = img * (gain if img.ndim == 2 else gain[..., None]) + np.float32(offset)
        img, gain, offset = cv2.GaussianBlur(lit, (0, 0), noise.blur_px), np.ones(1, np.float32), 0.0
    out = _sensor(img, gain, offset, noise, rng)
    if noise.jpeg_quality > 0:
        out = jpeg_roundtrip(out, int(round(noise.jpeg_quality)))
    return out


def jpeg_roundtrip(image: np.ndarray, quality: int) -> np.ndarray:
    """``image`` (uint8 mono or RGB) after JPEG compression at ``quality`` (1-100)."""
    rgb = image.ndim == 3
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if rgb else image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:  # pragma: no cover - OpenCV encodes any 8-bit image
        raise ValueError("could not JPEG-encode an image")
    out = cv2.imdecode(buf, cv2.IMREAD_COLOR if rgb else cv2.IMREAD_GRAYSCALE)
    return cv2.cvtColor(out, cv2.COLOR_BGR2RGB) if rgb else out
