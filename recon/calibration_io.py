"""Calibrations in other tools' formats: OpenCV FileStorage, OpenCV ``stereo_calib``, Kalibr, ROS ``camera_info``.

A lab that already calibrated its cameras (OpenCV scripts or samples, ``ros
camera_calibration``, Kalibr) builds the rig file from them instead of recalibrating;
``ctr-bench calibrate`` exports its result in the OpenCV and ROS forms. Distortion is
OpenCV's full model (:mod:`recon.distortion`: 4, 5, 8, 12 or 14 coefficients) wherever
the format can say it.

OpenCV (``cv2.FileStorage``, ``%YAML:1.0``)
    One camera: ``camera_name`` (optional), ``image_width``, ``image_height``,
    ``camera_matrix`` (3x3), ``distortion_coefficients`` (1xN, N = 4, 5, 8, 12, 14),
    optional ``T_cam_world`` (4x4).
    Stereo: ``M1 D1`` (the **top** camera), ``M2 D2`` (the **side** camera), ``R T``
    with ``X_side = R X_top + T`` (mm), i.e. ``T_side_top`` as ``cv2.stereoCalibrate``
    returns it for (top, side); ``image_width``, ``image_height``; optional
    ``T_top_world`` (4x4).

OpenCV ``stereo_calib`` sample (``samples/cpp/stereo_calib.cpp``)
    ``intrinsics.yml`` with ``M1 D1 M2 D2`` and no image size, ``extrinsics.yml`` with
    ``R T R1 R2 P1 P2 Q``; ``T`` is in the units of the sample's ``-s`` square size.
    The image size, which camera is camera 1 and the unit of ``T`` come from the caller.

Kalibr camchain (``camchain-*.yaml``, PyYAML)
    ``cam0``, ``cam1``: ``camera_model: pinhole``, ``intrinsics [fu fv pu pv]``,
    ``distortion_model: radtan``, ``distortion_coeffs [k1 k2 p1 p2]``, ``resolution [w h]``;
    ``cam1``'s ``T_cn_cnm1`` (4x4, **metres**) maps cam0's frame into cam1's.

ROS ``camera_info`` (PyYAML)
    ``image_width``, ``image_height``, ``camera_name``, ``camera_matrix`` /
    ``distortion_coefficients`` / ``rectification_matrix`` / ``projection_matrix`` as
    ``{rows, cols, data}``, ``distortion_model: plumb_bob`` (5) or ``rational_polynomial``
    (8). It holds no pose: the extrinsics come from elsewhere (a world file or a
    calibration folder). Written as a rectified stereo pair (``R``, ``P`` from
    ``cv2.stereoRectify``, top = left, side = right, ``P[0, 3] = -fx' B`` with B in
    metres) so that a ROS stereo pipeline accepts it.

World file (``--world-from FILE``): YAML or JSON with ``T_top_world`` and, where the
intrinsics files do not give it, ``T_side_top`` or ``T_side_world`` (4x4, mm, as
nested lists, or OpenCV matrices in a FileStorage file).

Every reader raises ``ValueError`` naming the file and the key at fault.
"""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import yaml

from .calibration_check import CalibrationError, camera_matrix_problem, rotation_problem
from .camera import Camera
from .distortion import as_coefficients, model_size
from .geometry import invert_transform
from .rigcal import RigCalibration

__all__ = [
    "save_opencv_camera",
    "load_opencv_camera",
    "save_opencv_stereo",
    "load_opencv_stereo",
    "load_stereo_calib",
    "load_kalibr_camchain",
    "ros_distortion",
    "ros_stereo_rectification",
    "rig_rectification",
    "export_rig_ros",
    "save_ros_camera_info",
    "load_ros_camera_info",
    "load_world_file",
    "save_world_file",
    "rig_from_parts",
    "export_rig_opencv",
]


# ----------------------------------------------------------------------------- helpers
def _dist(d, source: str, key: str) -> np.ndarray:
    """OpenCV distortion coefficients (4, 5, 8, 12 or 14) read from ``source``'s ``key``."""
    return as_coefficients(d, f"{source}: {key}")


