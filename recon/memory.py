"""Memory estimates of the big allocations, checked before anything is allocated.

A carving resolution, a scene's image size or a recorded session's frame size that
would need more memory than the machine should give is refused up front, with the
figure, rather than found out by the kernel's OOM killer minutes later. The
estimates are measured peaks (``tracemalloc`` for carving, peak RSS for rendering and
reconstruction) fitted to a simple law and rounded up; each says where its
coefficients come from.

The limit is 4 GB unless the environment variable ``CTR_BENCH_MEMORY_LIMIT_GB`` says
otherwise (a lab machine with 64 GB may allow more). GB here are 10^9 bytes.
"""
from __future__ import annotations

import math
import os

__all__ = [
    "DEFAULT_LIMIT_GB",
    "LIMIT_ENV",
    "MemoryBoundError",
    "memory_limit_bytes",
    "carving_bytes",
    "render_bytes",
    "reconstruction_bytes",
    "check_memory",
]

#: The limit (GB, 10^9 bytes) when ``CTR_BENCH_MEMORY_LIMIT_GB`` is not set.
DEFAULT_LIMIT_GB = 4.0
#: The environment variable that overrides :data:`DEFAULT_LIMIT_GB`.
LIMIT_ENV = "CTR_BENCH_MEMORY_LIMIT_GB"

# Carving (recon.carving._hull at resolution N): the first view's coarse-to-fine test
# holds one bool per 4^3 cell, then every voxel that survives the first view costs about
# 96 bytes (flat index 8, its concatenated and sorted copies 16, unravelled i, j, k 24,
# the gathered coordinates 24 and the stacked points 24). Once voxels are smaller than
# a pixel the survivors are a sheet of constant thickness in mm, i.e. a constant fraction
# of the grid: 1.4 % measured at N = 300-400 (carving tests' 1024x768 views, peak 1.16-1.24
# bytes per voxel); 2 % keeps the estimate above every measurement.
_CARVE_CELL = 4
_CARVE_SURVIVOR_FRACTION = 0.02
_CARVE_BYTES_PER_SURVIVOR = 96

# Rendering (twin.render, both cameras): peak RSS of `ctr-bench render` at 512^2, 1024^2
# and 2048^2 px grows by ~150 bytes per sensor pixel with EGL and ~200 with OSMesa (which
# supersamples 2x), over ~300 MB of libraries and scene; independent of the frame count.
_RENDER_BASE = 300e6
_RENDER_BYTES_PER_PX = 200

# Reconstruction (rig.bench.reconstruct, both cameras): peak RSS of `ctr-bench reconstruct` on
# 1024^2 and 2048^2 twin sessions with 10 and 30 background frames is ~260 MB plus
# ~115 bytes per pixel (fast; paper ~100) plus ~13 bytes per pixel per background frame
# (the eigenbackground stacks).
_RECON_BASE = 260e6
_RECON_BYTES_PER_PX = 120
_RECON_BYTES_PER_PX_PER_BACKGROUND = 14


class MemoryBoundError(ValueError):
    """An input whose processing would need more memory than :func:`memory_limit_bytes`; one line."""


def memory_limit_bytes() -> float:
    """The memory bound (bytes): ``CTR_BENCH_MEMORY_LIMIT_GB`` x 10^9, else :data:`DEFAULT_LIMIT_GB`.

    Returns
    -------
    float
        The limit in bytes (4e9 by default); read from the environment at each call.

    Raises
    ------
    MemoryBoundError
        The variable is set but is not a positive finite number.
    """
    text = os.environ.get(LIMIT_ENV)
    if text is None or not text.strip():
        return DEFAULT_LIMIT_GB * 1e9
    try:
        gb = float(text)
    except ValueError:
        gb = math.nan
    if not (math.isfinite(gb) and gb > 0):
        raise MemoryBoundError(f"{LIMIT_ENV}={text!r}: must be a positive number of GB")
    return gb * 1e9


def carving_bytes(resolution: int) -> float:
    """Peak memory (bytes) of carving an ``resolution``^3 grid (:func:`recon.carving.carve`).

    Parameters
    ----------
    resolution : int
        Voxels per axis.

    Returns
    -------
    float
        The cell grid (1 byte per 4^3 voxels) plus 96 bytes for each of the 2 % of the
        voxels taken to survive the first view (measured: 1.4 %).
    """
    n = float(resolution)  # in floats: a 64-bit resolution cubed must not overflow
    cells = math.ceil(n / _CARVE_CELL) ** 3
    return cells + _CARVE_SURVIVOR_FRACTION * _CARVE_BYTES_PER_SURVIVOR * n**3


def render_bytes(width_px: int, height_px: int) -> float:
    """Peak memory (bytes) of rendering a twin scene of ``width_px`` x ``height_px`` sensors (both cameras).

    ~300 MB plus 200 bytes per sensor pixel (OSMesa; EGL needs ~150).

    Parameters
    ----------
    width_px, height_px : int
        One camera's sensor size (px); the law covers both cameras at that size.

    Returns
    -------
    float
        The estimate (bytes), independent of the frame count.
    """
    return _RENDER_BASE + _RENDER_BYTES_PER_PX * float(width_px) * float(height_px)


def reconstruction_bytes(width_px: int, height_px: int, n_background_frames: int) -> float:
    """Peak memory (bytes) of reconstructing a two-camera session of ``width_px`` x ``height_px`` frames.

    ~260 MB plus, per pixel, 120 bytes and 14 bytes per background frame (the fast
    method; the paper method needs ~10 % less).

    Parameters
    ----------
    width_px, height_px : int
        One camera's frame size (px); the law covers both cameras at that size.
    n_background_frames : int
        Frames of the empty scene per camera (negative counts as 0).

    Returns
    -------
    float
        The estimate (bytes).
    """
    per_px = _RECON_BYTES_PER_PX + _RECON_BYTES_PER_PX_PER_BACKGROUND * max(int(n_background_frames), 0)
    return _RECON_BASE + per_px * float(width_px) * float(height_px)


def _gb(n_bytes: float) -> str:
    gb = n_bytes / 1e9
    return f"{gb:.1f} GB" if gb < 1000 else f"{gb:.3g} GB"


def check_memory(needed_bytes: float, where: str, what: str, error=MemoryBoundError) -> None:
    """Refuse ``what`` when it needs more than :func:`memory_limit_bytes`.

    Parameters
    ----------
    needed_bytes : float
        The estimate (bytes), e.g. from :func:`carving_bytes`.
    where : str
        The file and key at fault, e.g. ``"params.toml: carving.resolution"``.
    what : str
        What needs it, e.g. ``"carving 2000^3 voxels"``.
    error : type
        The ``ValueError`` subclass raised (a loader's own, so its callers catch it).

    Raises
    ------
    error
        One line: ``"params.toml: carving.resolution: carving 2000^3 voxels needs about
        15.4 GB (limit 4.0 GB; CTR_BENCH_MEMORY_LIMIT_GB raises it)"``.
    """
    limit = memory_limit_bytes()
    if needed_bytes > limit:
        raise error(f"{where}: {what} needs about {_gb(needed_bytes)} (limit {_gb(limit)}; {LIMIT_ENV} raises it)")
