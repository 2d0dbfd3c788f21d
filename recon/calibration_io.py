"""Calibrations in other tools' formats: OpenCV FileStorage YAML and ROS ``camera_info`` YAML.

A lab that already calibrated its cameras (OpenCV scripts, ``ros camera_calibration``,
Kalibr exports converted to these) can build the rig file from them instead of
recalibrating; and ``ctr-bench calibrate`` exports its result in the OpenCV form.

OpenCV (``cv2.FileStorage``, ``%YAML:1.0``)
    One camera: ``camera_name`` (optional), ``image_width``, ``image_height``,
    ``camera_matrix`` (3x3), ``distortion_coefficients`` (1x5: k1 k2 p1 p2 k3; 4 or
    8 coefficients are read when the extra ones are zero), optional ``T_cam_world``
    (4x4).
    Stereo: ``M1 D1`` (the **top** camera), ``M2 D2`` (the **side** camera), ``R T``
    with ``X_side = R X_top + T`` (mm), i.e. ``T_side_top`` as ``cv2.stereoCalibrate``
    returns it for (top, side); ``image_width``, ``image_height``; optional
    ``T_top_world`` (4x4).

ROS ``camera_info`` (PyYAML)
    ``image_width``, ``image_height``, ``camera_name``, ``camera_matrix`` /
    ``distortion_coefficients`` / ``rectification_matrix`` / ``projection_matrix`` as
    ``{rows, cols, data}``, ``distortion_model: plumb_bob``. It holds no pose: the
    extrinsics come from elsewhere (a world file or a calibration folder).

World file (``--world-from FILE``): YAML or JSON with ``T_top_world`` and, where the
intrinsics files do not give it, ``T_side_top`` or ``T_side_world`` (4x4, mm, as
nested lists, or OpenCV matrices in a FileStorage file).

Every reader raises ``ValueError`` naming the file and the key at fault.
"""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import yaml

from .camera import Camera, invert_transform
from .rigcal import RigCalibration

__all__ = [
    "save_opencv_camera",
    "load_opencv_camera",
    "save_opencv_stereo",
    "load_opencv_stereo",
    "save_ros_camera_info",
    "load_ros_camera_info",
    "load_world_file",
    "save_world_file",
    "rig_from_parts",
    "export_rig_opencv",
]


# ----------------------------------------------------------------------------- helpers
def _dist5(d, source: str, key: str) -> np.ndarray:
    d = np.asarray(d, np.float64).ravel()
    if d.size in (4, 5):
        return np.concatenate([d, np.zeros(5 - d.size)])
    if d.size > 5 and not np.any(d[5:]):
        return d[:5].copy()
    if d.size > 5:
        raise ValueError(f"{source}: {key}: only the k1 k2 p1 p2 k3 model is supported, got {d.size} coefficients with non-zero extras")
    raise ValueError(f"{source}: {key}: expected 4 or 5 distortion coefficients, got {d.size}")


def _check_K(K, source: str, key: str) -> np.ndarray:
    K = np.asarray(K, np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0 or abs(K[2, 2] - 1) > 1e-9:
        raise ValueError(f"{source}: {key}: not a camera matrix (3x3 with positive focal lengths and K[2,2] = 1), got {K.tolist()}")
    return K


def _check_T(T, source: str, key: str) -> np.ndarray:
    T = np.asarray(T, np.float64)
    if T.shape == (3, 4):
        T = np.vstack([T, [0, 0, 0, 1]])
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"{source}: {key}: must be a 4x4 transform, got shape {T.shape}")
    R = T[:3, :3]
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or abs(np.linalg.det(R) - 1) > 1e-6 or np.abs(T[3] - [0, 0, 0, 1]).max() > 1e-12:
        raise ValueError(f"{source}: {key}: not a rigid transform (rotation not orthonormal or last row not 0 0 0 1)")
    return T