def _row(dist) -> np.ndarray:
    """Coefficients as OpenCV writes them: one row, the shortest model that holds them (5 at least)."""
    d = np.asarray(dist, np.float64).ravel()
    return d[: model_size(d)].reshape(1, -1)


def _check_K(K, source: str, key: str) -> np.ndarray:
    """``K`` as a float64 camera matrix; CalibrationError naming ``source`` and ``key`` otherwise
    (:func:`recon.calibration_check.camera_matrix_problem`)."""
    K = np.asarray(K, np.float64)
    why = camera_matrix_problem(K)
    if why:
        raise CalibrationError(f"{source}: {key}: {why}")
    return K


def _check_T(T, source: str, key: str) -> np.ndarray:
    """``T`` (4x4, or 3x4 without its last row) as a float64 rigid transform; CalibrationError naming
    ``source`` and ``key`` otherwise (:func:`recon.calibration_check.rotation_problem`)."""
    T = np.asarray(T, np.float64)
    if T.shape == (3, 4):
        T = np.vstack([T, [0, 0, 0, 1]])
    why = rotation_problem(T)
    if why:
        raise CalibrationError(f"{source}: {key}: {why}")
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
    """One camera's intrinsics (and, with ``with_pose``, its ``T_cam_world``) as OpenCV YAML.

    Parameters
    ----------
    path : path
        The file written (``cv2.FileStorage``; its folder is created).
    camera : Camera
        Written as ``camera_name``, ``image_width``, ``image_height`` (px), ``camera_matrix``
        (3x3, px) and ``distortion_coefficients`` (1xN, the shortest OpenCV model holding them, 5 at least).
    with_pose : bool
        Also write ``T_cam_world`` (4x4, world -> camera, mm).

    Raises
    ------
    OSError
        The file cannot be written.
    """
    fs = _writer(path)
    fs.write("camera_name", camera.name)
    fs.write("image_width", int(camera.width))
    fs.write("image_height", int(camera.height))
    fs.write("camera_matrix", np.asarray(camera.K, np.float64))
    fs.write("distortion_coefficients", _row(camera.dist))
    if with_pose:
        fs.write("T_cam_world", np.asarray(camera.T_cam_world, np.float64))
    fs.release()


def load_opencv_camera(path, name: str | None = None) -> Camera:
    """A :class:`Camera` from an OpenCV YAML intrinsics file (identity pose unless it has ``T_cam_world``).

    Parameters
    ----------
    path : path
        A ``cv2.FileStorage`` file (YAML, XML or JSON) with the keys of :func:`save_opencv_camera`.
    name : str, optional
        The camera's name; default the file's ``camera_name``, else its stem.

    Returns
    -------
    Camera
        ``K`` (px), ``dist`` (OpenCV order), ``T_cam_world`` (4x4, mm; identity when absent).

    Raises
    ------
    ValueError
        Naming the file and the key: file missing or not FileStorage, a key missing, a bad
        image size, or (:class:`CalibrationError`) a ``K`` or ``T_cam_world`` that the checks refuse.
    """
    r = _Reader(path)
    try:
        src = str(r.path)
        w, h = r.size()
        K = _check_K(r.mat("camera_matrix"), src, "camera_matrix")
        D = _dist(r.mat("distortion_coefficients"), src, "distortion_coefficients")
        T = r.mat("T_cam_world", required=False)
        T = np.eye(4) if T is None else _check_T(T, src, "T_cam_world")
        nm = name or r.string("camera_name") or r.path.stem
    finally:
        r.close()
    return Camera(nm, w, h, K, D, T)


