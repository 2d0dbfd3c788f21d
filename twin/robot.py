"""Concentric tube robot description: tubes, joints and the backbone a model produces.

Conventions
-----------
* Lengths in mm, curvatures in 1/mm, angles in degrees in files and joints.
* Tubes are listed outermost first.
* Base frame ``b``: origin where the tubes leave the actuation unit (the front
  face of the distal pin vise); ``z_b`` is the insertion direction, ``x_b`` the
  direction a tube at rotation 0 bends towards. ``T_world_base`` places it in
  the world (mm).
* Arc length ``s`` (mm) is measured along the backbone from the base (s = 0).
* Joint ``extension_mm[i]``: arc length of tube ``i``'s distal end beyond the
  base, so tube ``i`` is exposed on ``0 <= s <= extension_mm[i]``; its precurved
  part is its last ``curved_length_mm`` and the rest of its ``length_mm``
  (straight) runs back through the actuation unit to the pin vise that rotates
  it. Joint ``rotation_deg[i]`` is that pin vise's rotation about ``z_b``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Tube", "Robot", "Joints", "Backbone"]


@dataclass(frozen=True)
class Tube:
    """One precurved superelastic tube.

    Attributes
    ----------
    name : str
    outer_diameter_mm, inner_diameter_mm : float
        Tube cross-section (mm).
    length_mm : float
        Total length from the pin vise to the distal end (mm).
    curved_length_mm : float
        Length of the precurved distal part (mm); the rest is straight.
    precurvature_per_mm : float
        Curvature of the precurved part (1/mm).
    youngs_modulus_gpa : float
        Young's modulus E (GPa); Nitinol ~ 50-80.
    poisson_ratio : float
        Poisson ratio nu; shear modulus G = E / (2 (1 + nu)).
    """

    name: str
    outer_diameter_mm: float
    inner_diameter_mm: float
    length_mm: float
    curved_length_mm: float
    precurvature_per_mm: float
    youngs_modulus_gpa: float = 60.0
    poisson_ratio: float = 0.33

    def __post_init__(self):
        def bad(key, why):
            raise ValueError(f"tube {self.name!r}: {key} {why}")

        if not self.outer_diameter_mm > 0:
            bad("outer_diameter_mm", f"must be > 0, got {self.outer_diameter_mm}")
        if not 0 <= self.inner_diameter_mm < self.outer_diameter_mm:
            bad("inner_diameter_mm", f"must be in [0, outer_diameter_mm={self.outer_diameter_mm}), got {self.inner_diameter_mm}")
        if not self.length_mm > 0:
            bad("length_mm", f"must be > 0, got {self.length_mm}")
        if not 0 <= self.curved_length_mm <= self.length_mm:
            bad("curved_length_mm", f"must be in [0, length_mm={self.length_mm}], got {self.curved_length_mm}")
        if not self.precurvature_per_mm >= 0:
            bad("precurvature_per_mm", f"must be >= 0, got {self.precurvature_per_mm}")
        if not self.youngs_modulus_gpa > 0:
            bad("youngs_modulus_gpa", f"must be > 0, got {self.youngs_modulus_gpa}")
        if not -1.0 < self.poisson_ratio < 0.5:
            bad("poisson_ratio", f"must be in (-1, 0.5), got {self.poisson_ratio}")

    @property
    def outer_radius_mm(self) -> float:
        return 0.5 * self.outer_diameter_mm

    @property
    def second_moment_mm4(self) -> float:
        """Area second moment of inertia I (mm^4)."""
        return np.pi / 64.0 * (self.outer_diameter_mm**4 - self.inner_diameter_mm**4)

    @property
    def polar_moment_mm4(self) -> float:
        """Polar moment J = 2 I (mm^4)."""
        return 2.0 * self.second_moment_mm4

    @property
    def bending_stiffness_nmm2(self) -> float:
        """E I (N mm^2); E in N/mm^2 = MPa."""
        return self.youngs_modulus_gpa * 1e3 * self.second_moment_mm4

    @property
    def torsional_stiffness_nmm2(self) -> float:
        """G J (N mm^2)."""
        G = self.youngs_modulus_gpa * 1e3 / (2.0 * (1.0 + self.poisson_ratio))
        return G * self.polar_moment_mm4


@dataclass(frozen=True, eq=False)
class Robot:
    """Tubes (outermost first) and where the robot base sits in the world."""

    tubes: tuple
    T_world_base: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self):
        tubes = tuple(self.tubes)
        if not tubes:
            raise ValueError("robot has no tubes")
        for outer, inner in zip(tubes[:-1], tubes[1:]):
            if inner.outer_diameter_mm > outer.inner_diameter_mm + 1e-9:
                raise ValueError(
                    f"tube {inner.name!r} (outer diameter {inner.outer_diameter_mm} mm) does not fit inside "
                    f"tube {outer.name!r} (inner diameter {outer.inner_diameter_mm} mm)"
                )
        T = np.asarray(self.T_world_base, dtype=np.float64)
        if T.shape != (4, 4):
            raise ValueError(f"robot: T_world_base must be 4x4, got {T.shape}")
        object.__setattr__(self, "tubes", tubes)
        object.__setattr__(self, "T_world_base", T)

    @property
    def n_tubes(self) -> int:
        return len(self.tubes)


@dataclass(frozen=True)
class Joints:
    """Joint values, one per tube (outermost first).

    Attributes
    ----------
    extension_mm : tuple of float
        Distal end of each tube beyond the base along the backbone (mm).
    rotation_deg : tuple of float
        Rotation of each tube's pin vise about the insertion axis (deg).
    """

    extension_mm: tuple
    rotation_deg: tuple

    def __post_init__(self):
        ext = tuple(float(e) for e in self.extension_mm)
        rot = tuple(float(r) for r in self.rotation_deg)
        if len(ext) != len(rot):
            raise ValueError(f"joints: {len(ext)} extensions but {len(rot)} rotations")
        object.__setattr__(self, "extension_mm", ext)
        object.__setattr__(self, "rotation_deg", rot)

    def check(self, robot: Robot) -> None:
        """Raise ``ValueError`` if these joints do not fit ``robot``."""
        if len(self.extension_mm) != robot.n_tubes:
            raise ValueError(f"joints: {len(self.extension_mm)} values for a robot of {robot.n_tubes} tubes")
        for tube, e in zip(robot.tubes, self.extension_mm):
            if e < 0 or e > tube.length_mm:
                raise ValueError(f"joints: extension of tube {tube.name!r} must be in [0, {tube.length_mm}] mm, got {e}")


@dataclass(frozen=True, eq=False)
class Backbone:
    """A robot backbone sampled along its arc length.

    Attributes
    ----------
    s_mm : (n,) array
        Arc length from the base (mm), increasing, spacing <= 0.1 mm.
    p_world_mm : (n, 3) array
        Backbone positions in the world frame (mm).
    R_world_body : (n, 3, 3) array
        Body frames (columns x, y, z; z is the tangent) in the world frame.
    outer_radius_mm : (n,) array
        Radius of the outermost tube at each sample (mm).
    outermost_tube : (n,) int array
        Index (into ``Robot.tubes``) of the outermost tube at each sample.
    """

    s_mm: np.ndarray
    p_world_mm: np.ndarray
    R_world_body: np.ndarray
    outer_radius_mm: np.ndarray
    outermost_tube: np.ndarray

    @property
    def tip_world_mm(self) -> np.ndarray:
        return self.p_world_mm[-1]

    @property
    def length_mm(self) -> float:
        return float(self.s_mm[-1] - self.s_mm[0])
