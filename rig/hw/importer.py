"""Sessions from a lab's own recordings: what ``ctr-bench import`` builds (docs/import.md).

A lab that recorded its cameras with its own tools has, per camera, a folder of
images or a video file, maybe a log of joint values, and a calibration. This
module turns them into a session directory (docs/session-format.md) written by
:class:`rig.session.SessionWriter` -- the one writer of the format -- so that
``ctr-bench reconstruct``, ``report``, ``verify`` and ``fit`` read it like any
recorded session.

Every input is checked before the output directory is created (file lists,
frame counts, times, the joints file, image sizes of the first frames), and an
import that fails later (an unreadable image in the middle) removes what it
wrote: a failed import leaves no half session behind. Errors are one line
naming the input and what is wrong (:class:`ImportInputError`).

Units: mm, degrees, seconds, pixels.
"""
from __future__ import annotations

import csv
import glob
import io
import math
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from recon.calibration import IMAGE_SUFFIXES
from recon.textfile import read_text
from rig.hw.camera import CameraError, to_mono
from rig.session import SessionWriter, atomic_write_bytes
from twin.robot import Joints
from twin.robotfile import robot_from_toml, robot_to_dict
from twin.schema import SceneError, read_toml

__all__ = ["ImportInputError", "Recording", "open_recording", "natural_key", "name_times", "JointTable",
           "load_joints_csv", "robot_meta", "ImportPlan", "plan_import", "write_import", "TIME_UNITS",
           "MASK_BACKGROUND_FRAMES"]

#: ``--time-unit``: seconds per unit of the number in the file names.
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}

#: Uniform background frames made for a masks-only import without background frames
#: (a segmentation's output where there is no robot; k + 1 for the default eigenbackgrounds).
MASK_BACKGROUND_FRAMES = 6

_PRINTF = re.compile(r"%(\d*)d")
_GLOB = re.compile(r"[*?[]")


class ImportInputError(ValueError):
    """An input that cannot be imported; the message (one line) names it and says what is wrong."""


def natural_key(text: str) -> list:
    """Sort key comparing digit runs as numbers, so ``img_9.png`` comes before ``img_10.png``."""
    return [(0, int(t), "") if t.isdigit() else (1, 0, t.lower()) for t in re.split(r"(\d+)", str(text)) if t]


# ----------------------------------------------------------------------------- inputs
@dataclass
class Recording:
    """One camera's input: image files in sorted order, or a video file.

    Attributes
    ----------
    label : str
        The option and what it was given (``--side 'rec/side/*.png'``), for messages.
    files : list of Path
        The image files, in the order they are paired (empty for a video).
    video : Path or None
    video_times_s : list of float or None
        Video: each frame's container time (``CAP_PROP_POS_MSEC``, s).
    size : (width, height) or None
        Video: the frame size the container declares.
    """

    label: str
    files: list = field(default_factory=list)
    video: Path | None = None
    video_times_s: list | None = None
    size: tuple | None = None

    def __len__(self) -> int:
        return len(self.video_times_s) if self.video is not None else len(self.files)

    def where(self, i: int) -> str:
        """Input frame ``i`` in words (the file, or the video and the frame number)."""
        return str(self.files[i]) if self.video is None else f"{self.video} frame {i}"

    def frames(self):
        """Yield ``(index, image)`` for every frame in order (images as decoded, uint8)."""
        if self.video is None:
            for i, path in enumerate(self.files):
                yield i, _read_file(path)
            return
        yield from _read_video(self)


def _printf_files(pattern: Path, label: str) -> list:
    """The files a printf pattern (``img_%04d.png``) matches, in the order of their number."""
    hits = list(_PRINTF.finditer(pattern.name))
    if len(hits) != 1 or "%" in str(pattern.parent):
        raise ImportInputError(f"{label}: a printf pattern needs exactly one %d (or %0Nd) in the file name")
    m = hits[0]
    width = int(m.group(1)) if m.group(1).startswith("0") else 0
    digits = rf"(\d{{{width}}})" if width else r"(\d+)"
    rx = re.compile(re.escape(pattern.name[:m.start()]) + digits + re.escape(pattern.name[m.end():]))
    folder = pattern.parent
    if not folder.is_dir():
        raise ImportInputError(f"{label}: folder {folder} not found")
    numbered = [(int(hit.group(1)), p) for p in folder.iterdir() if p.is_file() and (hit := rx.fullmatch(p.name))]
    return [p for _, p in sorted(numbered)]