def save_opencv_stereo(path, side: Camera, top: Camera, T_side_top: np.ndarray, T_top_world: np.ndarray | None = None) -> None:
    """The stereo file: ``M1 D1`` top, ``M2 D2`` side, ``R T`` = ``T_side_top`` (mm), optional ``T_top_world``.

    Parameters
    ----------
    path : path
        The ``cv2.FileStorage`` YAML file written (its folder is created).
    side, top : Camera
        Their intrinsics (``K`` px, ``dist``) and names; the poses are not written.
    T_side_top : (4, 4) array_like
        Top camera frame -> side camera frame (mm), written as ``R`` (3x3) and ``T`` (3x1, mm).
    T_top_world : (4, 4) array_like, optional
        World -> top camera frame (mm).

    Raises
    ------
    ValueError
        The cameras' image sizes differ (the format holds one).
    OSError
        The file cannot be written.
    """
    if (side.width, side.height) != (top.width, top.height):
        raise ValueError(f"stereo file: the cameras' image sizes differ ({side.width}x{side.height} vs {top.width}x{top.height})")
    T = np.asarray(T_side_top, np.float64)
    fs = _writer(path)
    fs.write("image_width", int(top.width))
    fs.write("image_height", int(top.height))
    fs.write("camera1", top.name)
    fs.write("camera2", side.name)
    fs.write("M1", np.asarray(top.K, np.float64))
    fs.write("D1", _row(top.dist))
    fs.write("M2", np.asarray(side.K, np.float64))
    fs.write("D2", _row(side.dist))
    fs.write("R", T[:3, :3])
    fs.write("T", T[:3, 3].reshape(3, 1))
    if T_top_world is not None:
        fs.write("T_top_world", np.asarray(T_top_world, np.float64))
    fs.release()


def _read_R_T(r: "_Reader", t_scale: float = 1.0) -> np.ndarray:
    """``R T`` of a FileStorage file as a 4x4 transform, ``T`` times ``t_scale`` (to mm)."""
    src = str(r.path)
    R = r.mat("R")
    if R.size == 3:
        R = cv2.Rodrigues(R.reshape(3, 1))[0]
    t = r.mat("T")
    if R.shape != (3, 3) or t.size != 3:
        raise ValueError(f"{src}: R must be 3x3 (or a rotation vector) and T a 3-vector")
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t.ravel() * t_scale
    return _check_T(T, src, "R, T")


def _cameras_1_2(r: "_Reader", size: tuple) -> tuple:
    """``M1 D1`` and ``M2 D2`` of a FileStorage file as two cameras of ``size`` (w, h) px at identity pose."""
    src = str(r.path)
    Ks = [_check_K(r.mat(f"M{i}"), src, f"M{i}") for i in (1, 2)]
    Ds = [_dist(r.mat(f"D{i}"), src, f"D{i}") for i in (1, 2)]
    return tuple(Camera(f"camera{i}", size[0], size[1], K, D) for i, K, D in zip((1, 2), Ks, Ds))


def load_opencv_stereo(path) -> dict:
    """Read a stereo file: ``{"side": Camera, "top": Camera, "T_side_top": 4x4, "T_top_world": 4x4 or None}``.

    The cameras come back at identity pose; ``T_top_world`` is None when the file has none.

    Parameters
    ----------
    path : path
        A ``cv2.FileStorage`` file with ``image_width``, ``image_height``, ``M1 D1`` (top),
        ``M2 D2`` (side), ``R`` (3x3 or a rotation vector), ``T`` (mm) and optionally ``T_top_world``.

    Returns
    -------
    dict
        ``"top"``, ``"side"``: :class:`Camera` (named so, identity pose); ``"T_side_top"``:
        (4, 4) top -> side (mm); ``"T_top_world"``: (4, 4) world -> top (mm) or None.

    Raises
    ------
    ValueError
        Naming the file and the key: missing, not a matrix, or (:class:`CalibrationError`)
        refused by the checks.
    """
    r = _Reader(path)
    try:
        src = str(r.path)
        top, side = _cameras_1_2(r, r.size())
        T = _read_R_T(r)
        Tw = r.mat("T_top_world", required=False)
        Tw = None if Tw is None else _check_T(Tw, src, "T_top_world")
    finally:
        r.close()
    return {"top": replace(top, name="top"), "side": replace(side, name="side"), "T_side_top": T, "T_top_world": Tw}


