"""Rig files: which cameras and which actuator an experiment runs on.

An experiment (``rig/hw/experiment.py``) is written against :class:`rig.hw.camera.CameraPair`
and :class:`rig.hw.actuator.Actuator` only; the rig file alone decides what is behind
them -- the digital twin, the Arduino (real or emulated) or a recorded session.
The format is documented key by key in ``docs/rig-file.md``; examples are
``scenes/rig-twin.toml``, ``scenes/rig-twin-arduino.toml`` and ``scenes/rig-lab.toml``.

Validation is strict, as for scene files (the same ``Table`` helper): unknown
keys are errors, and every error names the file and the key, e.g.
``scenes/rig-lab.toml: cameras.side.source: missing (required)``.

Typical use::

    spec = load_rig_file("scenes/rig-twin.toml")
    with spec.open() as rig:            # a Rig: cameras, actuator, calibration
        rig.actuator.home()
        pair = rig.cameras.grab()
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from recon.rigcal import load_rig_calibration
from rig.hw.actuator import JOINTS, Actuator, JointValues, SoftLimits
from rig.hw.arduino import ArduinoActuator
from rig.hw.camera import CameraPair, OpenCVCamera, ReplayCamera, ReplayWorld, TwinCameraPair, TwinWorld
from rig.hw.virtual import ReplayActuator, TwinActuator
from twin.robot import Joints
from twin.robotfile import robot_to_dict
from twin.scene import load_scene
from twin.schema import POSITIVE, REQUIRED, SceneError, Table, read_toml

__all__ = ["RigFileError", "JointMap", "RigFile", "Rig", "load_rig_file", "rig_file_from_dict",
           "CAMERA_KINDS", "ACTUATOR_KINDS"]

FORMAT = "ctr-bench-rig"
CAMERA_KINDS = ("twin", "opencv", "replay")
ACTUATOR_KINDS = ("twin", "arduino", "replay")


class RigFileError(ValueError):
    """A rig file that cannot be used; the message names the file and the key."""


# ----------------------------------------------------------------------------- joint map
@dataclass(frozen=True)
class JointMap:
    """Actuator joints (insertion / rotation of one tube) <-> per-tube joints of the robot.

    At ``insertion_mm = 0, rotation_deg = 0`` (the actuator's home) the robot's
    joints are ``home_extension_mm`` / ``home_rotation_deg`` (one per tube,
    outermost first); the actuator adds its insertion to the extension and its
    rotation to the rotation of tube ``actuated_tube``; the other tubes stay put.
    """

    home_extension_mm: tuple
    home_rotation_deg: tuple
    actuated_tube: int

    @property
    def n_tubes(self) -> int:
        return len(self.home_extension_mm)

    def to_joints(self, jv: JointValues):
        """Per-tube :class:`twin.robot.Joints` for actuator joints ``jv``."""
        ext = list(self.home_extension_mm)
        rot = list(self.home_rotation_deg)
        ext[self.actuated_tube] += jv.insertion_mm
        rot[self.actuated_tube] += jv.rotation_deg
        return Joints(extension_mm=tuple(ext), rotation_deg=tuple(rot))

    def from_joints(self, extension_mm, rotation_deg) -> JointValues:
        """Actuator joints for per-tube joints (e.g. a recorded frames.csv row)."""
        i = self.actuated_tube
        return JointValues(float(extension_mm[i]) - self.home_extension_mm[i],
                           float(rotation_deg[i]) - self.home_rotation_deg[i])


# ----------------------------------------------------------------------------- parsed file
@dataclass(frozen=True, eq=False)
class RigFile:
    """A validated rig file; nothing is opened until :meth:`open`.

    Attributes
    ----------
    source : str
        The file (for messages).
    name : str
    scene : twin.scene.Scene or None
        The twin scene (twin cameras; optional otherwise: its robot goes into session.json).
    calibration_path : Path or None
        Rig calibration JSON (``rig.json`` format); None: the scene's nominal rig
        (twin) or the recorded session's (replay).
    joint_map : JointMap
    cameras : dict
        ``kind``, ``timeout_s`` and backend options (``per_camera`` for opencv,
        ``session`` for replay).
    actuator : dict
        ``kind``, ``limits`` (SoftLimits) and backend options.
    """

    source: str
    name: str
    scene: object
    calibration_path: Path | None
    joint_map: JointMap
    cameras: dict
    actuator: dict = field(default_factory=dict)

    @property
    def limits(self) -> SoftLimits:
        return self.actuator["limits"]

    @property
    def n_tubes(self) -> int:
        return self.joint_map.n_tubes

    def _fail(self, key: str, why: str):
        raise RigFileError(f"{self.source}: {key}: {why}")

    def load_calibration(self, replay_world=None):
        """The RigCalibration experiments record (and reconstruct with)."""
        if self.calibration_path is not None:
            try:
                cal = load_rig_calibration(self.calibration_path)
            except FileNotFoundError:
                self._fail("calibration", f"{self.calibration_path} not found")
            except (ValueError, KeyError, OSError) as exc:
                self._fail("calibration", f"{self.calibration_path}: {str(exc).splitlines()[0] if str(exc) else exc}")
        elif self.cameras["kind"] == "replay" and replay_world is not None:
            cal = replay_world.session.rig
        elif self.scene is not None:
            cal = self.scene.rig
        else:
            self._fail("calibration", "missing (required for opencv cameras)")
        names = self.camera_names(cal)
        if sorted(names) != sorted(cal.names):
            self._fail("calibration", f"{self.calibration_path or 'calibration'} has cameras {', '.join(cal.names)}, "
                                      f"the rig has {', '.join(names)}")
        return cal

    def camera_names(self, cal=None) -> list:
        kind = self.cameras["kind"]
        if kind == "opencv":
            return list(self.cameras["per_camera"])
        if kind == "twin":
            return list(self.scene.rig.names)
        return list(cal.names) if cal is not None else []

    def open(self, serial: str | None = None) -> "Rig":
        """Open the actuator and the cameras (serial: override ``actuator.port``)."""
        return Rig(self, serial=serial)


class Rig:
    """An opened rig: ``cameras`` (CameraPair), ``actuator`` (Actuator), ``calibration``.

    Use as a context manager: leaving the block stops the actuator and closes
    everything, also after an exception or Ctrl-C.
    """

    def __init__(self, spec: RigFile, serial: str | None = None):
        self.spec = spec
        self.joint_map = spec.joint_map
        self.n_tubes = spec.n_tubes
        cams = spec.cameras
        act = spec.actuator
        if serial is not None and act["kind"] != "arduino":
            raise RigFileError(f"{spec.source}: actuator.kind: --serial given, but the actuator is {act['kind']!r}, "
                               f"not 'arduino'")
        self.replay_world = None
        self.world = None
        if cams["kind"] == "replay":
            try:
                self.replay_world = ReplayWorld(cams["session"])
            except ValueError as exc:
                raise RigFileError(f"{spec.source}: cameras.session: {exc}") from None
            if self.replay_world.session.n_tubes != spec.n_tubes:
                raise RigFileError(f"{spec.source}: joints.home_extension_mm: {spec.n_tubes} tubes, but "
                                   f"{cams['session']} records {self.replay_world.session.n_tubes}")
        self.calibration = spec.load_calibration(self.replay_world)
        # ---- actuator (opened first: the twin cameras read its joints)
        self.actuator: Actuator = self._make_actuator(serial)
        try:
            if cams["kind"] == "twin":
                self.world = TwinWorld(spec.scene, spec.joint_map)
                self.world.joint_source = getattr(self.actuator, "true_position", self.actuator.position)
                self.cameras = TwinCameraPair(self.world, cams["timeout_s"], names=self.calibration.names)
            elif cams["kind"] == "opencv":
                self.cameras = CameraPair(
                    [OpenCVCamera(n, timeout_s=cams["timeout_s"], **o) for n, o in cams["per_camera"].items()],
                    cams["timeout_s"])
            else:
                self.cameras = CameraPair([ReplayCamera(n, self.replay_world, cams["timeout_s"])
                                           for n in self.calibration.names], cams["timeout_s"])
            self.cameras.open()
        except BaseException:
            self.actuator.close()
            raise

    def _make_actuator(self, serial):
        spec, a = self.spec, self.spec.actuator
        kind = a["kind"]
        if kind == "twin":
            return TwinActuator(a["limits"], max_velocity=a["max_velocity"], acceleration=a["acceleration"],
                                settle_s=a["settle_s"], time_scale=a["time_scale"], start=a["start"])
        if kind == "replay":
            if self.replay_world is None:
                raise RigFileError(f"{spec.source}: actuator.kind: 'replay' needs cameras.kind = 'replay'")
            return ReplayActuator(self.replay_world, spec.joint_map, a["limits"])

        port = serial or a.get("port")
        if not port:
            raise RigFileError(f"{spec.source}: actuator.port: missing (required unless --serial URL is given)")
        return ArduinoActuator(port, a["limits"], baudrate=a["baudrate"], command_timeout_s=a["command_timeout_s"],
                               ready_timeout_s=a["ready_timeout_s"], tolerance=a["tolerance"])

    @property
    def source(self) -> str:
        """``"twin"`` when the images are rendered, else ``"rig"`` (session.json ``source``)."""
        if self.spec.cameras["kind"] == "twin":
            return "twin"
        if self.replay_world is not None:
            return self.replay_world.session.meta.get("source", "rig")
        return "rig"

    @property
    def joints_unobserved(self) -> str | None:
        """Why the actuator's joints do not describe the recorded images, or None when they do.

        Joints go into frames.csv only when the actuator moves what the cameras see:
        twin cameras render the actuator's joints, replay cameras come with the joints
        recorded with their frames, live cameras watch the arduino's robot. Video files
        (recorded beforehand) or a simulated actuator next to real images would put
        invented joints into the session, which verify and fit would then trust.
        """
        cams, act = self.spec.cameras["kind"], self.spec.actuator["kind"]
        if cams == "twin":
            return None
        if cams == "replay":
            if act != "replay":
                return f"replayed images with the {act} actuator, which does not move them"
            if any(f.extension_mm is None for f in self.replay_world.session.frames):
                return "the replayed session records no joint values for some frames"
            return None
        files = [n for n, c in self.cameras.cameras.items() if getattr(c, "kind", None) == "file"]
        if files:
            return f"camera(s) {', '.join(files)} play video files recorded beforehand"
        if act == "twin":
            return "live cameras with the twin (simulated) actuator, which moves no robot they see"
        return None

    def meta(self) -> dict:
        """Facts for session.json: the rig file, the backends and (with a scene) the robot."""
        s = self.spec
        out = {
            "rig_file": s.source,
            "rig_name": s.name,
            "camera_backend": s.cameras["kind"],
            "camera_sources": self.cameras.describe(),
            "actuator_backend": s.actuator["kind"],
            "actuator": repr(self.actuator),
            "soft_limits": s.limits.to_dict(),
            "joint_map": {"home_extension_mm": list(s.joint_map.home_extension_mm),
                          "home_rotation_deg": list(s.joint_map.home_rotation_deg),
                          "actuated_tube": s.joint_map.actuated_tube},
        }
        if s.calibration_path is not None:
            out["calibration_file"] = str(s.calibration_path)
        if self.joints_unobserved is not None:
            out["joints_not_recorded"] = self.joints_unobserved
        if s.scene is not None:
            out.update(scene=s.scene.source, scene_name=s.scene.name, robot=robot_to_dict(s.scene.robot, s.scene.model))
        elif self.replay_world is not None and "robot" in self.replay_world.session.meta:
            out["robot"] = self.replay_world.session.meta["robot"]
        return out

    def close(self) -> None:
        try:
            try:
                self.actuator.stop()
            finally:
                self.actuator.close()
        finally:
            self.cameras.close()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc):
        try:
            self.close()
        except Exception:
            if exc_type is None:
                raise
        return False


# ----------------------------------------------------------------------------- parsing
def _joint_values(t: Table, key: str, default: JointValues, check=None, why=None) -> JointValues:
    """``{insertion_mm = .., rotation_deg = ..}``; a missing joint keeps its default."""
    sub = t.table(key)
    vals = {j: sub.get(j, getattr(default, j), float, check, why) for j in JOINTS}
    sub.done()
    return JointValues(**vals)


def _parse_joints(j: Table, scene) -> JointMap:
    if not j.data and scene is None:
        j.fail("home_extension_mm", "missing (required: the [joints] table, unless a scene gives the default)")
    default_ext = list(scene.joints[0].extension_mm) if scene is not None else REQUIRED
    default_rot = list(scene.joints[0].rotation_deg) if scene is not None else None
    ext = j.get("home_extension_mm", default_ext, ("vec", None), lambda v: len(v) >= 1 and min(v) >= 0,
                "must be a non-empty list of extensions >= 0")
    n = len(ext)
    rot = j.get("home_rotation_deg", default_rot if default_rot is not None else [0.0] * n, ("vec", n))
    tube = j.get("actuated_tube", n - 1, int, lambda v: 0 <= v < n, f"must be a tube index in [0, {n - 1}]")
    if scene is not None and n != scene.robot.n_tubes:
        j.fail("home_extension_mm", f"{n} values, but the scene's robot has {scene.robot.n_tubes} tubes")
    j.done()
    return JointMap(tuple(float(v) for v in ext), tuple(float(v) for v in rot), tube)


def _parse_cameras(c: Table, base: Path, has_scene: bool) -> dict:
    kind = c.get("kind", REQUIRED, str, lambda v: v in CAMERA_KINDS, f"must be one of {', '.join(CAMERA_KINDS)}")
    default_timeout = 30.0 if kind == "twin" else 5.0
    out = {"kind": kind, "timeout_s": c.get("timeout_s", default_timeout, float, *POSITIVE)}
    if kind == "twin":
        if not has_scene:
            c.fail("kind", "twin cameras need the top-level 'scene' key (the scene file to render)")
    elif kind == "replay":
        out["session"] = str(base / c.get("session", REQUIRED, str))
    else:
        per = {}
        for name, value in c.data.items():
            if name in ("kind", "timeout_s"):
                continue
            if not isinstance(value, dict):
                c.fail(name, "unknown key (per-camera settings are tables: [cameras.<name>])")
            t = c.table(name)
            src = t.get("source", REQUIRED)
            if isinstance(src, bool) or not isinstance(src, (int, str)) or (isinstance(src, str) and not src.strip()):
                t.fail("source", f"must be a device index, a device path, a video file or a GStreamer pipeline, got {src!r}")
            if isinstance(src, str) and "!" not in src and not src.strip().isdigit() and not src.startswith("/dev/"):
                src = str(base / src)      # a video file, relative to the rig file
            if isinstance(src, int) and src < 0:
                t.fail("source", f"device index must be >= 0, got {src}")
            opts = {
                "source": src,
                "width": t.get("width", None, int, lambda v: v > 0, "must be > 0"),
                "height": t.get("height", None, int, lambda v: v > 0, "must be > 0"),
                "fps": t.get("fps", None, float, *POSITIVE),
                "discard": t.get("discard", 0, int, lambda v: 0 <= v <= 100, "must be in [0, 100]"),
                "loop": t.get("loop", False, bool),
            }
            t.done()
            per[name] = opts
        if len(per) < 2:
            c.fail("kind", f"opencv cameras need one [cameras.<name>] table per camera (e.g. side, top), found "
                           f"{', '.join(per) or 'none'}")
        out["per_camera"] = per
    c.done()
    return out


def _parse_actuator(a: Table, source: str) -> dict:
    kind = a.get("kind", REQUIRED, str, lambda v: v in ACTUATOR_KINDS, f"must be one of {', '.join(ACTUATOR_KINDS)}")
    lim = a.table("limits")
    try:
        limits = SoftLimits.from_dict(lim.data, prefix="actuator.limits.")
    except ValueError as exc:
        raise RigFileError(f"{source}: {exc}") from None
    out = {"kind": kind, "limits": limits}
    if kind == "twin":
        out["max_velocity"] = _joint_values(a, "max_velocity", JointValues(15.0, 180.0), *POSITIVE)
        out["acceleration"] = _joint_values(a, "acceleration", JointValues(195.0, 1750.0), *POSITIVE)
        out["settle_s"] = a.get("settle_s", 0.03, float, lambda v: v >= 0, "must be >= 0")
        out["time_scale"] = a.get("time_scale", 1.0, float, *POSITIVE)
        out["start"] = _joint_values(a, "start", JointValues(0.0, 0.0))
    elif kind == "arduino":
        port = a.get("port", None, str)
        out["port"] = port
        out["baudrate"] = a.get("baudrate", 115200, int, lambda v: v > 0, "must be > 0")
        out["command_timeout_s"] = a.get("command_timeout_s", 0.25, float, *POSITIVE)
        out["ready_timeout_s"] = a.get("ready_timeout_s", 3.0, float, *POSITIVE)
        out["tolerance"] = _joint_values(a, "tolerance", JointValues(0.05, 0.5), *POSITIVE)
    a.done()
    return out


def _check_travel(top: Table, jm: JointMap, limits: SoftLimits, scene, source: str) -> None:
    """Soft limits that would take a tube outside its length (twin scenes) are errors."""
    if scene is None:
        return
    tube = scene.robot.tubes[jm.actuated_tube]
    home = jm.home_extension_mm[jm.actuated_tube]
    lo, hi = limits.insertion_mm
    if home + lo < 0 or home + hi > tube.length_mm:
        raise RigFileError(
            f"{source}: actuator.limits.insertion_mm: [{lo:g}, {hi:g}] takes tube {tube.name!r} (extension "
            f"{home:g} mm at home) outside [0, {tube.length_mm:g}] mm")


def rig_file_from_dict(data: dict, source: str = "<rig>", serial: str | None = None) -> RigFile:
    """Validate a parsed TOML document and build a :class:`RigFile`."""
    base = Path(source).resolve().parent if not source.startswith("<") else Path.cwd()
    try:
        top = Table(data, "", source)
        top.get("format", FORMAT, str, lambda v: v == FORMAT, f'must be "{FORMAT}"')
        top.get("version", 1, int, lambda v: v == 1, "must be 1 (the only version this ctr-bench reads)")
        name = top.get("name", Path(source).stem, str)
        scene_rel = top.get("scene", None, str)
        scene = None
        if scene_rel is not None:
            try:
                scene = load_scene(base / scene_rel)
            except SceneError as exc:
                raise RigFileError(f"{source}: scene: {exc}") from None
        cal = top.get("calibration", None, str)
        cal_path = (base / cal) if cal is not None else None
        cameras = _parse_cameras(top.table("cameras", required=True), base, scene is not None)
        actuator = _parse_actuator(top.table("actuator", required=True), source)
        jm = _parse_joints(top.table("joints"), scene)
        if cameras["kind"] == "opencv" and cal_path is None:
            top.fail("calibration", "missing (required with opencv cameras: the rig calibration JSON)")
        if actuator["kind"] == "replay" and cameras["kind"] != "replay":
            raise RigFileError(f"{source}: actuator.kind: 'replay' needs cameras.kind = 'replay'")
        if serial is not None and actuator["kind"] != "arduino":
            raise RigFileError(f"{source}: actuator.kind: --serial given, but the actuator is "
                               f"{actuator['kind']!r}, not 'arduino'")
        if serial is not None:
            actuator["port"] = serial
        _check_travel(top, jm, actuator["limits"], scene, source)
        top.done()
    except SceneError as exc:
        raise RigFileError(str(exc)) from None
    return RigFile(source=source, name=name, scene=scene, calibration_path=cal_path, joint_map=jm,
                   cameras=cameras, actuator=actuator)


def load_rig_file(path, serial: str | None = None) -> RigFile:
    """Load and validate a rig TOML file; every error names the file and the key.

    ``serial`` (``--serial URL``) overrides ``actuator.port`` of an arduino actuator.
    """
    path = Path(path)
    data = read_toml(path, "rig file", RigFileError)
    return rig_file_from_dict(data, source=str(path), serial=serial)