def _list_images(spec: str, label: str) -> list | None:
    """Image files of a folder, glob or printf pattern (sorted); None when ``spec`` is none of these."""
    path = Path(spec)
    if _PRINTF.search(path.name):
        files = _printf_files(path, label)
    elif _GLOB.search(spec):
        files = sorted((Path(f) for f in glob.glob(spec) if Path(f).is_file()), key=lambda p: natural_key(str(p)))
    elif path.is_dir():
        files = sorted((p for p in path.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES),
                       key=lambda p: natural_key(p.name))
    elif path.suffix.lower() in IMAGE_SUFFIXES:
        if not path.is_file():
            raise ImportInputError(f"{label}: {path}: file not found")
        files = [path]
    else:
        return None
    if not files:
        raise ImportInputError(f"{label}: matches no image files")
    return files


def _probe_video(path: Path, label: str) -> Recording:
    """Open a video, count its frames and read their container times (a grab pass, no decoding to pixels)."""
    if not path.is_file():
        raise ImportInputError(f"{label}: {path}: not found (expected a folder, a glob, a printf pattern, an image or a video file)")
    cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            raise ImportInputError(f"{label}: {path}: not an image folder, pattern or a video OpenCV can read")
        size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        times = []
        # grab() demuxes and decodes but skips the pixel conversion: the exact count and every time, cheaply.
        while cap.grab():
            times.append(cap.get(cv2.CAP_PROP_POS_MSEC) / 1e3)
    finally:
        cap.release()
    if not times:
        raise ImportInputError(f"{label}: {path}: the video has no frames OpenCV can read")
    return Recording(label, video=path, video_times_s=times, size=size)


def open_recording(option: str, spec: str) -> Recording:
    """The input of one camera option: a folder, a glob, a printf pattern, one image or a video file.

    Parameters
    ----------
    option : str
        The command-line option (``--side``), for messages.
    spec : str
        What it was given.
    """
    label = f"{option} {spec!r}"
    files = _list_images(spec, label)
    return Recording(label, files=files) if files is not None else _probe_video(Path(spec), label)


def _read_file(path: Path) -> np.ndarray:
    """An image file as uint8, decoded by OpenCV (BGR order for colour); errors name the file."""
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as exc:
        raise ImportInputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if img is None:
        raise ImportInputError(f"{path}: not an image OpenCV can decode")
    return img


def _read_video(rec: Recording):
    cap = cv2.VideoCapture(str(rec.video))
    try:
        for i in range(len(rec)):
            ok, img = cap.read()
            if not ok or img is None:
                raise ImportInputError(f"{rec.label}: frame {i} could not be decoded (the grab pass counted {len(rec)})")
            yield i, img
    finally:
        cap.release()


def to_session_image(img: np.ndarray, where: str, size: tuple, masks: bool) -> np.ndarray:
    """An input frame as the session stores it: 8-bit mono (colour converted), masks binarised at 128.

    Parameters
    ----------
    img : ndarray
        As decoded (BGR order for colour).
    where : str
        The input frame in words, for messages.
    size : (width, height)
        The calibrated image size (px) the frame must have.
    masks : bool
        Binary silhouettes: values >= 128 become 255, the rest 0.
    """
    try:
        mono = to_mono(img, "bgr", where)
    except CameraError as exc:
        raise ImportInputError(str(exc)) from None
    if (mono.shape[1], mono.shape[0]) != tuple(size):
        raise ImportInputError(f"{where}: image is {mono.shape[1]}x{mono.shape[0]} but the calibration says {size[0]}x{size[1]}")
    return np.where(mono >= 128, np.uint8(255), np.uint8(0)) if masks else mono


