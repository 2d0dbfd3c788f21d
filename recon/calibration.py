"""Rig calibration from checkerboard images, as Morimoto & Sketch did (section II, eq. 1).

The paper calibrated each camera from 20 checkerboard images, set the world frame
from one more image of the board taken by the top camera (``T_top_world``), ran a
stereo calibration (``T_side_top``) and composed

    T_side_world = T_side_top @ T_top_world                        (eq. 1)

This module does the same with OpenCV, on images (arrays) or a folder laid out as
``docs/calibration.md`` describes, and ends with a joint refinement of everything
at once (both cameras' intrinsics, every board pose and ``T_side_top``), as the
stereo calibration of the Bouguet toolbox the paper used does.

Conventions
-----------
* Board (:class:`BoardSpec`): ``cols`` x ``rows`` *inner* corners, ``square_mm``.
* Board frame, which is also the **world frame** (up to the known offset
  ``world_origin_mm``): origin at the first inner corner, x along the ``cols``
  corners, y along the ``rows`` corners, z = x × y, out of the printed face.
  Looking at the print, y is 90° counter-clockwise from x. The square between the
  first four inner corners is black; this fixes which corner is first when
  ``cols + rows`` is odd (e.g. 9x6, 11x8). Boards with ``cols + rows`` even look
  the same turned by 180°: usable for intrinsics, not for stereo or the world frame.
* ``world_origin_mm``: where the world-frame board's first inner corner is in the
  world frame, its axes being the world axes (0 when the board *is* the world frame).
* Poses are 4x4 ``T_a_b`` mapping frame-b points (mm) into frame a; cameras follow
  :mod:`recon.camera` (OpenCV model ``k1 k2 p1 p2 k3``).
* The cameras are called ``"side"`` and ``"top"`` as in the paper.

Errors a user can fix (no images, no board, wrong board size, too few usable
views, mixed image sizes) raise ``ValueError`` with one clear line.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.spatial.transform import Rotation

from .camera import Camera
from .distortion import COEFFICIENT_NAMES, MODEL_SIZES, distort_xy, padded, tilt_matrix
from .geometry import invert_transform
from .rigcal import RigCalibration

__all__ = [
    "BoardSpec",
    "CalibrationParams",
    "Detection",
    "ViewRecord",
    "CameraCalibration",
    "StereoCalibration",
    "WorldFrame",
    "CalibrationReport",
    "CalibrationImages",
    "COMMON_BOARDS",
    "MODEL_TERMS",
    "parse_terms",
    "calibration_flags",
    "IMAGE_SUFFIXES",
    "detect_board",
    "detect_images",
    "refine_corners",
    "suggest_board_size",
    "calibrate_camera",
    "calibrate_stereo",
    "world_frame",
    "compose_side_world",
    "refine_jointly",
    "calibrate_rig",
    "calibrate_extrinsics",
    "draw_coverage",
    "load_calibration_folder",
    "read_image",
    "pose_difference",
    "save_report",
]

CAMERAS = ("side", "top")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")

#: Each OpenCV distortion model (:mod:`recon.distortion`): its coefficient count -> its terms.
MODEL_TERMS = {n: COEFFICIENT_NAMES[:n] for n in MODEL_SIZES}
#: Terms OpenCV estimates or fixes together (one flag each), in their order of significance.
_TERM_GROUPS = (("k1",), ("k2",), ("p1", "p2"), ("k3",), ("k4",), ("k5",), ("k6",), ("s1", "s2", "s3", "s4"), ("tau_x", "tau_y"))
_FIX_FLAG = {"k1": cv2.CALIB_FIX_K1, "k2": cv2.CALIB_FIX_K2, "p1": cv2.CALIB_ZERO_TANGENT_DIST, "k3": cv2.CALIB_FIX_K3,
             "k4": cv2.CALIB_FIX_K4, "k5": cv2.CALIB_FIX_K5, "k6": cv2.CALIB_FIX_K6, "s1": cv2.CALIB_FIX_S1_S2_S3_S4,
             "tau_x": cv2.CALIB_FIX_TAUX_TAUY}
_MODEL_FLAG = {4: cv2.CALIB_FIX_K3, 5: 0, 8: cv2.CALIB_RATIONAL_MODEL,
               12: cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_THIN_PRISM_MODEL,
               14: cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_THIN_PRISM_MODEL | cv2.CALIB_TILTED_MODEL}


def parse_terms(text: str, model: int) -> tuple:
    """The distortion terms estimated, from their text.

    Parameters
    ----------
    text : str
        The terms, e.g. ``"k1 k2 p1 p2"`` (commas allowed) or ``"none"``.
    model : int
        The OpenCV model's coefficient count (4, 5, 8, 12 or 14).

    Returns
    -------
    tuple of str
        The terms in OpenCV's order.

    Raises
    ------
    ValueError
        Naming ``--distortion``: a term outside the model, or a group OpenCV estimates together split apart.
    """
    terms = () if text.strip() == "none" else tuple(text.replace(",", " ").split())
    allowed = MODEL_TERMS[model]
    bad = [t for t in terms if t not in allowed]
    if bad:
        raise ValueError(f"--distortion: {' '.join(bad)} not in the {model}-coefficient model ({' '.join(allowed)})")
    for group in _TERM_GROUPS:
        if 0 < sum(t in terms for t in group) < len(group):
            raise ValueError(f"--distortion: {' '.join(group)} are estimated together or not at all (OpenCV)")
    return tuple(t for t in allowed if t in terms)


def calibration_flags(terms: tuple, model: int) -> int:
    """``cv2.calibrateCamera`` flags estimating ``terms`` of the ``model``-coefficient model, the others held.

    Parameters
    ----------
    terms : tuple of str
        The estimated terms (:func:`parse_terms`).
    model : int
        The OpenCV model's coefficient count (4, 5, 8, 12 or 14).

    Returns
    -------
    int
        The ``cv2.CALIB_*`` flags.
    """
    flags = _MODEL_FLAG[model]
    for group in _TERM_GROUPS:
        if group[0] in MODEL_TERMS[model] and group[0] not in terms:
            flags |= _FIX_FLAG[group[0]]
    return flags


#: Inner-corner sizes tried when the given board is found nowhere (to suggest the right one).
COMMON_BOARDS = (
    (9, 6), (8, 6), (7, 5), (7, 6), (8, 5), (9, 7), (10, 7), (11, 8), (6, 4), (5, 4), (7, 4), (6, 5),
    (10, 6), (11, 7), (12, 9), (13, 9), (12, 8), (9, 5), (8, 7), (10, 8), (5, 3), (4, 3), (14, 9), (15, 10),
)


# ----------------------------------------------------------------------------- board
@dataclass(frozen=True)
class BoardSpec:
    """A printed checkerboard: ``cols`` x ``rows`` inner corners, squares of ``square_mm``."""

    cols: int
    rows: int
    square_mm: float

    def __post_init__(self):
        for key in ("cols", "rows"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 2:
                raise ValueError(f"board {key} must be an integer >= 2 (inner corners), got {v!r}")
        if self.cols == self.rows:
            raise ValueError(f"a {self.cols}x{self.rows} board is square: its orientation is ambiguous; use cols != rows, e.g. 9x6")
        if not np.isfinite(self.square_mm) or self.square_mm <= 0:
            raise ValueError(f"board square size must be > 0 mm, got {self.square_mm!r}")
        object.__setattr__(self, "cols", int(self.cols))
        object.__setattr__(self, "rows", int(self.rows))
        object.__setattr__(self, "square_mm", float(self.square_mm))

    @classmethod
    def parse(cls, text: str, square_mm: float) -> "BoardSpec":
        """The board from its text and square size.

        Parameters
        ----------
        text : str
            ``"9x6"``: inner corners, cols x rows (``×`` and ``,`` accepted).
        square_mm : float
            Side of a square (mm).

        Returns
        -------
        BoardSpec

        Raises
        ------
        ValueError
            Naming the text when it is not COLSxROWS, or a value out of range.
        """
        parts = str(text).lower().replace("×", "x").replace(",", "x").split("x")
        try:
            cols, rows = (int(p) for p in parts)
        except ValueError:
            raise ValueError(f"board must be COLSxROWS inner corners, e.g. 9x6, got {text!r}") from None
        return cls(cols, rows, square_mm)

    @property
    def size(self) -> tuple:
        """``(cols, rows)``: OpenCV's pattern size.

        Returns
        -------
        tuple of int
            ``(cols, rows)`` inner corners, as ``cv2.findChessboardCorners`` takes them.
        """
        return (self.cols, self.rows)

    @property
    def label(self) -> str:
        """The board's size as text, e.g. ``"9x6"`` (cols x rows inner corners).

        Returns
        -------
        str
        """
        return f"{self.cols}x{self.rows}"

    @property
    def n_corners(self) -> int:
        """Number of inner corners, ``cols * rows``.

        Returns
        -------
        int
        """
        return self.cols * self.rows

    @property
    def asymmetric(self) -> bool:
        """Whether the first corner can be told from the last (``cols + rows`` odd).

        Returns
        -------
        bool
        """
        return (self.cols + self.rows) % 2 == 1

    def object_points(self) -> np.ndarray:
        """The inner corners in the board frame, row by row: index = row * cols + col.

        Returns
        -------
        (n, 3) array
            Board-frame points (mm), z = 0.
        """
        c, r = np.meshgrid(np.arange(self.cols), np.arange(self.rows))
        return np.stack([c.ravel() * self.square_mm, r.ravel() * self.square_mm, np.zeros(c.size)], 1)


@dataclass(frozen=True)
class CalibrationParams:
    """Tuning of the calibration; the defaults suit the paper's rig and most labs.

    Attributes
    ----------
    min_views : int
        Usable views each camera needs for its intrinsics.
    min_stereo_pairs : int
        Usable pairs the stereo calibration needs.
    max_edge_width_px : float
        Blur limit: a view whose black-to-white edges (10-90 %) are wider is rejected.
    max_oblique_deg : float
        A view whose board normal is further than this from the optical axis is rejected.
    outlier_factor, outlier_floor_px : float
        A view (or pair) is a reprojection outlier when its RMS error exceeds both
        ``outlier_factor`` times the median and ``outlier_floor_px``; the worst goes
        first, then the calibration is redone.
    refine : {"saddle", "cornersubpix", "none"}
        Sub-pixel corner refinement: the saddle point of a quadratic fitted to the
        smoothed image (unbiased for any corner angle, no pixel locking), or OpenCV's
        ``cornerSubPix``.
    distortion_model : int
        The OpenCV distortion model: 4 (k1 k2 p1 p2), 5 (+ k3), 8 (+ k4 k5 k6, rational),
        12 (+ s1..s4, thin prism) or 14 (+ tau_x tau_y, tilted sensor) coefficients.
    distortion : str
        Which of the model's terms are estimated: ``"auto"`` (all, then each group beyond
        k1 k2 - the tangential pair, k3, k4, k5, k6, the prism terms, the tilt - is held at 0
        when it is not significant, every |value| < 3 standard deviations: a narrow lens
        barely separates p1 p2 from the principal point, nor k3 from k2, and estimating
        noise there costs accuracy), ``"none"``, or the terms, e.g. ``"k1 k2 p1 p2"``.
    intrinsics_from_stereo : bool
        Also use the stereo images for each camera's intrinsics.
    joint_refinement : bool
        Finish with one least-squares adjustment of all intrinsics, poses and
        ``T_side_top`` together (with the stereo pairs tying the cameras together).
        Skipped when the pairs disagree with the rigid rig (stereo RMS above
        ``max_stereo_ratio`` times the single views'), e.g. when a camera moved between
        pairs: forcing them together would bend the intrinsics.
    max_stereo_ratio : float
    suggest_sizes : bool
        When the board is found nowhere, try common sizes to say which one is there.
    exhaustive : bool
        When the quick detectors miss a board, also try OpenCV's exhaustive search
        (about a second per image; finds boards in poor images).
    """

    min_views: int = 5
    min_stereo_pairs: int = 3
    max_edge_width_px: float = 5.0
    max_oblique_deg: float = 65.0
    outlier_factor: float = 3.0
    outlier_floor_px: float = 0.3
    refine: str = "saddle"
    distortion_model: int = 5
    distortion: str = "auto"
    intrinsics_from_stereo: bool = True
    joint_refinement: bool = True
    max_stereo_ratio: float = 3.0
    suggest_sizes: bool = True
    exhaustive: bool = False

    def __post_init__(self):
        if self.refine not in ("saddle", "cornersubpix", "none"):
            raise ValueError(f"refine must be 'saddle', 'cornersubpix' or 'none', got {self.refine!r}")
        if self.distortion_model not in MODEL_SIZES:
            raise ValueError(f"--distortion-model: OpenCV models have {', '.join(map(str, MODEL_SIZES))} coefficients, "
                             f"got {self.distortion_model!r}")
        if self.distortion != "auto":
            parse_terms(self.distortion, self.distortion_model)
        if self.min_views < 3:
            raise ValueError(f"--min-views must be at least 3, got {self.min_views}")
        if self.min_stereo_pairs < 1:
            raise ValueError(f"min_stereo_pairs must be >= 1, got {self.min_stereo_pairs}")


# ----------------------------------------------------------------------------- detection
@dataclass(frozen=True, eq=False)
class Detection:
    """The board as found in one image.

    Attributes
    ----------
    name : str
        Where the image came from, e.g. ``"side/003.png"``.
    image_size : (width, height)
    corners : (n, 2) array or None
        Inner corners (px) in board order (see the module conventions); None when not found.
    oriented : bool
        Whether the first corner was told from the last by the square colours.
    edge_width_px : float or None
        Mean 10-90 % black-to-white edge width (blur measure).
    reason : str or None
        Why the view cannot be used (not found, blurred); None when usable.
    """

    name: str
    image_size: tuple
    corners: np.ndarray | None = None
    oriented: bool = False
    edge_width_px: float | None = None
    reason: str | None = None

    @property
    def found(self) -> bool:
        """Whether the board's corners were found in the image (``corners`` is not None).

        Returns
        -------
        bool
        """
        return self.corners is not None

    @property
    def usable(self) -> bool:
        """Whether the view can be used: corners found and no ``reason`` against it (e.g. blur).

        Returns
        -------
        bool
        """
        return self.corners is not None and self.reason is None


def _gray(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 3:
        if img.shape[2] == 1:
            img = img[:, :, 0]
        elif img.shape[2] == 4:
            img = cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY)
        else:
            img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.ndim != 2:
        raise ValueError(f"expected a grey or colour image, got an array of shape {np.shape(image)}")
    if img.dtype != np.uint8:
        f = img.astype(np.float64)
        hi = f.max() if f.max() > 0 else 1.0
        img = np.clip(f * (255.0 / (hi if hi > 255 else (1.0 if hi <= 1.0 else 255.0))), 0, 255).astype(np.uint8)
    return img


_CLASSIC_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK


def _shrunk(gray: np.ndarray, factor: int) -> tuple:
    """The image shrunk ``factor`` times (area filter) and the scale back to full-size pixels."""
    h, w = gray.shape
    small = cv2.resize(gray, (w // factor, h // factor), interpolation=cv2.INTER_AREA)
    return small, np.array([w / (w // factor), h / (h // factor)])


def _find_corners(gray: np.ndarray, size: tuple, effort: int = 1) -> np.ndarray | None:
    """Inner corners (n, 2, px, up to a few pixels off) in OpenCV's order, or None.

    ``effort`` 0: OpenCV's classic and sector-based detectors on the half-size image
    (milliseconds when the board is there, a fraction of a second when not); 1: then
    the sector-based one at full size, plainly and exhaustively (a second or two to
    give up); 2: then the classic one at full size (which can take seconds to give up)
    and the sector-based one at its most accurate.
    """
    h, w = gray.shape
    if min(h, w) >= 240:
        small, scale = _shrunk(gray, 2)
        ok, c = cv2.findChessboardCorners(small, size, flags=_CLASSIC_FLAGS)
        if not ok:
            ok, c = cv2.findChessboardCornersSB(small, size, flags=cv2.CALIB_CB_NORMALIZE_IMAGE)
        if ok:
            return (c.reshape(-1, 2).astype(np.float64) + 0.5) * scale - 0.5
    tries = []
    if effort >= 1 or min(h, w) < 240:
        tries += [("sb", cv2.CALIB_CB_NORMALIZE_IMAGE), ("sb", cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE)]
    if effort >= 2:
        tries += [("classic", _CLASSIC_FLAGS), ("sb", cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)]
    for kind, flags in tries:
        if kind == "sb":
            ok, c = cv2.findChessboardCornersSB(gray, size, flags=flags)
        else:
            ok, c = cv2.findChessboardCorners(gray, size, flags=flags)
        if ok:
            return c.reshape(-1, 2).astype(np.float64)
    return None


def _repair(gray: np.ndarray, corners: np.ndarray, board: BoardSpec, spacing_px: float) -> np.ndarray:
    """Put corners that left the grid back where the others say they are, then settle them again.

    A homography fitted to the grid (robustly) predicts every corner to within the lens
    distortion (a pixel or two); a corner further off than a quarter of the spacing (a
    detector mistake at the board's border) restarts from its prediction.
    """
    grid = np.stack(np.meshgrid(np.arange(board.cols), np.arange(board.rows)), -1).reshape(-1, 2).astype(np.float64)
    H, _ = cv2.findHomography(grid, corners, cv2.RANSAC, 0.1 * spacing_px)
    if H is None:
        return corners
    pred = cv2.perspectiveTransform(grid.reshape(-1, 1, 2), H).reshape(-1, 2)
    off = np.linalg.norm(corners - pred, axis=1) > 0.25 * spacing_px
    if not off.any():
        return corners
    out = corners.copy()
    out[off] = refine_corners(gray, pred[off], spacing_px, "cornersubpix")
    return out


def _grid_spacing_px(grid: np.ndarray) -> float:
    """Near-smallest distance (px) between neighbouring corners of a (rows, cols, 2) grid
    (the 5th percentile: one misplaced corner does not shrink it)."""
    dx = np.linalg.norm(np.diff(grid, axis=1), axis=2).ravel()
    dy = np.linalg.norm(np.diff(grid, axis=0), axis=2).ravel()
    return float(np.percentile(np.concatenate([dx, dy]), 5))


def refine_corners(gray: np.ndarray, corners: np.ndarray, spacing_px: float, method: str = "saddle",
                   sigma_px: float | None = None, half_px: int | None = None) -> np.ndarray:
    """Sub-pixel refinement of checkerboard corners.

    ``"saddle"`` starts from ``cornerSubPix``, smooths the image (Gaussian, about 6 % of
    the corner spacing, 0.7 to 1.5 px) and moves each corner to the saddle point of a quadratic surface fitted in
    a window centred on it, iterating until it settles. A checkerboard corner is
    point-symmetric, so the saddle lies on it for any corner angle (perspective) and the
    smoothing removes the pull toward pixel boundaries that sharp edges give gradient
    methods. ``"cornersubpix"`` is OpenCV's ``cornerSubPix``.

    Parameters
    ----------
    gray : (h, w) uint8 array
        The image.
    corners : (n, 2) array
        Starting corners (px, image frame: x right, y down, pixel centres at integers).
    spacing_px : float
        Smallest distance between neighbouring corners (px); sizes the windows.
    method : {"saddle", "cornersubpix", "none"}
    sigma_px : float, optional
        Smoothing of the saddle fit (px); default from ``spacing_px``.
    half_px : int, optional
        Half-size of the saddle fit's window (px); default from ``spacing_px``.

    Returns
    -------
    (n, 2) array
        Refined corners (px); a corner whose fit wandered off keeps its ``cornerSubPix`` position.
    """
    pts = np.asarray(corners, np.float64).reshape(-1, 2)
    if method == "none" or len(pts) == 0:
        return pts.copy()
    if method == "cornersubpix":
        win = int(np.clip(round(spacing_px * 0.3), 3, 11))
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
        out = cv2.cornerSubPix(gray, pts.astype(np.float32).reshape(-1, 1, 2), (win, win), (-1, -1), crit)
        return out.reshape(-1, 2).astype(np.float64)
    # OpenCV's cornerSubPix first: it pulls a detector corner that is off by a pixel or
    # two (at the board's border) into the saddle's basin.
    pts = refine_corners(gray, pts, spacing_px, "cornersubpix")
    sigma = float(sigma_px if sigma_px is not None else np.clip(spacing_px * 0.06, 0.7, 1.5))
    half = int(half_px if half_px is not None else np.clip(round(spacing_px * 0.2), 2, 5))
    smooth = cv2.GaussianBlur(gray.astype(np.float32), (0, 0), sigma)
    ys, xs = np.mgrid[-half : half + 1, -half : half + 1].astype(np.float64)
    xs, ys = xs.ravel(), ys.ravel()
    w = np.exp(-(xs**2 + ys**2) / (2.0 * (half / 1.5) ** 2))
    A = np.stack([xs * xs, xs * ys, ys * ys, xs, ys, np.ones_like(xs)], 1) * w[:, None]
    pinv = np.linalg.pinv(A)  # (6, m)
    start = pts.copy()
    p = pts.copy()
    active = np.ones(len(p), bool)
    for _ in range(10):
        mx = (p[active, 0:1] + xs[None, :]).astype(np.float32)
        my = (p[active, 1:2] + ys[None, :]).astype(np.float32)
        patch = cv2.remap(smooth, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
        coef = (patch * w[None, :]) @ pinv.T  # (k, 6): a b c d e f
        a, b, c, d, e = coef[:, 0], coef[:, 1], coef[:, 2], coef[:, 3], coef[:, 4]
        det = 4 * a * c - b * b
        saddle = det < 0  # a checkerboard corner is a saddle of the intensity
        with np.errstate(divide="ignore", invalid="ignore"):
            ox = (-2 * c * d + b * e) / det
            oy = (b * d - 2 * a * e) / det
        step = np.stack([ox, oy], 1)
        ok = saddle & np.all(np.isfinite(step), 1) & (np.linalg.norm(step, axis=1) < half)
        idx = np.flatnonzero(active)
        p[idx[ok]] += step[ok]
        done = ~ok | (np.linalg.norm(np.where(np.isfinite(step), step, 0), axis=1) < 1e-3)
        active[idx[done]] = False
        if not active.any():
            break
    # a corner that wandered off (a bad fit) keeps its detector position
    moved = np.linalg.norm(p - start, axis=1) > max(1.5, half * 0.6)
    p[moved] = start[moved]
    return p


def _orient(gray: np.ndarray, corners: np.ndarray, board: BoardSpec) -> tuple:
    """Put detected corners in board order: handedness from the image, first corner by colour.

    Returns ``(corners (n, 2), oriented)``; ``oriented`` is False when the board's colours
    cannot tell its first corner from its last (``cols + rows`` even).
    """
    G = corners.reshape(board.rows, board.cols, 2)
    smooth = cv2.blur(gray, (3, 3)).astype(np.float64)
    best = None
    for cand in (G, G[:, ::-1], G[::-1, :], G[::-1, ::-1]):
        vx = cand[:, -1].mean(0) - cand[:, 0].mean(0)
        vy = cand[-1, :].mean(0) - cand[0, :].mean(0)
        if vx[0] * vy[1] - vx[1] * vy[0] >= 0:
            continue  # seen from the back: z = x × y must point toward the camera
        centres = 0.25 * (cand[:-1, :-1] + cand[1:, :-1] + cand[:-1, 1:] + cand[1:, 1:])  # squares inside the grid
        i, j = np.meshgrid(np.arange(board.cols - 1), np.arange(board.rows - 1))
        u = np.clip(np.rint(centres[..., 0]).astype(int), 0, gray.shape[1] - 1)
        v = np.clip(np.rint(centres[..., 1]).astype(int), 0, gray.shape[0] - 1)
        val = smooth[v, u]
        even = (i + j) % 2 == 0  # these squares are black in board order
        contrast = val[~even].mean() - val[even].mean()
        if best is None or contrast > best[0]:
            best = (contrast, cand)
    if best is None:  # degenerate geometry: keep the detector's order
        return corners.copy(), False
    return best[1].reshape(-1, 2).copy(), board.asymmetric


def detect_board(image: np.ndarray, board: BoardSpec, params: CalibrationParams | None = None, name: str = "image",
                 quick: bool = False) -> Detection:
    """Find ``board`` in one image, refine its corners and put them in board order.

    A board that is not found or too blurred gives a Detection with a ``reason`` (never an exception).

    Parameters
    ----------
    image : (h, w) or (h, w, 1 | 3 | 4) array
        Grey, BGR or BGRA image; any dtype (scaled to 8 bits).
    board : BoardSpec
    params : CalibrationParams, optional
        Refinement method, blur limit, exhaustive search.
    name : str
        The image's name in messages and in the Detection.
    quick : bool
        Try only the fast detectors (a first pass over many images).

    Returns
    -------
    Detection
        Corners (n, 2) px in board order (module conventions), or None with the reason.
    """
    params = params or CalibrationParams()
    gray = _gray(image)
    size = (gray.shape[1], gray.shape[0])
    raw = _find_corners(gray, board.size, 0 if quick else (2 if params.exhaustive else 1))
    if raw is None:
        return Detection(name, size, reason=f"no {board.label} board found")
    sharp = cv2.estimateChessboardSharpness(gray, board.size, raw.reshape(-1, 1, 2).astype(np.float32))[0]
    edge = float(sharp[0])
    spacing = _grid_spacing_px(raw.reshape(board.rows, board.cols, 2))
    if params.refine != "none":
        raw = _repair(gray, refine_corners(gray, raw, spacing, "cornersubpix"), board, spacing)
    refined = refine_corners(gray, raw, spacing, params.refine)
    corners, oriented = _orient(gray, refined, board)
    reason = None
    if edge > params.max_edge_width_px:
        reason = f"blurred: edges {edge:.1f} px wide (limit {params.max_edge_width_px:g} px)"
    return Detection(name, size, corners=corners, oriented=oriented, edge_width_px=edge, reason=reason)


def detect_images(items: list, board: BoardSpec, params: CalibrationParams | None = None, progress=None,
                  stage: str = "detect", done: int = 0, total: int | None = None, quick: bool = False) -> list:
    """:func:`detect_board` over many images.

    Parameters
    ----------
    items : list of (name, image)
    board : BoardSpec
    params : CalibrationParams, optional
    progress : callable, optional
        ``progress(stage, done, total)`` after each image.
    stage : str
        The stage named to ``progress``.
    done, total : int
        Offset and size of the count, when this is part of a longer run (``total`` defaults to
        ``len(items) + done``).
    quick : bool
        Fast detectors only (see :func:`detect_board`).

    Returns
    -------
    list of Detection
        One per item, in order.
    """
    out = []
    total = len(items) + done if total is None else total
    for k, (name, img) in enumerate(items):
        out.append(detect_board(img, board, params, name, quick))
        if progress is not None:
            progress(stage, done + k + 1, total)
    return out


def suggest_board_size(images: list, exclude: tuple = (), max_images: int = 3) -> tuple | None:
    """Which common board size (inner corners) is in ``images``.

    Tries :data:`COMMON_BOARDS` on a third-size copy of up to ``max_images`` images (the
    detector finds a board either way round), keeps the largest size found (a big board
    also holds smaller ones), then counts the images that show it.

    Parameters
    ----------
    images : list of arrays
        The images (grey or colour).
    exclude : tuple of (cols, rows)
        Sizes not to suggest (the one already tried), either way round.
    max_images : int
        Images searched for a size.

    Returns
    -------
    ((cols, rows), found_in) or None
        The size and the number of ``images`` it was found in; None when no common size is there.
    """
    grays = [_gray(im) for im in images]
    excluded = {tuple(e) for e in exclude} | {tuple(e)[::-1] for e in exclude}
    found = None
    for g in grays[:max_images]:
        small, _ = _shrunk(g, 3) if min(g.shape) >= 360 else (g, None)
        hits = [size for size in COMMON_BOARDS if size not in excluded
                and cv2.findChessboardCorners(small, size, flags=_CLASSIC_FLAGS)[0]]
        if hits:
            found = max(hits, key=lambda sz: sz[0] * sz[1])
            break
    if found is None:
        return None
    count = sum(_find_corners(g, found, 0) is not None for g in grays)
    return found, count


# ----------------------------------------------------------------------------- results
@dataclass(frozen=True, eq=False)
class ViewRecord:
    """One image (or stereo pair) in the report: used or rejected, and why."""

    name: str
    used: bool
    reason: str | None = None
    rms_px: float | None = None
    max_px: float | None = None
    oblique_deg: float | None = None
    edge_width_px: float | None = None

    def to_dict(self) -> dict:
        """The record as JSON-ready values for the calibration report.

        Returns
        -------
        dict
            ``name`` and ``used`` always; ``reason``, ``rms_px``, ``max_px`` (px),
            ``oblique_deg`` (deg) and ``edge_width_px`` (px) when set, floats
            rounded to 5 decimals.
        """
        d = {"name": self.name, "used": self.used}
        for k in ("reason", "rms_px", "max_px", "oblique_deg", "edge_width_px"):
            v = getattr(self, k)
            if v is not None:
                d[k] = round(v, 5) if isinstance(v, float) else v
        return d


@dataclass(frozen=True, eq=False)
class CameraCalibration:
    """One camera's intrinsics with the views behind them.

    Attributes
    ----------
    name : str
    image_size : (width, height)
    K : (3, 3) array
    dist : (5,) array
        ``k1 k2 p1 p2 k3``.
    rms_px : float
        RMS reprojection error over the used views (px).
    views : list of ViewRecord
        Every view offered, used or rejected (with the reason).
    poses : dict name -> (4, 4) array
        ``T_cam_board`` of each used view.
    std : dict or None
        Standard deviations of fx, fy, cx, cy and the estimated distortion terms.
    model : str
        The estimated distortion terms (the others are held at 0), e.g. ``"k1 k2"``.
    corners : dict name -> (n, 2) array
        Detected corners of every view in which the board was found (used or not).
    """

    name: str
    image_size: tuple
    K: np.ndarray
    dist: np.ndarray
    rms_px: float
    views: list
    poses: dict = field(default_factory=dict)
    std: dict | None = None
    model: str = "k1 k2 p1 p2 k3"
    corners: dict = field(default_factory=dict)

    def camera(self, T_cam_world: np.ndarray | None = None) -> Camera:
        """The :class:`Camera` with these intrinsics at a pose.

        Parameters
        ----------
        T_cam_world : (4, 4) array, optional
            World frame -> camera frame (mm); identity by default.

        Returns
        -------
        Camera
        """
        return Camera(self.name, self.image_size[0], self.image_size[1], self.K, self.dist, np.eye(4) if T_cam_world is None else T_cam_world)

    @property
    def used(self) -> list:
        """The views the intrinsics were fitted to.

        Returns
        -------
        list of ViewRecord
            The records of ``views`` with ``used`` True, in their order.
        """
        return [v for v in self.views if v.used]

    @property
    def rejected(self) -> list:
        """The views left out, each with its ``reason``.

        Returns
        -------
        list of ViewRecord
            The records of ``views`` with ``used`` False, in their order.
        """
        return [v for v in self.views if not v.used]

    def coverage(self, cells: tuple = (8, 6)) -> float:
        """Fraction of the image that used views' corners reach.

        Parameters
        ----------
        cells : (columns, rows)
            The grid the image is cut into.

        Returns
        -------
        float
            Fraction of the grid cells holding at least one used corner (0 to 1).
        """
        hit = np.zeros(cells[::-1], bool)
        w, h = self.image_size
        for v in self.used:
            c = self.corners.get(v.name)
            if c is None:
                continue
            i = np.clip((c[:, 0] + 0.5) * cells[0] / w, 0, cells[0] - 1).astype(int)
            j = np.clip((c[:, 1] + 0.5) * cells[1] / h, 0, cells[1] - 1).astype(int)
            hit[j, i] = True
        return float(hit.mean())


def draw_coverage(cal: CameraCalibration, board: BoardSpec, background: np.ndarray | None = None) -> np.ndarray:
    """An image of where the corners fell.

    Each used view's board outline and corners in its own colour, rejected views in red, over a
    dimmed ``background``, with a one-line summary on top.

    Parameters
    ----------
    cal : CameraCalibration
        The views and their corners (px).
    board : BoardSpec
    background : array, optional
        An image of the camera (grey or colour) to draw over; white when None.

    Returns
    -------
    (h, w, 3) uint8 array
        BGR, the camera's image size.
    """
    w, h = cal.image_size
    if background is None:
        img = np.full((h, w, 3), 255, np.uint8)
    else:
        g = _gray(background)
        img = cv2.cvtColor((128 + g.astype(np.float32) * 0.35).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    used = {v.name for v in cal.used}
    for k, (name, c) in enumerate(sorted(cal.corners.items())):
        ok = name in used
        hue = int(179 * ((k * 0.618) % 1.0))
        col = tuple(int(x) for x in cv2.cvtColor(np.uint8([[[hue, 220, 170]]]), cv2.COLOR_HSV2BGR)[0, 0]) if ok else (0, 0, 230)
        pts = np.round(c * 16).astype(np.int32)
        for p in pts:
            cv2.circle(img, (int(p[0]), int(p[1])), 2 * 16, col, 1, cv2.LINE_AA, shift=4)
        n, cols = len(c), board.cols
        quad = np.array([c[0], c[cols - 1], c[n - 1], c[n - cols]])  # the outer corners, in board order
        cv2.polylines(img, [np.round(quad * 16).astype(np.int32)], True, col, 1 if ok else 2, cv2.LINE_AA, shift=4)
        cv2.circle(img, (int(round(c[0][0])), int(round(c[0][1]))), 5, col, -1, cv2.LINE_AA)  # the first corner
    text = (f"{cal.name}: {len(cal.used)} views used, {len(cal.rejected)} rejected (red); RMS {cal.rms_px:.3f} px; "
            f"corners reach {100 * cal.coverage():.0f} % of the image")
    cv2.rectangle(img, (0, 0), (w - 1, 32), (40, 40, 40), -1)
    cv2.putText(img, text, (10, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1, cv2.LINE_AA)
    return img


@dataclass(frozen=True, eq=False)
class StereoCalibration:
    """``T_side_top`` (top camera frame -> side camera frame, mm) from the pairs.

    ``T_top_board`` holds each used pair's board pose in the top camera (4x4, mm), as the stereo fit found it.
    """

    T_side_top: np.ndarray
    rms_px: float
    pairs: list
    T_top_board: dict = field(default_factory=dict)

    @property
    def used(self) -> list:
        """The stereo pairs ``T_side_top`` was fitted to.

        Returns
        -------
        list of ViewRecord
            The records of ``pairs`` with ``used`` True, in their order.
        """
        return [v for v in self.pairs if v.used]


@dataclass(frozen=True, eq=False)
class WorldFrame:
    """``T_top_world`` from the world-frame image, and the check through the side camera."""

    T_top_world: np.ndarray
    T_top_board: np.ndarray
    world_origin_mm: np.ndarray
    rms_px: float
    view: ViewRecord
    side_check: ViewRecord | None = None


def _coefficients_text(dist) -> str:
    """``k1 +0.0123 k2 ... k3 ...`` and, for the longer models, their further coefficients."""
    return " ".join(f"{n} {v:+.5f}" if n[0] == "p" else f"{n} {v:+.4f}" for n, v in zip(COEFFICIENT_NAMES, np.ravel(dist)))


def _frobenius_rotation_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))))


def pose_difference(T_a: np.ndarray, T_b: np.ndarray) -> tuple:
    """How far apart two ``T_cam_world`` poses of one camera are.

    Parameters
    ----------
    T_a, T_b : (4, 4) array
        World frame -> camera frame (mm), e.g. calibrated and true ``T_cam_world``.

    Returns
    -------
    (float, float)
        The camera centres' distance (mm) and the rotation between the poses (deg).
    """
    ca = invert_transform(T_a)[:3, 3]
    cb = invert_transform(T_b)[:3, 3]
    return float(np.linalg.norm(ca - cb)), _frobenius_rotation_deg(T_a[:3, :3] @ T_b[:3, :3].T)


@dataclass(frozen=True, eq=False)
class CalibrationReport:
    """Everything the calibration found, for ``calibration_report.json`` and the printed summary.

    Attributes
    ----------
    board : BoardSpec
    cameras : dict name -> CameraCalibration
        Final intrinsics and per-view errors.
    stereo : StereoCalibration
    world : WorldFrame
    T_side_world : (4, 4) array
        Eq. (1).
    refined : bool
        Whether the joint refinement ran (the figures are then after it).
    stages : dict
        RMS (px) of the OpenCV stages before the joint refinement.
    notes : list of str
        Warnings worth reading (e.g. why the joint refinement was skipped).
    """

    board: BoardSpec
    cameras: dict
    stereo: StereoCalibration
    world: WorldFrame
    T_side_world: np.ndarray
    refined: bool
    stages: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)

    def to_dict(self) -> dict:
        """The report as JSON-ready values (``format`` ``"ctr-bench-calibration-report"``, version 1).

        Returns
        -------
        dict
            The board (``square_mm`` in mm), per camera ``K`` (3x3, px), ``dist``
            (OpenCV order), RMS (px), view counts, coverage and per-view records;
            the stereo ``T_side_top`` and the world ``T_top_world`` and
            ``T_side_world`` (4x4 lists, mm; ``T_<to>_<from>``) with their RMS
            (px); the stage RMS (px) and the notes.
        """
        cams = {}
        for n, c in self.cameras.items():
            cams[n] = {
                "image_size": list(c.image_size),
                "K": c.K.tolist(),
                "dist": c.dist.tolist(),
                "rms_px": round(c.rms_px, 5),
                "distortion_model": c.model,
                "views_used": len(c.used),
                "views_rejected": len(c.rejected),
                "coverage": round(c.coverage(), 3),
                "std": None if c.std is None else {k: float(v) for k, v in c.std.items()},
                "views": [v.to_dict() for v in c.views],
            }
        return {
            "format": "ctr-bench-calibration-report",
            "version": 1,
            "board": {"cols": self.board.cols, "rows": self.board.rows, "square_mm": self.board.square_mm},
            "world_frame": "board frame: origin at the first inner corner, x along cols, y along rows, z = x × y out of the print",
            "world_origin_mm": self.world.world_origin_mm.tolist(),
            "refined_jointly": self.refined,
            "stages_rms_px": {k: round(v, 5) for k, v in self.stages.items()},
            "cameras": cams,
            "stereo": {
                "T_side_top": self.stereo.T_side_top.tolist(),
                "rms_px": round(self.stereo.rms_px, 5),
                "pairs": [v.to_dict() for v in self.stereo.pairs],
            },
            "world": {
                "T_top_world": self.world.T_top_world.tolist(),
                "rms_px": round(self.world.rms_px, 5),
                "view": self.world.view.to_dict(),
                "side_check": None if self.world.side_check is None else self.world.side_check.to_dict(),
            },
            "T_side_world": self.T_side_world.tolist(),
            "notes": list(self.notes),
        }

    def summary(self, truth: RigCalibration | None = None) -> str:
        """A readable multi-line summary.

        Parameters
        ----------
        truth : RigCalibration, optional
            The true rig (the twin): adds the errors against it (K in % and px, poses in mm and deg).

        Returns
        -------
        str
        """
        lines = [f"board {self.board.label} inner corners, {self.board.square_mm:g} mm squares"]
        for n, c in self.cameras.items():
            K = c.K
            lines.append(
                f"{n:>5}: {len(c.used)} views used, {len(c.rejected)} rejected, corners reach {100 * c.coverage():.0f} % of the image; "
                f"RMS {c.rms_px:.3f} px; "
                f"fx {K[0, 0]:.2f} fy {K[1, 1]:.2f} cx {K[0, 2]:.2f} cy {K[1, 2]:.2f}; "
                f"{_coefficients_text(c.dist)} (estimated: {c.model})"
            )
            for v in c.rejected:
                lines.append(f"         rejected {v.name}: {v.reason}")
        s = self.stereo
        lines.append(f"stereo: {len(s.used)} of {len(s.pairs)} pairs used; RMS {s.rms_px:.3f} px")
        for v in s.pairs:
            if not v.used:
                lines.append(f"         rejected {v.name}: {v.reason}")
        w = self.world
        lines.append(f"world: {w.view.name} RMS {w.rms_px:.3f} px, board origin at {np.round(w.world_origin_mm, 3).tolist()} mm in the world")
        if w.side_check is not None:
            sc = w.side_check
            lines.append(f"world check through side: {sc.name} " + (f"RMS {sc.rms_px:.3f} px" if sc.used else f"not checked ({sc.reason})"))
        if self.stages and self.refined:
            lines.append("before joint refinement: " + ", ".join(f"{k} {v:.3f} px" for k, v in self.stages.items()))
        lines += [f"note: {n}" for n in self.notes]
        if truth is not None:
            for n, c in self.cameras.items():
                if n not in truth.cameras:
                    continue
                Kt = truth[n].K
                lines.append(
                    f"vs truth {n}: fx {100 * (c.K[0, 0] / Kt[0, 0] - 1):+.3f} %, fy {100 * (c.K[1, 1] / Kt[1, 1] - 1):+.3f} %, "
                    f"principal point {np.hypot(c.K[0, 2] - Kt[0, 2], c.K[1, 2] - Kt[1, 2]):.2f} px"
                )
            if "side" in truth.cameras:
                d_mm, d_deg = pose_difference(self.T_side_world, truth["side"].T_cam_world)
                lines.append(f"vs truth T_side_world: {d_mm:.3f} mm, {d_deg:.4f} deg")
            if "top" in truth.cameras:
                d_mm, d_deg = pose_difference(self.world.T_top_world, truth["top"].T_cam_world)
                lines.append(f"vs truth T_top_world: {d_mm:.3f} mm, {d_deg:.4f} deg")
        return "\n".join(lines)


# ----------------------------------------------------------------------------- geometry helpers
def _pose(rvec, tvec) -> np.ndarray:
    """``T_a_b`` (4x4, mm) from OpenCV's rotation vector (3,) rad and translation (3,) mm (``cv2.Rodrigues``)."""
    T_a_b = np.eye(4)
    T_a_b[:3, :3] = cv2.Rodrigues(np.asarray(rvec, np.float64).reshape(3, 1))[0]
    T_a_b[:3, 3] = np.asarray(tvec, np.float64).ravel()
    return T_a_b


def _rt(T_a_b: np.ndarray) -> tuple:
    """OpenCV's ``(rvec (3,) rad, tvec (3,) mm)`` of a 4x4 ``T_a_b`` (mm): the inverse of :func:`_pose`."""
    return cv2.Rodrigues(np.ascontiguousarray(T_a_b[:3, :3]))[0].ravel(), T_a_b[:3, 3].copy()


def _reprojection(obj: np.ndarray, img: np.ndarray, K, dist, T_cam_board) -> np.ndarray:
    """Per-corner reprojection error (px)."""
    rvec, tvec = _rt(T_cam_board)
    proj, _ = cv2.projectPoints(obj, rvec, tvec, K, dist)
    return np.linalg.norm(proj.reshape(-1, 2) - img, axis=1)


def _oblique_deg(T_cam_board: np.ndarray) -> float:
    """Angle between the board normal and the optical axis (deg)."""
    return float(np.degrees(np.arccos(np.clip(abs(T_cam_board[2, 2]), 0.0, 1.0))))


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(e)))) if len(e) else float("nan")


