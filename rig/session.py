"""Session directories: what the twin renders and the rig records, and what ``reconstruct`` reads.

The layout (version 1) is documented in ``docs/session-format.md``. Writing is
crash-safe: every image is written to a temporary name and renamed, and a frame
exists only once its row is appended (and flushed to disk) in ``frames.csv``,
after all its files. A process killed at any moment leaves every finished frame
readable.
"""
from __future__ import annotations

import csv
import io
import json
import os
from datetime import datetime, timezone
from pathlib import Path

import cv2
import numpy as np

from recon.memory import MemoryBoundError, check_memory, reconstruction_bytes
from recon.rigcal import RigCalibration, load_rig_calibration, save_rig_calibration
from recon.textfile import parse_json
from rig.session_checks import (
    FrameRecord,
    SessionError,
    TruthError,
    check_cameras,
    check_meta,
    check_truth,
    frame_columns,
    load_truth,
    parse_frames_csv,
    read_text,
    tube_radii_mm,
)

__all__ = ["SessionWriter", "Session", "SessionError", "TruthError", "FrameRecord", "FORMAT", "VERSION", "read_image", "atomic_write_bytes"]

FORMAT = "ctr-bench-session"
VERSION = 1


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def _png_bytes(image: np.ndarray) -> bytes:
    img = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise SessionError("could not encode a PNG image")
    return buf.tobytes()


def read_image(path) -> np.ndarray:
    """Read a PNG as mono (H, W) or RGB (H, W, 3) uint8; a clear error names an unreadable file."""
    path = Path(path)
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except FileNotFoundError:
        raise SessionError(f"{path}: image file missing") from None
    except IsADirectoryError:
        raise SessionError(f"{path}: is a directory, not an image file") from None
    except OSError as exc:
        raise SessionError(f"{path}: cannot read the image ({exc.strerror or type(exc).__name__})") from None
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if img is None:
        raise SessionError(f"{path}: unreadable image (not a valid PNG)")
    if img.dtype != np.uint8:
        raise SessionError(f"{path}: expected an 8-bit image, got {img.dtype}")
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB if img.shape[2] == 4 else cv2.COLOR_BGR2RGB)
    return img