# ----------------------------------------------------------------------------- times
def name_times(rec: Recording, regex: str, unit: str) -> list:
    """Each file's time (s) from the number ``regex`` finds in its name.

    Parameters
    ----------
    rec : Recording
        Image files (a video's times come from its container).
    regex : str
        Searched in the file name (not the folder); its first group, or the whole
        match without groups, is the number, e.g. ``img_(\\d+)_us``.
    unit : str
        A key of :data:`TIME_UNITS`: what one unit of the number is.
    """
    try:
        rx = re.compile(regex)
    except re.error as exc:
        raise ImportInputError(f"--time-from-name {regex!r}: not a regular expression ({exc})") from None
    if unit not in TIME_UNITS:
        raise ImportInputError(f"--time-unit {unit!r}: must be one of {', '.join(TIME_UNITS)}")
    times = []
    for path in rec.files:
        m = rx.search(path.name)
        if m is None:
            raise ImportInputError(f"{path}: --time-from-name {regex!r} finds no number in the file name")
        text = m.group(1) if rx.groups else m.group(0)
        try:
            times.append(float(text) * TIME_UNITS[unit])
        except (TypeError, ValueError):
            raise ImportInputError(f"{path}: --time-from-name {regex!r} matched {text!r}, not a number") from None
    return times


def recording_times(rec: Recording, fps: float | None, regex: str | None, unit: str) -> tuple:
    """``(times_s, source)`` of every input frame: ``--fps``, else the video's container times,
    else numbers in the file names; increasing, or a one-line error naming the frame."""
    if fps is not None and regex is not None:
        raise ImportInputError("give --fps F or --time-from-name REGEX, not both (which times would be right?)")
    if fps is not None:
        if not (math.isfinite(fps) and fps > 0):
            raise ImportInputError(f"--fps {fps:g}: must be > 0")
        times, source = [i / fps for i in range(len(rec))], f"frame index / {fps:g} fps"
    elif rec.video is not None:
        if regex is not None:
            raise ImportInputError(f"--time-from-name: {rec.label} is a video: its times come from the container "
                                   "(--fps F overrides them)")
        times, source = list(rec.video_times_s), "video container times (CAP_PROP_POS_MSEC)"
    elif regex is not None:
        times, source = name_times(rec, regex, unit), f"file names ({regex!r}, {unit})"
    else:
        raise ImportInputError(f"{rec.label}: image files carry no times: give --fps F (t = frame index / F) "
                               "or --time-from-name REGEX")
    for i in range(1, len(times)):
        if not times[i] > times[i - 1]:
            raise ImportInputError(f"{rec.where(i)}: time {times[i]:.6f} s is not after the previous frame's "
                                   f"({times[i - 1]:.6f} s); frames are paired in sorted order (give --fps F to "
                                   "ignore the recorded times)")
    return times, source


# ----------------------------------------------------------------------------- joints
@dataclass(frozen=True, eq=False)
class JointTable:
    """Joint values read from a CSV file (``--joints``), one row per frame that has them.

    Attributes
    ----------
    source : str
        The file.
    by : {"frame", "t_s"}
        How rows find their frame: the session frame index, or the frame time (s).
    keys : ndarray (m,)
        Frame indices or times (s), one per row, increasing.
    extension_mm, rotation_deg : ndarray (m, n_tubes)
    lines : ndarray (m,)
        Line numbers of the rows (for messages).
    """

    source: str
    by: str
    keys: np.ndarray
    extension_mm: np.ndarray
    rotation_deg: np.ndarray
    lines: np.ndarray

    @property
    def n_tubes(self) -> int:
        return int(self.extension_mm.shape[1])

    def _joints(self, row: int):
        return Joints(tuple(self.extension_mm[row]), tuple(self.rotation_deg[row]))

    def match(self, frame_times_s) -> list:
        """Joints of every session frame (``twin.robot.Joints``, or None where the file has no row).

        By ``frame``: the row of that index (one past the last frame is an error).
        By ``t_s``: the nearest row within half the shortest frame interval (1 ms for a
        single frame); no row near any frame is an error (the file is on another clock).
        """
        t = np.asarray(frame_times_s, float)
        out = [None] * len(t)
        if self.by == "frame":
            for k, line, row in zip(self.keys.astype(int), self.lines, range(len(self.keys))):
                if k >= len(t):
                    raise ImportInputError(f"{self.source}:{line}: frame {k}, but the import has {len(t)} robot "
                                           f"frames (0-{len(t) - 1}; frame counts the robot frames from 0)")
                out[k] = self._joints(row)
            return out
        tol = 0.5 * float(np.min(np.diff(t))) if len(t) > 1 else 1e-3
        for i, ti in enumerate(t):
            j = int(np.argmin(np.abs(self.keys - ti)))
            if abs(self.keys[j] - ti) <= tol:
                out[i] = self._joints(j)
        if not any(j is not None for j in out):
            raise ImportInputError(f"{self.source}: no row's t_s is within {tol:.6g} s of a frame time (frames at "
                                   f"{t[0]:.6g}-{t[-1]:.6g} s, rows at {self.keys[0]:.6g}-{self.keys[-1]:.6g} s): t_s is "
                                   "the session's clock, s since the first input frame")
        return out


