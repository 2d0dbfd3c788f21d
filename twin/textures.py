"""Backdrop textures of the twin: the original plain/gradient/blotch kinds, procedural
materials (wood, woven fabric, printed text, bricks, fine noise) and photographs.

Every texture is seeded and square. A pattern is a field ``p`` in [0, 1] (grey, or
RGB for photographs); the backdrop colours map it as ``color2 + p * (color - color2)``,
so the two colours set both the brightness and the contrast of the backdrop: two
colours 15 gray levels apart give a backdrop whose whole range spans 15 gray levels.
"""
from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

__all__ = ["KINDS", "LEGACY_KINDS", "PHOTOS", "backdrop_texture", "pattern", "legacy_texture"]

#: The kinds the twin had before procedural textures (drawn exactly as before).
LEGACY_KINDS = ("plain", "gradient", "textured")
#: Procedural and photographic kinds.
PATTERN_KINDS = ("wood", "fabric", "text", "bricks", "noise", "photo")
KINDS = LEGACY_KINDS + PATTERN_KINDS

#: Photographs shipped inside scikit-image's wheel (loadable offline), by name.
PHOTOS = ("camera", "brick", "grass", "gravel", "coffee", "astronaut", "rocket", "chelsea", "coins", "moon", "page",
          "text", "clock", "hubble_deep_field", "immunohistochemistry", "motorcycle")

_WORDS = ("tube", "robot", "nitinol", "sample", "lot", "batch", "calibration", "figure", "table", "result", "the", "of",
          "and", "camera", "frame", "mm", "deg", "protocol", "trial", "patient", "surgery", "vision", "model", "error",
          "page", "section", "method", "data", "image", "ref", "lab", "notes", "12.5", "0.34", "2024", "exp", "run")


def legacy_texture(kind: str, c1, c2, seed: int, size: int = 256) -> np.ndarray:
    """Backdrop texture (size, size, 3) uint8: plain, gradient or textured (seeded blotches).

    This is the twin's original texture code, kept unchanged so existing scenes render
    bit for bit as before.
    """
    c1 = np.asarray(c1, float)
    c2 = np.asarray(c2, float)
    if kind == "plain":
        img = np.broadcast_to(c1, (size, size, 3))
    else:
        t = np.linspace(0.0, 1.0, size)[:, None, None]
        img = (1 - t) * c1 + t * c2
        img = np.broadcast_to(img, (size, size, 3)).copy()
        if kind == "textured":
            rng = np.random.default_rng(seed)
            noise = rng.normal(0.0, 1.0, (size, size)).astype(np.float32)
            blotches = cv2.GaussianBlur(noise, (0, 0), 6.0)
            blotches /= np.abs(blotches).max() + 1e-9
            fine = cv2.GaussianBlur(noise, (0, 0), 0.8) * 0.15
            img = img * (1.0 + 0.25 * blotches[..., None] + fine[..., None])
    return (np.clip(img, 0, 1) * 255).astype(np.uint8)


def _normalize(p: np.ndarray, lo_pct: float = 0.5, hi_pct: float = 99.5) -> np.ndarray:
    """Stretch ``p`` so its ``lo_pct``..``hi_pct`` percentiles map to 0..1 (clipped)."""
    lo, hi = np.percentile(p, [lo_pct, hi_pct])
    return np.clip((p - lo) / max(hi - lo, 1e-9), 0.0, 1.0).astype(np.float32)


def _smooth_noise(rng: np.random.Generator, size: int, sigma_px: float) -> np.ndarray:
    """Gaussian-blurred white noise (size, size) float32 with unit peak magnitude."""
    if sigma_px <= 4.0:
        n = cv2.GaussianBlur(rng.standard_normal((size, size)).astype(np.float32), (0, 0), max(sigma_px, 0.3))
    else:
        # Wide blurs are slow at full size: blur a grid ``sigma / 2`` times coarser, then enlarge.
        step = sigma_px / 2.0
        small = max(4, int(np.ceil(size / step)))
        n = cv2.GaussianBlur(rng.standard_normal((small, small)).astype(np.float32), (0, 0), 2.0)
        n = cv2.resize(n, (size, size), interpolation=cv2.INTER_CUBIC)
    return n / (np.abs(n).max() + 1e-9)


