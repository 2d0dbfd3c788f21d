"""Cameras of the rig: one interface, several backends, and a synchronised pair.

:class:`Camera` is the interface the experiment code uses; the backends are

* :class:`OpenCVCamera` -- ``cv2.VideoCapture`` on a device index, a V4L2 path,
  a video file or a GStreamer pipeline string (the physical rig),
* :class:`TwinCamera` -- renders the digital twin (:mod:`twin.simulator`) at
  the joints the actuator reports at the moment of the exposure,
* :class:`ReplayCamera` -- the frames of a recorded session directory, in order.

A grab has two phases: ``trigger`` latches an exposure (for a live camera: the
frame arrives) and ``retrieve`` produces its image (decode, render, read).
Each camera runs them on its own worker thread, so every call is bounded: a
camera that does not answer within its timeout raises :class:`TimeoutError`
naming the camera (and is then marked hung: later grabs fail at once).
:class:`CameraPair` starts the triggers of both cameras together and reports
their spread as the pair's skew (ms), which ``frames.csv`` records.

Typical use::

    pair = CameraPair([OpenCVCamera("side", 0), OpenCVCamera("top", 1)])
    with pair:
        fp = pair.grab()
        fp.images["side"], fp.skew_ms, fp.frames["top"].timestamp_s
"""
from __future__ import annotations

import abc
import concurrent.futures
import os
import queue
import re
import threading
import time
from concurrent.futures import Future
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from rig.session import Session, read_image
from twin.record import truth_arrays
from twin.simulator import Twin

__all__ = [
    "Frame",
    "FramePair",
    "Camera",
    "CameraPair",
    "CameraError",
    "EndOfStream",
    "OpenCVCamera",
    "TwinWorld",
    "TwinCamera",
    "TwinCameraPair",
    "ReplayWorld",
    "ReplayCamera",
    "to_mono",
]


class CameraError(RuntimeError):
    """A camera that cannot deliver frames; the message names the camera."""


class EndOfStream(CameraError):
    """A finite source (video file, recorded session) has no more frames."""


@dataclass(frozen=True, eq=False)
class Frame:
    """One image from one camera.

    Attributes
    ----------
    image : (H, W) uint8
        Mono image.
    timestamp_s : float
        ``time.monotonic()`` at the exposure (when the trigger returned: a live
        camera's frame had arrived, the twin had latched the joints).
    wall_time_s : float
        ``time.time()`` at the same instant.
    seq : int
        Frames this camera delivered before this one (from 0).
    camera : str
        Camera name.
    """

    image: np.ndarray
    timestamp_s: float
    wall_time_s: float
    seq: int
    camera: str


@dataclass(frozen=True, eq=False)
class FramePair:
    """Frames of all cameras of a :class:`CameraPair`, grabbed together.

    Attributes
    ----------
    frames : dict name -> Frame
    skew_ms : float
        Spread of the cameras' timestamps (ms).
    truth : dict or None
        Twin only: ground-truth arrays (:func:`twin.record.truth_arrays`).
    joints : twin.robot.Joints or None
        Twin only: the joints the robot was rendered at.
    """

    frames: dict
    skew_ms: float
    truth: dict | None = None
    joints: object = None

    @property
    def images(self) -> dict:
        return {name: f.image for name, f in self.frames.items()}

    @property
    def timestamp_s(self) -> float:
        """Mean of the cameras' monotonic timestamps."""
        return float(np.mean([f.timestamp_s for f in self.frames.values()]))

    def times_s(self, t0: float = 0.0) -> dict:
        """Per-camera timestamps relative to ``t0`` (monotonic s)."""
        return {name: f.timestamp_s - t0 for name, f in self.frames.items()}