class _Reader:
    """Checked access to a cv2.FileStorage file."""

    def __init__(self, path):
        self.path = Path(path)
        if not self.path.is_file():
            raise ValueError(f"{self.path}: file not found")
        try:
            self.fs = cv2.FileStorage(str(self.path), cv2.FILE_STORAGE_READ)
        except cv2.error:
            raise ValueError(f"{self.path}: not an OpenCV FileStorage file (YAML/XML/JSON)") from None
        if not self.fs.isOpened():
            raise ValueError(f"{self.path}: not an OpenCV FileStorage file (YAML/XML/JSON)")

    def has(self, key) -> bool:
        node = self.fs.getNode(key)
        return not node.empty()

    def mat(self, key, required=True):
        node = self.fs.getNode(key)
        if node.empty():
            if required:
                raise ValueError(f"{self.path}: missing {key}")
            return None
        m = node.mat()
        if m is None:
            raise ValueError(f"{self.path}: {key}: not a matrix")
        return np.asarray(m, np.float64)

    def number(self, key, required=True):
        node = self.fs.getNode(key)
        if node.empty():
            if required:
                raise ValueError(f"{self.path}: missing {key}")
            return None
        if not node.isReal() and not node.isInt():
            raise ValueError(f"{self.path}: {key}: must be a number")
        return node.real()

    def string(self, key):
        node = self.fs.getNode(key)
        return None if node.empty() or not node.isString() else node.string()

    def size(self):
        w, h = self.number("image_width"), self.number("image_height")
        if w <= 0 or h <= 0 or w != int(w) or h != int(h):
            raise ValueError(f"{self.path}: image_width/image_height must be positive integers, got {w} x {h}")
        return int(w), int(h)

    def close(self):
        self.fs.release()


def _writer(path) -> cv2.FileStorage:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    if not fs.isOpened():
        raise OSError(f"{path}: cannot write")
    return fs


# ----------------------------------------------------------------------------- OpenCV
def save_opencv_camera(path, camera: Camera, with_pose: bool = True) -> None:
    """One camera's intrinsics (and, with ``with_pose``, its ``T_cam_world``) as OpenCV YAML."""
    fs = _writer(path)
    fs.write("camera_name", camera.name)
    fs.write("image_width", int(camera.width))
    fs.write("image_height", int(camera.height))
    fs.write("camera_matrix", np.asarray(camera.K, np.float64))
    fs.write("distortion_coefficients", np.asarray(camera.dist, np.float64).reshape(1, 5))
    if with_pose:
        fs.write("T_cam_world", np.asarray(camera.T_cam_world, np.float64))
    fs.release()


def load_opencv_camera(path, name: str | None = None) -> Camera:
    """A :class:`Camera` from an OpenCV YAML intrinsics file (identity pose unless it has ``T_cam_world``)."""
    r = _Reader(path)
    try:
        src = str(r.path)
        w, h = r.size()
        K = _check_K(r.mat("camera_matrix"), src, "camera_matrix")
        D = _dist5(r.mat("distortion_coefficients"), src, "distortion_coefficients")
        T = r.mat("T_cam_world", required=False)
        T = np.eye(4) if T is None else _check_T(T, src, "T_cam_world")
        nm = name or r.string("camera_name") or r.path.stem
    finally:
        r.close()
    return Camera(nm, w, h, K, D, T)


def save_opencv_stereo(path, side: Camera, top: Camera, T_side_top: np.ndarray, T_top_world: np.ndarray | None = None) -> None:
    """The stereo file: ``M1 D1`` top, ``M2 D2`` side, ``R T`` = ``T_side_top`` (mm), optional ``T_top_world``."""
    if (side.width, side.height) != (top.width, top.height):
        raise ValueError(f"stereo file: the cameras' image sizes differ ({side.width}x{side.height} vs {top.width}x{top.height})")
    T = np.asarray(T_side_top, np.float64)
    fs = _writer(path)
    fs.write("image_width", int(top.width))
    fs.write("image_height", int(top.height))
    fs.write("camera1", top.name)
    fs.write("camera2", side.name)
    fs.write("M1", np.asarray(top.K, np.float64))
    fs.write("D1", np.asarray(top.dist, np.float64).reshape(1, 5))
    fs.write("M2", np.asarray(side.K, np.float64))
    fs.write("D2", np.asarray(side.dist, np.float64).reshape(1, 5))
    fs.write("R", T[:3, :3])
    fs.write("T", T[:3, 3].reshape(3, 1))
    if T_top_world is not None:
        fs.write("T_top_world", np.asarray(T_top_world, np.float64))
    fs.release()


