"""Actuator interface of the CTR rig (the joints of the inner tube).

The paper actuates only the inner tube, with two joints:

* ``insertion_mm`` -- translation of the inner tube along the robot axis (mm)
* ``rotation_deg`` -- axial rotation of the inner tube (degrees)

:class:`Actuator` is the abstract interface the rest of the code base uses;
:class:`rig.hw.arduino.ArduinoActuator` implements it for the Arduino Uno
firmware in ``rig/hw/firmware``.  Every implementation checks targets against
its :class:`SoftLimits` *before* anything is sent to the hardware.

Typical use::

    limits = SoftLimits.from_dict(rig_toml["actuator"]["limits"])
    with ArduinoActuator("/dev/ttyACM0", limits) as act:
        act.home()
        act.move_to({"insertion_mm": 20.0, "rotation_deg": 90.0})
        act.wait_settled(timeout_s=5.0)
        print(act.position())
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass, fields
from typing import Any, Mapping, Union

__all__ = [
    "JOINTS",
    "JointValues",
    "JointTargets",
    "SoftLimits",
    "Actuator",
    "ActuatorError",
    "ActuatorResetError",
    "LinkError",
    "FirmwareError",
]

#: joint names, in wire order
JOINTS: tuple[str, ...] = ("insertion_mm", "rotation_deg")


class ActuatorError(RuntimeError):
    """Base class of the actuator errors (other than ValueError / TimeoutError)."""


class LinkError(ActuatorError, ConnectionError):
    """The link to the controller is broken (port closed, unplugged, I/O error)."""


class ActuatorResetError(ActuatorError):
    """The controller rebooted (power loss, reset, watchdog): motion was lost,
    the motors are stopped and the joints must be homed again."""


class FirmwareError(ActuatorError):
    """The controller refused a command (``ERR`` reply)."""

    def __init__(self, message: str, code: int = 0, name: str = ""):
        super().__init__(message)
        self.code = code
        self.name = name


@dataclass(frozen=True)
class JointValues:
    """One value per joint: a position, a target or a tolerance."""

    insertion_mm: float
    rotation_deg: float

    def as_dict(self) -> dict[str, float]:
        return {"insertion_mm": self.insertion_mm, "rotation_deg": self.rotation_deg}

    def __iter__(self):
        return iter((self.insertion_mm, self.rotation_deg))

    @classmethod
    def coerce(cls, value: "TargetsLike", base: "JointValues | None" = None) -> "JointValues":
        """Build from a JointValues or a mapping; joints missing from a mapping
        are taken from ``base`` (ValueError if there is none).  Unknown keys
        and non-finite numbers raise ValueError naming the key."""
        if isinstance(value, JointValues):
            out = value.as_dict()
        elif isinstance(value, Mapping):
            unknown = sorted(set(value) - set(JOINTS))
            if unknown:
                raise ValueError(f"unknown joint {unknown[0]!r} (joints are {', '.join(JOINTS)})")
            out = {}
            for j in JOINTS:
                if j in value:
                    out[j] = value[j]
                elif base is not None:
                    out[j] = getattr(base, j)
                else:
                    raise ValueError(f"missing joint {j!r}")
        else:
            raise TypeError(f"targets must be a mapping or JointValues, got {type(value).__name__}")
        clean = {}
        for j in JOINTS:
            v = out[j]
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ValueError(f"{j}: expected a number, got {v!r}")
            v = float(v)
            if not math.isfinite(v):
                raise ValueError(f"{j}: expected a finite number, got {v!r}")
            clean[j] = v
        return cls(**clean)


#: targets are given as JointValues (or its alias JointTargets) or a mapping
JointTargets = JointValues
TargetsLike = Union[JointValues, Mapping[str, float]]


@dataclass(frozen=True)
class SoftLimits:
    """Allowed range ``(min, max)`` of each joint, in joint units.

    Loaded from the rig TOML, e.g.::

        [actuator.limits]
        insertion_mm = { min = 0.0, max = 90.0 }
        rotation_deg = [-180.0, 180.0]
    """

    insertion_mm: tuple[float, float] = (0.0, 100.0)
    rotation_deg: tuple[float, float] = (-360.0, 360.0)

    def __post_init__(self):
        for f in fields(self):
            lo, hi = getattr(self, f.name)
            if not (math.isfinite(lo) and math.isfinite(hi)):
                raise ValueError(f"soft limits: {f.name} must be finite, got ({lo}, {hi})")
            if lo >= hi:
                raise ValueError(f"soft limits: {f.name}.min ({lo}) must be < {f.name}.max ({hi})")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], *, prefix: str = "") -> "SoftLimits":
        """Parse a TOML table.  Each joint is ``{min = .., max = ..}`` or
        ``[min, max]``; a missing joint keeps the default range.  Errors are
        ValueErrors naming the offending key (``prefix`` is prepended, e.g.
        ``"actuator.limits."``)."""
        if not isinstance(d, Mapping):
            raise ValueError(f"{prefix or 'soft limits'}: expected a table, got {type(d).__name__}")
        unknown = sorted(set(d) - set(JOINTS))
        if unknown:
            raise ValueError(f"{prefix}{unknown[0]}: unknown joint (joints are {', '.join(JOINTS)})")
        kw: dict[str, tuple[float, float]] = {}
        for j in JOINTS:
            if j not in d:
                continue
            v = d[j]
            if isinstance(v, Mapping):
                extra = sorted(set(v) - {"min", "max"})
                if extra:
                    raise ValueError(f"{prefix}{j}.{extra[0]}: unknown key (expected min, max)")
                for k in ("min", "max"):
                    if k not in v:
                        raise ValueError(f"{prefix}{j}.{k}: missing")
                pair = (v["min"], v["max"])
            elif isinstance(v, (list, tuple)):
                if len(v) != 2:
                    raise ValueError(f"{prefix}{j}: expected [min, max], got {len(v)} values")
                pair = (v[0], v[1])
            else:
                raise ValueError(f"{prefix}{j}: expected {{min, max}} or [min, max], got {v!r}")
            out = []
            for k, x in zip(("min", "max"), pair):
                if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
                    raise ValueError(f"{prefix}{j}.{k}: expected a finite number, got {x!r}")
                out.append(float(x))
            if out[0] >= out[1]:
                raise ValueError(f"{prefix}{j}: min ({out[0]}) must be < max ({out[1]})")
            kw[j] = (out[0], out[1])
        return cls(**kw)

    def to_dict(self) -> dict[str, dict[str, float]]:
        return {j: {"min": getattr(self, j)[0], "max": getattr(self, j)[1]} for j in JOINTS}

    def check(self, targets: JointValues) -> None:
        """Raise ValueError naming the joint if a target is out of range."""
        for j in JOINTS:
            lo, hi = getattr(self, j)
            v = getattr(targets, j)
            if not lo <= v <= hi:
                raise ValueError(f"{j}={v:g} is outside the soft limits [{lo:g}, {hi:g}]")


class Actuator(abc.ABC):
    """Abstract actuator of the inner tube.

    Subclasses implement the ``_send_move`` hook and the abstract methods.
    :meth:`move_to` validates the targets (joint names, numbers, soft limits)
    before calling ``_send_move``; nothing reaches the hardware otherwise.
    Use as a context manager: leaving the block stops the motors and closes
    the connection.
    """

    def __init__(self, limits: SoftLimits | None = None):
        self.limits = limits if limits is not None else SoftLimits()
        self._last_target: JointValues | None = None

    # -- motion ---------------------------------------------------------
    @abc.abstractmethod
    def home(self, timeout_s: float = 30.0) -> None:
        """Find the joint zeros; blocks until done (TimeoutError naming the joint)."""

    def move_to(self, targets: TargetsLike, *, wait: bool = False,
                timeout_s: float = 10.0) -> JointValues:
        """Start a move to ``targets`` (a JointValues or a mapping; joints left
        out of a mapping keep their last target or current position).
        Raises ValueError -- before anything is sent -- if a target is outside
        the soft limits.  With ``wait=True`` also :meth:`wait_settled`.
        Returns the full target that was commanded."""
        base = self._last_target
        if base is None and not (isinstance(targets, JointValues)
                                 or (isinstance(targets, Mapping) and set(JOINTS) <= set(targets))):
            base = self.position()
        t = JointValues.coerce(targets, base)
        self.limits.check(t)
        self._send_move(t)
        self._last_target = t
        if wait:
            self.wait_settled(timeout_s)
        return t

    @abc.abstractmethod
    def _send_move(self, target: JointValues) -> None:
        """Send an already validated target to the hardware."""

    @abc.abstractmethod
    def position(self) -> JointValues:
        """Measured joint positions."""

    @abc.abstractmethod
    def wait_settled(self, timeout_s: float = 10.0) -> JointValues:
        """Block until every joint is at its target (within tolerance) and
        at rest; returns the position.  TimeoutError names the joints that
        did not settle."""

    @abc.abstractmethod
    def stop(self) -> None:
        """Stop both motors now (the target is dropped)."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the hardware (idempotent)."""

    @property
    def target(self) -> JointValues | None:
        """Last commanded target (None before the first move or after a reset)."""
        return self._last_target

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        try:
            self.stop()
        except Exception:
            if exc_type is None:
                raise
        finally:
            self.close()
        return False
