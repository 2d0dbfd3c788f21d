"""The rig calibration file: the cameras (intrinsics, distortion, pose) and the robot base.

This is what ``ctr-bench reconstruct`` reads (``rig.json`` in a session
directory). JSON, mm and pixels; every pose is ``T_cam_world`` (world -> camera).

``base_point_world_mm`` and ``insertion_axis_world`` say where the robot leaves
the actuation unit and in which direction it is inserted; the pipeline uses them
only to tell the base end of a backbone from its tip.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .calibration_check import CalibrationError, check_rig
from .camera import Camera
from .distortion import MODEL_SIZES
from .textfile import parse_json, read_text

__all__ = ["RigCalibration", "UnknownCameraError", "CalibrationError", "load_rig_calibration", "save_rig_calibration",
           "FORMAT_VERSION"]

FORMAT_VERSION = 1


#: Keys of a rig file and of each of its cameras (:meth:`RigCalibration.to_dict` writes them all).
_RIG_KEYS = ("format", "version", "units", "cameras", "base_point_world_mm", "insertion_axis_world")
_CAMERA_KEYS = ("name", "width", "height", "K", "dist", "T_cam_world")
_FORMAT = "ctr-bench-rig-calibration"
#: Largest image side (px) a rig file may give; far beyond any sensor (the memory bounds come later).
_MAX_SIDE_PX = 1 << 20


class UnknownCameraError(KeyError, ValueError):
    """A camera name the rig calibration lacks: a ``KeyError`` for lookups, a ``ValueError``
    (one line naming the file) for the command line."""

    def __str__(self) -> str:
        # KeyError's own __str__ quotes its message
        return str(self.args[0]) if self.args else ""


@dataclass(frozen=True, eq=False)
class RigCalibration:
    """Calibrated cameras by name plus the robot base location (world frame, mm).

    ``source`` is where it came from (a file name), for messages.
    """

    cameras: dict
    base_point_world_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    insertion_axis_world: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0]))
    source: str = "rig calibration"

    def __post_init__(self):
        if not self.cameras:
            raise CalibrationError(f"{self.source}: cameras: no cameras")
        base = np.asarray(self.base_point_world_mm, dtype=np.float64).reshape(3)
        axis = np.asarray(self.insertion_axis_world, dtype=np.float64).reshape(3)
        if not (np.all(np.isfinite(base)) and np.all(np.isfinite(axis))):
            raise CalibrationError(f"{self.source}: base_point_world_mm and insertion_axis_world must be finite")
        peak = np.abs(axis).max()
        if peak == 0:
            raise CalibrationError(f"{self.source}: insertion_axis_world: must be non-zero")
        axis = axis / peak  # first: the norm of a vector near the float limit overflows
        object.__setattr__(self, "base_point_world_mm", base)
        object.__setattr__(self, "insertion_axis_world", axis / np.linalg.norm(axis))
        object.__setattr__(self, "cameras", dict(self.cameras))

    @property
    def names(self) -> list:
        """Camera names in file order.

        Returns
        -------
        list of str
            The keys of ``cameras``, e.g. ``["side", "top"]``.
        """
        return list(self.cameras)

    def __getitem__(self, name: str) -> Camera:
        try:
            return self.cameras[name]
        except KeyError:
            raise UnknownCameraError(f"{self.source}: no camera {name!r} (has {', '.join(self.cameras)})") from None

    def to_dict(self) -> dict:
        """The rig as the JSON-ready mapping a rig file holds (format, version, ``units: "mm"``).

        Returns
        -------
        dict
            ``cameras`` by name (:meth:`recon.camera.Camera.to_dict`: size px, ``K`` px,
            ``dist``, ``T_cam_world`` world -> camera, mm), ``base_point_world_mm`` (world
            frame, mm) and ``insertion_axis_world`` (unit vector, world frame), as lists.
        """
        return {
            "format": _FORMAT,
            "version": FORMAT_VERSION,
            "units": "mm",
            "cameras": {n: c.to_dict() for n, c in self.cameras.items()},
            "base_point_world_mm": self.base_point_world_mm.tolist(),
            "insertion_axis_world": self.insertion_axis_world.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict, source: str = "rig calibration", cameras=None) -> "RigCalibration":
        """A rig from its :meth:`to_dict` form, validated (:func:`recon.calibration_check.check_rig`).

        ``cameras`` names the cameras the caller needs. Raises :class:`CalibrationError`,
        one line naming ``source`` and the key: a missing or unknown key, a wrong type or
        shape, a non-finite number, a camera missing or named differently inside, or a
        calibration that the checks refuse.

        Parameters
        ----------
        d : dict
            The decoded JSON object of a rig file.
        source : str
            The file it came from, named in every message.
        cameras : sequence of str, optional
            Camera names the caller needs, e.g. ``("side", "top")``.

        Returns
        -------
        RigCalibration
            Validated; ``insertion_axis_world`` normalized to unit length.

        Raises
        ------
        CalibrationError
            One line naming ``source`` and the key (see above).
        """
        if not isinstance(d, dict):
            raise CalibrationError(f"{source}: must be a JSON object with a 'cameras' table, got {_kind(d)}")
        _check_keys(d, _RIG_KEYS, source, "")
        for key, want in (("format", _FORMAT), ("version", FORMAT_VERSION), ("units", "mm")):
            if key in d and (d[key] != want or isinstance(d[key], bool)):
                raise CalibrationError(f"{source}: {key}: must be {want!r}, got {d[key]!r}")
        if "cameras" not in d:
            raise CalibrationError(f"{source}: cameras: missing (required)")
        table = d["cameras"]
        if not isinstance(table, dict):
            raise CalibrationError(f"{source}: cameras: must be an object mapping camera names to cameras "
                                   f'(e.g. {{"side": {{...}}, "top": {{...}}}}), got {_kind(table)}')
        cams = {name: _camera_from_dict(cd, name, source) for name, cd in table.items()}
        rig = cls(
            cameras=cams,
            base_point_world_mm=_numbers(d, "base_point_world_mm", (3,), source, "", [0.0, 0.0, 0.0]),
            insertion_axis_world=_numbers(d, "insertion_axis_world", (3,), source, "", [1.0, 0.0, 0.0]),
            source=source,
        )
        check_rig(rig, source, cameras)
        return rig


def _kind(value) -> str:
    """A JSON value's kind, for messages."""
    names = {dict: "an object", list: "a list", str: "a string", bool: "true/false", type(None): "null"}
    return names.get(type(value), f"the number {value!r}" if isinstance(value, (int, float)) else type(value).__name__)


