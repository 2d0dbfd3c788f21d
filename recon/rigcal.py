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

from .camera import Camera

__all__ = ["RigCalibration", "load_rig_calibration", "save_rig_calibration", "FORMAT_VERSION"]

FORMAT_VERSION = 1


@dataclass(frozen=True, eq=False)
class RigCalibration:
    """Calibrated cameras by name plus the robot base location (world frame, mm)."""

    cameras: dict
    base_point_world_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    insertion_axis_world: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0]))

    def __post_init__(self):
        if not self.cameras:
            raise ValueError("rig calibration has no cameras")
        base = np.asarray(self.base_point_world_mm, dtype=np.float64).reshape(3)
        axis = np.asarray(self.insertion_axis_world, dtype=np.float64).reshape(3)
        n = np.linalg.norm(axis)
        if n == 0:
            raise ValueError("rig calibration: insertion_axis_world must be non-zero")
        object.__setattr__(self, "base_point_world_mm", base)
        object.__setattr__(self, "insertion_axis_world", axis / n)
        object.__setattr__(self, "cameras", dict(self.cameras))

    @property
    def names(self) -> list:
        """Camera names in file order."""
        return list(self.cameras)

    def __getitem__(self, name: str) -> Camera:
        try:
            return self.cameras[name]
        except KeyError:
            raise KeyError(f"rig calibration has no camera {name!r} (has {', '.join(self.cameras)})") from None

    def to_dict(self) -> dict:
        return {
            "format": "ctr-bench-rig-calibration",
            "version": FORMAT_VERSION,
            "units": "mm",
            "cameras": {n: c.to_dict() for n, c in self.cameras.items()},
            "base_point_world_mm": self.base_point_world_mm.tolist(),
            "insertion_axis_world": self.insertion_axis_world.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict, source: str = "rig calibration") -> "RigCalibration":
        if not isinstance(d, dict) or "cameras" not in d:
            raise ValueError(f"{source}: no 'cameras' table")
        cams = {}
        for name, cd in d["cameras"].items():
            try:
                cams[name] = Camera.from_dict(cd, name=name)
            except (ValueError, TypeError) as exc:
                raise ValueError(f"{source}: {exc}") from None
        return cls(
            cameras=cams,
            base_point_world_mm=d.get("base_point_world_mm", [0.0, 0.0, 0.0]),
            insertion_axis_world=d.get("insertion_axis_world", [1.0, 0.0, 0.0]),
        )


def save_rig_calibration(path, rig: RigCalibration) -> None:
    """Write ``rig`` as JSON to ``path``."""
    Path(path).write_text(json.dumps(rig.to_dict(), indent=2) + "\n")


def load_rig_calibration(path) -> RigCalibration:
    """Read a rig calibration JSON file; errors name the file and what is wrong."""
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"{path}: rig calibration file not found") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    return RigCalibration.from_dict(d, source=str(path))
