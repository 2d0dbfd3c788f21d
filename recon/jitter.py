"""Camera jitter: the image shift of a frame against a mean background, and a frame moved back by it.

A camera on a mount shakes by a fraction of a pixel from frame to frame. On a
plain backdrop that changes nothing; on a textured one every edge of the
backdrop flickers by its gradient times the shift, and a thin tube is as
faint as that flicker. The shift is measured at the mean background's
steepest edges (:func:`prepare_shift`, :func:`frame_shift`), and a frame is
moved back onto the background by resampling (:func:`shifted`). Positions
are image pixels (px), OpenCV convention; gray levels are the image's.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ._kernels import SHIFT_PATCH, SHIFT_PATCH_BACK, frame_shift_nb

__all__ = ["ShiftModel", "pixel_noise", "prepare_shift", "frame_shift", "shifted"]


@dataclass(frozen=True, eq=False)
class ShiftModel:
    """What a frame's shift is measured on (:func:`prepare_shift`).

    Attributes
    ----------
    shape : (H, W)
        Image size (px).
    mean : (H*W,) float32
        The mean background (gray levels), flattened.
    index : (N,) int64
        The strongest-gradient pixels of the mean background (edges of static
        objects), flat indices.
    design : (N, 6) float64
        Regressors there: mean, 1, x * mean, y * mean, -d mean/du, -d mean/dv.
    gram : (6, 6) float64
        ``design.T @ design``.
    patches : (N, 8, 8) float32
        The mean background around each of those pixels (from 3 px above and
        left of it), for the shift's Gauss-Newton step.
    texture_dn_per_px : float
        The mean background's steepest 2 % of gradients (98th percentile,
        gray levels per px; of the mean blurred by 1 px, so that the noise
        left in a mean of few frames does not pass for texture): a shift of
        ``d`` px makes those pixels flicker by ``d`` times this.
    """

    shape: tuple
    mean: np.ndarray
    index: np.ndarray
    design: np.ndarray
    gram: np.ndarray
    patches: np.ndarray
    texture_dn_per_px: float


def pixel_noise(frames: np.ndarray) -> float:
    """Pixel noise (gray levels, at least 0.5) from differences of consecutive background frames.

    Robust (medians of absolute values), and differences of horizontal
    neighbours of the frame-to-frame difference cancel its smooth part (gain,
    ramps): 4 sigma^2 of pixel noise remain. The edges a shift is measured on
    must be steeper than a few times this (:func:`prepare_shift`).

    Parameters
    ----------
    frames : (N, H, W) array
        Background frames (gray levels), N >= 1.

    Returns
    -------
    float
        The noise's standard deviation (gray levels); 1 from a single frame.
    """
    H, W = frames.shape[1:]
    sub = np.arange(0, H * W, 61)
    flat = frames.reshape(len(frames), -1)
    sub = sub[(sub % W) < W - 1]
    dd = [(flat[i + 1, sub + 1].astype(np.float32) - flat[i, sub + 1]) - (flat[i + 1, sub].astype(np.float32) - flat[i, sub])
          for i in range(min(len(frames) - 1, 8))]
    sigma_pix = float(np.median([1.4826 * np.median(np.abs(d)) for d in dd])) / 2.0 if dd else 1.0
    return max(sigma_pix, 0.5)


def prepare_shift(mean_img: np.ndarray, sigma_pix: float, n: int = 3000, border: int = 8) -> ShiftModel | None:
    """The pixels and regressors a frame's shift is measured on: the mean background's steepest gradients, half
    each way (:func:`_steepest_both_ways`).

    Parameters
    ----------
    mean_img : (H, W) array
        The mean background (gray levels).
    sigma_pix : float
        The pixel noise (gray levels): gradients under three times it are not edges.
    n : int, optional
        Most pixels taken.
    border : int, optional
        Pixels at the image border left out (px).

    Returns
    -------
    ShiftModel or None
        None where the backdrop has too little texture to measure a shift on
        (fewer than 50 edge pixels, or edges in one direction only).
    """
    H, W = mean_img.shape
    m = mean_img.astype(np.float64)
    gx = cv2.Sobel(m, cv2.CV_64F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(m, cv2.CV_64F, 0, 1, ksize=3) / 8.0
    g2 = gx * gx + gy * gy
    g2[:border] = g2[-border:] = 0.0
    g2[:, :border] = g2[:, -border:] = 0.0
    flat = g2.reshape(-1)
    idx = _steepest_both_ways(gx.reshape(-1) * (flat > 0), gy.reshape(-1) * (flat > 0), n, 3.0 * sigma_pix)
    if idx.size < 50:
        return None  # no texture to register on: frames are used as they are
    y, x = np.divmod(idx, W)
    mv = m.reshape(-1)[idx]
    D = np.stack([mv, np.ones(idx.size), (x / W - 0.5) * mv, (y / H - 0.5) * mv, -gx.reshape(-1)[idx], -gy.reshape(-1)[idx]], axis=1)
    G = D.T @ D
    # Both shift directions must be measurable (edges in more than one direction).
    ev = np.linalg.eigvalsh(G[4:, 4:])
    if ev[0] < 1e-3 * ev[-1] or ev[0] < 50.0 * sigma_pix ** 2:
        return None
    mean = np.ascontiguousarray(mean_img, np.float32)
    return ShiftModel(shape=(H, W), mean=mean.reshape(-1), index=idx.astype(np.int64), design=D, gram=G,
                      patches=_shift_patches(mean, y, x), texture_dn_per_px=_texture_dn_per_px(m, border))


def _texture_dn_per_px(mean_img: np.ndarray, border: int) -> float:
    """:attr:`ShiftModel.texture_dn_per_px` of the mean background ``mean_img`` (gray levels), ``border`` px left out."""
    m = cv2.GaussianBlur(mean_img.astype(np.float32), (0, 0), 1.0)
    g = np.hypot(cv2.Sobel(m, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(m, cv2.CV_32F, 0, 1, ksize=3)) / 8.0
    return float(np.percentile(g[border:-border, border:-border], 98.0))


def _steepest_both_ways(gx: np.ndarray, gy: np.ndarray, n: int, floor: float) -> np.ndarray:
    """Up to ``n`` flat pixel indices, sorted: half the steepest along u (``|gx|``), half along v (``|gy|``), each
    steeper than ``floor`` (gray levels per px), fewer where fewer are.

    Half each way: among the steepest pixels of a backdrop one edge direction can crowd out the other (bricks
    whose long joints are the sharper: 2800 of 3000 pixels on them left the shift across them unmeasured,
    and it came out a pixel off). In raster order: the frame's pixels are read in passes over a few MB, and
    read in order they come from memory at a third less cost than scattered (0.45 -> 0.30 ms a view with
    cold caches).
    """
    picked = []
    for g in (np.abs(gx), np.abs(gy)):
        k = min(n // 2, int(np.count_nonzero(g > floor)))
        if k > 0:
            picked.append(np.argpartition(g, -k)[-k:])
    return np.unique(np.concatenate(picked)) if picked else np.zeros(0, np.int64)


def _shift_patches(mean_f32: np.ndarray, y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(N, 8, 8) float32: ``mean_f32`` (the mean background, (H, W)) from ``SHIFT_PATCH_BACK`` px above and left of
    each pixel ``(y, x)`` on (:func:`recon._kernels.frame_shift_nb`); the pixels lie over 4 px inside the image."""
    r = np.arange(SHIFT_PATCH) - SHIFT_PATCH_BACK
    return np.ascontiguousarray(mean_f32[(y[:, None] + r)[:, :, None], (x[:, None] + r)[:, None, :]], np.float32)