def _is_outlier(errors: list, params: CalibrationParams) -> int | None:
    """Index of the worst view if it is a reprojection outlier, else None."""
    rms = np.array([_rms(e) for e in errors])
    limit = max(params.outlier_factor * float(np.median(rms)), params.outlier_floor_px)
    worst = int(np.argmax(rms))
    return worst if rms[worst] > limit else None


def _check_sizes(detections: list, what: str) -> tuple:
    sizes = {}
    for d in detections:
        sizes.setdefault(tuple(d.image_size), []).append(d.name)
    if len(sizes) > 1:
        (main, names), *others = sorted(sizes.items(), key=lambda kv: -len(kv[1]))
        other = others[0]
        raise ValueError(
            f"mixed image sizes in {what}: {main[0]}x{main[1]} ({len(names)} images) and "
            f"{other[0][0]}x{other[0][1]} ({len(other[1])}, e.g. {other[1][0]})"
        )
    return next(iter(sizes))


# ----------------------------------------------------------------------------- stages
def _require_views(k: int, records: dict, name: str, board: BoardSpec, params: CalibrationParams) -> None:
    """Raise ``ValueError`` when ``k`` usable views are fewer than ``params.min_views``, counting the
    rejected views (``records``) by reason."""
    if k >= params.min_views:
        return
    reasons = {}
    for r in records.values():
        key = r.reason.split(":")[0]
        reasons[key] = reasons.get(key, 0) + 1
    detail = ", ".join(f"{v} {k}" for k, v in reasons.items())
    raise ValueError(
        f"{name}: only {k} usable views of the {board.label} board (need at least {params.min_views})"
        + (f"; rejected: {detail}" if detail else "")
    )


