"""Validation of a rig calibration: intrinsics, poses, lens distortion and camera names.

A calibration that is wrong in a way the numbers themselves show must be refused
when it is loaded: a sheared or scaled rotation, a zero focal length or a lens model
that folds the image over gives "ok" frames with errors of many mm, or fails every
frame with a message about something else. Each check is a pure function returning
``None`` or a one-line reason; :func:`check_camera` and :func:`check_rig` raise
:class:`CalibrationError` naming the file and the key.

Tolerances
----------
* ``K``: finite, ``fx, fy > 0``, ``K[1, 0] = 0`` and last row ``0 0 1`` to
  :data:`K_ROW_TOL`; principal point inside the image, ``-0.5 <= cx <= width - 0.5``
  and likewise ``cy`` (pixel centres at integers); image corners between 1e-6 and 1e6
  focal lengths off axis.
* ``T_cam_world``: finite, last row ``0 0 0 1`` to :data:`LAST_ROW_TOL`, rotation with
  ``max |R^T R - I| <= ROTATION_TOL`` and ``|det R - 1| <= ROTATION_TOL`` (1e-6: a
  rotation written with full double precision is good to ~1e-15; one typed as ``0.7071``
  is not, and is refused with the figure).
* Distortion: monotonic out to the image corners (no fold-over) and of a plausible
  strength, at most :data:`MAX_DISTORTION_COEFFICIENT` x the squared field at the
  corners; see :func:`distortion_problem`.
"""
from __future__ import annotations

import numpy as np

from .distortion import distort_normalized

__all__ = [
    "CalibrationError",
    "ROTATION_TOL",
    "K_ROW_TOL",
    "LAST_ROW_TOL",
    "camera_matrix_problem",
    "principal_point_problem",
    "field_of_view_problem",
    "rotation_problem",
    "MAX_DISTORTION_COEFFICIENT",
    "distortion_problem",
    "camera_problems",
    "check_camera",
    "check_rig",
]

#: Largest ``|R^T R - I|`` entry and ``|det R - 1|`` accepted (unitless).
ROTATION_TOL = 1e-6
#: Largest deviation of ``K[1, 0]`` from 0 and of K's last row from ``0 0 1`` (px, unitless).
K_ROW_TOL = 1e-9
#: Largest deviation of a transform's last row from ``0 0 0 1``.
LAST_ROW_TOL = 1e-12
#: Largest net relative distortion at the image corners per squared (normalized) field radius.
MAX_DISTORTION_COEFFICIENT = 10.0
# The fold check samples this many directions out of the principal point, and this many
# undistorted radii on each, up to REACH times the image corners' distorted radius: a lens
# that compresses the corners more than 10x is taken not to reach them at all.
_DIRECTIONS = 64
_RADII = 1024
_REACH = 10.0
# A pinhole camera whose corners lie more than this many focal lengths off axis sees within
# 1e-4 deg of 180 deg, one within the minimum sees less than 1e-4 deg: no lens does, and the
# sampling below would overflow or underflow.
_MAX_CORNER_RADIUS = 1e6
_MIN_CORNER_RADIUS = 1e-6


class CalibrationError(ValueError):
    """A rig calibration that cannot be used; the message is one line naming the file and the key."""


def camera_matrix_problem(K) -> str | None:
    """Why ``K`` (3x3, px) is no camera matrix, or None.

    Finite, positive focal lengths, ``K[1, 0] = 0`` and last row ``0 0 1`` (to :data:`K_ROW_TOL`).

    Parameters
    ----------
    K : array_like
        The camera matrix, ``(3, 3)`` (px; ``K[0, 1]`` is the skew, allowed).

    Returns
    -------
    str or None
        A one-line reason (shape, non-finite, focal lengths, last row), or None when sound.
    """
    K = np.asarray(K, np.float64)
    if K.shape != (3, 3):
        return f"must be 3x3, got shape {K.shape}"
    if not np.all(np.isfinite(K)):
        return f"must be finite, got {K.tolist()}"
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        return f"focal lengths must be > 0, got fx = {K[0, 0]:g}, fy = {K[1, 1]:g} px"
    if np.abs(K[2] - [0.0, 0.0, 1.0]).max() > K_ROW_TOL or abs(K[1, 0]) > K_ROW_TOL:
        return f"not a camera matrix (K[1, 0] = 0 and last row 0 0 1), got {K.tolist()}"
    return None