def frame_shift(model: ShiftModel | None, frame: np.ndarray, max_px: float = 3.0, iterations: int = 1) -> np.ndarray:
    """Image shift of a frame against the mean background: the camera's jitter.

    Fitted at the static edges of the background (:func:`prepare_shift`) with
    the lighting (gain, offset, linear ramps) as nuisance terms; pixels that do
    not fit (the robot in front of an edge) are dropped and the fit repeated,
    then ``iterations`` Gauss-Newton steps re-sample the regressors at the
    shifted positions (:func:`recon._kernels.frame_shift_nb`).

    Parameters
    ----------
    model : ShiftModel or None
        The view's edge pixels (:func:`prepare_shift`); None: no texture to measure on.
    frame : (H, W) uint8 array
        The frame (gray levels).
    max_px : float, optional
        Largest plausible shift (px); a larger or non-finite one gives zeros.
    iterations : int, optional
        Gauss-Newton steps after the first, linearized fit.

    Returns
    -------
    (2,) float64 array
        ``(du, dv)`` px in the image's pixel frame: where the frame's content
        lies relative to the mean background. Zeros when the background has
        no usable texture or the fit is implausible.
    """
    if model is None:
        return np.zeros(2)
    H, W = model.shape
    d = np.array(frame_shift_nb(frame.reshape(-1), model.mean, W, H, model.index, model.design, model.gram,
                                iterations, model.patches))
    if not np.all(np.isfinite(d)) or float(np.hypot(d[0], d[1])) > max_px:
        return np.zeros(2)
    return d


def shifted(image: np.ndarray, shift_px) -> np.ndarray:
    """The image resampled at its pixels plus a shift, by separable cubic convolution (:func:`_keys_weights`).

    Parameters
    ----------
    image : (H, W) array
        Gray levels (uint8 or float32).
    shift_px : (2,) array_like
        ``(du, dv)`` px along u (columns) and v (rows).

    Returns
    -------
    (H, W) array
        ``out[v, u] = image(u + du, v + dv)``, the border repeated beyond the
        image; the image's dtype (integers rounded and saturated).
    """
    taps = []
    for d in (float(shift_px[0]), float(shift_px[1])):
        i = int(np.floor(d))
        # The kernel spans the four taps' offsets i-1..i+2 and 0 (the anchor, which must lie inside it).
        lo, hi = min(i - 1, 0), max(i + 2, 0)
        k = np.zeros(hi - lo + 1, np.float32)
        k[i - 1 - lo: i + 3 - lo] = _keys_weights(d - i)
        taps.append((k, -lo))
    (kx, ax), (ky, ay) = taps
    # One pass: rows then columns as two uint8 filter2D passes took half the time (3.2 vs 6.0 ms at 5 MP) but
    # rounded in between, and a thin faint tube lost to the 0.3 gray levels of rounding noise (wide seeds 2
    # and 3: 3 good frames fewer, the tip error median 1.10 -> 1.09 and 1.18 -> 1.26 px).
    return cv2.sepFilter2D(image, -1, kx, ky, anchor=(ax, ay), borderType=cv2.BORDER_REPLICATE)


def _keys_weights(f: float) -> np.ndarray:
    """The weights of Keys' cubic convolution (a = -1/2, Catmull-Rom) at the taps -1, 0, 1, 2 px around a sample
    ``f`` (0 <= f < 1) px past tap 0: interpolating, exact for quadratics."""
    t = np.abs(np.arange(-1.0, 3.0) - f)
    return np.where(t <= 1.0, 1.5 * t ** 3 - 2.5 * t ** 2 + 1.0, -0.5 * t ** 3 + 2.5 * t ** 2 - 4.0 * t + 2.0)