def load_stereo_calib(intrinsics, extrinsics, image_size: tuple, first: str = "top", t_scale_mm: float = 1.0) -> dict:
    """OpenCV's ``stereo_calib`` output: ``intrinsics.yml`` (M1 D1 M2 D2) and ``extrinsics.yml`` (R T ...).

    Parameters
    ----------
    intrinsics, extrinsics : path
    image_size : (width, height)
        px; the files do not hold it.
    first : {"top", "side"}
        Which camera was the sample's camera 1 (the left image of each pair).
    t_scale_mm : float
        mm per unit of ``T`` (the sample writes T in the units of its ``-s`` square size).

    Returns
    -------
    dict like :func:`load_opencv_stereo`'s (``T_top_world`` None).
    """
    if first not in ("top", "side"):
        raise ValueError(f"camera 1 of {intrinsics} must be 'top' or 'side', got {first!r}")
    if not t_scale_mm > 0:
        raise ValueError(f"the unit of T in {extrinsics} must be a positive number of mm, got {t_scale_mm}")
    w, h = (int(v) for v in image_size)
    if w <= 0 or h <= 0:
        raise ValueError(f"{intrinsics}: the image size must be positive, got {w}x{h}")
    r = _Reader(intrinsics)
    try:
        c1, c2 = _cameras_1_2(r, (w, h))
    finally:
        r.close()
    r = _Reader(extrinsics)
    try:
        T_2_1 = _read_R_T(r, t_scale_mm)
    finally:
        r.close()
    if first == "top":
        return {"top": replace(c1, name="top"), "side": replace(c2, name="side"), "T_side_top": T_2_1, "T_top_world": None}
    return {"top": replace(c2, name="top"), "side": replace(c1, name="side"), "T_side_top": invert_transform(T_2_1), "T_top_world": None}


# ----------------------------------------------------------------------------- Kalibr
def _yaml_doc(path, what: str) -> dict:
    """A YAML file's top-level mapping; ``ValueError`` naming the file when it is missing or not ``what``."""
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"{path}: file not found") from None
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(doc, dict):
        raise ValueError(f"{path}: not a {what} (no keys)")
    return doc


def _kalibr_numbers(cam: dict, key: str, n: int, src: str) -> np.ndarray:
    v = cam.get(key)
    try:
        arr = np.asarray(v, np.float64).ravel()
    except (TypeError, ValueError):
        arr = np.zeros(0)
    if v is None or arr.size != n or not np.all(np.isfinite(arr)):
        raise ValueError(f"{src}: {key}: expected {n} numbers, got {v!r}")
    return arr


def _kalibr_camera(doc: dict, key: str, name: str, src: str) -> Camera:
    cam = doc.get(key)
    if not isinstance(cam, dict):
        raise ValueError(f"{src}: missing {key} (the camchain's cameras are {', '.join(k for k in doc if k.startswith('cam')) or 'none'})")
    where = f"{src}: {key}"
    if cam.get("camera_model", "pinhole") != "pinhole":
        raise ValueError(f"{where}: camera_model {cam.get('camera_model')!r}: only pinhole cameras are supported")
    if cam.get("distortion_model", "radtan") not in ("radtan", "none"):
        raise ValueError(f"{where}: distortion_model {cam.get('distortion_model')!r}: only radtan (OpenCV k1 k2 p1 p2) is supported")
    fu, fv, pu, pv = _kalibr_numbers(cam, "intrinsics", 4, where)
    w, h = _kalibr_numbers(cam, "resolution", 2, where)
    D = np.zeros(4) if cam.get("distortion_model") == "none" else _kalibr_numbers(cam, "distortion_coeffs", 4, where)
    K = _check_K([[fu, 0.0, pu], [0.0, fv, pv], [0.0, 0.0, 1.0]], where, "intrinsics")
    return Camera(name, int(w), int(h), K, D)