def principal_point_problem(K, width: int, height: int) -> str | None:
    """Why the principal point of ``K`` lies outside a ``width`` x ``height`` image, or None.

    Pixel centres are at integers, so the image spans ``[-0.5, width - 0.5]`` x
    ``[-0.5, height - 0.5]`` px.

    Parameters
    ----------
    K : array_like
        The ``(3, 3)`` camera matrix (px); ``(cx, cy) = (K[0][2], K[1][2])``.
    width, height : int
        The image size (px).

    Returns
    -------
    str or None
        A one-line reason giving the point and the image size, or None when inside.
    """
    cx, cy = float(K[0][2]), float(K[1][2])
    if not (-0.5 <= cx <= width - 0.5 and -0.5 <= cy <= height - 0.5):
        return f"principal point ({cx:g}, {cy:g}) px lies outside the {width}x{height} image"
    return None


def field_of_view_problem(camera) -> str | None:
    """Why ``camera``'s focal lengths do not fit its image size, or None.

    The image corners must lie between 1e-6 and 1e6 focal lengths off axis (normalized):
    a field of view beyond 0.0001 deg and short of 180 deg. Needs a sound ``K``.

    Parameters
    ----------
    camera : recon.camera.Camera
        Its ``K`` (px), ``width`` and ``height`` (px) are used.

    Returns
    -------
    str or None
        A one-line reason giving the corners' radius (normalized), or None.
    """
    rho = _corner_radius(camera)
    if not _MIN_CORNER_RADIUS <= rho <= _MAX_CORNER_RADIUS:
        return (f"the image corners lie {rho:.3g} focal lengths off axis (between {_MIN_CORNER_RADIUS:g} and "
                f"{_MAX_CORNER_RADIUS:g}: a field of view beyond 0.0001 deg and short of 180 deg): the focal lengths "
                "do not fit the image size")
    return None


def rotation_problem(T) -> str | None:
    """Why ``T`` (4x4, mm) is no rigid transform, or None.

    Finite, last row ``0 0 0 1`` (to :data:`LAST_ROW_TOL`), ``max |R^T R - I| <=``
    :data:`ROTATION_TOL` and ``|det R - 1| <=`` :data:`ROTATION_TOL`.

    Parameters
    ----------
    T : array_like
        A homogeneous transform, ``(4, 4)``, e.g. ``T_cam_world`` (translation in mm).

    Returns
    -------
    str or None
        A one-line reason (shape, non-finite, last row, not orthonormal with the figure,
        a reflection), or None when rigid.
    """
    T = np.asarray(T, np.float64)
    if T.shape != (4, 4):
        return f"must be 4x4, got shape {T.shape}"
    if not np.all(np.isfinite(T)):
        return "must be finite (rotation and translation), got NaN or inf"
    if np.abs(T[3] - [0.0, 0.0, 0.0, 1.0]).max() > LAST_ROW_TOL:
        return f"last row must be 0 0 0 1, got {T[3].tolist()}"
    R = T[:3, :3]
    with np.errstate(over="ignore", invalid="ignore"):  # entries near the float limit: off is inf, refused
        off = float(np.abs(R.T @ R - np.eye(3)).max())
    if off > ROTATION_TOL:
        return f"rotation not orthonormal (max |R^T R - I| = {off:.3g} > {ROTATION_TOL:g}: scaled or sheared)"
    det = float(np.linalg.det(R))
    if abs(det - 1.0) > ROTATION_TOL:
        return f"rotation has det {det:.6g}, not +1 (a reflection)"
    return None


def _corner_xy(camera) -> np.ndarray:
    """The image corners (outer pixel edges) in distorted normalized coordinates, (4, 2)."""
    K = camera.K
    u = np.array([-0.5, camera.width - 0.5, -0.5, camera.width - 0.5])
    v = np.array([-0.5, -0.5, camera.height - 0.5, camera.height - 0.5])
    y = (v - K[1, 2]) / K[1, 1]
    x = (u - K[0, 2] - K[0, 1] * y) / K[0, 0]
    return np.stack([x, y], axis=1)