def load_opencv_stereo(path) -> dict:
    """Read a stereo file: ``{"side": Camera, "top": Camera, "T_side_top": 4x4, "T_top_world": 4x4 or None}``.

    The cameras come back at identity pose; ``T_top_world`` is None when the file has none.
    """
    r = _Reader(path)
    try:
        src = str(r.path)
        w, h = r.size()
        M1 = _check_K(r.mat("M1"), src, "M1")
        M2 = _check_K(r.mat("M2"), src, "M2")
        D1 = _dist5(r.mat("D1"), src, "D1")
        D2 = _dist5(r.mat("D2"), src, "D2")
        R = r.mat("R")
        if R.size == 3:
            R = cv2.Rodrigues(R.reshape(3, 1))[0]
        t = r.mat("T")
        if R.shape != (3, 3) or t.size != 3:
            raise ValueError(f"{src}: R must be 3x3 (or a rotation vector) and T a 3-vector")
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = t.ravel()
        T = _check_T(T, src, "R, T")
        Tw = r.mat("T_top_world", required=False)
        Tw = None if Tw is None else _check_T(Tw, src, "T_top_world")
    finally:
        r.close()
    return {"top": Camera("top", w, h, M1, D1), "side": Camera("side", w, h, M2, D2), "T_side_top": T, "T_top_world": Tw}


# ----------------------------------------------------------------------------- ROS
def _ros_matrix(rows: int, cols: int, data) -> dict:
    return {"rows": rows, "cols": cols, "data": [float(v) for v in np.asarray(data, np.float64).ravel()]}


def save_ros_camera_info(path, camera: Camera, camera_name: str | None = None) -> None:
    """A ROS ``camera_info`` YAML file (plumb_bob; no rectification: R = I, P = [K | 0])."""
    K = np.asarray(camera.K, np.float64)
    P = np.hstack([K, np.zeros((3, 1))])
    doc = {
        "image_width": int(camera.width),
        "image_height": int(camera.height),
        "camera_name": camera_name or camera.name,
        "camera_matrix": _ros_matrix(3, 3, K),
        "distortion_model": "plumb_bob",
        "distortion_coefficients": _ros_matrix(1, 5, camera.dist),
        "rectification_matrix": _ros_matrix(3, 3, np.eye(3)),
        "projection_matrix": _ros_matrix(3, 4, P),
    }
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(yaml.safe_dump(doc, sort_keys=False))


def _ros_get(doc: dict, key: str, src: str, rows: int | None = None, cols: int | None = None) -> np.ndarray:
    if key not in doc:
        raise ValueError(f"{src}: missing {key}")
    m = doc[key]
    if not isinstance(m, dict) or "data" not in m:
        raise ValueError(f"{src}: {key}: must be a table with rows, cols and data")
    try:
        data = np.asarray(m["data"], np.float64)
        r, c = int(m.get("rows", rows or 1)), int(m.get("cols", cols or data.size))
    except (TypeError, ValueError):
        raise ValueError(f"{src}: {key}: data must be numbers") from None
    if data.size != r * c:
        raise ValueError(f"{src}: {key}: {data.size} values for a {r}x{c} matrix")
    return data.reshape(r, c)