def _cell(row: dict, col: str, where: str) -> float:
    text = (row.get(col) or "").strip()
    try:
        v = float(text)
    except ValueError:
        raise ImportInputError(f"{where}: {col}: {text!r} is not a number") from None
    if not math.isfinite(v):
        raise ImportInputError(f"{where}: {col}: {text!r} is not finite")
    return v


def _joint_header(cols: list, src: str, n_tubes: int | None) -> tuple:
    """``(by, n)``: the key column and the number of tubes of a joints CSV header."""
    by = "frame" if "frame" in cols else "t_s" if "t_s" in cols else None
    if by is None:
        raise ImportInputError(f"{src}: needs a 'frame' or a 't_s' column (found: {', '.join(cols) or 'none'})")
    n = 0
    while f"extension_{n}_mm" in cols:
        n += 1
    if n == 0:
        raise ImportInputError(f"{src}: no extension_0_mm column (columns extension_<i>_mm, rotation_<i>_deg per "
                               "tube, outermost first)")
    missing = [f"rotation_{i}_deg" for i in range(n) if f"rotation_{i}_deg" not in cols]
    if missing:
        raise ImportInputError(f"{src}: missing column {missing[0]} (every extension_<i>_mm needs its rotation_<i>_deg)")
    if n_tubes is not None and n != n_tubes:
        raise ImportInputError(f"{src}: joint columns for {n} tube(s), but the robot has {n_tubes}")
    return by, n


def load_joints_csv(path, n_tubes: int | None = None) -> JointTable:
    """Read a joints CSV: ``frame`` or ``t_s``, then ``extension_<i>_mm, rotation_<i>_deg`` per tube.

    Parameters
    ----------
    path : path
    n_tubes : int, optional
        The robot's tube count (the columns must match); None: as many as the file has.
    """
    path = Path(path)
    src = str(path)
    text = read_text(path, "joints", "joints CSV file", ImportInputError)
    reader = csv.DictReader(io.StringIO(text))
    cols = [c.strip() for c in reader.fieldnames or []]
    reader.fieldnames = cols
    by, n = _joint_header(cols, src, n_tubes)
    keys, ext, rot, lines = [], [], [], []
    for row in reader:
        where = f"{src}:{reader.line_num}"
        key = _cell(row, by, where)
        if by == "frame" and (key < 0 or key != int(key)):
            raise ImportInputError(f"{where}: frame: {row[by]!r} is not a frame index (an integer >= 0)")
        if keys and key <= keys[-1]:
            raise ImportInputError(f"{where}: {by} {key:g} does not increase (the previous row has {keys[-1]:g})")
        keys.append(key)
        ext.append([_cell(row, f"extension_{i}_mm", where) for i in range(n)])
        rot.append([_cell(row, f"rotation_{i}_deg", where) for i in range(n)])
        lines.append(reader.line_num)
    if not keys:
        raise ImportInputError(f"{src}: no rows (a header and one row per frame with joint values)")
    return JointTable(src, by, np.asarray(keys), np.asarray(ext, float), np.asarray(rot, float), np.asarray(lines))


# ----------------------------------------------------------------------------- robot
def _diameters_meta(text: str) -> dict:
    try:
        d = [float(v) for v in text.split(",")]
    except ValueError:
        raise ImportInputError(f"--tube-diameters-mm {text!r}: expected comma-separated outer diameters (mm), "
                               "outermost first") from None
    if not all(math.isfinite(v) and v > 0 for v in d):
        raise ImportInputError(f"--tube-diameters-mm {text!r}: every diameter must be > 0 mm")
    if any(b > a for a, b in zip(d, d[1:])):
        raise ImportInputError(f"--tube-diameters-mm {text!r}: outermost first, so no tube may be wider than the one before")
    # Only what reconstruction needs (tube radii); verify/fit need a full robot (--robot).
    return {"diameters_only": True, "tubes": [{"name": f"tube{i}", "outer_diameter_mm": v} for i, v in enumerate(d)]}


