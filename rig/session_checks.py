"""Checks of what a session directory holds: ``session.json``, ``frames.csv`` and ``truth/*.npz``.

:class:`rig.session.Session` runs these when it opens a session, before any
frame is read, so that a malformed input is refused at once with one line that
names the file, the key or line, and what is wrong (docs/session-format.md).
They are pure functions of their inputs (text, parsed JSON, arrays) so that a
test can call each on its own.
"""
from __future__ import annotations

import math
import re
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["SessionError", "TruthError", "FrameRecord", "MAX_TUBES", "read_text", "check_meta", "check_cameras",
           "tube_radii_mm", "frame_columns", "parse_frames_csv", "load_truth", "check_truth"]

MAX_TUBES = 8  # no concentric tube robot has more; a larger n_tubes is a typo, not a robot
_CAMERA_NAME = re.compile(r"\w[\w.-]*")  # a name is a folder under frames/ and background/: no path parts
_INDEX = re.compile(r"[0-9]+")


class SessionError(ValueError):
    """A session directory or file that cannot be read; the message names the path."""


class TruthError(SessionError):
    """One frame's ground truth that cannot be used (missing, corrupt, wrong shape, not finite).

    It concerns that frame only: a caller scoring many frames records the message
    (e.g. as the frame's note) and goes on with the next frame.
    """


@dataclass(frozen=True)
class FrameRecord:
    """One row of ``frames.csv``."""

    index: int
    t_s: float
    skew_ms: float
    extension_mm: tuple | None
    rotation_deg: tuple | None


