"""Actuators without hardware: the twin's motors and the replay of a recorded session.

* :class:`TwinActuator` -- the two joints of the inner tube driven like the
  firmware drives them: a trapezoidal velocity profile per joint (maximum
  velocity and acceleration), then a settling time before the joint reports
  settled; soft limits; homing required before moves (as the firmware's
  ``NOTHOMED``).  Time is wall-clock time multiplied by ``time_scale`` (10 runs
  the motions ten times faster), so tests stay fast and still exercise waiting.
* :class:`ReplayActuator` -- reports the joints recorded with the frame a
  :class:`~rig.hw.camera.ReplayWorld` delivers next; moves are checked against the
  soft limits and otherwise ignored (the recording moved as it did).

Both implement :class:`rig.hw.actuator.Actuator`, so experiment code cannot tell
them from :class:`rig.hw.arduino.ArduinoActuator`.
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

from rig.hw.actuator import JOINTS, Actuator, ActuatorError, JointValues, SoftLimits

__all__ = ["TwinActuator", "ReplayActuator", "Trapezoid"]


@dataclass(frozen=True)
class Trapezoid:
    """Position along a trapezoidal (or triangular) velocity profile from rest to rest."""

    t0: float
    p0: float
    p1: float
    v_max: float
    a_max: float

    @property
    def _shape(self) -> tuple:
        d = abs(self.p1 - self.p0)
        if d == 0:
            return 0.0, 0.0, 0.0
        if d <= self.v_max**2 / self.a_max:          # triangular: never reaches v_max
            ta = math.sqrt(d / self.a_max)
            return ta, 0.0, self.a_max * ta
        ta = self.v_max / self.a_max
        return ta, (d - self.v_max * ta) / self.v_max, self.v_max

    @property
    def duration(self) -> float:
        ta, tc, _ = self._shape
        return 2 * ta + tc

    def at(self, t: float) -> float:
        ta, tc, vp = self._shape
        tau = t - self.t0
        sign = 1.0 if self.p1 >= self.p0 else -1.0
        if tau <= 0:
            return self.p0
        if tau >= 2 * ta + tc:
            return self.p1
        a = self.a_max
        if tau < ta:
            s = 0.5 * a * tau**2
        elif tau < ta + tc:
            s = 0.5 * a * ta**2 + vp * (tau - ta)
        else:
            r = 2 * ta + tc - tau
            s = abs(self.p1 - self.p0) - 0.5 * a * r**2
        return self.p0 + sign * s


class TwinActuator(Actuator):
    """Simulated motors of the inner tube (see the module docstring).

    Parameters
    ----------
    limits : SoftLimits
    max_velocity, acceleration : JointValues
        Per joint (mm/s, deg/s; mm/s^2, deg/s^2). Defaults: the firmware's
        profile (15 mm/s, 195 mm/s^2; 180 deg/s, 1750 deg/s^2).
    settle_s : float
        Time after a profile ends before the joint reports settled (the PID's
        settling; simulated seconds).
    time_scale : float
        Simulated seconds per wall-clock second (> 0).
    start : JointValues
        Physical joint positions at power-up (insertion from the home switch).
    require_home : bool
        Refuse moves before :meth:`home` (as the firmware does).
    """

    name = "twin"

    def __init__(self, limits: SoftLimits | None = None, *, max_velocity: JointValues = JointValues(15.0, 180.0),
                 acceleration: JointValues = JointValues(195.0, 1750.0), settle_s: float = 0.03,
                 time_scale: float = 1.0, start: JointValues = JointValues(0.0, 0.0), require_home: bool = True):
        super().__init__(limits)
        for what, jv in (("max_velocity", max_velocity), ("acceleration", acceleration)):
            for j in JOINTS:
                if not getattr(jv, j) > 0:
                    raise ValueError(f"twin actuator: {what}.{j} must be > 0, got {getattr(jv, j)}")
        if not settle_s >= 0:
            raise ValueError(f"twin actuator: settle_s must be >= 0, got {settle_s}")
        if not time_scale > 0:
            raise ValueError(f"twin actuator: time_scale must be > 0, got {time_scale}")
        self.max_velocity = max_velocity
        self.acceleration = acceleration
        self.settle_s = float(settle_s)
        self.time_scale = float(time_scale)
        self.require_home = require_home
        self.homed = not require_home
        self._lock = threading.Lock()
        self._stop_evt = threading.Event()
        self._m0 = time.monotonic()
        self._zero_rotation = 0.0          # the rotation has no index: homing makes the current angle 0
        self._profiles = {j: Trapezoid(0.0, getattr(start, j), getattr(start, j), 1.0, 1.0) for j in JOINTS}
        self._closed = False

    # -- time -----------------------------------------------------------------
    def sim_time(self) -> float:
        return (time.monotonic() - self._m0) * self.time_scale

    # -- state -----------------------------------------------------------------
    def true_position(self) -> JointValues:
        """Physical joints (insertion from the home switch, rotation from the power-up angle)."""
        t = self.sim_time()
        with self._lock:
            return JointValues(*(self._profiles[j].at(t) for j in JOINTS))

    def position(self) -> JointValues:
        self._check_open()
        p = self.true_position()
        return JointValues(p.insertion_mm, p.rotation_deg - self._zero_rotation)

    def _settled_at(self) -> float:
        with self._lock:
            return max(p.t0 + p.duration for p in self._profiles.values()) + self.settle_s

    def _start(self, physical: JointValues) -> None:
        t = self.sim_time()
        with self._lock:
            cur = {j: self._profiles[j].at(t) for j in JOINTS}
            self._profiles = {
                j: Trapezoid(t, cur[j], getattr(physical, j), getattr(self.max_velocity, j), getattr(self.acceleration, j))
                for j in JOINTS
            }

    def _check_open(self) -> None:
        if self._closed:
            raise ActuatorError("twin actuator: closed")

    # -- Actuator ----------------------------------------------------------------
    def home(self, timeout_s: float = 30.0) -> None:
        self._check_open()
        self._stop_evt.clear()
        p = self.true_position()
        self._zero_rotation = p.rotation_deg
        self._last_target = None
        self._start(JointValues(0.0, p.rotation_deg))
        self._last_target = JointValues(0.0, 0.0)
        try:
            self.wait_settled(timeout_s)
        except TimeoutError:
            raise TimeoutError(f"twin actuator: HOME: joint insertion_mm did not reach its home switch "
                               f"within {timeout_s:.1f}s") from None
        self.homed = True

    def _send_move(self, target: JointValues) -> None:
        self._check_open()
        if not self.homed:
            raise ActuatorError("twin actuator: MOV refused: not homed (home first)")
        self._stop_evt.clear()
        self._start(JointValues(target.insertion_mm, target.rotation_deg + self._zero_rotation))

    def wait_settled(self, timeout_s: float = 10.0) -> JointValues:
        self._check_open()
        target = self._last_target
        if target is None:
            raise ActuatorError("twin actuator: wait_settled: no target (call move_to or home first)")
        deadline = time.monotonic() + timeout_s
        while True:
            remaining_sim = self._settled_at() - self.sim_time()
            if remaining_sim <= 0:
                return self.position()
            wall = remaining_sim / self.time_scale
            now = time.monotonic()
            if now + wall > deadline:
                self._stop_evt.wait(max(0.0, deadline - now))
                pos = self.position()
                bad = [f"{j} at {getattr(pos, j):.3f} (target {getattr(target, j):.3f})" for j in JOINTS
                       if abs(getattr(pos, j) - getattr(target, j)) > 1e-9]
                raise TimeoutError(f"twin actuator: wait_settled: joint {', '.join(bad) or 'motion'} "
                                   f"not settled within {timeout_s:.1f}s")
            if self._stop_evt.wait(wall):
                raise ActuatorError("twin actuator: wait_settled: motors stopped")

    def stop(self) -> None:
        if self._closed:
            return
        p = self.true_position()
        with self._lock:
            self._profiles = {j: Trapezoid(0.0, getattr(p, j), getattr(p, j), 1.0, 1.0) for j in JOINTS}
        self._last_target = None
        self._stop_evt.set()

    def close(self) -> None:
        self._closed = True
        self._stop_evt.set()

    def __repr__(self) -> str:
        return f"TwinActuator(time_scale={self.time_scale:g})"


class ReplayActuator(Actuator):
    """Reports the joints recorded in a session, in step with the replay cameras.

    Parameters
    ----------
    world : rig.hw.camera.ReplayWorld
    joint_map : rig.hw.rigfile.JointMap
        Converts the recorded per-tube joints back to insertion / rotation.
    limits : SoftLimits
    """

    name = "replay"

    def __init__(self, world, joint_map, limits: SoftLimits | None = None):
        super().__init__(limits)
        self.world = world
        self.joint_map = joint_map

    def position(self) -> JointValues:
        frames = self.world.session.frames
        if not frames:
            return self._last_target or JointValues(0.0, 0.0)
        rec = frames[min(self.world.next_frame, len(frames) - 1)]
        if rec.extension_mm is None:
            return self._last_target or JointValues(0.0, 0.0)
        return self.joint_map.from_joints(rec.extension_mm, rec.rotation_deg)

    def home(self, timeout_s: float = 30.0) -> None:
        self._last_target = JointValues(0.0, 0.0)

    def _send_move(self, target: JointValues) -> None:
        pass

    def wait_settled(self, timeout_s: float = 10.0) -> JointValues:
        return self.position()

    def stop(self) -> None:
        self._last_target = None

    def close(self) -> None:
        pass