def robot_meta(robot_file=None, diameters: str | None = None) -> dict | None:
    """session.json's ``robot``: the ``[robot]`` table of a robot or scene TOML, or tube diameters only.

    Parameters
    ----------
    robot_file : path, optional
        A robot file (``ctr-bench fit`` writes them) or a scene file: its ``[robot]`` table.
    diameters : str, optional
        ``"1.6,1.0"``: outer diameters (mm), outermost first.
    """
    if robot_file is not None and diameters is not None:
        raise ImportInputError("give --robot FILE or --tube-diameters-mm LIST, not both")
    if diameters is not None:
        return _diameters_meta(diameters)
    if robot_file is None:
        return None
    data = read_toml(robot_file, "robot file", ImportInputError)
    try:
        robot, model = robot_from_toml(data, str(robot_file))
    except SceneError as exc:
        raise ImportInputError(str(exc)) from None
    return robot_to_dict(robot, model)


# ----------------------------------------------------------------------------- plan
@dataclass
class ImportPlan:
    """Everything an import writes, checked before anything is written.

    Attributes
    ----------
    rig : recon.rigcal.RigCalibration
    passes : list of (dict camera -> Recording, list of str)
        Inputs read one after the other; the list says, per input frame, whether it is
        a ``"background"`` or a robot ``"frame"``.
    times_s : dict camera -> list of float
        Per camera, the time (s since the first input frame) of every input frame.
    joints : list
        Per robot frame: ``twin.robot.Joints`` or None (unknown: the row stays empty).
    n_tubes : int
    meta : dict
        session.json keys beyond the writer's.
    masks : bool
        The inputs are binary silhouettes.
    mask_background_value : int or None
        Masks without background frames: the value of the uniform background frames made.
    """

    rig: object
    passes: list
    times_s: dict
    joints: list
    n_tubes: int
    meta: dict
    masks: bool = False
    mask_background_value: int | None = None

    @property
    def frame_count(self) -> int:
        return sum(roles.count("frame") for _, roles in self.passes)

    @property
    def background_count(self) -> int:
        n = sum(roles.count("background") for _, roles in self.passes)
        return n if self.mask_background_value is None else MASK_BACKGROUND_FRAMES


def _check_counts(recs: dict, why: str) -> int:
    """The common frame count of ``recs``; unequal counts are one line naming both inputs."""
    counts = {cam: len(r) for cam, r in recs.items()}
    if len(set(counts.values())) > 1:
        listed = ", ".join(f"{recs[c].label} has {n}" for c, n in counts.items())
        raise ImportInputError(f"unequal frame counts: {listed} ({why})")
    return next(iter(counts.values()))


def _check_cameras(rig, given: dict, option: str) -> None:
    missing = [c for c in rig.names if c not in given]
    if missing:
        raise ImportInputError(f"no {option.format(cam=missing[0])} input: the calibration's cameras are "
                               f"{', '.join(rig.names)} and each needs one")


def _check_first_sizes(rig, recs: dict) -> None:
    """Decode one frame per camera (a video's declared size) before anything is written."""
    for cam, rec in recs.items():
        c = rig[cam]
        if rec.video is not None:
            w, h = rec.size
            if (w, h) != (c.width, c.height):
                raise ImportInputError(f"{rec.label}: frames are {w}x{h} but the calibration says {c.width}x{c.height}")
        else:
            to_session_image(_read_file(rec.files[0]), str(rec.files[0]), (c.width, c.height), False)


def _split_roles(n: int, background_frames: set | None, label: str) -> list:
    """Per input frame, ``"background"`` (in ``background_frames``) or ``"frame"``."""
    background_frames = background_frames or set()
    outside = sorted(i for i in background_frames if i >= n)
    if outside:
        raise ImportInputError(f"--background-frames: frame {outside[0]} is past the end of {label} ({n} frames, 0-{n - 1})")
    roles = ["background" if i in background_frames else "frame" for i in range(n)]
    if "frame" not in roles:
        raise ImportInputError(f"--background-frames: every frame of {label} is a background frame; none is left for the robot")
    return roles


