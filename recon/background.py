"""Eigenbackground model: background subtraction robust to lighting and jitter.

Following the paper (Section III-A, after Oliver et al.), the background of a
camera is modelled as the mean of a video of the empty scene plus a
low-dimensional linear subspace ("eigenbackgrounds") spanned by the principal
components of that video. Projecting a live frame onto the subspace and back
reproduces the frame's own lighting and small camera motion but not the robot,
which no background frame contains; the absolute difference between the frame
and that estimate is the foreground evidence.

Images are (H, W) arrays of gray levels (0-255 for uint8 input); every
computation is in float32.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .errors import FrameError

__all__ = [
    "EigenBackgroundParams",
    "EigenBackground",
    "fit_eigenbackground",
    "background_estimate",
    "difference_image",
    "to_gray",
]


def to_gray(images: np.ndarray) -> np.ndarray:
    """Gray images from RGB ones: (..., H, W, 3) -> (..., H, W) with OpenCV's luma weights; gray passes through.

    Colour cameras deliver RGB frames; the background model and the difference
    work on one channel, as the mono cameras of the paper's rig give.

    Parameters
    ----------
    images : array_like
        ``(..., H, W, 3)`` RGB images (uint8 gray levels 0-255 or float32), or
        gray ones of any other shape (e.g. ``(H, W)`` or ``(N, H, W)``).

    Returns
    -------
    ndarray
        ``(..., H, W)`` gray images of the input's dtype (``cv2.COLOR_RGB2GRAY``
        weights); input that is not 3-channel comes back as ``np.asarray(images)``.
    """
    a = np.asarray(images)
    if a.ndim < 3 or a.shape[-1] != 3:
        return a
    flat = a.reshape((-1,) + a.shape[-3:])
    out = np.stack([cv2.cvtColor(np.ascontiguousarray(f), cv2.COLOR_RGB2GRAY) for f in flat])
    return out.reshape(a.shape[:-1])


@dataclass(frozen=True)
class EigenBackgroundParams:
    """Parameters of :func:`fit_eigenbackground`.

    Attributes
    ----------
    k : int
        Number of eigenbackgrounds kept (the paper: the five with the largest
        eigenvalues).
    min_variance : float
        Directions along which the frames vary by less than this (gray
        levels^2, per pixel and frame) are dropped: they span rounding noise
        (e.g. a perfectly static scene), and normalizing them would divide by
        ~0.
    """

    k: int = 5
    min_variance: float = 1e-6

    def __post_init__(self):
        if int(self.k) < 1:
            raise ValueError(f"EigenBackgroundParams.k must be >= 1, got {self.k}")


@dataclass(frozen=True, eq=False)
class EigenBackground:
    """A fitted eigenbackground model of one camera.

    Attributes
    ----------
    mean : (H*W,) float32 array
        Mean background frame, raveled (gray levels).
    basis : (k', H*W) float32 array
        Orthonormal eigenbackgrounds as rows (k' <= k: near-null directions are
        dropped).
    eigenvalues : (k',) float64 array
        Variance along each row of ``basis`` (gray levels^2, summed over
        pixels, per frame), largest first.
    shape : tuple of int
        Image shape ``(H, W)`` in pixels.
    """

    mean: np.ndarray
    basis: np.ndarray
    eigenvalues: np.ndarray
    shape: tuple

    def __post_init__(self):
        # Needed for every frame; computed once here.
        object.__setattr__(self, "_basis_mean", self.basis @ self.mean)
        object.__setattr__(self, "_peak", float(self.mean.max()))
        object.__setattr__(self, "_range", float(self.mean.max() - self.mean.min()))

    @property
    def k(self) -> int:
        """Number of eigenbackgrounds actually kept.

        Returns
        -------
        int
            ``k'``, the rows of ``basis`` (at most ``EigenBackgroundParams.k``).
        """
        return int(self.basis.shape[0])


def _size(shape) -> str:
    return f"{shape[1]}x{shape[0]}"


# float64 values per block of fit_eigenbackground (~16 MB).
_CHUNK_VALUES = 1 << 21


def fit_eigenbackground(frames, params: EigenBackgroundParams = EigenBackgroundParams()) -> EigenBackground:
    """Fit an eigenbackground model to frames of the empty scene.

    Uses the Sirovich-Kirby snapshot method: with N frames of P = H*W pixels,
    the eigenvectors of the P x P covariance are obtained from those of the
    N x N Gram matrix of the mean-subtracted frames, so the P x P matrix is
    never formed.

    Parameters
    ----------
    frames : (N, H, W) array or sequence of (H, W) arrays
        Background frames (gray levels, uint8 or float).
    params : EigenBackgroundParams

    Returns
    -------
    EigenBackground

    Raises
    ------
    ValueError
        Fewer than ``k + 1`` frames (the mean removes one degree of freedom),
        frames of different sizes, or frames that are not 2-D.
    """
    k = int(params.k)
    if isinstance(frames, np.ndarray):
        stack = frames
    else:
        frames = list(frames)
        shapes = {np.shape(f) for f in frames}
        if len(shapes) > 1:
            a, b = sorted(shapes)[:2]
            raise ValueError(
                f"background frames have different sizes: {_size(a)} and {_size(b)}"
                if len(a) == 2 and len(b) == 2
                else f"background frames have different shapes: {a} and {b}"
            )
        stack = np.asarray(frames) if frames else np.zeros((0, 0, 0))
    n = stack.shape[0] if stack.ndim >= 1 else 0
    if n < k + 1:
        raise ValueError(f"need at least k+1={k + 1} background frames, got {n}")
    if stack.ndim != 3:
        raise ValueError(f"background frames must be (N, H, W) gray images, got shape {stack.shape}")
    shape = tuple(int(s) for s in stack.shape[1:])
    X = stack.reshape(n, -1)
    P = X.shape[1]
    # In float64 over blocks of pixels: a float64 copy of 30 frames of 5
    # megapixels would be 1.2 GB; a block is a few MB.
    step = max(1, _CHUNK_VALUES // max(n, 1))
    mean = np.empty(P, np.float64)
    # Gram matrix in float64: it sums ~1e6 products per entry.
    gram = np.zeros((n, n))
    for a in range(0, P, step):
        xa = X[:, a : a + step].astype(np.float64)
        mean[a : a + step] = xa.mean(axis=0)
        xa -= mean[a : a + step]
        gram += xa @ xa.T
    evals, evecs = np.linalg.eigh(gram)
    order = np.argsort(evals)[::-1][:k]
    evals, evecs = evals[order], evecs[:, order]
    # Gram eigenvalues are variances summed over pixels and frames.
    keep = evals > params.min_variance * n * P
    evals, evecs = evals[keep], evecs[:, keep]
    # u_i = X^T v_i / sqrt(lambda_i) are unit eigenvectors of X^T X.
    basis = np.empty((evals.size, P), np.float32)
    scale = 1.0 / np.sqrt(evals)[:, None]
    for a in range(0, P, step):
        xa = X[:, a : a + step].astype(np.float64)
        xa -= mean[a : a + step]
        basis[:, a : a + step] = (evecs.T @ xa) * scale
    return EigenBackground(
        mean=mean.astype(np.float32),
        basis=basis,
        eigenvalues=evals / n,
        shape=shape,
    )


def _frame_vector(model: EigenBackground, frame, camera_name: str | None) -> np.ndarray:
    frame = np.asarray(frame)
    if frame.shape != model.shape:
        got = _size(frame.shape) if frame.ndim == 2 else str(frame.shape)
        raise FrameError(f"frame is {got} but the background model is {_size(model.shape)}", camera_name)
    return frame.reshape(-1).astype(np.float32)


def no_picture(values: np.ndarray, background_peak: float, background_range: float,
               black_fraction: float = 0.01, flat_fraction: float = 0.01) -> str | None:
    """Why a frame holds no picture of the scene, or None: all black, or one flat level.

    Parameters
    ----------
    values : array
        The frame's gray levels (all pixels, or a spread-out sample of them).
    background_peak, background_range : float
        The mean background's brightest level and its spread (max - min), gray levels.
    black_fraction : float
        A frame whose brightest value is at most this fraction of
        ``background_peak`` is all black (lens cap, camera not delivering);
        0.01 is ~2 gray levels for a scene peaking at 200.
    flat_fraction : float
        A frame whose values span at most this fraction of
        ``background_range`` is one flat level (a saturated or blank picture;
        ~2 gray levels for a backdrop spanning 200): no robot can be told
        from it, and calling its edges "the robot at the border" would
        mislead. A uniform background (masks) has no range: never flat.

    Returns
    -------
    str or None
        A one-line reason (``"all-black frame"`` or ``"blank frame (...)"``), or
        None when the frame may hold a picture.
    """
    hi = float(np.max(values))
    if background_peak > 0 and hi <= black_fraction * background_peak:
        return "all-black frame"
    lo = float(np.min(values))
    if background_range > 0 and hi - lo <= flat_fraction * background_range:
        return f"blank frame (every pixel about {0.5 * (hi + lo):.4g} gray levels): no picture of the scene"
    return None


def _estimate(model: EigenBackground, f: np.ndarray) -> np.ndarray:
    # mean + B^T B (f - mean), with B mean precomputed: two passes over B.
    coeffs = model.basis @ f
    coeffs -= model._basis_mean
    bg = coeffs @ model.basis
    bg += model.mean
    return bg


def background_estimate(model: EigenBackground, frame, camera_name: str | None = None) -> np.ndarray:
    """Background of ``frame``: its projection onto the eigenbackgrounds and back.

    Parameters
    ----------
    model : EigenBackground
    frame : (H, W) array
        Camera frame (gray levels).
    camera_name : str, optional
        Prefix of error messages.

    Returns
    -------
    (H, W) float32 array
        ``mean + basis^T basis (frame - mean)`` (gray levels).

    Raises
    ------
    FrameError
        The frame's size differs from the model's.
    """
    return _estimate(model, _frame_vector(model, frame, camera_name)).reshape(model.shape)


def difference_image(
    model: EigenBackground,
    frame,
    camera_name: str | None = None,
    *,
    black_fraction: float = 0.01,
    ignore: np.ndarray | None = None,
    blur_sigma_px: float = 0.0,
) -> tuple[np.ndarray, float]:
    """Normalized absolute difference between a frame and its background.

    The paper binarizes "the absolute value of the (normalized) difference
    image" at 0.25. The normalization is taken as MATLAB's ``mat2gray`` does:
    ``|frame - background|`` divided by its maximum over the frame, so the
    result spans [0, 1] whatever the contrast of the robot. That division also
    blows up pure sensor noise to [0, 1] when no robot is in view, so the raw
    maximum is returned too; :func:`recon.silhouette.extract_silhouette`
    rejects frames whose raw maximum is below a minimum contrast.

    Parameters
    ----------
    model : EigenBackground
    frame : (H, W) array
        Camera frame (gray levels, uint8 or float on the same scale as the
        background frames).
    camera_name : str, optional
        Prefix of error messages.
    black_fraction : float
        A frame whose brightest pixel is at most this fraction of the mean
        background's brightest is rejected as all-black (lens cap, camera not
        delivering); 0.01 is ~2 gray levels for a scene peaking at 200.
    ignore : array of int, optional
        Flat pixel indices that cannot hold the robot (e.g. behind its base):
        their difference is set to 0 before the maximum is taken, so clutter
        there neither sets the normalization nor joins the silhouette.
    blur_sigma_px : float
        Gaussian blur (px) of the signed difference before its absolute value
        (0: none, the paper). Sensor noise averages out over the blur while a
        tube several pixels wide keeps its contrast: a faint tube over a
        backdrop of nearly its brightness rises above the noise.

    Returns
    -------
    diff : (H, W) float32 array
        ``|frame - background| / max |frame - background|`` in [0, 1]; all
        zeros when the frame equals its background.
    max_difference : float
        ``max |frame - background|`` in gray levels.

    Raises
    ------
    FrameError
        The frame's size differs from the model's, or it holds no picture
        (:func:`no_picture`: all black, or one flat level).
    """
    f = _frame_vector(model, frame, camera_name)
    why = no_picture(f, model._peak, model._range, black_fraction)
    if why:
        raise FrameError(why, camera_name)
    diff = _estimate(model, f)
    np.subtract(f, diff, out=diff)
    if blur_sigma_px > 0:
        diff = cv2.GaussianBlur(diff.reshape(model.shape), (0, 0), float(blur_sigma_px),
                                borderType=cv2.BORDER_REFLECT).reshape(-1)
    np.abs(diff, out=diff)
    if ignore is not None:
        diff[ignore] = 0.0
    peak = float(diff.max())
    if peak > 0.0:
        diff *= np.float32(1.0 / peak)
    return diff.reshape(model.shape), peak