def _identifiable_model(terms: tuple, D: np.ndarray, std: dict) -> tuple:
    """The estimated ``terms`` less the groups beyond k1 k2 that the views cannot tell from zero:
    every coefficient of ``D`` (OpenCV order) in the group within 3 standard deviations ``std`` of it."""
    D = np.concatenate([np.ravel(D), np.zeros(14)])
    keep = set(terms)
    for group in _TERM_GROUPS[2:]:
        if group[0] in keep and all(abs(D[COEFFICIENT_NAMES.index(t)]) < 3 * std[t] for t in group):
            keep -= set(group)
    return tuple(t for t in terms if t in keep)


def calibrate_camera(detections: list, board: BoardSpec, name: str, params: CalibrationParams | None = None) -> CameraCalibration:
    """One camera's intrinsics (``cv2.calibrateCamera``, the OpenCV model ``params.distortion_model``) with view rejection.

    Views not found or blurred are rejected up front; then views whose board is too
    oblique, then reprojection outliers one at a time (recalibrating after each).

    Parameters
    ----------
    detections : list of Detection
        The camera's views (corners px, board order), all of one image size.
    board : BoardSpec
    name : str
        The camera's name (``"side"``, ``"top"``), in messages and the result.
    params : CalibrationParams, optional
        Distortion model and terms, view counts and rejection limits.

    Returns
    -------
    CameraCalibration
        K (3, 3) px, distortion coefficients, RMS (px), every view's record and each used view's
        ``T_cam_board`` (4x4, mm).

    Raises
    ------
    ValueError
        No images, mixed image sizes, or fewer than ``params.min_views`` usable views (counted by reason).
    """
    params = params or CalibrationParams()
    if not detections:
        raise ValueError(f"{name}: no images")
    size = _check_sizes(detections, f"the {name} camera's images")
    records = {d.name: ViewRecord(d.name, False, d.reason or "not found", edge_width_px=d.edge_width_px) for d in detections if not d.usable}
    views = [d for d in detections if d.usable]
    obj = board.object_points().astype(np.float32)

    _require_views(len(views), records, name, board, params)
    n_model = params.distortion_model
    terms = MODEL_TERMS[n_model] if params.distortion == "auto" else parse_terms(params.distortion, n_model)
    n_dist = max(5, n_model)
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    std = {}

    def run(vs):
        out = cv2.calibrateCameraExtended(
            [obj] * len(vs), [v.corners.astype(np.float32) for v in vs], size, None, None,
            flags=calibration_flags(terms, n_model), criteria=crit,
        )
        K, D, rvecs, tvecs, sd = out[1], out[2].ravel()[:n_dist], out[3], out[4], out[5].ravel()
        std.clear()
        std.update({k: float(x) for k, x in zip(_INTR, sd) if k[0] in "fc" or k in terms})
        poses = [_pose(r, t) for r, t in zip(rvecs, tvecs)]
        errs = [_reprojection(obj, v.corners, K, D, T_cam_board) for v, T_cam_board in zip(vs, poses)]
        return K, D, poses, errs

    K, D, poses, errs = run(views)
    oblique = [_oblique_deg(T_cam_board) for T_cam_board in poses]
    keep = [a <= params.max_oblique_deg for a in oblique]
    if not all(keep):
        for v, a, k in zip(views, oblique, keep):
            if not k:
                records[v.name] = ViewRecord(v.name, False, f"too oblique: board normal {a:.0f} deg from the optical axis (limit {params.max_oblique_deg:g})",
                                             oblique_deg=a, edge_width_px=v.edge_width_px)
        views = [v for v, k in zip(views, keep) if k]
        _require_views(len(views), records, name, board, params)
        K, D, poses, errs = run(views)
    while True:
        worst = _is_outlier(errs, params)
        if worst is None or len(views) <= params.min_views:
            break
        v = views[worst]
        records[v.name] = ViewRecord(v.name, False, f"reprojection outlier: RMS {_rms(errs[worst]):.3f} px "
                                     f"(median {np.median([_rms(e) for e in errs]):.3f} px)",
                                     rms_px=_rms(errs[worst]), edge_width_px=v.edge_width_px)
        views = views[:worst] + views[worst + 1 :]
        K, D, poses, errs = run(views)
    if params.distortion == "auto" and _identifiable_model(terms, D, std) != terms:
        terms = _identifiable_model(terms, D, std)
        K, D, poses, errs = run(views)
    for v, T_cam_board, e in zip(views, poses, errs):
        records[v.name] = ViewRecord(v.name, True, None, _rms(e), float(e.max()), _oblique_deg(T_cam_board), v.edge_width_px)
    order = [d.name for d in detections]
    return CameraCalibration(
        name=name, image_size=size, K=K, dist=np.asarray(D, np.float64), rms_px=_rms(np.concatenate(errs)),
        views=[records[n] for n in order], poses={v.name: T_cam_board for v, T_cam_board in zip(views, poses)}, std=dict(std),
        model=" ".join(terms) or "none",
        corners={d.name: d.corners for d in detections if d.found},
    )


