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
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import cv2
import numpy as np

from recon.rigcal import RigCalibration, load_rig_calibration, save_rig_calibration

__all__ = ["SessionWriter", "Session", "SessionError", "FORMAT", "VERSION", "read_image"]

FORMAT = "ctr-bench-session"
VERSION = 1


class SessionError(ValueError):
    """A session directory or file that cannot be read; the message names the path."""


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


def _atomic_write_bytes(path: Path, data: bytes) -> None:
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
    data = np.fromfile(path, dtype=np.uint8) if path.exists() else None
    if data is None:
        raise SessionError(f"{path}: image file missing")
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if img is None:
        raise SessionError(f"{path}: unreadable image (not a valid PNG)")
    if img.dtype != np.uint8:
        raise SessionError(f"{path}: expected an 8-bit image, got {img.dtype}")
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB if img.shape[2] == 4 else cv2.COLOR_BGR2RGB)
    return img


def _joint_columns(n_tubes: int) -> list:
    cols = []
    for i in range(n_tubes):
        cols += [f"extension_{i}_mm", f"rotation_{i}_deg"]
    return cols


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
        self._columns = ["frame", "t_s"] + [f"t_{c}_s" for c in self.cameras] + ["skew_ms"] + _joint_columns(self.n_tubes)
        with open(self._csv_path, "w", newline="") as fh:
            csv.writer(fh).writerow(self._columns)
        self._csv = open(self._csv_path, "a", newline="")
        self.frames_written = 0

    def _write_meta(self) -> None:
        _atomic_write_bytes(self.dir / "session.json", (json.dumps(self.meta, indent=2) + "\n").encode())

    def _write_images(self, sub: str, index: int, images: dict) -> None:
        for cam in self.cameras:
            if cam not in images:
                raise SessionError(f"frame {index}: no image from camera {cam!r}")
            _atomic_write_bytes(self.dir / sub / cam / f"{index:06d}.png", _png_bytes(images[cam]))

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
            _atomic_write_bytes(self.dir / "truth" / f"{index:06d}.npz", buf.getvalue())
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


@dataclass(frozen=True)
class FrameRecord:
    """One row of ``frames.csv``."""

    index: int
    t_s: float
    skew_ms: float
    extension_mm: tuple | None
    rotation_deg: tuple | None


class Session:
    """A session directory opened for reading.

    Raises :class:`SessionError` naming the file when something is missing or malformed.
    """

    def __init__(self, directory):
        self.dir = Path(directory)
        meta_path = self.dir / "session.json"
        if not self.dir.is_dir():
            raise SessionError(f"{self.dir}: not a directory")
        try:
            self.meta = json.loads(meta_path.read_text())
        except FileNotFoundError:
            raise SessionError(f"{self.dir}: no session.json (not a ctr-bench session directory)") from None
        except json.JSONDecodeError as exc:
            raise SessionError(f"{meta_path}: not valid JSON ({exc.msg})") from None
        if self.meta.get("format") != FORMAT:
            raise SessionError(f"{meta_path}: format is {self.meta.get('format')!r}, expected {FORMAT!r}")
        if self.meta.get("version") != VERSION:
            raise SessionError(f"{meta_path}: version {self.meta.get('version')!r} is not supported (this ctr-bench reads {VERSION})")
        self.rig: RigCalibration = load_rig_calibration(self.dir / "rig.json")
        self.cameras = list(self.meta.get("cameras", self.rig.names))
        self.n_tubes = int(self.meta.get("n_tubes", 0))
        self.frames = self._read_frames()

    def _read_frames(self) -> list:
        path = self.dir / "frames.csv"
        if not path.exists():
            raise SessionError(f"{path}: missing")
        records = []
        with open(path, newline="") as fh:
            reader = csv.DictReader(fh)
            for line, row in enumerate(reader, start=2):
                if None in row or any(v is None for v in row.values()):
                    break  # a row cut short by a crash: the frame never committed
                try:
                    ext = rot = None
                    if self.n_tubes and row.get("extension_0_mm"):
                        ext = tuple(float(row[f"extension_{i}_mm"]) for i in range(self.n_tubes))
                        rot = tuple(float(row[f"rotation_{i}_deg"]) for i in range(self.n_tubes))
                    records.append(FrameRecord(int(row["frame"]), float(row["t_s"]), float(row.get("skew_ms") or 0.0), ext, rot))
                except (KeyError, ValueError) as exc:
                    raise SessionError(f"{path}:{line}: malformed row ({exc})") from None
        return records

    @property
    def robot_tube_radii_mm(self):
        """(outermost, innermost) tube radius (mm) of the robot in session.json (one tube: both the same), or None without one."""
        tubes = (self.meta.get("robot") or {}).get("tubes") or []
        try:
            radii = [float(t["outer_diameter_mm"]) / 2 for t in tubes]
        except (KeyError, TypeError, ValueError):
            raise SessionError(f"{self.dir / 'session.json'}: robot.tubes: each tube needs a numeric outer_diameter_mm") from None
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
        """Images of frame ``index`` by camera (mono unless ``mono=False``)."""
        out = {}
        for cam in self.cameras:
            img = read_image(self.frame_path(index, cam))
            if mono and img.ndim == 3:
                img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
            out[cam] = img
        return out

    def truth(self, index: int) -> dict | None:
        """Ground truth arrays of frame ``index`` (None when the session has none)."""
        path = self.dir / "truth" / f"{index:06d}.npz"
        if not path.exists():
            return None
        try:
            with np.load(path) as z:
                return {k: z[k] for k in z.files}
        except (OSError, ValueError) as exc:
            raise SessionError(f"{path}: unreadable ground truth ({exc})") from None