def to_mono(image: np.ndarray, order: str = "bgr", who: str = "camera") -> np.ndarray:
    """(H, W) uint8 from a mono, BGR(A) or RGB(A) uint8 image."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        raise CameraError(f"{who}: {img.dtype} frames are not supported (configure the source for 8-bit mono)")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 2:
        return np.ascontiguousarray(img)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        if order == "rgb":
            code = cv2.COLOR_RGB2GRAY if img.shape[2] == 3 else cv2.COLOR_RGBA2GRAY
        else:
            code = cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        return cv2.cvtColor(img, code)
    raise CameraError(f"{who}: unexpected frame shape {img.shape}")


# ----------------------------------------------------------------------------- worker thread
class _Worker:
    """One daemon thread running submitted calls in order (a hung call cannot block exit)."""

    def __init__(self, name: str):
        self._q: queue.Queue = queue.Queue()
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def _loop(self):
        while True:
            item = self._q.get()
            if item is None:
                return
            fn, fut = item
            if not fut.set_running_or_notify_cancel():
                continue
            try:
                fut.set_result(fn())
            except BaseException as exc:  # noqa: BLE001 - handed to the caller
                fut.set_exception(exc)

    def submit(self, fn) -> Future:
        fut: Future = Future()
        self._q.put((fn, fut))
        return fut

    def stop(self, wait_s: float = 1.0) -> None:
        self._q.put(None)
        if self._thread is not threading.current_thread():
            self._thread.join(wait_s)


# ----------------------------------------------------------------------------- interface
class Camera(abc.ABC):
    """A camera: ``open``/``close`` (or a ``with`` block) and :meth:`grab`.

    Subclasses implement ``_open``, ``_close``, ``_trigger`` (latch an exposure;
    may block until the frame is there) and ``_retrieve`` (the latched frame as a
    mono uint8 image). They run on the camera's worker thread, except for
    backends with ``retrieve_in_caller = True`` (the twin: OpenGL contexts belong
    to the thread that made them), whose ``_open``/``_retrieve``/``_close`` run
    on the calling thread.

    Parameters
    ----------
    name : str
        Camera name, e.g. ``"side"``.
    timeout_s : float
        Bound on each open, trigger and retrieve.
    """

    #: _open/_retrieve/_close run on the caller's thread (OpenGL rendering)
    retrieve_in_caller = False
    #: robot-free (background) frames need a person to clear the view
    needs_operator = False

    def __init__(self, name: str, timeout_s: float = 5.0):
        if not timeout_s > 0:
            raise ValueError(f"camera {name!r}: timeout_s must be > 0, got {timeout_s}")
        self.name = name
        self.timeout_s = float(timeout_s)
        self.background = False
        self.frames_delivered = 0
        self._worker: _Worker | None = None
        self._hung: str | None = None
        self._opened = False

    # -- backend hooks ------------------------------------------------------
    @abc.abstractmethod
    def _open(self) -> None: ...

    @abc.abstractmethod
    def _close(self) -> None: ...

    @abc.abstractmethod
    def _trigger(self) -> None: ...

    @abc.abstractmethod
    def _retrieve(self) -> np.ndarray: ...

    def describe(self) -> str:
        """One line saying what this camera is (for logs and session.json)."""
        return f"{type(self).__name__}({self.name!r})"

    # -- plumbing -------------------------------------------------------------
    def _wait(self, fut: Future, what: str, timeout_s: float):
        try:
            return fut.result(timeout_s)
        except (TimeoutError, concurrent.futures.TimeoutError):
            fut.cancel()
            self._hung = f"{what} did not return within {timeout_s:.1f} s"
            raise TimeoutError(f"camera {self.name!r}: {what} did not return within {timeout_s:.1f} s") from None

    def _check_usable(self) -> None:
        if self._hung:
            raise CameraError(f"camera {self.name!r}: unusable, an earlier call hung ({self._hung})")
        if not self._opened:
            raise CameraError(f"camera {self.name!r}: not open")

    def _run(self, fn, what: str, timeout_s: float | None, in_caller: bool = False):
        t = self.timeout_s if timeout_s is None else timeout_s
        if in_caller:
            return fn()
        return self._wait(self._worker.submit(fn), what, t)

    def _timed_trigger(self):
        self._trigger()
        return time.monotonic(), time.time()

    def _frame(self, image: np.ndarray, t: tuple) -> Frame:
        f = Frame(image=image, timestamp_s=t[0], wall_time_s=t[1], seq=self.frames_delivered, camera=self.name)
        self.frames_delivered += 1
        return f

    # -- public API -----------------------------------------------------------
    def open(self) -> "Camera":
        if self._opened:
            return self
        self._worker = _Worker(f"camera-{self.name}")
        try:
            self._run(self._open, "open", None, in_caller=self.retrieve_in_caller)
        except BaseException:
            self._worker.stop(0.0)
            self._worker = None
            raise
        self._opened = True
        return self

    def close(self) -> None:
        """Release the camera (idempotent; a hung camera is abandoned, not waited for)."""
        if not self._opened:
            return
        self._opened = False
        try:
            if self._hung:
                return
            self._run(self._close, "close", None, in_caller=self.retrieve_in_caller)
        finally:
            if self._worker is not None:
                self._worker.stop(0.0 if self._hung else 1.0)
                self._worker = None

    def __enter__(self):
        return self.open()

    def __exit__(self, *exc):
        self.close()
        return False

    def start_trigger(self) -> Future:
        """Start an exposure on the worker thread; the future gives (monotonic, wall) time."""
        self._check_usable()
        return self._worker.submit(self._timed_trigger)

    def finish_trigger(self, fut: Future, timeout_s: float | None = None) -> tuple:
        return self._wait(fut, "trigger", self.timeout_s if timeout_s is None else timeout_s)

    def retrieve(self, timeout_s: float | None = None) -> np.ndarray:
        self._check_usable()
        img = self._run(self._retrieve, "retrieve", timeout_s, in_caller=self.retrieve_in_caller)
        if img is None or img.dtype != np.uint8 or img.ndim != 2:
            raise CameraError(f"camera {self.name!r}: backend returned no mono 8-bit image")
        return img

    def grab(self, timeout_s: float | None = None) -> Frame:
        """One frame; TimeoutError naming the camera when it does not come in time."""
        t = self.finish_trigger(self.start_trigger(), timeout_s)
        return self._frame(self.retrieve(timeout_s), t)

    def set_background(self, flag: bool) -> None:
        """Robot-free frames from now on (twin: no robot; replay: the background stream)."""
        self.background = bool(flag)


class CameraPair:
    """Two (or more) cameras grabbed together.

    :meth:`grab` starts every camera's trigger at once (each on its own worker
    thread), waits for all of them, then retrieves the images. ``skew_ms`` of the
    result is the spread of the trigger timestamps.
    """

    def __init__(self, cameras, timeout_s: float | None = None):
        cams = list(cameras.values()) if isinstance(cameras, dict) else list(cameras)
        if not cams:
            raise ValueError("CameraPair needs at least one camera")
        names = [c.name for c in cams]
        if len(set(names)) != len(names):
            raise ValueError(f"CameraPair: duplicate camera names {names}")
        self.cameras = {c.name: c for c in cams}
        self.timeout_s = timeout_s

    @property
    def names(self) -> list:
        return list(self.cameras)

    @property
    def needs_operator(self) -> bool:
        return any(c.needs_operator for c in self.cameras.values())

    def open(self) -> "CameraPair":
        opened = []
        try:
            for c in self.cameras.values():
                c.open()
                opened.append(c)
        except BaseException:
            for c in opened:
                try:
                    c.close()
                except Exception:  # noqa: BLE001 - the first error is the one to report
                    pass
            raise
        return self

    def close(self) -> None:
        errors = []
        for c in self.cameras.values():
            try:
                c.close()
            except Exception as exc:  # noqa: BLE001
                errors.append(exc)
        if errors:
            raise errors[0]

    def __enter__(self):
        return self.open()

    def __exit__(self, exc_type, *exc):
        try:
            self.close()
        except Exception:
            if exc_type is None:
                raise
        return False

    def set_background(self, flag: bool) -> None:
        for c in self.cameras.values():
            c.set_background(flag)

    @contextmanager
    def background_view(self):
        """Within the block, grabs are robot-free (background) frames."""
        self.set_background(True)
        try:
            yield self
        finally:
            self.set_background(False)

    def describe(self) -> dict:
        return {name: c.describe() for name, c in self.cameras.items()}

    def grab(self, timeout_s: float | None = None) -> FramePair:
        cams = list(self.cameras.values())
        t_out = timeout_s if timeout_s is not None else self.timeout_s
        futs = [c.start_trigger() for c in cams]          # all started before any is awaited
        times = [c.finish_trigger(f, t_out) for c, f in zip(cams, futs)]
        images = {}
        # retrieves on worker threads run in parallel; caller-thread ones one after the other
        pending = {c.name: c._worker.submit(c._retrieve) for c in cams if not c.retrieve_in_caller}
        for c in cams:
            if c.retrieve_in_caller:
                images[c.name] = c.retrieve(t_out)
        for c in cams:
            if c.name in pending:
                img = c._wait(pending[c.name], "retrieve", c.timeout_s if t_out is None else t_out)
                if img is None or img.dtype != np.uint8 or img.ndim != 2:
                    raise CameraError(f"camera {c.name!r}: backend returned no mono 8-bit image")
                images[c.name] = img
        frames = {c.name: c._frame(images[c.name], t) for c, t in zip(cams, times)}
        ts = [t[0] for t in times]
        skew_ms = (max(ts) - min(ts)) * 1e3
        truth, joints = self._extras(cams)
        return FramePair(frames=frames, skew_ms=skew_ms, truth=truth, joints=joints)

    def _extras(self, cams) -> tuple:
        return None, None


# ----------------------------------------------------------------------------- OpenCV
def _parse_source(source):
    """(what cv2.VideoCapture gets, api preference, kind) for a source spec."""
    if isinstance(source, bool):
        raise ValueError(f"bad camera source {source!r}")
    if isinstance(source, int) or (isinstance(source, str) and source.strip().isdigit()):
        return int(source), cv2.CAP_ANY, "device"
    if not isinstance(source, str) or not source.strip():
        raise ValueError(f"bad camera source {source!r}")
    s = source.strip()
    if "!" in s:
        return s, cv2.CAP_GSTREAMER, "gstreamer"
    if s.startswith("/dev/"):
        # OpenCV's V4L2 backend opens devices by index: /dev/video2 (or a /dev/v4l/by-id/... link to it) -> 2
        m = re.fullmatch(r"/dev/video(\d+)", os.path.realpath(s))
        return (int(m.group(1)), cv2.CAP_V4L2, "device") if m else (s, cv2.CAP_ANY, "device")
    return s, cv2.CAP_ANY, "file"


class OpenCVCamera(Camera):
    """``cv2.VideoCapture`` on a device index, a V4L2 path, a video file or a GStreamer pipeline.

    Parameters
    ----------
    name : str
    source : int or str
        ``0`` / ``"0"`` (device index), ``"/dev/video2"`` (V4L2), ``"clip.avi"``
        (video file, relative paths as given), or a GStreamer pipeline (any
        string containing ``!``, opened with ``cv2.CAP_GSTREAMER``; it must end
        in an ``appsink``).
    timeout_s : float
    width, height, fps : optional
        Requested mode (``CAP_PROP_FRAME_WIDTH`` ...) for devices.
    discard : int
        Frames read and thrown away before each grab, so a free-running camera
        delivers an exposure taken after the robot settled, not a stale buffer.
    loop : bool
        Video files: start over at the end instead of raising :class:`EndOfStream`.
    """

    def __init__(self, name: str, source, timeout_s: float = 5.0, width: int | None = None,
                 height: int | None = None, fps: float | None = None, discard: int = 0, loop: bool = False):
        super().__init__(name, timeout_s)
        self.source = source
        self.target, self.api, self.kind = _parse_source(source)
        self.width, self.height, self.fps = width, height, fps
        self.discard = int(discard)
        self.loop = bool(loop)
        self.needs_operator = self.kind != "file"
        self._cap = None

    def describe(self) -> str:
        return f"opencv {self.kind} {self.source!r}"

    def _open(self) -> None:
        if self.kind == "file" and not Path(self.target).exists():
            raise CameraError(f"camera {self.name!r}: video file {self.target} not found")
        cap = cv2.VideoCapture(self.target, self.api)
        if not cap.isOpened():
            cap.release()
            hint = ""
            if self.kind == "gstreamer" and "GStreamer:                   NO" in cv2.getBuildInformation():
                hint = (" (this OpenCV has no GStreamer support -- the PyPI wheel has none: use an OpenCV built with "
                        "GStreamer, or feed the camera into a V4L2 loopback device; see docs/rig-file.md)")
            raise CameraError(f"camera {self.name!r}: cannot open {self.kind} source {self.source!r}{hint}")
        if self.kind == "device":
            cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)
            if self.width:
                cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.width)
            if self.height:
                cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height)
            if self.fps:
                cap.set(cv2.CAP_PROP_FPS, self.fps)
        self._cap = cap

    def _close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    def _grab_one(self) -> None:
        if self._cap.grab():
            return
        if self.kind == "file":
            if self.loop and self._cap.set(cv2.CAP_PROP_POS_FRAMES, 0) and self._cap.grab():
                return
            raise EndOfStream(f"camera {self.name!r}: end of video file {self.target}")
        raise CameraError(f"camera {self.name!r}: {self.kind} source {self.source!r} delivered no frame")

    def _trigger(self) -> None:
        for _ in range(self.discard):
            self._grab_one()
        self._grab_one()

    def _retrieve(self) -> np.ndarray:
        ok, img = self._cap.retrieve()
        if not ok or img is None:
            raise CameraError(f"camera {self.name!r}: could not decode the frame from {self.source!r}")
        return to_mono(img, "bgr", f"camera {self.name!r}")


# ----------------------------------------------------------------------------- twin
class TwinWorld:
    """The twin's world: the scene, the robot state and one renderer, shared by the twin cameras.

    The robot's joints come from ``joint_source`` (a callable returning the
    actuator's :class:`~rig.hw.actuator.JointValues`; the rig wires it to the
    actuator, twin or physical), mapped to per-tube joints by ``joint_map``.
    Frames are rendered on the calling thread (created lazily), and the last
    render is cached so that both cameras of a pair share one render.
    """

    def __init__(self, scene, joint_map, joint_source=None):
        self.scene = scene
        self.joint_map = joint_map
        self.joint_source = joint_source
        self._twin = None
        self._lock = threading.Lock()
        self._last_key = None
        self._last = None

    def snapshot(self, stream: str, index: int):
        """The render key of an exposure taken now: ("background", i) or ("frame", i, Joints)."""
        if stream == "background":
            return ("background", index, None)
        if self.joint_source is None:
            raise CameraError("twin cameras: no joint source (no actuator wired to the twin world)")
        joints = self.joint_map.to_joints(self.joint_source())
        return ("frame", index, joints)

    def render(self, key):
        """The TwinFrame for ``key`` (cached: the second camera of a pair reuses the first's)."""
        with self._lock:
            if key == self._last_key:
                return self._last
            if self._twin is None:
                self._twin = Twin(self.scene)
            stream, index, joints = key
            frame = self._twin.background(index) if stream == "background" else self._twin.frame(index, joints=joints)
            self._last_key, self._last = key, frame
            return frame

    def close(self) -> None:
        with self._lock:
            if self._twin is not None:
                self._twin.close()
                self._twin = None
            self._last_key = self._last = None


class TwinCamera(Camera):
    """One camera of the scene's rig, rendered by the twin at the exposure's joints."""

    retrieve_in_caller = True

    def __init__(self, name: str, world: TwinWorld, timeout_s: float = 30.0):
        super().__init__(name, timeout_s)
        if name not in world.scene.rig.cameras:
            raise ValueError(f"twin camera {name!r}: the scene has cameras {', '.join(world.scene.rig.cameras)}")
        self.world = world
        self._counts = {"background": 0, "frame": 0}
        self.last_key = None

    def describe(self) -> str:
        return f"twin {self.name!r} of scene {self.world.scene.name!r}"

    def _open(self) -> None:
        pass

    def _close(self) -> None:
        pass

    def _trigger(self) -> None:
        stream = "background" if self.background else "frame"
        self.last_key = self.world.snapshot(stream, self._counts[stream])
        self._counts[stream] += 1

    def _retrieve(self) -> np.ndarray:
        frame = self.world.render(self.last_key)
        order = "rgb" if self.world.scene.color == "rgb" else "bgr"
        return to_mono(frame.images[self.name], order, f"camera {self.name!r}")


class TwinCameraPair(CameraPair):
    """The twin's cameras; frame pairs carry the ground truth of the render."""

    def __init__(self, world: TwinWorld, timeout_s: float = 30.0, names=None):
        names = list(names) if names is not None else list(world.scene.rig.cameras)
        super().__init__([TwinCamera(n, world, timeout_s) for n in names], timeout_s)
        self.world = world

    def close(self) -> None:
        try:
            super().close()
        finally:
            self.world.close()

    def _extras(self, cams) -> tuple:
        keys = {c.last_key for c in cams}
        if len(keys) != 1:
            return None, None           # the robot moved between the two exposures: no single truth
        key = keys.pop()
        if key[0] != "frame":
            return None, None

        frame = self.world.render(key)
        return truth_arrays(frame), frame.joints


# ----------------------------------------------------------------------------- replay
class ReplayWorld:
    """A recorded session replayed: per-camera cursors over its background and robot frames.

    The replay actuator (:class:`rig.hw.rigfile.ReplayActuator`) reports the joints
    recorded with the robot frame the cameras deliver next.
    """

    def __init__(self, session_dir):
        self.session = Session(session_dir)
        self.cursors: dict = {}

    @property
    def next_frame(self) -> int:
        """Position (in frames.csv order) of the next robot frame the slowest camera delivers."""
        return min(self.cursors.values()) if self.cursors else 0


class ReplayCamera(Camera):
    """One camera of a recorded session: its background frames, then its robot frames, in order."""

    def __init__(self, name: str, world: ReplayWorld, timeout_s: float = 5.0):
        super().__init__(name, timeout_s)
        if name not in world.session.cameras:
            raise ValueError(f"replay camera {name!r}: the session has cameras {', '.join(world.session.cameras)}")
        self.world = world
        self._bg = 0
        world.cursors[name] = 0
        self._path = None

    def describe(self) -> str:
        return f"replay {self.name!r} of {self.world.session.dir}"

    def _open(self) -> None:
        pass

    def _close(self) -> None:
        pass

    def _trigger(self) -> None:
        s = self.world.session
        if self.background:
            paths = s.background_paths(self.name)
            if self._bg >= len(paths):
                raise EndOfStream(f"camera {self.name!r}: {s.dir} has only {len(paths)} background frames")
            self._path = paths[self._bg]
            self._bg += 1
        else:
            i = self.world.cursors[self.name]
            if i >= len(s.frames):
                raise EndOfStream(f"camera {self.name!r}: {s.dir} has only {len(s.frames)} frames")
            self._path = s.frame_path(s.frames[i].index, self.name)
            self.world.cursors[self.name] = i + 1

    def _retrieve(self) -> np.ndarray:
        return to_mono(read_image(self._path), "rgb", f"camera {self.name!r}")