def _rotate(p: np.ndarray, angle_deg: float) -> np.ndarray:
    """Rotate a square field about its centre, mirroring at the borders (no empty corners)."""
    size = p.shape[0]
    M = cv2.getRotationMatrix2D(((size - 1) / 2, (size - 1) / 2), angle_deg, 1.0)
    return cv2.warpAffine(p, M, (size, size), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def _wood(rng, size: int, scale: float) -> np.ndarray:
    """Wood grain: growth rings bent by low-frequency noise, plus fibres along the grain."""
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32)
    period = rng.uniform(18.0, 45.0) * scale  # ring spacing (texels)
    # Rings wander at two scales (the trunk's shape and knots), so the grain is not a sine.
    warp = (_smooth_noise(rng, size, size / 10) * rng.uniform(60.0, 150.0)
            + _smooth_noise(rng, size, size / 40) * rng.uniform(8.0, 25.0)) * scale
    rings = 0.5 + 0.5 * np.sin(2 * np.pi * (yy + warp + 0.05 * xx) / period)
    rings = rings ** rng.uniform(1.5, 3.0)  # late wood is a narrow dark band
    # Fibres: noise stretched along the grain (blurred on a grid 8x coarser along x, then enlarged).
    fibres = cv2.GaussianBlur(rng.standard_normal((size, size // 8)).astype(np.float32), (0, 0), sigmaX=1.5 * scale, sigmaY=0.7)
    fibres = cv2.resize(fibres, (size, size), interpolation=cv2.INTER_CUBIC)
    fibres /= np.abs(fibres).max() + 1e-9
    p = 0.75 * rings + 0.25 * fibres + 0.15 * _smooth_noise(rng, size, 3.0)
    return _rotate(_normalize(p), rng.uniform(-20.0, 20.0))


def _fabric(rng, size: int, scale: float) -> np.ndarray:
    """Plain weave: warp and weft threads passing over and under each other."""
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32)
    t = rng.uniform(6.0, 16.0) * scale  # thread pitch (texels)
    # Thread positions wander a little, as real yarn does.
    wx = xx + _smooth_noise(rng, size, 25.0) * 0.3 * t
    wy = yy + _smooth_noise(rng, size, 25.0) * 0.3 * t
    i = np.floor(wx / t)
    j = np.floor(wy / t)
    fx = wx / t - i
    fy = wy / t - j
    warp_on_top = ((i + j) % 2) == 0
    # Each thread is a rounded ridge: bright along its middle, dark at its edges and where it dives.
    warp = np.sin(np.pi * fx) * (0.55 + 0.45 * np.sin(np.pi * fy))
    weft = np.sin(np.pi * fy) * (0.55 + 0.45 * np.sin(np.pi * fx))
    p = np.where(warp_on_top, warp, weft)
    # Per-thread shade (slubs) and fluff.
    shade_i = rng.uniform(0.8, 1.0, int(size / t) + 3)
    shade_j = rng.uniform(0.8, 1.0, int(size / t) + 3)
    idx_i = np.clip(i.astype(int), 0, len(shade_i) - 1)
    idx_j = np.clip(j.astype(int), 0, len(shade_j) - 1)
    p = p * np.where(warp_on_top, shade_i[idx_i], shade_j[idx_j]) + 0.08 * _smooth_noise(rng, size, 0.8)
    return _rotate(_normalize(p.astype(np.float32)), rng.uniform(-10.0, 10.0))


def _text(rng, size: int, scale: float) -> np.ndarray:
    """Printed paper: lines of random words in a few blocks (dark ink on bright paper)."""
    img = np.full((size, size), 255, np.uint8)  # cv2.putText draws on 8-bit images only
    fonts = (cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_COMPLEX, cv2.FONT_HERSHEY_TRIPLEX)
    y = int(rng.uniform(10, 40) * scale)
    while y < size:
        font = fonts[rng.integers(len(fonts))]
        font_scale = float(rng.uniform(0.35, 0.9) * scale * size / 1024)
        thick = max(1, int(round(font_scale * rng.uniform(1.2, 2.2))))
        (_, h), _ = cv2.getTextSize("Ag", font, font_scale, thick)
        for _ in range(int(rng.integers(3, 12))):  # lines of this block
            y += int(h * rng.uniform(1.6, 2.0))
            if y >= size:
                break
            x = int(rng.uniform(5, 60) * scale)
            line = " ".join(_WORDS[k] for k in rng.integers(len(_WORDS), size=int(rng.integers(6, 30))))
            cv2.putText(img, line, (x, y), font, font_scale, int(rng.uniform(0, 64)), thick, cv2.LINE_AA)
        y += int(h * rng.uniform(2.0, 5.0))  # paragraph gap
    paper = 0.06 * _smooth_noise(rng, size, 1.0) + 0.05 * _smooth_noise(rng, size, size / 8)
    return _rotate(np.clip(img.astype(np.float32) / 255.0 + paper, 0.0, 1.0), rng.uniform(-6.0, 6.0))


def _bricks(rng, size: int, scale: float) -> np.ndarray:
    """Running-bond brick wall: per-brick shade and grain, lighter mortar joints."""
    h = rng.uniform(40.0, 90.0) * scale  # course height (texels)
    w = h * rng.uniform(2.0, 3.0)
    mortar = max(2.0, h * rng.uniform(0.08, 0.15))
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32)
    row = np.floor(yy / h)
    xs = xx + (row % 2) * w / 2
    col = np.floor(xs / w)
    fy = yy - row * h
    fx = xs - col * w
    in_mortar = (fy < mortar) | (fx < mortar)
    n_rows = int(size / h) + 2
    n_cols = int(size / w) + 3
    shade = rng.uniform(0.15, 0.55, (n_rows, n_cols)).astype(np.float32)
    b = shade[np.clip(row.astype(int), 0, n_rows - 1), np.clip(col.astype(int), 0, n_cols - 1)]
    b = b + 0.12 * _smooth_noise(rng, size, 1.2) + 0.08 * _smooth_noise(rng, size, 8.0)
    m = 0.85 + 0.08 * _smooth_noise(rng, size, 1.0)
    p = np.where(in_mortar, m, b)
    return np.clip(cv2.GaussianBlur(p.astype(np.float32), (0, 0), 0.7), 0.0, 1.0)


def _noise(rng, size: int, scale: float) -> np.ndarray:
    """Fine multi-scale noise (like matte paint, cardboard or a foam board)."""
    p = sum(a * _smooth_noise(rng, size, s * scale) for a, s in ((1.0, 0.8), (0.6, 3.0), (0.5, 12.0), (0.4, 50.0)))
    return _normalize(p)


@lru_cache(maxsize=8)
def _photo_source(name: str) -> np.ndarray:
    """A scikit-image sample photograph as float32 RGB in [0, 1] (read-only, cached)."""
    import skimage.data

    if name not in PHOTOS:
        raise ValueError(f"unknown photo {name!r}; one of {', '.join(PHOTOS)}")
    img = skimage.data.stereo_motorcycle()[0] if name == "motorcycle" else getattr(skimage.data, name)()
    img = np.asarray(img)
    if img.ndim == 2:
        img = np.stack([img] * 3, axis=-1)
    img = img[..., :3].astype(np.float32) / 255.0
    img.setflags(write=False)
    return img


def _photo(rng, size: int, scale: float, name: str) -> np.ndarray:
    """A photograph, magnified by ``scale`` and tiled by mirroring to fill the square.

    The sample photos are 300-1000 px; the backdrop texture shows them at about one
    photo pixel per texel (``scale`` 1) so they stay sharp at the backdrop's resolution,
    mirrored rather than stretched where one photo does not cover the plane.
    """
    src = _photo_source(name)
    zoom = max(scale, 0.25)
    src = cv2.resize(src, None, fx=zoom, fy=zoom, interpolation=cv2.INTER_LANCZOS4 if zoom > 1 else cv2.INTER_AREA)
    h, w = src.shape[:2]
    reps_y = int(np.ceil(size / h)) + 1
    reps_x = int(np.ceil(size / w)) + 1
    row = np.concatenate([src if k % 2 == 0 else src[:, ::-1] for k in range(reps_x)], axis=1)
    tiled = np.concatenate([row if k % 2 == 0 else row[::-1] for k in range(reps_y)], axis=0)
    y0 = int(rng.integers(0, tiled.shape[0] - size + 1))
    x0 = int(rng.integers(0, tiled.shape[1] - size + 1))
    p = tiled[y0 : y0 + size, x0 : x0 + size]
    lum = p @ np.array([0.299, 0.587, 0.114], np.float32)
    lo, hi = np.percentile(lum, [0.5, 99.5])
    return np.clip((p - lo) / max(hi - lo, 1e-6), 0.0, 1.0).astype(np.float32)


def pattern(kind: str, seed: int, size: int, scale: float = 1.0, photo: str = "camera") -> np.ndarray:
    """The pattern field of a procedural or photographic kind.

    Parameters
    ----------
    kind : str
        One of :data:`PATTERN_KINDS`.
    seed : int
    size : int
        Texture side (texels).
    scale : float
        Feature size multiplier (threads, bricks, rings, letters; photo magnification).
    photo : str
        Photograph name (``kind == "photo"``), one of :data:`PHOTOS`.

    Returns
    -------
    (size, size) or (size, size, 3) float32 in [0, 1]
    """
    rng = np.random.default_rng(seed)
    if kind == "photo":
        return _photo(rng, size, scale, photo)
    makers = {"wood": _wood, "fabric": _fabric, "text": _text, "bricks": _bricks, "noise": _noise}
    if kind not in makers:
        raise ValueError(f"unknown backdrop kind {kind!r}")
    return makers[kind](rng, size, scale)


def backdrop_texture(kind: str, c1, c2, seed: int, size: int = 256, scale: float = 1.0, photo: str = "camera") -> np.ndarray:
    """Backdrop texture (size, size, 3) uint8 of any kind.

    Parameters
    ----------
    kind : str
        One of :data:`KINDS`.
    c1, c2 : 3 floats in [0, 1]
        Colours: for the pattern kinds, ``p = 1`` maps to ``c1`` and ``p = 0`` to ``c2``.
    seed : int
    size : int
        Texture side (texels).
    scale, photo
        See :func:`pattern`.
    """
    if kind in LEGACY_KINDS:
        return legacy_texture(kind, c1, c2, seed, size)
    p = pattern(kind, seed, size, scale, photo)
    if p.ndim == 2:
        p = p[..., None]
    c1 = np.asarray(c1, np.float32)
    c2 = np.asarray(c2, np.float32)
    img = c2 + p * (c1 - c2)
    return (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