def load_ros_camera_info(path, name: str | None = None) -> Camera:
    """A :class:`Camera` (identity pose) from a ROS ``camera_info`` YAML file."""
    path = Path(path)
    src = str(path)
    try:
        doc = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"{src}: file not found") from None
    except yaml.YAMLError as exc:
        raise ValueError(f"{src}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(doc, dict):
        raise ValueError(f"{src}: not a ROS camera_info file (no keys)")
    for key in ("image_width", "image_height"):
        if key not in doc:
            raise ValueError(f"{src}: missing {key}")
        if isinstance(doc[key], bool) or not isinstance(doc[key], int) or doc[key] <= 0:
            raise ValueError(f"{src}: {key}: must be a positive integer, got {doc[key]!r}")
    model = doc.get("distortion_model", "plumb_bob")
    if model not in ("plumb_bob", "rational_polynomial"):
        raise ValueError(f"{src}: distortion_model: only plumb_bob (k1 k2 p1 p2 k3) is supported, got {model!r}")
    K = _check_K(_ros_get(doc, "camera_matrix", src, 3, 3), src, "camera_matrix")
    D = _dist5(_ros_get(doc, "distortion_coefficients", src), src, "distortion_coefficients")
    return Camera(name or str(doc.get("camera_name") or path.stem), doc["image_width"], doc["image_height"], K, D)


# ----------------------------------------------------------------------------- world file
_WORLD_KEYS = ("T_top_world", "T_side_top", "T_side_world")


def load_world_file(path) -> dict:
    """Transforms from a world file (YAML, JSON, or OpenCV FileStorage): any of ``T_top_world``,
    ``T_side_top``, ``T_side_world`` (4x4, mm). At least ``T_top_world`` or ``T_side_world`` is required."""
    path = Path(path)
    src = str(path)
    if not path.is_file():
        raise ValueError(f"{src}: file not found")
    text = path.read_text(errors="replace")
    out = {}
    if text.lstrip().startswith("%YAML") or path.suffix.lower() == ".xml":
        r = _Reader(path)
        try:
            for key in _WORLD_KEYS:
                m = r.mat(key, required=False)
                if m is not None:
                    out[key] = _check_T(m, src, key)
        finally:
            r.close()
    else:
        try:
            doc = json.loads(text) if path.suffix.lower() == ".json" else yaml.safe_load(text)
        except (json.JSONDecodeError, yaml.YAMLError) as exc:
            raise ValueError(f"{src}: not valid {'JSON' if path.suffix.lower() == '.json' else 'YAML'} ({str(exc).splitlines()[0]})") from None
        if not isinstance(doc, dict):
            raise ValueError(f"{src}: expected keys {', '.join(_WORLD_KEYS)}")
        for key in _WORLD_KEYS:
            if key in doc:
                v = doc[key]
                if isinstance(v, dict) and "data" in v:
                    v = _ros_get(doc, key, src, 4, 4)
                try:
                    out[key] = _check_T(np.asarray(v, np.float64), src, key)
                except (TypeError, ValueError) as exc:
                    raise ValueError(str(exc) if str(exc).startswith(src) else f"{src}: {key}: must be a 4x4 matrix") from None
    if "T_top_world" not in out and "T_side_world" not in out:
        raise ValueError(f"{src}: missing T_top_world (the world frame in the top camera, 4x4 mm)")
    return out


def save_world_file(path, T_top_world: np.ndarray, T_side_top: np.ndarray | None = None) -> None:
    """Write a YAML world file (``T_top_world`` and optionally ``T_side_top``)."""
    doc = {"T_top_world": np.asarray(T_top_world, float).tolist()}
    if T_side_top is not None:
        doc["T_side_top"] = np.asarray(T_side_top, float).tolist()
    Path(path).write_text(yaml.safe_dump(doc, sort_keys=False))


# ----------------------------------------------------------------------------- rig
def rig_from_parts(side: Camera, top: Camera, T_top_world: np.ndarray, T_side_top: np.ndarray | None = None,
                   T_side_world: np.ndarray | None = None, base_point_world_mm=(0.0, 0.0, 0.0),
                   insertion_axis_world=(1.0, 0.0, 0.0)) -> RigCalibration:
    """The rig file from two cameras' intrinsics and the transforms of the paper's eq. (1).

    ``T_side_world`` is ``T_side_top @ T_top_world`` unless given directly.
    """
    T_top_world = _check_T(T_top_world, "rig", "T_top_world")
    if T_side_world is None:
        if T_side_top is None:
            raise ValueError("rig: need T_side_top (stereo) or T_side_world to place the side camera")
        T_side_world = _check_T(T_side_top, "rig", "T_side_top") @ T_top_world
    T_side_world = _check_T(T_side_world, "rig", "T_side_world")
    return RigCalibration(
        cameras={
            "side": Camera("side", side.width, side.height, side.K, side.dist, T_side_world),
            "top": Camera("top", top.width, top.height, top.K, top.dist, T_top_world),
        },
        base_point_world_mm=base_point_world_mm,
        insertion_axis_world=insertion_axis_world,
    )


def export_rig_opencv(rig: RigCalibration, stem) -> list:
    """Write ``<stem>_stereo.yaml`` (M1 D1 = top, M2 D2 = side, R T = T_side_top, T_top_world) and
    ``<stem>_side.yaml`` / ``<stem>_top.yaml`` (intrinsics and ``T_cam_world``); returns the paths."""
    stem = Path(stem)
    side, top = rig["side"], rig["top"]
    T_side_top = side.T_cam_world @ invert_transform(top.T_cam_world)
    paths = [stem.with_name(stem.name + "_stereo.yaml"), stem.with_name(stem.name + "_side.yaml"), stem.with_name(stem.name + "_top.yaml")]
    save_opencv_stereo(paths[0], side, top, T_side_top, top.T_cam_world)
    save_opencv_camera(paths[1], side)
    save_opencv_camera(paths[2], top)
    return paths