def _relative_times(inputs: dict, fps, regex, unit) -> tuple:
    """Per camera, the input frames' times (s) since the first input frame, and where they come from."""
    raw, sources = {}, {}
    for cam, rec in inputs.items():
        raw[cam], sources[cam] = recording_times(rec, fps, regex, unit)
    t0 = min(t[0] for t in raw.values())
    return {cam: [v - t0 for v in t] for cam, t in raw.items()}, sources


def _background_passes(rig, inputs: dict, n: int, background_frames, background_inputs, masks: bool) -> tuple:
    """``(passes, description)``: where the background frames come from."""
    if background_frames and background_inputs:
        raise ImportInputError("give --background-frames LIST or per-camera background inputs, not both")
    if background_inputs:
        _check_cameras(rig, background_inputs, "--{cam}-background")
        nb = _check_counts(background_inputs, "background frames are stored in pairs")
        desc = {cam: r.label for cam, r in background_inputs.items()}
        return [(background_inputs, ["background"] * nb), (inputs, ["frame"] * n)], desc
    if background_frames:
        label = " and ".join(r.label for r in inputs.values())
        roles = _split_roles(n, background_frames, label)
        return [(inputs, roles)], f"{roles.count('background')} frames of the inputs (--background-frames)"
    if masks:
        return [(inputs, ["frame"] * n)], f"{MASK_BACKGROUND_FRAMES} uniform frames (masks without background)"
    raise ImportInputError("no background frames: give --background-frames LIST (robot-free frames of the inputs, "
                           "e.g. 0-9) or a background input per camera (--side-background, --top-background)")


def _frame_times(passes: list, times_s: dict, inputs: dict) -> list:
    """Session time (s) of every robot frame: the mean of its cameras' times."""
    roles = next(r for recs, r in passes if recs is inputs)
    return [float(np.mean([times_s[c][i] for c in inputs])) for i, role in enumerate(roles) if role == "frame"]


def plan_import(rig, inputs: dict, *, background_frames: set | None = None, background_inputs: dict | None = None,
                fps: float | None = None, time_regex: str | None = None, time_unit: str = "s", joints_file=None,
                robot: dict | None = None, masks: bool = False, mask_polarity: str = "robot-white",
                calibration_source: str = "") -> ImportPlan:
    """Check every input and work out what to write (nothing is written yet).

    Parameters
    ----------
    rig : recon.rigcal.RigCalibration
    inputs : dict camera -> Recording
        Robot frames (and, with ``background_frames``, the background frames too).
    background_frames : set of int, optional
        Input frame indices that are robot-free background frames.
    background_inputs : dict camera -> Recording, optional
        Separate background recordings, one per camera.
    fps, time_regex, time_unit
        Frame times: ``t = index / fps``, else a video's container times, else the
        number ``time_regex`` finds in each file name, in ``time_unit`` (s, ms, us, ns).
    joints_file : path, optional
        Joint values per frame (:func:`load_joints_csv`); without it the joints stay empty.
    robot : dict, optional
        session.json's ``robot`` (:func:`robot_meta`).
    masks : bool
        The inputs are binary silhouettes (``mask_polarity``: robot-white or robot-black).
    calibration_source : str
        Where the calibration came from (recorded in session.json).
    """
    if mask_polarity not in ("robot-white", "robot-black"):
        raise ImportInputError(f"--mask-polarity {mask_polarity!r}: must be robot-white or robot-black")
    _check_cameras(rig, inputs, "--{cam}")
    unknown = [c for c in list(inputs) + list(background_inputs or {}) if c not in rig.names]
    if unknown:
        raise ImportInputError(f"--{unknown[0]}: the calibration has no camera {unknown[0]!r} (it has {', '.join(rig.names)})")
    n = _check_counts(inputs, "frames are paired in sorted order")
    passes, bg_desc = _background_passes(rig, inputs, n, background_frames, background_inputs, masks)
    times_s, time_sources = _relative_times(inputs, fps, time_regex, time_unit)
    frame_t = _frame_times(passes, times_s, inputs)
    n_tubes = len(robot["tubes"]) if robot else None
    table = load_joints_csv(joints_file, n_tubes) if joints_file is not None else None
    joints = table.match(frame_t) if table is not None else [None] * len(frame_t)
    for recs, _ in passes:
        _check_first_sizes(rig, recs)
    info = {"tool": "ctr-bench import", "calibration": calibration_source,
            "inputs": {c: r.label for c, r in inputs.items()}, "background": bg_desc, "times": time_sources,
            "joints": None if table is None else table.source,
            "frames_with_joints": sum(j is not None for j in joints)}
    meta = {"import": info, "calibration_file": calibration_source}
    if robot:
        meta["robot"] = robot
    if masks:
        meta.update(image_kind="masks", mask_polarity=mask_polarity)
    mask_bg = (0 if mask_polarity == "robot-white" else 255) if masks and not (background_frames or background_inputs) else None
    return ImportPlan(rig, passes, times_s, joints, n_tubes if n_tubes is not None else (table.n_tubes if table else 0),
                      meta, masks, mask_bg)