def load_kalibr_camchain(path, cams: dict | None = None) -> dict:
    """A Kalibr camchain YAML file as :func:`load_opencv_stereo`'s dict (``T_top_world`` None).

    ``cams`` maps ``"top"`` and ``"side"`` to camchain keys (default ``cam0`` top, ``cam1``
    side). The chain's ``T_cn_cnm1`` (metres) becomes ``T_side_top`` in mm.

    Parameters
    ----------
    path : path
        The camchain YAML file.
    cams : dict of str to str, optional
        ``{"top": "camN", "side": "camM"}``: two neighbouring camchain keys.

    Returns
    -------
    dict
        ``"top"``, ``"side"``: :class:`Camera` (identity pose; ``K`` px, ``dist`` k1 k2 p1 p2);
        ``"T_side_top"``: (4, 4) top -> side (mm); ``"T_top_world"``: None.

    Raises
    ------
    ValueError
        Naming the file and the key: not YAML, cameras not neighbours in the chain, a
        missing ``T_cn_cnm1``, a non-pinhole or non-radtan camera, bad numbers, or
        (:class:`CalibrationError`) intrinsics or a transform the checks refuse.
    """
    src = str(path)
    doc = _yaml_doc(path, "Kalibr camchain")
    cams = cams or {"top": "cam0", "side": "cam1"}
    keys = sorted(cams.values())
    if len(set(keys)) != 2 or any(not (k.startswith("cam") and k[3:].isdigit()) for k in keys):
        raise ValueError(f"{src}: the top and side cameras must be two different camchain keys like cam0, cam1; got {cams}")
    if int(keys[1][3:]) != int(keys[0][3:]) + 1:
        raise ValueError(f"{src}: {keys[0]} and {keys[1]} are not neighbours in the chain (T_cn_cnm1 links cam_n to cam_n-1)")
    later = doc.get(keys[1]) if isinstance(doc.get(keys[1]), dict) else {}
    if "T_cn_cnm1" not in later:
        raise ValueError(f"{src}: {keys[1]}: missing T_cn_cnm1 (its pose relative to {keys[0]})")
    T = np.asarray(later["T_cn_cnm1"], np.float64) if np.shape(later["T_cn_cnm1"]) == (4, 4) else np.zeros((1, 1))
    T = _check_T(T, src, f"{keys[1]}: T_cn_cnm1").copy()
    T[:3, 3] *= 1000.0  # Kalibr works in metres
    top = _kalibr_camera(doc, cams["top"], "top", src)
    side = _kalibr_camera(doc, cams["side"], "side", src)
    T_side_top = T if cams["side"] == keys[1] else invert_transform(T)
    return {"top": top, "side": side, "T_side_top": T_side_top, "T_top_world": None}


# ----------------------------------------------------------------------------- ROS
def _ros_matrix(rows: int, cols: int, data) -> dict:
    return {"rows": rows, "cols": cols, "data": [float(v) for v in np.asarray(data, np.float64).ravel()]}


#: ROS ``distortion_model`` names of OpenCV's coefficient counts (ROS has none for the 12 and 14 models).
_ROS_MODELS = {5: "plumb_bob", 8: "rational_polynomial"}


def ros_distortion(camera: Camera) -> tuple:
    """``(distortion_model, D)`` of ``camera`` for ROS: plumb_bob (5) or rational_polynomial (8 coefficients).

    ``ValueError`` when its thin-prism or tilt terms are non-zero: ROS cannot carry them.

    Parameters
    ----------
    camera : Camera

    Returns
    -------
    tuple of (str, list of float)
        ``("plumb_bob", [k1 k2 p1 p2 k3])`` or ``("rational_polynomial", [k1 k2 p1 p2 k3 k4 k5 k6])``.

    Raises
    ------
    ValueError
        Naming the camera: non-zero terms beyond the 8-coefficient model.
    """
    n = model_size(camera.dist)
    if n not in _ROS_MODELS:
        raise ValueError(f"camera {camera.name!r}: its {n}-coefficient distortion (thin prism / tilted sensor) has no ROS "
                         "camera_info model (plumb_bob: 5, rational_polynomial: 8)")
    return _ROS_MODELS[n], [float(v) for v in np.asarray(camera.dist, np.float64)[:n]]