def calibrate_stereo(side: CameraCalibration, top: CameraCalibration, pairs: list, board: BoardSpec,
                     params: CalibrationParams | None = None) -> StereoCalibration:
    """``T_side_top`` from pairs seen by both cameras, intrinsics fixed (``cv2.stereoCalibrate``).

    Pairs with a view not found, blurred or rejected by its camera's calibration are rejected up
    front, then reprojection outliers one at a time.

    Parameters
    ----------
    side, top : CameraCalibration
        Each camera's intrinsics (K px, distortion) and rejected views.
    pairs : list of (name, Detection side, Detection top)
        Corners (px) of the same board pose in both cameras.
    board : BoardSpec
        Must be asymmetric (``cols + rows`` odd).
    params : CalibrationParams, optional
        ``min_stereo_pairs`` and the outlier limits.

    Returns
    -------
    StereoCalibration
        ``T_side_top`` (4x4, top camera frame -> side camera frame, mm), RMS (px), every pair's record
        and each used pair's ``T_top_board`` (4x4, mm).

    Raises
    ------
    ValueError
        A symmetric board, or fewer than ``params.min_stereo_pairs`` usable pairs.
    """
    params = params or CalibrationParams()
    if not board.asymmetric:
        raise ValueError(
            f"the {board.label} board looks the same turned by 180 degrees (cols + rows even), so the stereo pairs "
            "cannot be matched corner for corner between the cameras: use a board with cols + rows odd, e.g. 9x6"
        )
    rejected_in = {}
    for cam in (side, top):
        for v in cam.rejected:
            rejected_in[v.name] = f"{cam.name}: {v.reason}"
    records = {}
    usable = []
    for name, ds, dt in pairs:
        why = None
        for d in (ds, dt):
            if why is None and not d.usable:
                why = f"{d.name}: {d.reason}"
            elif why is None and d.name in rejected_in:
                why = f"{d.name} rejected in {rejected_in[d.name]}"
        if why is None and (ds.image_size != side.image_size or dt.image_size != top.image_size):
            why = "image size differs from the camera's calibration images"
        if why:
            records[name] = ViewRecord(name, False, why)
        else:
            usable.append((name, ds, dt))
    if len(usable) < params.min_stereo_pairs:
        raise ValueError(
            f"stereo: only {len(usable)} usable pairs with the whole {board.label} board in both images "
            f"(need at least {params.min_stereo_pairs})"
        )
    obj = board.object_points().astype(np.float32)
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)

    def run(ps):
        out = cv2.stereoCalibrateExtended(
            [obj] * len(ps), [p[2].corners.astype(np.float32) for p in ps], [p[1].corners.astype(np.float32) for p in ps],
            top.K, top.dist, side.K, side.dist, top.image_size, np.eye(3), np.zeros(3),
            flags=cv2.CALIB_FIX_INTRINSIC, criteria=crit,
        )
        R_side_top, t_side_top_mm, rvecs, tvecs = out[5], out[6], out[9], out[10]
        T_side_top = np.eye(4)
        T_side_top[:3, :3] = R_side_top
        T_side_top[:3, 3] = t_side_top_mm.ravel()
        errs = []
        poses.clear()
        for (name, ds, dt), r, t in zip(ps, rvecs, tvecs):
            T_top_board = poses[name] = _pose(r, t)
            e_top = _reprojection(obj, dt.corners, top.K, top.dist, T_top_board)
            e_side = _reprojection(obj, ds.corners, side.K, side.dist, T_side_top @ T_top_board)
            errs.append(np.concatenate([e_side, e_top]))
        return T_side_top, errs

    poses = {}
    T_side_top, errs = run(usable)
    while True:
        worst = _is_outlier(errs, params)
        if worst is None or len(usable) <= params.min_stereo_pairs:
            break
        name = usable[worst][0]
        records[name] = ViewRecord(name, False, f"reprojection outlier: RMS {_rms(errs[worst]):.3f} px", rms_px=_rms(errs[worst]))
        usable = usable[:worst] + usable[worst + 1 :]
        T_side_top, errs = run(usable)
    for (name, _, _), e in zip(usable, errs):
        records[name] = ViewRecord(name, True, None, _rms(e), float(e.max()))
    return StereoCalibration(T_side_top=T_side_top, rms_px=_rms(np.concatenate(errs)), pairs=[records[p[0]] for p in pairs],
                             T_top_board=dict(poses))