class SessionWriter:
    """Creates a session directory and appends frames to it as they come.

    Parameters
    ----------
    directory : path
        Created if missing; must not already hold a session (no silent overwrite).
    rig : RigCalibration
        The calibration reconstruction should use (nominal for the twin).
    source : {"twin", "rig"}
    n_tubes : int
        Joint columns in ``frames.csv`` (extension and rotation per tube).
    meta : dict, optional
        Extra JSON-ready facts stored in ``session.json`` (scene file, robot, model...).
    """

    def __init__(self, directory, rig: RigCalibration, source: str, n_tubes: int, meta: dict | None = None):
        self.dir = Path(directory)
        if (self.dir / "session.json").exists():
            raise SessionError(f"{self.dir}: already holds a session; choose another --out or remove it")
        self.cameras = rig.names
        self.n_tubes = int(n_tubes)
        for sub in ("background", "frames"):
            for cam in self.cameras:
                (self.dir / sub / cam).mkdir(parents=True, exist_ok=True)
        self.has_truth = False
        save_rig_calibration(self.dir / "rig.json", rig)
        cam0 = rig[self.cameras[0]]
        self.meta = {
            "format": FORMAT,
            "version": VERSION,
            "source": source,
            "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "cameras": self.cameras,
            "image_size": [cam0.width, cam0.height],
            "n_tubes": self.n_tubes,
            "background_frames": 0,
            **(meta or {}),
        }
        self._write_meta()
        self._csv_path = self.dir / "frames.csv"
        self._columns = frame_columns(self.cameras, self.n_tubes)
        with open(self._csv_path, "w", newline="") as fh:
            csv.writer(fh).writerow(self._columns)
        self._csv = open(self._csv_path, "a", newline="")
        self.frames_written = 0

    def _write_meta(self) -> None:
        atomic_write_bytes(self.dir / "session.json", (json.dumps(self.meta, indent=2) + "\n").encode())

    def _write_images(self, sub: str, index: int, images: dict) -> None:
        for cam in self.cameras:
            if cam not in images:
                raise SessionError(f"frame {index}: no image from camera {cam!r}")
            atomic_write_bytes(self.dir / sub / cam / f"{index:06d}.png", _png_bytes(images[cam]))

    def add_background(self, index: int, images: dict) -> None:
        """Store robot-free frame ``index`` (one image per camera)."""
        self._write_images("background", index, images)
        self.meta["background_frames"] = max(self.meta["background_frames"], index + 1)
        self._write_meta()

    def add_frame(self, index: int, images: dict, t_s: float, joints=None, camera_times_s: dict | None = None, truth: dict | None = None) -> None:
        """Store robot frame ``index``: images, joint values and (twin) ground truth.

        Parameters
        ----------
        images : dict camera -> uint8 image
        t_s : float
            Frame time (s since the session started).
        joints : object with ``extension_mm`` and ``rotation_deg`` sequences, or None
        camera_times_s : dict camera -> s, optional
            Per-camera grab times; their spread is recorded as ``skew_ms``.
        truth : dict, optional
            Arrays saved to ``truth/NNNNNN.npz`` (see docs/session-format.md).
        """
        self._write_images("frames", index, images)
        if truth is not None:
            (self.dir / "truth").mkdir(exist_ok=True)
            buf = io.BytesIO()
            np.savez_compressed(buf, **truth)
            atomic_write_bytes(self.dir / "truth" / f"{index:06d}.npz", buf.getvalue())
            if not self.has_truth:
                self.has_truth = True
                self.meta["ground_truth"] = True
                self._write_meta()
        times = camera_times_s or {c: t_s for c in self.cameras}
        skew_ms = (max(times.values()) - min(times.values())) * 1e3
        row = [index, f"{t_s:.6f}"] + [f"{times[c]:.6f}" for c in self.cameras] + [f"{skew_ms:.3f}"]
        if joints is not None:
            for e, r in zip(joints.extension_mm, joints.rotation_deg):
                row += [f"{e:.6f}", f"{r:.6f}"]
        else:
            row += [""] * (2 * self.n_tubes)
        # The row is the commit mark of the frame: written last, flushed and synced.
        csv.writer(self._csv).writerow(row)
        self._csv.flush()
        os.fsync(self._csv.fileno())
        self.frames_written += 1

    def close(self) -> None:
        if not self._csv.closed:
            self._csv.close()
        _fsync_dir(self.dir)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class Session:
    """A session directory opened for reading (docs/session-format.md).

    Everything but the images and the ground truth is read and checked when the
    session is opened: ``session.json``, ``rig.json``, ``frames.csv``, and that the
    cameras agree between them and with the ``frames/`` and ``background/`` folders.

    Parameters
    ----------
    directory : path
    allow_empty : bool
        Accept a session without any committed frame (e.g. background frames only);
        by default that is refused, as nothing could be reconstructed from it.

    Attributes
    ----------
    meta : dict
        ``session.json``.
    rig : RigCalibration
    cameras : list of str
    n_tubes : int
    frames : list of FrameRecord
        The committed frames, in ``frames.csv`` order.
    notes : list of str
        One line per thing forgiven while reading (a last ``frames.csv`` row cut short by a crash).

    Raises
    ------
    SessionError
        One line naming the file (and its key or line) and what is wrong.
    """

    def __init__(self, directory, allow_empty: bool = False):
        self.dir = Path(directory)
        if not self.dir.is_dir():
            raise SessionError(f"{self.dir}: not a directory")
        meta_path = self.dir / "session.json"
        self.meta = _read_meta(meta_path)
        self.rig: RigCalibration = _read_rig(self.dir / "rig.json")
        self.cameras = check_cameras(self.meta.get("cameras", self.rig.names), meta_path, self.rig.names, self.dir / "rig.json")
        self.n_tubes = self.meta.get("n_tubes", 0)
        self._check_memory()
        self.frames, self.notes = self._read_frames()
        if not self.frames and not allow_empty:
            cut = f" ({self.notes[0]})" if self.notes else ""
            raise SessionError(f"{self.dir / 'frames.csv'}: no committed frames, nothing to reconstruct{cut}")

    def _check_memory(self) -> None:
        """Refuse a session whose reconstruction would exceed the memory bound (:mod:`recon.memory`), before any image is read.

        The estimate is that of the largest camera's frames with its background frames; the
        message names rig.json's camera and the figure (``CTR_BENCH_MEMORY_LIMIT_GB`` raises the limit).
        """
        cam = max((self.rig[c] for c in self.cameras), key=lambda c: c.width * c.height)
        n_bg = len(self.background_paths(cam.name))
        try:
            check_memory(reconstruction_bytes(cam.width, cam.height, n_bg), f"{self.dir / 'rig.json'}: cameras.{cam.name}",
                         f"reconstructing {cam.width}x{cam.height} px frames with {n_bg} background frames", SessionError)
        except MemoryBoundError as exc:  # the variable itself is malformed
            raise SessionError(f"{self.dir}: {exc}") from None

    def _read_frames(self) -> tuple:
        path = self.dir / "frames.csv"
        try:
            text = read_text(path)
        except FileNotFoundError:
            raise SessionError(f"{path}: missing") from None
        return parse_frames_csv(text, path, self.cameras, self.n_tubes)

    @property
    def robot_tube_radii_mm(self):
        """(outermost, innermost) tube radius (mm) of the robot in session.json (one tube: both the same), or None without one."""
        radii = tube_radii_mm(self.meta.get("robot"), self.dir / "session.json")
        return (radii[0], radii[-1]) if radii else None

    @property
    def has_truth(self) -> bool:
        return bool(self.meta.get("ground_truth"))

    @property
    def image_size(self) -> tuple:
        return tuple(self.meta.get("image_size", (0, 0)))

    def background_paths(self, camera: str) -> list:
        """Sorted background PNG paths of ``camera``."""
        return sorted((self.dir / "background" / camera).glob("[0-9]*.png"))

    def background_stack(self, camera: str) -> np.ndarray:
        """All background frames of ``camera`` as (N, H, W) uint8; errors name the bad file."""
        paths = self.background_paths(camera)
        if not paths:
            raise SessionError(f"{self.dir / 'background' / camera}: no background frames")
        imgs = []
        for p in paths:
            img = read_image(p)
            if img.ndim == 3:
                img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
            if imgs and img.shape != imgs[0].shape:
                raise SessionError(f"{p}: size {img.shape[1]}x{img.shape[0]} differs from the other background frames ({imgs[0].shape[1]}x{imgs[0].shape[0]})")
            imgs.append(img)
        return np.stack(imgs)

    def frame_path(self, index: int, camera: str) -> Path:
        return self.dir / "frames" / camera / f"{index:06d}.png"

    def frame_images(self, index: int, mono: bool = True) -> dict:
        """Images of frame ``index`` by camera (mono unless ``mono=False``); an unreadable one is a SessionError naming it."""
        out = {}
        for cam in self.cameras:
            img = read_image(self.frame_path(index, cam))
            if mono and img.ndim == 3:
                img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
            out[cam] = img
        return out

    def truth_path(self, index: int) -> Path:
        return self.dir / "truth" / f"{index:06d}.npz"

    def truth(self, index: int) -> dict | None:
        """Ground truth arrays of frame ``index``, checked (docs/session-format.md); None when the session has none.

        A frame's truth concerns that frame only: a caller scoring several frames
        catches :class:`TruthError` per frame, records its one-line message (e.g.
        ``rec["note"] = f"not scored: {exc}"``) and goes on::

            try:
                truth = session.truth(i)
            except TruthError as exc:
                truth, note = None, str(exc)

        Raises
        ------
        TruthError
            Naming the npz file: missing while ``session.json`` says the session has
            ground truth, not a readable npz archive, no ``backbone_world_mm``, an array
            of the wrong shape or dtype, NaN or inf where the format has finite values.
        """
        path = self.truth_path(index)
        try:
            arrays = load_truth(path)
        except FileNotFoundError:
            if self.has_truth:
                raise TruthError(f"{path}: missing (session.json says the session has ground truth)") from None
            return None
        sizes = {c: (self.rig[c].height, self.rig[c].width) for c in self.cameras}
        return check_truth(arrays, path, sizes, self.n_tubes)


def _read_meta(path: Path) -> dict:
    """``session.json``, parsed and checked (:func:`rig.session_checks.check_meta`)."""
    try:
        text = read_text(path)
    except FileNotFoundError:
        raise SessionError(f"{path.parent}: no session.json (not a ctr-bench session directory)") from None
    meta = parse_json(text, path, SessionError)
    check_meta(meta, path, FORMAT, VERSION)
    return meta


def _read_rig(path: Path) -> RigCalibration:
    """The session's rig calibration; whatever is wrong with it is a SessionError naming ``path``."""
    try:
        read_text(path)  # binary content: say so, rather than the codec's message
        return load_rig_calibration(path)
    except FileNotFoundError:
        raise SessionError(f"{path}: rig calibration file not found") from None
    except SessionError:
        raise
    except (ValueError, TypeError, KeyError, AttributeError) as exc:
        # recon.rigcal's messages name the file; anything else it lets through is made to.
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise SessionError(msg if msg.startswith(str(path)) else f"{path}: malformed rig calibration ({msg})") from None