def _stereo_rectify(c1: Camera, c2: Camera, T_2_1: np.ndarray) -> tuple:
    T = np.asarray(T_2_1, np.float64)
    R1, R2, P1, P2, *_ = cv2.stereoRectify(c1.K, c1.dist, c2.K, c2.dist, c1.image_size, np.ascontiguousarray(T[:3, :3]),
                                           (T[:3, 3] / 1000.0).reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
    return (R1, P1), (R2, P2)


def ros_stereo_rectification(top: Camera, side: Camera, T_side_top: np.ndarray) -> dict:
    """ROS's rectified stereo pair: ``{"top": (R, P), "side": (R, P)}`` from ``cv2.stereoRectify``.

    R rotates each camera's frame into the rectified one; P (3x4, px) projects rectified
    points. The first camera (``P[:2, 3] = 0``) is the one the rectified geometry puts first;
    the second has ``P[0, 3] = -fx' B`` (a horizontal pair) or ``P[1, 3] = -fy' B`` (a
    vertical pair, which OpenCV chooses when the baseline runs more along the images' y
    axes, as on the paper's rig), B the baseline in metres as ROS reads it. ROS's
    ``stereo_image_proc`` only handles horizontal pairs; ``image_proc`` rectifies either.
    With near-orthogonal cameras the epipoles lie in or near the images, so rectified
    images are strongly warped.

    Parameters
    ----------
    top, side : Camera
        Their intrinsics (``K`` px, ``dist``); the image sizes must agree.
    T_side_top : (4, 4) array_like
        Top camera frame -> side camera frame (mm); passed to OpenCV in metres.

    Returns
    -------
    dict
        ``"top"``, ``"side"``: ``(R, P)``, R (3, 3) camera -> rectified frame, P (3, 4)
        rectified projection (px, translation column in px x m).

    Raises
    ------
    ValueError
        The cameras' image sizes differ.
    """
    if top.image_size != side.image_size:
        raise ValueError(f"stereo rectification: the cameras' image sizes differ ({top.width}x{top.height} vs {side.width}x{side.height})")
    a, b = _stereo_rectify(top, side, T_side_top)
    if b[1][0, 3] + b[1][1, 3] > 0:  # side comes first once rectified: ROS wants the second camera's Tx (Ty) negative
        b, a = _stereo_rectify(side, top, invert_transform(T_side_top))
    return {"top": a, "side": b}


def save_ros_camera_info(path, camera: Camera, camera_name: str | None = None, R: np.ndarray | None = None,
                         P: np.ndarray | None = None) -> None:
    """A ROS ``camera_info`` YAML file; without ``R``, ``P`` (:func:`ros_stereo_rectification`) a monocular one
    (R = I, P = [K | 0]).

    Parameters
    ----------
    path : path
        The YAML file written (its folder is created).
    camera : Camera
        Image size (px), ``K`` (px) and ``dist`` (:func:`ros_distortion`); the pose is not written.
    camera_name : str, optional
        The file's ``camera_name``; default ``camera.name``.
    R : (3, 3) array_like, optional
        Rectification rotation (camera -> rectified frame).
    P : (3, 4) array_like, optional
        Projection matrix (px).

    Raises
    ------
    ValueError
        The camera's distortion has no ROS model (:func:`ros_distortion`).
    """
    K = np.asarray(camera.K, np.float64)
    R = np.eye(3) if R is None else np.asarray(R, np.float64)
    P = np.hstack([K, np.zeros((3, 1))]) if P is None else np.asarray(P, np.float64)
    model, D = ros_distortion(camera)
    doc = {
        "image_width": int(camera.width),
        "image_height": int(camera.height),
        "camera_name": camera_name or camera.name,
        "camera_matrix": _ros_matrix(3, 3, K),
        "distortion_model": model,
        "distortion_coefficients": _ros_matrix(1, len(D), D),
        "rectification_matrix": _ros_matrix(3, 3, R),
        "projection_matrix": _ros_matrix(3, 4, P),
    }
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(yaml.safe_dump(doc, sort_keys=False))


def _side_top(rig: RigCalibration) -> np.ndarray:
    """The rig's ``T_side_top`` (4x4, mm) from its two cameras' poses."""
    return rig["side"].T_cam_world @ invert_transform(rig["top"].T_cam_world)


def rig_rectification(rig: RigCalibration) -> dict:
    """:func:`ros_stereo_rectification` of a rig's top and side cameras.

    Parameters
    ----------
    rig : RigCalibration
        Must have ``"top"`` and ``"side"`` cameras; ``T_side_top`` comes from their ``T_cam_world``.

    Returns
    -------
    dict
        ``"top"``, ``"side"``: ``(R, P)`` as :func:`ros_stereo_rectification` gives them.

    Raises
    ------
    UnknownCameraError
        The rig lacks ``top`` or ``side``.
    ValueError
        The image sizes differ.
    """
    return ros_stereo_rectification(rig["top"], rig["side"], _side_top(rig))


def export_rig_ros(rig: RigCalibration, stem) -> list:
    """``<stem>_ros_top.yaml`` and ``<stem>_ros_side.yaml``: the rig as a rectified ROS stereo pair; returns the paths.

    Parameters
    ----------
    rig : RigCalibration
        With ``"top"`` and ``"side"`` cameras.
    stem : path
        Path prefix of the files, e.g. ``out/rig`` -> ``out/rig_ros_top.yaml``.

    Returns
    -------
    list of Path
        The top file, then the side file.

    Raises
    ------
    ValueError
        A camera's distortion has no ROS model, or the image sizes differ.
    """
    stem = Path(stem)
    side, top = rig["side"], rig["top"]
    rect = rig_rectification(rig)
    paths = []
    for name, cam in (("top", top), ("side", side)):
        path = stem.with_name(f"{stem.name}_ros_{name}.yaml")
        save_ros_camera_info(path, cam, name, *rect[name])
        paths.append(path)
    return paths


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
    """A :class:`Camera` (identity pose) from a ROS ``camera_info`` YAML file (plumb_bob or rational_polynomial).

    Parameters
    ----------
    path : path
        The ``camera_info`` YAML file.
    name : str, optional
        The camera's name; default the file's ``camera_name``, else its stem.

    Returns
    -------
    Camera
        Image size (px), ``K`` (px), ``dist`` (5 or 8 coefficients), identity ``T_cam_world``.
        ``rectification_matrix`` and ``projection_matrix`` are ignored.

    Raises
    ------
    ValueError
        Naming the file and the key: missing, not YAML, a bad size, an unsupported
        distortion model, malformed matrices, or (:class:`CalibrationError`) a ``K`` the checks refuse.
    """
    path = Path(path)
    src = str(path)
    doc = _yaml_doc(path, "ROS camera_info file")
    for key in ("image_width", "image_height"):
        if key not in doc:
            raise ValueError(f"{src}: missing {key}")
        if isinstance(doc[key], bool) or not isinstance(doc[key], int) or doc[key] <= 0:
            raise ValueError(f"{src}: {key}: must be a positive integer, got {doc[key]!r}")
    model = doc.get("distortion_model", "plumb_bob")
    if model not in _ROS_MODELS.values():
        raise ValueError(f"{src}: distortion_model: only plumb_bob (k1 k2 p1 p2 k3) and rational_polynomial (+ k4 k5 k6) "
                         f"are supported, got {model!r}")
    K = _check_K(_ros_get(doc, "camera_matrix", src, 3, 3), src, "camera_matrix")
    D = _dist(_ros_get(doc, "distortion_coefficients", src), src, "distortion_coefficients")
    if model_size(D) > 8 or (model == "plumb_bob" and model_size(D) > 5):
        raise ValueError(f"{src}: distortion_coefficients: {D.size} coefficients with non-zero terms beyond {model}'s")
    return Camera(name or str(doc.get("camera_name") or path.stem), doc["image_width"], doc["image_height"], K, D)


# ----------------------------------------------------------------------------- world file
_WORLD_KEYS = ("T_top_world", "T_side_top", "T_side_world")


def load_world_file(path) -> dict:
    """Transforms from a world file (YAML, JSON, or OpenCV FileStorage): any of ``T_top_world``,
    ``T_side_top``, ``T_side_world`` (4x4, mm). At least ``T_top_world`` or ``T_side_world`` is required.

    Parameters
    ----------
    path : path
        ``.json``, ``.xml`` or ``%YAML`` FileStorage, else YAML; matrices as nested lists,
        ROS-style ``{rows, cols, data}`` tables or OpenCV matrices.

    Returns
    -------
    dict of str to ndarray
        The keys present among ``T_top_world`` (world -> top), ``T_side_top`` (top -> side)
        and ``T_side_world`` (world -> side), each (4, 4) float64, mm.

    Raises
    ------
    ValueError
        Naming the file and the key: missing file, invalid JSON/YAML, not 4x4, neither
        ``T_top_world`` nor ``T_side_world``, or (:class:`CalibrationError`) not a rigid transform.
    """
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
    """Write a YAML world file (``T_top_world`` and optionally ``T_side_top``).

    Parameters
    ----------
    path : path
        The YAML file written (its folder must exist).
    T_top_world : (4, 4) array_like
        World -> top camera frame (mm).
    T_side_top : (4, 4) array_like, optional
        Top camera frame -> side camera frame (mm).
    """
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

    Parameters
    ----------
    side, top : Camera
        Their image sizes (px), ``K`` (px) and ``dist``; their poses are replaced.
    T_top_world : (4, 4) array_like
        World -> top camera frame (mm).
    T_side_top : (4, 4) array_like, optional
        Top camera frame -> side camera frame (mm); needed unless ``T_side_world`` is given.
    T_side_world : (4, 4) array_like, optional
        World -> side camera frame (mm); takes precedence over ``T_side_top``.
    base_point_world_mm : (3,) array_like
        Where the robot leaves the actuation unit (world frame, mm).
    insertion_axis_world : (3,) array_like
        Insertion direction (world frame, unitless; normalized by :class:`RigCalibration`).

    Returns
    -------
    RigCalibration
        Cameras ``"side"`` and ``"top"`` with ``T_cam_world`` set.

    Raises
    ------
    ValueError
        Neither ``T_side_top`` nor ``T_side_world``, or (:class:`CalibrationError`) a
        transform that is not rigid.
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
    ``<stem>_side.yaml`` / ``<stem>_top.yaml`` (intrinsics and ``T_cam_world``); returns the paths.

    Parameters
    ----------
    rig : RigCalibration
        With ``"top"`` and ``"side"`` cameras; ``T_side_top`` (mm) comes from their poses.
    stem : path
        Path prefix of the files, e.g. ``out/rig`` -> ``out/rig_stereo.yaml``.

    Returns
    -------
    list of Path
        The stereo file, then the side and top camera files.

    Raises
    ------
    ValueError
        The cameras' image sizes differ.
    OSError
        A file cannot be written.
    """
    stem = Path(stem)
    side, top = rig["side"], rig["top"]
    T_side_top = _side_top(rig)
    paths = [stem.with_name(stem.name + "_stereo.yaml"), stem.with_name(stem.name + "_side.yaml"), stem.with_name(stem.name + "_top.yaml")]
    save_opencv_stereo(paths[0], side, top, T_side_top, top.T_cam_world)
    save_opencv_camera(paths[1], side)
    save_opencv_camera(paths[2], top)
    return paths