def _T_board_world(world_origin_mm) -> np.ndarray:
    """``T_board_world`` (4x4, mm): world points into the world board's frame (axes shared, origin offset).

    ``world_origin_mm`` (3,) is the board's first inner corner in the world frame (mm).
    """
    T_board_world = np.eye(4)
    T_board_world[:3, 3] = -np.asarray(world_origin_mm, np.float64).reshape(3)
    return T_board_world


def world_frame(top: CameraCalibration, detections, board: BoardSpec, world_origin_mm=(0.0, 0.0, 0.0)) -> WorldFrame:
    """``T_top_world`` from the top camera's image(s) of the board in the world-frame pose (``cv2.solvePnP``).

    Several exposures of the board lying still (``world/top.png``, ``world/top_2.png``, ...)
    are solved together, which averages the sensor noise down. The world frame is the
    board frame moved by ``world_origin_mm`` (its axes are the world axes).

    Parameters
    ----------
    top : CameraCalibration
        The top camera's intrinsics (K px, distortion) and image size.
    detections : Detection or list of Detection
        The world board's corners (px) in each exposure.
    board : BoardSpec
        Must be asymmetric (``cols + rows`` odd).
    world_origin_mm : (3,)
        World position (mm) of the world board's first inner corner.

    Returns
    -------
    WorldFrame
        ``T_top_world`` and ``T_top_board`` (4x4, mm), the RMS error (px) and the view's record.

    Raises
    ------
    ValueError
        No image, a symmetric board, or an image naming itself: board not found, not oriented, wrong size.
    """
    dets = [detections] if isinstance(detections, Detection) else list(detections)
    if not dets:
        raise ValueError("no world-frame image from the top camera")
    if not board.asymmetric:
        raise ValueError(
            f"the {board.label} board looks the same turned by 180 degrees (cols + rows even), so it cannot fix the world "
            "frame: use a board with cols + rows odd, e.g. 9x6"
        )
    for d in dets:
        if not d.found:
            raise ValueError(f"{d.name}: {d.reason} — the world-frame image must show the whole board")
        if not d.oriented:
            raise ValueError(f"{d.name}: cannot tell the board's first corner (square colours unclear)")
        if d.image_size != top.image_size:
            raise ValueError(f"{d.name}: image is {d.image_size[0]}x{d.image_size[1]} but the top camera's are "
                             f"{top.image_size[0]}x{top.image_size[1]}")
    obj1 = board.object_points()
    obj = np.concatenate([obj1] * len(dets))
    img = np.concatenate([d.corners for d in dets])
    K, D = np.array(top.K), np.array(top.dist)
    ok, rvec, tvec = cv2.solvePnP(obj1, dets[0].corners, K, D, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise ValueError(f"{dets[0].name}: cannot find the board's pose")
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, K, D, rvec, tvec)
    T_top_board = _pose(rvec, tvec)
    e = _reprojection(obj, img, K, D, T_top_board)
    origin = np.asarray(world_origin_mm, np.float64).reshape(3)
    name = dets[0].name if len(dets) == 1 else f"{dets[0].name} (+{len(dets) - 1} more exposures)"
    view = ViewRecord(name, True, None, _rms(e), float(e.max()), _oblique_deg(T_top_board), dets[0].edge_width_px)
    return WorldFrame(T_top_world=T_top_board @ _T_board_world(origin), T_top_board=T_top_board, world_origin_mm=origin,
                      rms_px=_rms(e), view=view)


def compose_side_world(T_side_top: np.ndarray, T_top_world: np.ndarray) -> np.ndarray:
    """Eq. (1) of the paper: ``T_side_world = T_side_top @ T_top_world``.

    Parameters
    ----------
    T_side_top : (4, 4) array
        Top camera frame -> side camera frame (mm).
    T_top_world : (4, 4) array
        World frame -> top camera frame (mm).

    Returns
    -------
    (4, 4) array
        ``T_side_world``: world frame -> side camera frame (mm).
    """
    return np.asarray(T_side_top, np.float64) @ np.asarray(T_top_world, np.float64)


def _side_check(side_detection: Detection | None, side_camera: Camera, board: BoardSpec, world_origin_mm) -> ViewRecord | None:
    """Reproject the world board into the side camera (when the side camera saw it)."""
    if side_detection is None:
        return None
    if side_detection.image_size != side_camera.image_size:
        return ViewRecord(side_detection.name, False, "image size differs from the side camera's")
    if not side_detection.found or not side_detection.oriented:
        return ViewRecord(side_detection.name, False, side_detection.reason or "board orientation unclear")
    pts = board.object_points() + np.asarray(world_origin_mm, float)
    uv, _ = side_camera.project(pts)
    e = np.linalg.norm(uv - side_detection.corners, axis=1)
    return ViewRecord(side_detection.name, True, None, _rms(e), float(e.max()))


# ----------------------------------------------------------------------------- joint refinement
_INTR = ("fx", "fy", "cx", "cy") + COEFFICIENT_NAMES
_NI = len(_INTR)  # parameters per camera in the joint problem