def _where(source: str, table: str, key: str) -> str:
    """``"<source>: <table>.<key>"`` (``table`` "" at the top level), the prefix of every message."""
    return f"{source}: {table}.{key}" if table else f"{source}: {key}"


def _check_keys(d: dict, known: tuple, source: str, table: str) -> None:
    # A misspelt key would otherwise be ignored and its default used without a word.
    unknown = [k for k in d if k not in known]
    if unknown:
        raise CalibrationError(f"{_where(source, table, str(unknown[0]))}: unknown key (known: {', '.join(known)})")


def _is_numbers(value) -> bool:
    """Whether ``value`` is a number or (nested) lists of numbers; booleans are not numbers."""
    if isinstance(value, list):
        return all(_is_numbers(v) for v in value)
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _numbers(d: dict, key: str, shape: tuple, source: str, table: str, default=None) -> np.ndarray:
    """``d[key]`` as a finite float64 array of ``shape`` (None: any length); CalibrationError naming the key."""
    where = _where(source, table, key)
    if key not in d:
        if default is None:
            raise CalibrationError(f"{where}: missing (required)")
        return np.asarray(default, np.float64)
    value = d[key]
    want = "a list of numbers" if shape == (None,) else "x".join(map(str, shape)) + " numbers (nested lists)"
    try:
        arr = np.asarray(value, np.float64) if _is_numbers(value) else None
    except (ValueError, OverflowError, RecursionError):  # ragged nesting; ints beyond float range; deep nesting
        arr = None
    if arr is None or arr.ndim != len(shape) or any(s is not None and a != s for a, s in zip(arr.shape, shape)):
        raise CalibrationError(f"{where}: must be {want}, got {_kind(value)}{_shape(arr)}")
    if not np.all(np.isfinite(arr)):
        raise CalibrationError(f"{where}: must be finite, got {arr.tolist()}")
    return arr


def _shape(arr) -> str:
    return f" of shape {arr.shape}" if arr is not None and arr.ndim else ""


def _size(cd: dict, key: str, source: str, table: str) -> int:
    """``cd[key]``, an image side (px) as a JSON integer; CalibrationError naming the key."""
    where = _where(source, table, key)
    if key not in cd:
        raise CalibrationError(f"{where}: missing (required)")
    v = cd[key]
    if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= _MAX_SIDE_PX:
        raise CalibrationError(f"{where}: must be an integer number of pixels in [1, {_MAX_SIDE_PX}], got {v!r}")
    return v


def _camera_from_dict(cd, name: str, source: str) -> Camera:
    """Camera ``name`` of a rig file, its keys, types and shapes checked (the geometry is :func:`check_rig`'s)."""
    table = f"cameras.{name}"
    if not isinstance(cd, dict):
        raise CalibrationError(f"{source}: {table}: must be an object with width, height, K, dist and T_cam_world, "
                               f"got {_kind(cd)}")
    _check_keys(cd, _CAMERA_KEYS, source, table)
    inner = cd.get("name", name)
    if inner != name:
        raise CalibrationError(f"{_where(source, table, 'name')}: {inner!r} differs from the camera's key {name!r}; "
                               "the names must agree")
    dist = _numbers(cd, "dist", (None,), source, table, [0.0] * 5)
    if dist.size not in MODEL_SIZES:
        raise CalibrationError(f"{_where(source, table, 'dist')}: OpenCV distortion has 4, 5, 8, 12 or 14 coefficients, "
                               f"got {dist.size}")
    return Camera(name=name, width=_size(cd, "width", source, table), height=_size(cd, "height", source, table),
                  K=_numbers(cd, "K", (3, 3), source, table), dist=dist,
                  T_cam_world=_numbers(cd, "T_cam_world", (4, 4), source, table))


def save_rig_calibration(path, rig: RigCalibration) -> None:
    """Write ``rig`` as JSON to ``path``.

    Parameters
    ----------
    path : path
        The file written (indented JSON; its folder must exist).
    rig : RigCalibration
        Written as :meth:`RigCalibration.to_dict` gives it (mm, px).
    """
    Path(path).write_text(json.dumps(rig.to_dict(), indent=2) + "\n")


def load_rig_calibration(path, cameras=None) -> RigCalibration:
    """Read and validate a rig calibration JSON file (:meth:`RigCalibration.from_dict`).

    Parameters
    ----------
    path : path
    cameras : sequence of str, optional
        Camera names the caller needs, e.g. ``("side", "top")``.

    Returns
    -------
    RigCalibration
        With ``source`` set to ``str(path)``.

    Raises
    ------
    CalibrationError
        One line naming the file: missing, unreadable, not JSON, or not a usable calibration.
    """
    path = Path(path)
    text = read_text(path, "rig calibration", "rig calibration JSON file", CalibrationError)
    d = parse_json(text, path, CalibrationError)
    return RigCalibration.from_dict(d, source=str(path), cameras=cameras)