def _corner_radius(camera) -> float:
    """The image corners' largest distorted radius (normalized); inf or 0 for focal lengths near the float limits."""
    with np.errstate(all="ignore"):
        return float(np.linalg.norm(_corner_xy(camera), axis=1).max())


def _radial_profile(camera):
    """The distorted radius along rays out of the axis: ``(angles, r, radius, rho)`` or a reason string.

    ``r`` (n,) are undistorted normalized radii from 0 to ``_REACH * rho``, ``radius``
    (directions, n) the distorted radius ``|distort(r e)|`` along each direction ``e`` at
    ``angles`` (rad), ``rho`` the image corners' largest distorted radius (normalized).
    """
    why = field_of_view_problem(camera)
    if why:
        return why
    rho = _corner_radius(camera)
    angles = np.linspace(0.0, 2.0 * np.pi, _DIRECTIONS, endpoint=False)
    r = np.linspace(0.0, _REACH * rho, _RADII + 1)
    xy = (r[None, :, None] * np.stack([np.cos(angles), np.sin(angles)], axis=1)[:, None, :]).reshape(-1, 2)
    with np.errstate(all="ignore"):  # a rational model's pole gives inf/NaN: a fold below
        radius = np.linalg.norm(distort_normalized(xy, camera.dist), axis=1).reshape(_DIRECTIONS, -1)
    return angles, r, radius, rho


def _fold_reason(angle: float, r: np.ndarray, radius: np.ndarray, rho: float) -> tuple:
    """``(reason or None, r_corner)`` along one direction: the fold check, and where the corners' radius is reached."""
    with np.errstate(invalid="ignore"):
        reached = radius >= rho
    if not reached.any():
        return (f"the lens model folds the image over: in direction {np.degrees(angle):.0f} deg the "
                f"distorted radius never reaches the corners' {rho:.3g} (normalized)"), None
    end = int(np.argmax(reached))
    rising = np.diff(radius[: end + 1]) > 0
    if not rising.all():
        peak = int(np.argmin(rising))
        return (f"the lens model folds the image over: in direction {np.degrees(angle):.0f} deg the distorted "
                f"radius peaks at {radius[peak]:.3g} (undistorted {r[peak]:.3g}) short of the corners' {rho:.3g} "
                "(normalized)"), None
    # linear interpolation between the last sample short of rho and the first at or beyond it
    # (that first sample itself where the step to it is unbounded)
    with np.errstate(all="ignore"):
        r_c = r[end - 1] + (rho - radius[end - 1]) / (radius[end] - radius[end - 1]) * (r[end] - r[end - 1])
    return None, float(r_c if r_c > 0 else r[end])


def distortion_problem(camera) -> str | None:
    """Why ``camera``'s lens model is no lens over its image, or None.

    Along rays out of the axis in 64 directions, sampled at 1024 undistorted radii ``r``
    (normalized) up to 10x the image corners' distorted radius ``rho``:

    * **No fold-over**: the distorted radius ``|distort(r e)|`` must grow strictly with
      ``r`` until it reaches ``rho``; for a radial lens it is ``r (1 + k1 r^2 + k2 r^4 +
      ...)`` and this is ``d/dr > 0`` out to the corners. A lens whose distorted radius
      turns back first, or never gets there (the corners would show nothing), folds.
    * **A plausible strength**: the net relative distortion at the corners, ``rho / r_c -
      1`` (``r_c`` the undistorted radius that reaches ``rho``), divided by ``r_c^2``: a
      lens's distortion is a third-order aberration, growing as the field squared with a
      coefficient of order 0.1-1 (the wide suite's ranges allow ~0.6; its first 120
      scenes of seeds 1, 2, 3, 7 and 11 reach 0.35), so more than
      :data:`MAX_DISTORTION_COEFFICIENT` (10) in size is a calibration gone wrong, e.g.
      ``k1 = 50`` on the paper's 12 mm lenses: +88 % at the corners. It is the net effect
      at the corners, so over-fitted coefficients that cancel there pass.

    Needs a finite ``K`` with positive focal lengths.

    Parameters
    ----------
    camera : recon.camera.Camera
        Its ``K`` (px), image size (px) and ``dist`` (OpenCV coefficients, any model) are used.

    Returns
    -------
    str or None
        A one-line reason (the field of view, a fold-over with its direction in deg, or an
        implausible strength with the figure), or None when the lens model is plausible.
    """
    profile = _radial_profile(camera)
    if isinstance(profile, str):
        return profile
    angles, r, radius, rho = profile
    for angle, rad in zip(angles, radius):
        why, r_c = _fold_reason(angle, r, rad, rho)
        if why:
            return why
        coefficient = (rho / r_c - 1.0) / r_c**2
        if not abs(coefficient) <= MAX_DISTORTION_COEFFICIENT:
            return (f"the lens model distorts the image corners by {100 * (rho / r_c - 1):+.0f} % at {r_c:.3g} "
                    f"(normalized) off axis in direction {np.degrees(angle):.0f} deg: {coefficient:.3g} x the squared "
                    f"field, beyond any lens (at most {MAX_DISTORTION_COEFFICIENT:g})")
    return None