@dataclass(frozen=True, eq=False)
class _JointProblem:
    """:func:`refine_jointly`'s parameter vector and observed corners, flattened for vectorised residuals.

    Attributes
    ----------
    x0 : (42 + 6 F,) array
        Starting parameters ``[side intrinsics 18][top intrinsics 18][T_side_top 6][board poses 6 F]``: intrinsics
        are fx fy cx cy (px) then OpenCV's 14 distortion coefficients; a transform is a rotation vector (rad)
        then a translation (mm).
    free : (42 + 6 F,) bool array
        The parameters adjusted (distortion terms outside a camera's model stay at their start).
    frames : list of str
        The F placements, in the order of their poses (``T_ref_board``) in ``x0``.
    fidx, cidx : (m,) int arrays
        Placement and camera (0 side, 1 top) of each observed corner.
    via : (m,) bool array
        Whether the corner is seen through ``T_side_top`` (side camera, pose in the top camera's frame).
    uv : (m, 2) array
        Observed corners (px).
    P : (m, 3) array
        The same corners in the board frame (mm).
    """

    x0: np.ndarray
    free: np.ndarray
    frames: list
    fidx: np.ndarray
    cidx: np.ndarray
    via: np.ndarray
    uv: np.ndarray
    P: np.ndarray

    def residual(self, xf: np.ndarray) -> np.ndarray:
        """Reprojection residuals (2 m,) px, every corner's u then every corner's v, at the free parameters ``xf``."""
        x = self.x0.copy()
        x[self.free] = xf
        intr = x[: 2 * _NI].reshape(2, _NI)
        R_side_top = Rotation.from_rotvec(x[2 * _NI : 2 * _NI + 3]).as_matrix()
        t_side_top_mm = x[2 * _NI + 3 : 2 * _NI + 6]
        poses = x[2 * _NI + 6 :].reshape(len(self.frames), 6)
        R_ref_board = Rotation.from_rotvec(poses[:, :3]).as_matrix()  # one batched call for every placement
        X = np.einsum("nij,nj->ni", R_ref_board[self.fidx], self.P) + poses[self.fidx, 3:]  # board -> the pose's camera (mm)
        Xs = X @ R_side_top.T + t_side_top_mm  # top camera -> side camera (mm)
        X = np.where(self.via[:, None], Xs, X)
        x, y = X[:, 0] / X[:, 2], X[:, 1] / X[:, 2]
        u, v = np.empty_like(x), np.empty_like(y)
        for ci, p in enumerate(intr):  # each corner through its own camera's intrinsics and distortion
            sel = self.cidx == ci
            xd, yd = distort_xy(x[sel], y[sel], p[4:], tilt_matrix.__wrapped__(p[16], p[17])[0])
            u[sel], v[sel] = p[0] * xd + p[2], p[1] * yd + p[3]
        return np.concatenate([u - self.uv[:, 0], v - self.uv[:, 1]])