# ----------------------------------------------------------------------------- writing
def check_out_dir(out: Path) -> None:
    """An import writes a new session: ``out`` must not exist or be an empty folder."""
    if (out / "session.json").exists():
        raise ImportInputError(f"{out}: already holds a session; choose another --out (recorded data is never overwritten)")
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ImportInputError(f"{out}: exists and is not an empty folder; choose another --out")


def _pairs(recs: dict):
    """``(index, {camera: image})`` over all inputs in step (their counts were checked equal)."""
    gens = {cam: rec.frames() for cam, rec in recs.items()}
    for items in zip(*gens.values()):
        yield items[0][0], {cam: img for cam, (_, img) in zip(gens, items)}


def _write_passes(plan: ImportPlan, writer, progress) -> list:
    """Write every input frame as a background or robot frame; returns the provenance rows."""
    total = sum(len(roles) for _, roles in plan.passes)
    done, n_bg, n_fr, rows = 0, 0, 0, []
    sizes = {c: (plan.rig[c].width, plan.rig[c].height) for c in plan.rig.names}
    for recs, roles in plan.passes:
        for i, raw in _pairs(recs):
            images = {c: to_session_image(img, recs[c].where(i), sizes[c], plan.masks) for c, img in raw.items()}
            if roles[i] == "background":
                writer.add_background(n_bg, images)
                rows.append(["background", n_bg] + [recs[c].where(i) for c in plan.rig.names])
                n_bg += 1
            else:
                cam_t = {c: plan.times_s[c][i] for c in plan.rig.names}
                writer.add_frame(n_fr, images, t_s=float(np.mean(list(cam_t.values()))), joints=plan.joints[n_fr],
                                 camera_times_s=cam_t)
                rows.append(["frame", n_fr] + [recs[c].where(i) for c in plan.rig.names])
                n_fr += 1
            done += 1
            if progress is not None:
                progress("import", done, total)
    return rows


def _write_mask_background(plan: ImportPlan, writer) -> None:
    for i in range(MASK_BACKGROUND_FRAMES):
        writer.add_background(i, {c: np.full((plan.rig[c].height, plan.rig[c].width), plan.mask_background_value,
                                             np.uint8) for c in plan.rig.names})


def write_import(plan: ImportPlan, out, progress=None) -> Path:
    """Write the session of ``plan`` into ``out`` (new or empty) with :class:`rig.session.SessionWriter`.

    Also writes ``sources.csv``: the input file (or video frame) of every stored frame.
    A failure or Ctrl-C part way removes what was written (the inputs are still there:
    run the import again).
    """
    out = Path(out)
    check_out_dir(out)
    existed = out.exists()
    try:
        with SessionWriter(out, plan.rig, source="rig", n_tubes=plan.n_tubes, meta=plan.meta) as writer:
            if plan.mask_background_value is not None:
                _write_mask_background(plan, writer)
            rows = _write_passes(plan, writer, progress)
        buf = io.StringIO()
        csv.writer(buf, lineterminator="\n").writerows([["kind", "index"] + list(plan.rig.names)] + rows)
        atomic_write_bytes(out / "sources.csv", buf.getvalue().encode())
    except BaseException:
        shutil.rmtree(out, ignore_errors=True)
        if existed:
            out.mkdir()          # it was an empty folder the user made: leave it as it was
        raise
    return out