def camera_problems(camera) -> list:
    """Every problem of a :class:`recon.camera.Camera`, as ``(key, reason)`` pairs.

    Keys are ``"K"`` (:func:`camera_matrix_problem`, :func:`principal_point_problem`,
    :func:`field_of_view_problem`), ``"dist"`` (:func:`distortion_problem`) and
    ``"T_cam_world"`` (:func:`rotation_problem`). The distortion, whose coefficients the
    Camera already holds finite, is only looked at when ``K`` is sound: its checks need
    the image in normalized coordinates.

    Parameters
    ----------
    camera : recon.camera.Camera

    Returns
    -------
    list of tuple of (str, str)
        ``(key, reason)`` pairs, at most one per key in the order ``K`` or ``dist``, then
        ``T_cam_world``; empty when the camera is sound.
    """
    problems = []
    K, size = camera.K, (camera.width, camera.height)
    why = camera_matrix_problem(K) or principal_point_problem(K, *size) or field_of_view_problem(camera)
    if why:
        problems.append(("K", why))
    else:
        why = distortion_problem(camera)
        if why:
            problems.append(("dist", why))
    why = rotation_problem(camera.T_cam_world)
    if why:
        problems.append(("T_cam_world", why))
    return problems


def check_camera(camera, where: str, error=CalibrationError) -> None:
    """Raise ``error`` (one line: ``"<where>.<key>: <reason>"``) at ``camera``'s first problem.

    ``where`` names the file and the camera, e.g. ``"S/rig.json: cameras.side"``.

    Parameters
    ----------
    camera : recon.camera.Camera
    where : str
        The message's prefix, naming the file and the camera.
    error : type
        The ``ValueError`` subclass raised.

    Raises
    ------
    error
        At the first of :func:`camera_problems`.
    """
    problems = camera_problems(camera)
    if problems:
        key, why = problems[0]
        raise error(f"{where}.{key}: {why}")


def check_rig(rig, source: str, cameras=None, error=CalibrationError) -> None:
    """Validate a :class:`recon.rigcal.RigCalibration` read from ``source``.

    Parameters
    ----------
    rig : RigCalibration
    source : str
        The file it came from (named in every message).
    cameras : sequence of str, optional
        Names the caller needs (e.g. ``("side", "top")``); each must be calibrated.
    error : type
        The ``ValueError`` subclass raised.

    Raises
    ------
    error
        One line naming ``source`` and the key: a camera whose name differs from its
        key, a needed camera missing, or :func:`check_camera`'s first problem.
    """
    for name, cam in rig.cameras.items():
        if cam.name != name:
            raise error(f"{source}: cameras.{name}: is named {cam.name!r} inside; the names must agree")
    missing = [n for n in (cameras or ()) if n not in rig.cameras]
    if missing:
        raise error(f"{source}: cameras: no camera {missing[0]!r} (has {', '.join(rig.cameras) or 'none'})")
    for name, cam in rig.cameras.items():
        check_camera(cam, f"{source}: cameras.{name}", error)