def _joint_problem(cams: dict, observations: list, T_side_top: np.ndarray, board: BoardSpec,
                   models: dict | None) -> _JointProblem:
    """Lay out :func:`refine_jointly`'s parameters (start, which are free) and its observed corners.

    Parameters
    ----------
    cams, observations, T_side_top, board, models
        As :func:`refine_jointly`'s: K (px), 4x4 ``T_side_top`` and ``T_ref_board`` (mm), corners (px).

    Raises ``ValueError`` when a placement seen by the side camera through ``T_side_top`` is posed in the side camera.
    """
    names = list(CAMERAS)
    obj = board.object_points()
    n = len(obj)
    # parameter layout: [side intr 18][top intr 18][T_side_top 6][frame poses 6F]
    x0 = []
    for nm in names:
        K, D = cams[nm]
        x0 += [K[0, 0], K[1, 1], K[0, 2], K[1, 2], *padded(D)]
    r, t = _rt(T_side_top)
    x0 += [*r, *t]
    for o in observations:
        r, t = _rt(o["T_ref_board"])
        x0 += [*r, *t]
    x0 = np.asarray(x0, float)
    free = np.ones(len(x0), bool)
    for i, nm in enumerate(names):
        terms = (models or {}).get(nm, "k1 k2 p1 p2 k3").split()
        for j, term in enumerate(_INTR[4:]):
            free[_NI * i + 4 + j] = term in terms
    # observation index arrays
    fidx, cidx, via, uv = [], [], [], []
    for fi, o in enumerate(observations):
        for cam, corners in o["views"]:
            ci = names.index(cam)
            fidx.append(np.full(n, fi))
            cidx.append(np.full(n, ci))
            via.append(np.full(n, cam != o["ref"]))
            uv.append(np.asarray(corners, float))
    fidx = np.concatenate(fidx)
    cidx = np.concatenate(cidx)
    via = np.concatenate(via)
    uv = np.concatenate(uv)
    P = np.tile(obj, (len(uv) // n, 1))
    if np.any(via & (cidx != 0)):
        raise ValueError("joint refinement: a placement seen by both cameras must have its pose in the top camera")
    return _JointProblem(x0=x0, free=free, frames=[o["frame"] for o in observations], fidx=fidx, cidx=cidx, via=via, uv=uv, P=P)


def _joint_jacobian(pb: _JointProblem):
    """``jac(xf, f0)``: the sparse (2 m, free parameters) Jacobian of ``pb.residual`` (px per parameter unit)
    at ``xf``, by forward differences from the residuals ``f0`` there.

    Each corner depends on its camera's intrinsics, one placement's pose, and ``T_side_top`` when seen
    through it, so the k-th parameter of every pose is perturbed at once (6 evaluations for all poses),
    plus one evaluation per free intrinsic and ``T_side_top`` parameter.
    """
    residual, free, F = pb.residual, pb.free, len(pb.frames)
    m = len(pb.uv)
    nf = int(free.sum())
    full_to_free = -np.ones(len(pb.x0), int)
    full_to_free[free] = np.arange(nf)
    both = lambda rows: np.concatenate([rows, rows + m])  # noqa: E731
    frame_rows = [both(np.flatnonzero(pb.fidx == f)) for f in range(F)]
    single_rows = {}
    n_fixed = 2 * _NI + 6  # the cameras' intrinsics and T_side_top, before the poses
    for j in range(n_fixed):
        if free[j]:
            single_rows[j] = both(np.flatnonzero(pb.cidx == j // _NI)) if j < 2 * _NI else both(np.flatnonzero(pb.via))

    def jac(xf, f0):
        ri, ci, vals = [], [], []
        for j, rows in single_rows.items():
            k = full_to_free[j]
            h = 1e-6 * max(1.0, abs(xf[k]))
            x1 = xf.copy()
            x1[k] += h
            ri.append(rows)
            ci.append(np.full(len(rows), k))
            vals.append((residual(x1)[rows] - f0[rows]) / h)
        for q in range(6):
            cols = full_to_free[n_fixed + 6 * np.arange(F) + q]
            h = 1e-7 * np.maximum(1.0, np.abs(xf[cols]))
            x1 = xf.copy()
            x1[cols] += h
            d = residual(x1) - f0
            for f in range(F):
                rows = frame_rows[f]
                ri.append(rows)
                ci.append(np.full(len(rows), cols[f]))
                vals.append(d[rows] / h[f])
        return coo_matrix((np.concatenate(vals), (np.concatenate(ri), np.concatenate(ci))), shape=(2 * m, nf)).tocsr()

    return jac


def _levenberg_marquardt(residual, jac, xf: np.ndarray) -> tuple:
    """Minimise ``|residual(x)|²`` from ``xf``: at most 100 Levenberg-Marquardt steps, damped by diag(JᵀJ).

    J stays sparse; the normal equations are small and solved densely.

    Kept instead of ``scipy.optimize.least_squares`` because it measured better (issue 16). The 14-term tilted
    model leaves a long, nearly flat valley (the tilt and the rational terms against the principal point;
    cond(J) ~ 1e9). Here every step that lowers the cost is taken and the damping cut tenfold, but never
    below 1e-12 diag(JᵀJ), which keeps the steps out of the near-null direction. ``least_squares`` shrinks
    its trust region whenever the actual/predicted reduction ratio is under 0.25, and so crawls along the
    valley. On tests/test_calibration_models.py's tilted-model rig:

    * this solver: 1.2 s, 1.6e-12 px², distortion off the truth by 0.012 / 0.011 px (top / side),
      held-out error 8.7e-6 / 2.1e-5 px;
    * 'trf' with ``jac_sparsity``: 4.0 s, 2.4e-7 px², 0.55 / 0.18 px, 2.4e-4 / 7.7e-4 px. Tighter
      tolerances, lsmr's ``damp``, fixed or Jacobian ``x_scale``, 3-point or exact Jacobians and
      restarts all stop at the same place ('exact' cannot take ``jac_sparsity``);
    * 'lm': 3.4 s, 1.4e-8 px², 1.04 / 0.004 px (over the test's 0.05 px limit).

    On the rendered capture of tests/test_calibration.py all three reach the same solution (to 4 digits)
    in 0.09 s (this solver), 0.2 s ('trf') and 0.7 s ('lm').

    Parameters
    ----------
    residual : callable
        ``residual(x)`` -> (k,) residuals (px) at the free parameters ``x``.
    jac : callable
        ``jac(x, residual(x))`` -> sparse (k, len(x)) Jacobian (px per parameter unit).
    xf : (len(x),) array
        Starting free parameters (px, rad, mm as laid out by :class:`_JointProblem`).

    Returns
    -------
    (x, residuals (px), cost = |residuals|² (px²), JᵀJ of the last linearisation or None)
    """
    res = residual(xf)
    cost = float(res @ res)
    lam = 1e-4
    A = None
    for _ in range(100):
        J = jac(xf, res)
        A = (J.T @ J).toarray()
        g = J.T @ res
        d = np.maximum(np.diag(A), 1e-12)
        improved = False
        while lam < 1e12:
            try:
                step = np.linalg.solve(A + lam * np.diag(d), -g)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            r1 = residual(xf + step)
            c1 = float(r1 @ r1)
            if np.isfinite(c1) and c1 < cost:
                improved = True
                small = cost - c1 < 1e-12 * cost or np.all(np.abs(step) < 1e-12 * np.maximum(1.0, np.abs(xf)))
                xf, res, cost = xf + step, r1, c1
                lam = max(lam * 0.1, 1e-12)
                break
            lam *= 10
        if not improved or small:
            break
    return xf, res, cost, A


def _joint_std(pb: _JointProblem, A: np.ndarray | None, cost: float, n_res: int) -> np.ndarray:
    """Standard deviation of every parameter of ``pb.x0`` (its units: px, rad, mm) from ``inv(JᵀJ)`` times the
    residual variance (``cost`` px² over the degrees of freedom); NaN for the fixed ones, or all when JᵀJ is singular."""
    nf = int(pb.free.sum())
    dof = max(n_res - nf, 1)
    sigma2 = cost / dof
    std_full = np.full(len(pb.x0), np.nan)
    if A is not None:
        try:
            std_full[pb.free] = np.sqrt(np.clip(np.diag(np.linalg.inv(A)) * sigma2, 0, None))
        except np.linalg.LinAlgError:
            pass
    return std_full


def _joint_solution(pb: _JointProblem, observations: list, xf: np.ndarray, res: np.ndarray, cost: float,
                    std_full: np.ndarray, n: int, sizes: dict) -> dict:
    """:func:`refine_jointly`'s result from the solved free parameters ``xf``, the residuals ``res`` (px), their
    ``cost`` (px²) and ``std_full`` (:func:`_joint_std`); ``n`` corners per view; ``sizes``: each camera's
    distortion coefficient count (as it came in).

    K (px), ``T_side_top`` and the poses ``T_ref_board`` as 4x4 (mm); per-corner errors (px) split per view.
    """
    names = list(CAMERAS)
    free = pb.free
    x = pb.x0.copy()
    x[free] = xf
    out_cams, std = {}, {}
    at = 2 * _NI  # T_side_top, then the poses
    for i, nm in enumerate(names):
        p = x[_NI * i : _NI * i + _NI]
        K = np.array([[p[0], 0.0, p[2]], [0.0, p[1], p[3]], [0.0, 0.0, 1.0]])
        out_cams[nm] = (K, p[4 : 4 + sizes[nm]].copy())
        std[nm] = {k: float(v) for k, v, f in zip(_INTR, std_full[_NI * i : _NI * i + _NI], free[_NI * i : _NI * i + _NI]) if f}
    T_side_top = _pose(x[at : at + 3], x[at + 3 : at + 6])
    poses = {f: _pose(x[at + 6 + 6 * i : at + 9 + 6 * i], x[at + 9 + 6 * i : at + 12 + 6 * i]) for i, f in enumerate(pb.frames)}
    m = len(pb.uv)
    err = np.hypot(res[:m], res[m:])
    errors = {}
    start = 0
    for o in observations:
        errors[o["frame"]] = []
        for _ in o["views"]:
            errors[o["frame"]].append(err[start : start + n])
            start += n
    return {"cams": out_cams, "std": std, "T_side_top": T_side_top, "poses": poses, "errors": errors, "cost": 0.5 * cost,
            "std_T_side_top": std_full[at : at + 6].copy()}


def _check_joint_inputs(cams: dict, observations: list, T_side_top, board: BoardSpec, models: dict | None) -> None:
    """Raise a one-line ``ValueError`` naming the bad input of :func:`refine_jointly`."""
    for nm in CAMERAS:
        if nm not in cams:
            raise ValueError(f"refine_jointly: cams has no {nm!r} camera (has {', '.join(map(str, cams)) or 'none'})")
        if np.shape(cams[nm][0]) != (3, 3):
            raise ValueError(f"refine_jointly: cams[{nm!r}] K must be 3x3, got shape {np.shape(cams[nm][0])}")
        terms = (models or {}).get(nm, "").split()
        bad = [t for t in terms if t not in COEFFICIENT_NAMES]
        if bad:
            raise ValueError(f"refine_jointly: models[{nm!r}]: unknown distortion terms {' '.join(bad)}")
    if np.shape(T_side_top) != (4, 4):
        raise ValueError(f"refine_jointly: T_side_top must be 4x4, got shape {np.shape(T_side_top)}")
    if not observations:
        raise ValueError("refine_jointly: no observations")
    for o in observations:
        if o["ref"] not in CAMERAS or np.shape(o["T_ref_board"]) != (4, 4):
            raise ValueError(f"refine_jointly: observation {o['frame']!r}: ref must be side or top and T_ref_board 4x4")
        for cam, corners in o["views"]:
            if cam not in CAMERAS or np.shape(corners) != (board.n_corners, 2):
                raise ValueError(f"refine_jointly: observation {o['frame']!r}: a view must be (side or top, "
                                 f"({board.n_corners}, 2) corners px), got ({cam!r}, shape {np.shape(corners)})")


def refine_jointly(cams: dict, observations: list, T_side_top: np.ndarray, board: BoardSpec, models: dict | None = None) -> dict:
    """One least-squares adjustment of both cameras' intrinsics, every board pose and ``T_side_top``.

    The solver is the Levenberg-Marquardt of :func:`_levenberg_marquardt` on the vectorised residuals of
    :class:`_JointProblem` (through :mod:`recon.distortion`), with a sparse forward-difference Jacobian.
    ``scipy.optimize.least_squares`` ('trf' with ``jac_sparsity``, and 'lm') was measured and stopped
    far short on the tilted model (issue 16; the figures are in :func:`_levenberg_marquardt`).

    Parameters
    ----------
    cams : dict name -> (K, dist)
        Starting intrinsics of ``"side"`` and ``"top"``: K (3, 3) px, dist OpenCV coefficients
        (5, 8, 12 or 14).
    observations : list of dict
        Each board placement: ``{"frame": str, "ref": camera the pose is in, "T_ref_board": 4x4 (mm),
        "views": [(camera, corners (n, 2) px, board order), ...]}``. A placement may be seen several
        times (exposures of a board that did not move). A placement seen by both cameras has its
        pose in the top camera and is seen by the side camera through ``T_side_top``.
    T_side_top : (4, 4) array
        Starting top camera frame -> side camera frame (mm).
    board : BoardSpec
        The board (its inner corners in the board frame, mm).
    models : dict name -> str, optional
        Each camera's estimated distortion terms (e.g. ``"k1 k2 p1 p2 k3"``, :data:`MODEL_TERMS`);
        the others stay at their starting value. Default: ``k1 k2 p1 p2 k3``.

    Returns
    -------
    dict
        ``cams``: name -> (K (3, 3) px, dist as long as it came in, at least 5); ``std``: name -> {fx fy
        cx cy (px) and each estimated term: standard deviation}, from inv(JᵀJ) at the solution times the
        residual variance; ``T_side_top``: (4, 4) mm; ``std_T_side_top``: (6,) rotation vector (rad)
        then translation (mm); ``poses``: frame -> ``T_ref_board`` (4, 4) mm; ``errors``: frame ->
        list of per-corner errors (n,) px, one per view; ``cost``: half the sum of squared residuals (px²).

    Raises
    ------
    ValueError
        One line naming the input that is missing or of the wrong shape.
    """
    _check_joint_inputs(cams, observations, T_side_top, board, models)
    pb = _joint_problem(cams, observations, T_side_top, board, models)
    xf, res, cost, A = _levenberg_marquardt(pb.residual, _joint_jacobian(pb), pb.x0[pb.free].copy())
    sizes = {nm: max(5, np.asarray(cams[nm][1]).size) for nm in CAMERAS}
    return _joint_solution(pb, observations, xf, res, cost, _joint_std(pb, A, cost, len(res)), board.n_corners, sizes)


# ----------------------------------------------------------------------------- inputs
@dataclass(frozen=True, eq=False)
class CalibrationImages:
    """The images of one calibration, by role.

    Attributes
    ----------
    views : dict camera -> list of (name, image)
        Each camera's own views (intrinsics), ``"side"`` and ``"top"``.
    stereo : list of (name, {camera: image})
        Pairs taken by both cameras at once (the board in the same pose).
    world : dict camera -> list of (name, image)
        The world-frame image(s): ``"top"`` (required; several exposures of the board lying
        still are averaged); ``"side"`` optional, for the check.
    source : str
        Where they came from (for messages).
    """

    views: dict
    stereo: list
    world: dict
    source: str = "<images>"


def _image_files(folder: Path) -> list:
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)


def _read(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"{path}: cannot read the image")
    return img


def load_calibration_folder(path, extrinsics_only: bool = False) -> CalibrationImages:
    """Read a calibration folder (layout in docs/calibration.md)::

        side/*.png              the side camera's views (intrinsics)
        top/*.png               the top camera's views
        stereo/side/*.png       pairs, matched by file name
        stereo/top/*.png
        world/top.png           the board in the world-frame pose, top camera
        world/top_*.png         optional: more exposures of it (the board not moved)
        world/side.png          optional: the same pose through the side camera (check)

    Parameters
    ----------
    path : str or Path
        The folder.
    extrinsics_only : bool
        Only ``world/`` is required (and ``stereo/`` is read if there), for cameras whose
        intrinsics come from elsewhere.

    Returns
    -------
    CalibrationImages
        The images by role, named by their paths in the folder.

    Raises
    ------
    ValueError
        Naming the folder or file when something is missing or unreadable.
    """
    root = Path(path)
    if not root.is_dir():
        raise ValueError(f"{root}: no such calibration folder")
    exts = " ".join(IMAGE_SUFFIXES)
    views = {}
    for cam in CAMERAS:
        files = _image_files(root / cam)
        if not files and not extrinsics_only:
            raise ValueError(f"{root / cam}: no images ({exts}) — see docs/calibration.md for the folder layout")
        views[cam] = [(f"{cam}/{f.name}", _read(f)) for f in files]
    s_files = {cam: {f.stem: f for f in _image_files(root / "stereo" / cam)} for cam in CAMERAS}
    if not s_files["side"] and not s_files["top"] and not extrinsics_only:
        raise ValueError(f"{root / 'stereo'}: no image pairs (stereo/side/*.png with stereo/top/*.png of the same names)")
    lonely = sorted(set(s_files["side"]) ^ set(s_files["top"]))
    if lonely:
        which = "side" if lonely[0] in s_files["side"] else "top"
        other = "top" if which == "side" else "side"
        raise ValueError(f"{s_files[which][lonely[0]]}: no partner in {root / 'stereo' / other} (pairs are matched by file name)")
    stereo = [(s_files["side"][stem].name, {cam: _read(s_files[cam][stem]) for cam in CAMERAS}) for stem in sorted(s_files["side"])]
    world = {}
    for cam in CAMERAS:
        files = [f for f in _image_files(root / "world") if f.stem == cam or f.stem.startswith(cam + "_")]
        if files:
            world[cam] = [(f"world/{f.name}", _read(f)) for f in files]
    if "top" not in world:
        raise ValueError(f"{root / 'world'}: no top.png (the top camera's image of the board in the world-frame pose)")
    return CalibrationImages(views=views, stereo=stereo, world=world, source=str(root))


def read_image(path) -> np.ndarray:
    """An image file as an array.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    array
        As ``cv2.imread(..., IMREAD_UNCHANGED)`` reads it (BGR order for colour).

    Raises
    ------
    ValueError
        Naming the file when it cannot be read.
    """
    return _read(Path(path))


# ----------------------------------------------------------------------------- the whole rig
def _no_board_error(board: BoardSpec, cam: str, items: list, params: CalibrationParams) -> ValueError:
    msg = f"no {board.label} board found in any of {len(items)} images of {cam}/ — is --board right?"
    if params.suggest_sizes:
        hit = suggest_board_size([im for _, im in items], exclude=(board.size,))
        if hit is not None:
            (c, r), k = hit
            msg += f" a {c}x{r} board was found in {k} of them"
        else:
            msg += " no common board size was found either"
    return ValueError(msg)


def _pair_of(view_name: str) -> str:
    """The stereo pair's name of a stereo view (``stereo/side/003.png`` -> ``003.png``)."""
    return view_name.split("/", 2)[2]


def _require_rig_images(images: CalibrationImages) -> None:
    """Raise ``ValueError`` naming ``images.source`` when a role :func:`calibrate_rig` needs has no images."""
    for cam in CAMERAS:
        if not images.views.get(cam):
            raise ValueError(f"{images.source}: no images of the {cam} camera")
    if "top" not in images.world:
        raise ValueError(f"{images.source}: no world-frame image from the top camera")
    if not images.stereo:
        raise ValueError(f"{images.source}: no stereo pairs")


def _detect_rig(images: CalibrationImages, board: BoardSpec, params: CalibrationParams, progress=None) -> dict:
    """The board in every image of ``images``: image name (``side/...``, ``stereo/top/...``, ``world/...``) -> :class:`Detection`.

    Each camera's own views go first, with the fast detectors, so that a wrong ``--board`` shows at once
    (``ValueError``, with the size found instead); then the stereo and world images; then the slower
    detectors where the fast ones missed a view.
    """
    rest = [(f"stereo/{cam}/{name}", pair[cam]) for name, pair in images.stereo for cam in CAMERAS]
    rest += [(n, im) for cam in CAMERAS for n, im in images.world.get(cam, [])]
    total = sum(len(images.views[c]) for c in CAMERAS) + len(rest)
    found = {}
    for cam in CAMERAS:
        items = images.views[cam]
        for d in detect_images(items, board, params, progress, done=len(found), total=total, quick=True):
            found[d.name] = d
        if not any(found[n].found for n, _ in items):
            raise _no_board_error(board, cam, items, params)
    for d in detect_images(rest, board, params, progress, done=len(found), total=total):
        found[d.name] = d
    missed = [(n, im) for cam in CAMERAS for n, im in images.views[cam] if not found[n].found]
    for d in detect_images(missed, board, params):
        found[d.name] = d
    return found


def _rig_intrinsics(images: CalibrationImages, found: dict, board: BoardSpec, params: CalibrationParams, progress=None) -> dict:
    """Each camera's intrinsics (K px, k1 k2 p1 p2 k3) from its views and, with ``params.intrinsics_from_stereo``,
    its stereo images: camera name -> :class:`CameraCalibration` (poses ``T_cam_board``, mm)."""
    per_cam = {}
    for cam in CAMERAS:
        dets = [found[n] for n, _ in images.views[cam]]
        if params.intrinsics_from_stereo:
            dets += [found[f"stereo/{cam}/{name}"] for name, _ in images.stereo]
        per_cam[cam] = calibrate_camera(dets, board, cam, params)
        if progress is not None:
            progress("intrinsics", CAMERAS.index(cam) + 1, len(CAMERAS))
    return per_cam


def _joint_observations(per_cam: dict, stereo: StereoCalibration, pairs: list, world: WorldFrame, world_dets: list,
                        found: dict) -> tuple:
    """The board placements for :func:`refine_jointly` and the names of the stereo pairs used.

    A used single view is a placement posed in its own camera (``T_cam_board``, mm); a used pair one posed in
    the top camera (``T_top_board``) and seen by the side camera through ``T_side_top``; the world board one
    more, posed in the top camera and seen once per exposure. Corners in px.
    """
    obs = []
    used_pairs = {v.name for v in stereo.used}
    for cam in CAMERAS:
        for name, T_cam_board in per_cam[cam].poses.items():
            # A stereo view whose pair is not used (the board found in this camera only) is one more
            # view of this camera's intrinsics.
            if not name.startswith("stereo/") or _pair_of(name) not in used_pairs:
                obs.append({"frame": name, "ref": cam, "T_ref_board": T_cam_board, "views": [(cam, found[name].corners)]})
    for name, ds, dt in pairs:
        if name in used_pairs:
            T_top_board = per_cam["top"].poses.get(dt.name)
            if T_top_board is None and ds.name in per_cam["side"].poses:
                # no top-camera pose for this view: T_top_board = T_top_side @ T_side_board
                T_top_board = invert_transform(stereo.T_side_top) @ per_cam["side"].poses[ds.name]
            if T_top_board is None:
                # Neither camera's intrinsics used this view (intrinsics_from_stereo off): the stereo fit's pose.
                T_top_board = stereo.T_top_board[name]
            obs.append({"frame": f"stereo/{name}", "ref": "top", "T_ref_board": T_top_board,
                        "views": [("side", ds.corners), ("top", dt.corners)]})
    obs.append({"frame": "world", "ref": "top", "T_ref_board": world.T_top_board,
                "views": [("top", d.corners) for d in world_dets]})
    return obs, used_pairs


def _refined_cameras(per_cam: dict, sol: dict, used_pairs: set) -> dict:
    """Each camera's calibration with :func:`refine_jointly`'s solution ``sol``: its K (px), distortion, std and
    per-view errors (px, obliquity from the refined ``T_cam_board``); rejected views stay as they were."""
    T_side_top = sol["T_side_top"]
    cameras = {}
    for cam in CAMERAS:
        K, D = sol["cams"][cam]
        errs, recs = [], []
        for v in per_cam[cam].views:
            if not v.used:
                recs.append(v)
                continue
            if v.name.startswith("stereo/") and _pair_of(v.name) in used_pairs:
                frame = f"stereo/{_pair_of(v.name)}"
                e = sol["errors"][frame][CAMERAS.index(cam)]
                # a pair's pose is T_top_board: the side camera sees it through T_side_top
                T_cam_board = sol["poses"][frame] if cam == "top" else T_side_top @ sol["poses"][frame]
            else:
                e = sol["errors"][v.name][0]
                T_cam_board = sol["poses"][v.name]
            errs.append(e)
            recs.append(replace(v, rms_px=_rms(e), max_px=float(e.max()), oblique_deg=_oblique_deg(T_cam_board)))
        cameras[cam] = replace(per_cam[cam], K=K, dist=D, rms_px=_rms(np.concatenate(errs)), views=recs, std=sol["std"][cam])
    return cameras


def _refined_stereo(stereo: StereoCalibration, sol: dict) -> StereoCalibration:
    """The stereo calibration with :func:`refine_jointly`'s ``T_side_top`` (4x4, mm) and the used pairs' errors (px)."""
    s_errs, s_recs = [], []
    for v in stereo.pairs:
        if v.used:
            e = np.concatenate(sol["errors"][f"stereo/{v.name}"])
            s_errs.append(e)
            v = replace(v, rms_px=_rms(e), max_px=float(e.max()))
        s_recs.append(v)
    return replace(stereo, T_side_top=sol["T_side_top"], rms_px=_rms(np.concatenate(s_errs)), pairs=s_recs)


def _refined_world(world: WorldFrame, sol: dict) -> WorldFrame:
    """The world frame with :func:`refine_jointly`'s ``T_top_board`` (4x4, mm), hence ``T_top_world``, and its errors (px)."""
    e = np.concatenate(sol["errors"]["world"])
    T_top_board = sol["poses"]["world"]
    return replace(world, T_top_board=T_top_board, T_top_world=T_top_board @ _T_board_world(world.world_origin_mm),
                   rms_px=_rms(e), view=replace(world.view, rms_px=_rms(e), max_px=float(e.max())))


def _refine_rig(per_cam: dict, stereo: StereoCalibration, world: WorldFrame, pairs: list, world_dets: list, found: dict,
                board: BoardSpec) -> tuple:
    """The joint refinement of the whole rig, started from the OpenCV stages' results.

    Returns
    -------
    (cameras: name -> CameraCalibration, StereoCalibration, WorldFrame), all with the refined figures.
    """
    obs, used_pairs = _joint_observations(per_cam, stereo, pairs, world, world_dets, found)
    sol = refine_jointly({c: (per_cam[c].K, per_cam[c].dist) for c in CAMERAS}, obs, stereo.T_side_top, board,
                         {c: per_cam[c].model for c in CAMERAS})
    return _refined_cameras(per_cam, sol, used_pairs), _refined_stereo(stereo, sol), _refined_world(world, sol)


def calibrate_rig(
    images: CalibrationImages,
    board: BoardSpec,
    params: CalibrationParams | None = None,
    world_origin_mm=(0.0, 0.0, 0.0),
    base_point_world_mm=(0.0, 0.0, 0.0),
    insertion_axis_world=(1.0, 0.0, 0.0),
    progress=None,
) -> tuple:
    """Calibrate the two-camera rig as the paper did, and refine it jointly.

    Steps: detect the board everywhere; each camera's intrinsics from its views (and
    the stereo images); ``T_side_top`` from the pairs; ``T_top_world`` from the world
    image; eq. (1); then (``params.joint_refinement``) one least-squares adjustment of
    everything; and the check of the world board through the side camera when
    ``world/side`` exists.

    Parameters
    ----------
    images : CalibrationImages
        Each camera's views, the stereo pairs and the world image(s).
    board : BoardSpec
    params : CalibrationParams, optional
    world_origin_mm : (3,)
        World position (mm) of the world board's first inner corner (its axes are the world's).
    base_point_world_mm : (3,)
        Where the robot leaves the actuation unit (world frame, mm), for the rig file.
    insertion_axis_world : (3,)
        The insertion direction (world frame, unit vector), for the rig file.
    progress : callable, optional
        ``progress(stage, done, total)``.

    Returns
    -------
    (RigCalibration, CalibrationReport)
        The rig (each camera's K px, distortion and ``T_cam_world`` 4x4 mm) and the report.

    Raises
    ------
    ValueError
        One line naming what is missing or wrong (no images of a role, no board, too few views).
    """
    params = params or CalibrationParams()
    _require_rig_images(images)
    found = _detect_rig(images, board, params, progress)
    per_cam = _rig_intrinsics(images, found, board, params, progress)
    # ---- stereo
    pairs = [(name, found[f"stereo/side/{name}"], found[f"stereo/top/{name}"]) for name, _ in images.stereo]
    stereo = calibrate_stereo(per_cam["side"], per_cam["top"], pairs, board, params)
    # ---- world frame
    world_dets = [found[n] for n, _ in images.world["top"]]
    world = world_frame(per_cam["top"], world_dets, board, world_origin_mm)
    stages = {f"{c} intrinsics": per_cam[c].rms_px for c in CAMERAS}
    stages["stereo"] = stereo.rms_px
    stages["world"] = world.rms_px
    cameras = per_cam
    refined = False
    T_side_top = stereo.T_side_top
    # ---- joint refinement
    single_rms = max(per_cam[c].rms_px for c in CAMERAS)
    notes = []
    if params.joint_refinement and stereo.rms_px > params.max_stereo_ratio * max(single_rms, 0.02):
        notes.append(
            f"joint refinement skipped: the stereo pairs disagree with a rigid rig (RMS {stereo.rms_px:.3f} px vs "
            f"{single_rms:.3f} px for single views) — did a camera move between pairs?"
        )
    elif params.joint_refinement:
        cameras, stereo, world = _refine_rig(per_cam, stereo, world, pairs, world_dets, found, board)
        T_side_top = stereo.T_side_top
        refined = True
    T_side_world = compose_side_world(T_side_top, world.T_top_world)
    rig = RigCalibration(
        cameras={
            "side": cameras["side"].camera(T_side_world),
            "top": cameras["top"].camera(world.T_top_world),
        },
        base_point_world_mm=base_point_world_mm,
        insertion_axis_world=insertion_axis_world,
    )
    side_world = images.world.get("side", [])
    if side_world:
        check = _side_check(found[side_world[0][0]], rig["side"], board, world.world_origin_mm)
        world = replace(world, side_check=check)
    report = CalibrationReport(board=board, cameras=cameras, stereo=stereo, world=world, T_side_world=T_side_world,
                               refined=refined, stages=stages, notes=notes)
    return rig, report


def _fixed(camera: Camera) -> CameraCalibration:
    return CameraCalibration(camera.name, camera.image_size, np.array(camera.K), np.array(camera.dist), float("nan"), [])


def calibrate_extrinsics(
    side: Camera,
    top: Camera,
    images: CalibrationImages,
    board: BoardSpec,
    params: CalibrationParams | None = None,
    world_origin_mm=(0.0, 0.0, 0.0),
    T_side_top: np.ndarray | None = None,
    progress=None,
) -> tuple:
    """The rig's extrinsics for cameras whose intrinsics are known (imported).

    ``T_top_world`` from ``images.world["top"]`` and, unless given, ``T_side_top`` from ``images.stereo``.

    Parameters
    ----------
    side, top : Camera
        The cameras' intrinsics (K px, distortion, image size); their poses are ignored.
    images : CalibrationImages
        The world image(s) and, when ``T_side_top`` is None, the stereo pairs.
    board : BoardSpec
    params : CalibrationParams, optional
    world_origin_mm : (3,)
        World position (mm) of the world board's first inner corner.
    T_side_top : (4, 4) array, optional
        Top camera frame -> side camera frame (mm), when known.
    progress : callable, optional
        ``progress(stage, done, total)``.

    Returns
    -------
    (T_side_top (4, 4) mm, WorldFrame, StereoCalibration or None)
        The stereo calibration is None when ``T_side_top`` was given.

    Raises
    ------
    ValueError
        Naming ``images.source``: no world image, or no pairs and no ``T_side_top``.
    """
    params = params or CalibrationParams()
    if not images.world.get("top"):
        raise ValueError(f"{images.source}: no world-frame image from the top camera (world/top.png)")
    jobs = [(n, im) for n, im in images.world["top"]]
    if T_side_top is None:
        if not images.stereo:
            raise ValueError(f"{images.source}: no stereo pairs to place the side camera (stereo/side, stereo/top), and no T_side_top given")
        jobs += [(f"stereo/{cam}/{name}", pair[cam]) for name, pair in images.stereo for cam in CAMERAS]
    found = {d.name: d for d in detect_images(jobs, board, params, progress)}
    cams = {"side": _fixed(side), "top": _fixed(top)}
    stereo = None
    if T_side_top is None:
        pairs = [(name, found[f"stereo/side/{name}"], found[f"stereo/top/{name}"]) for name, _ in images.stereo]
        stereo = calibrate_stereo(cams["side"], cams["top"], pairs, board, params)
        T_side_top = stereo.T_side_top
    world = world_frame(cams["top"], [found[n] for n, _ in images.world["top"]], board, world_origin_mm)
    return np.asarray(T_side_top, np.float64), world, stereo


def save_report(path, report: CalibrationReport) -> None:
    """Write ``report`` as JSON (:meth:`CalibrationReport.to_dict`).

    Parameters
    ----------
    path : str or Path
        The file written (``calibration_report.json``).
    report : CalibrationReport
    """
    Path(path).write_text(json.dumps(report.to_dict(), indent=2, ensure_ascii=False) + "\n")