def _show(value, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters: a message stays one short line whatever the file holds."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def read_text(path: Path) -> str:
    """The UTF-8 text of ``path`` (a leading BOM dropped).

    Raises
    ------
    FileNotFoundError
        When ``path`` does not exist (the caller says what that means).
    SessionError
        ``"<path>: not a text file (...)"`` for binary content; ``"<path>: cannot read (...)"``
        for a directory or a file that cannot be opened.
    """
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise
    except OSError as exc:
        raise SessionError(f"{path}: cannot read ({exc.strerror or type(exc).__name__})") from None
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise SessionError(f"{path}: not a text file (byte 0x{data[exc.start]:02x} at offset {exc.start} is not UTF-8)") from None
    if "\x00" in text:
        raise SessionError(f"{path}: not a text file (NUL byte at offset {text.index(chr(0))})")
    return text


# ----------------------------------------------------------------------------- session.json

def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


# key -> (test, what the value must be); keys absent from session.json are not checked here.
_META_KEYS = {
    "source": (lambda v: isinstance(v, str), "a string"),
    "created": (lambda v: isinstance(v, str), "a string"),
    "n_tubes": (lambda v: _is_int(v) and 0 <= v <= MAX_TUBES, f"an integer from 0 to {MAX_TUBES}"),
    "image_size": (lambda v: isinstance(v, list) and len(v) == 2 and all(_is_int(x) and x > 0 for x in v),
                   "[width, height] in pixels (two positive integers)"),
    "background_frames": (lambda v: _is_int(v) and v >= 0, "an integer >= 0"),
    "ground_truth": (lambda v: isinstance(v, bool), "true or false"),
}


def check_meta(meta, path: Path, fmt: str, version: int) -> None:
    """Refuse a ``session.json`` that is not an object of the documented keys and types.

    Parameters
    ----------
    meta : object
        The parsed JSON.
    path : Path
        The file, named in every message.
    fmt, version : str, int
        The format name and the version this reader understands.

    Raises
    ------
    SessionError
        One line: ``"<path>: <key> must be <what>, got <value>"`` (or the format/version refused).
    """
    if not isinstance(meta, dict):
        raise SessionError(f"{path}: must be a JSON object, got {type(meta).__name__} {_show(meta, 30)}")
    if meta.get("format") != fmt:
        raise SessionError(f"{path}: format is {_show(meta.get('format'))}, expected {fmt!r}")
    if meta.get("version") != version or not _is_int(meta.get("version")):
        raise SessionError(f"{path}: version {_show(meta.get('version'))} is not supported (this ctr-bench reads {version})")
    for key, (ok, what) in _META_KEYS.items():
        if key in meta and not ok(meta[key]):
            raise SessionError(f"{path}: {key} must be {what}, got {_show(meta[key])}")
    tube_radii_mm(meta.get("robot"), path)


def tube_radii_mm(robot, path: Path) -> list:
    """Radii (mm) of ``session.json``'s ``robot.tubes``, outermost first; ``[]`` without a robot or tubes.

    Raises
    ------
    SessionError
        ``robot`` not an object, ``robot.tubes`` not a list, or a tube without a finite,
        positive numeric ``outer_diameter_mm``.
    """
    if robot is None:
        return []
    if not isinstance(robot, dict):
        raise SessionError(f"{path}: robot must be an object, got {_show(robot)}")
    tubes = robot.get("tubes") or []
    if not isinstance(tubes, list):
        raise SessionError(f"{path}: robot.tubes must be a list, got {_show(tubes)}")
    radii = []
    for i, tube in enumerate(tubes):
        od = tube.get("outer_diameter_mm") if isinstance(tube, dict) else None
        if not (_is_number(od) and od > 0):
            raise SessionError(f"{path}: robot.tubes[{i}]: each tube needs a numeric outer_diameter_mm > 0, got {_show(od)}")
        radii.append(od / 2)
    return radii


def check_cameras(cameras, meta_path: Path, rig_names: list, rig_path: Path) -> list:
    """The camera names of ``session.json``, checked against the rig calibration and the folders.

    Parameters
    ----------
    cameras : object
        ``session.json``'s ``cameras`` value (``rig_names`` when the key is absent).
    meta_path, rig_path : Path
        ``session.json`` and ``rig.json``; the session directory is their folder.
    rig_names : list of str
        The cameras ``rig.json`` calibrates.

    Returns
    -------
    list of str

    Raises
    ------
    SessionError
        One line naming ``session.json``'s ``cameras`` key: not a list of names, a name twice,
        a name ``rig.json`` lacks (or one it has that the list lacks), or no ``frames/<name>``
        or ``background/<name>`` folder.
    """
    where = f"{meta_path}: cameras"
    if not isinstance(cameras, list) or not all(isinstance(c, str) for c in cameras):
        raise SessionError(f"{where} must be a list of camera names, got {_show(cameras)}")
    if not cameras:
        raise SessionError(f"{where} must name at least one camera, got []")
    session_dir = meta_path.parent
    for i, name in enumerate(cameras):
        if not _CAMERA_NAME.fullmatch(name):
            raise SessionError(f"{where}[{i}]: {name!r} is not a camera name (letters, digits, '_', '.', '-')")
        if name in cameras[:i]:
            raise SessionError(f"{where}: {name!r} is listed twice")
        if name not in rig_names:
            raise SessionError(f"{where}: {name!r} is not in {rig_path} (it calibrates {', '.join(rig_names)})")
        for sub in ("frames", "background"):
            if not (session_dir / sub / name).is_dir():
                raise SessionError(f"{where}: {name!r} has no {sub}/{name} folder")
    extra = [n for n in rig_names if n not in cameras]
    if extra:
        raise SessionError(f"{where} lacks {', '.join(map(repr, extra))}, which {rig_path} calibrates")
    return list(cameras)


# ----------------------------------------------------------------------------- frames.csv

def frame_columns(cameras: list, n_tubes: int) -> list:
    """The columns of ``frames.csv`` for these cameras and tubes, in the writer's order."""
    joints = [col for i in range(n_tubes) for col in (f"extension_{i}_mm", f"rotation_{i}_deg")]
    return ["frame", "t_s"] + [f"t_{c}_s" for c in cameras] + ["skew_ms"] + joints


def _check_header(header: list, path: Path, cameras: list, n_tubes: int) -> None:
    """Refuse a header with a column twice, a column missing or one the format does not have."""
    expected = frame_columns(cameras, n_tubes)
    for i, col in enumerate(header):
        if col in header[:i]:
            raise SessionError(f"{path}:1: column {col!r} appears twice")
    why = f"(cameras {', '.join(cameras)}, n_tubes {n_tubes} in session.json)"
    missing = [c for c in expected if c not in header]
    if missing:
        raise SessionError(f"{path}:1: missing column {missing[0]!r} {why}")
    extra = [c for c in header if c not in expected]
    if extra:
        raise SessionError(f"{path}:1: unexpected column {_show(extra[0])} {why}")


def _number(row: dict, col: str, where: str, empty=None) -> float:
    """The finite number in ``row[col]``; ``empty`` for an empty field when that is allowed (not None)."""
    text = row[col]
    if text == "" and empty is not None:
        return empty
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not math.isfinite(v):
        raise SessionError(f"{where}: {col} must be a finite number, got {_show(text)}")
    return v


def _joints(row: dict, where: str, n_tubes: int) -> tuple:
    """(extension_mm, rotation_deg) of a row, or (None, None) when all its joint fields are empty."""
    cols = frame_columns([], n_tubes)[3:]
    filled = [c for c in cols if row[c] != ""]
    if not filled:
        return None, None
    if len(filled) < len(cols):
        empty = next(c for c in cols if row[c] == "")
        raise SessionError(f"{where}: joint values partly empty ({empty} is empty, {filled[0]} is not)")
    values = [_number(row, c, where) for c in cols]
    return tuple(values[0::2]), tuple(values[1::2])


def _record(row: dict, where: str, cameras: list, n_tubes: int) -> FrameRecord:
    """The :class:`FrameRecord` of one complete row; a bad field is one line naming its column."""
    if not _INDEX.fullmatch(row["frame"]):
        raise SessionError(f"{where}: frame must be an integer >= 0, got {_show(row['frame'])}")
    t_s = _number(row, "t_s", where)
    for cam in cameras:
        _number(row, f"t_{cam}_s", where)
    skew = _number(row, "skew_ms", where, empty=0.0)  # empty: an older writer had no skew to record
    ext, rot = _joints(row, where, n_tubes)
    return FrameRecord(int(row["frame"]), t_s, skew, ext, rot)


def _fast_record(fields: list, n_cameras: int, n_tubes: int) -> FrameRecord | None:
    """The record of a row in the writer's column order whose fields are all finite numbers, else None.

    Most rows are such; the checking path (:func:`_record`) is about 5 times slower and
    is only needed to say what is wrong with a row, or for rows without joint values.
    """
    if not (fields[0].isascii() and fields[0].isdigit()):
        return None
    try:
        nums = [float(f) for f in fields[1:]]
    except ValueError:
        return None
    if not all(map(math.isfinite, nums)):
        return None
    joints = nums[2 + n_cameras :]
    ext, rot = (tuple(joints[0::2]), tuple(joints[1::2])) if n_tubes else (None, None)
    return FrameRecord(int(fields[0]), nums[0], nums[1 + n_cameras], ext, rot)


def _lines(text: str) -> tuple:
    """``(numbered lines, ended)``: (line number, text) without line ends or trailing blank lines,
    and whether the last of them ended with a line end (a row is committed with its line end)."""
    raw = text.split("\n")  # not splitlines(): garbage characters must not make lines of their own
    lines = [(n, s.rstrip("\r")) for n, s in enumerate(raw, start=1)]
    ended = raw[-1] == ""
    while lines and not lines[-1][1].strip():
        lines.pop()
        ended = True
    return lines, ended


def parse_frames_csv(text: str, path: Path, cameras: list, n_tubes: int) -> tuple:
    """The frame rows of ``frames.csv``.

    Only the last row may be cut short (fewer fields than the header, or no line end):
    a crash while the writer appended it, so the frame was never committed. It is
    left out and said so in the notes. Anything else malformed is refused.

    Parameters
    ----------
    text : str
        The file's text.
    path : Path
        The file, named in every message.
    cameras : list of str
    n_tubes : int

    Returns
    -------
    records : list of FrameRecord
        In file order.
    notes : list of str
        One line per row left out.

    Raises
    ------
    SessionError
        ``"<path>:<line>: <what is wrong>"``: a missing, repeated or unknown column, a row of
        the wrong length, a field that is not a (finite) number, a frame index seen before.
    """
    lines, ended = _lines(text)
    if not lines:
        raise SessionError(f"{path}: empty (no header row)")
    header = [c.strip() for c in lines[0][1].split(",")]
    _check_header(header, path, cameras, n_tubes)
    in_order = header == frame_columns(cameras, n_tubes)
    records, notes, seen = [], [], {}
    for k, (n, line) in enumerate(lines[1:], start=2):
        fields = [f.strip() for f in line.split(",")]
        if k == len(lines) and (len(fields) < len(header) or not ended):
            cut = "no line end" if len(fields) >= len(header) else f"{len(fields)} of {len(header)} fields"
            notes.append(f"{path}:{n}: last row cut short ({cut}): its frame was never committed, left out")
            break
        if len(fields) != len(header):
            raise SessionError(f"{path}:{n}: {len(fields)} fields, the header has {len(header)}"
                               + (" (an empty line)" if not line.strip() else ""))
        rec = _fast_record(fields, len(cameras), n_tubes) if in_order else None
        rec = rec or _record(dict(zip(header, fields)), f"{path}:{n}", cameras, n_tubes)
        if rec.index in seen:
            raise SessionError(f"{path}:{n}: frame {rec.index} repeats line {seen[rec.index]}")
        seen[rec.index] = n
        records.append(rec)
    return records, notes


# ----------------------------------------------------------------------------- truth/NNNNNN.npz

# array -> (shape, finite); "n" is the backbone's sample count, "k" n_tubes, "H"/"W" the camera's image size.
_TRUTH_SHAPES = {
    "s_mm": (("n",), True),
    "R_world_body": (("n", 3, 3), True),
    "outer_radius_mm": (("n",), True),
    "outermost_tube": (("n",), True),
    "tip_world_mm": ((3,), True),
    "extension_mm": (("k",), True),
    "rotation_deg": (("k",), True),
}
_TRUTH_CAMERA_SHAPES = {
    "T_cam_world_{}": ((4, 4), True),
    "labels_{}": (("H", "W"), False),
    "depth_mm_{}": (("H", "W"), True),
    "centerline_px_{}": (("n", 2), False),  # NaN where a sample does not project (behind the camera)
}


def load_truth(path: Path) -> dict:
    """All arrays of a truth npz; a file that is no readable npz archive is a :class:`TruthError`."""
    try:
        with zipfile.ZipFile(path) as _:
            pass  # np.load would take a non-zip file for a pickle or .npy, with a misleading message
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise
    except OSError as exc:
        raise TruthError(f"{path}: unreadable ground truth ({exc.strerror or type(exc).__name__})") from None
    except (zipfile.BadZipFile, zlib.error, ValueError, EOFError, KeyError) as exc:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise TruthError(f"{path}: unreadable ground truth (not an npz archive, or a damaged one: {reason})") from None
    odd = [k for k, v in arrays.items() if not isinstance(v, np.ndarray)]  # a zip member that is no .npy file
    if odd:
        raise TruthError(f"{path}: unreadable ground truth ({odd[0]!r} is not an array)")
    return arrays


def _check_array(name: str, a: np.ndarray, shape: tuple, finite: bool, dims: dict, path: Path) -> None:
    """Refuse an array of another shape than ``shape`` (names in ``dims``), not numeric or not finite."""
    want = tuple(dims.get(d, d) for d in shape)
    if a.dtype.kind not in "biuf":
        raise TruthError(f"{path}: {name} has dtype {a.dtype}, expected numbers")
    if a.shape != want:
        show = ", ".join(f"{d}={dims[d]}" if d in dims else str(d) for d in shape)
        raise TruthError(f"{path}: {name} has shape {a.shape}, expected ({show}{',' if len(shape) == 1 else ''})")
    if finite and a.dtype.kind == "f" and not np.all(np.isfinite(a)):
        raise TruthError(f"{path}: {name} holds NaN or inf")


def check_truth(arrays: dict, path: Path, image_sizes: dict, n_tubes: int) -> dict:
    """``arrays`` when they are the ground truth docs/session-format.md describes, else a :class:`TruthError`.

    ``backbone_world_mm`` (n >= 2, 3) is required and finite; every other documented array
    is optional and, when present, checked for its shape and (where the format says so)
    finiteness. Arrays the format does not name are kept unchecked.

    Parameters
    ----------
    arrays : dict name -> ndarray
    path : Path
        The npz file, named in every message.
    image_sizes : dict camera -> (height, width)
    n_tubes : int
        Length of the joint arrays (not checked when 0).
    """
    bb = arrays.get("backbone_world_mm")
    if bb is None:
        raise TruthError(f"{path}: no backbone_world_mm array")
    n = bb.shape[0] if bb.ndim else 0
    _check_array("backbone_world_mm", bb, ("n", 3), True, {"n": n}, path)
    if n < 2:
        raise TruthError(f"{path}: backbone_world_mm has {n} point(s), a backbone needs at least 2")
    for name, (shape, finite) in _TRUTH_SHAPES.items():
        if name in arrays and not (name in ("extension_mm", "rotation_deg") and n_tubes == 0):
            _check_array(name, arrays[name], shape, finite, {"n": n, "k": n_tubes}, path)
    for cam, (h, w) in image_sizes.items():
        for pattern, (shape, finite) in _TRUTH_CAMERA_SHAPES.items():
            name = pattern.format(cam)
            if name in arrays:
                _check_array(name, arrays[name], shape, finite, {"n": n, "H": h, "W": w}, path)
    return arrays
