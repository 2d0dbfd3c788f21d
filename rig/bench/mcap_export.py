"""A run as an MCAP file of ROS 2 messages (``ctr-bench export RUN --mcap FILE``).

Written with the ``mcap`` library in ROS 2 (CDR) message encoding, so that
Foxglove opens it and ``ros2 bag play`` plays it without ROS installed here.
Per frame of the run, at the frame's time ``t_s``:

* ``/<camera>/image/compressed`` (``sensor_msgs/msg/CompressedImage``, PNG)
  and ``/<camera>/camera_info`` (``sensor_msgs/msg/CameraInfo``: plumb_bob or
  rational_polynomial, with R and P of the rectified stereo pair, top = left, as
  ``ctr-bench calibrate`` writes them: :func:`recon.calibration_io.rig_rectification`)
  for each camera of the session;
* ``/ctr/backbone`` (``nav_msgs/msg/Path``): the backbone, base first,
  every pose oriented along the curve's tangent (x axis);
* ``/ctr/tube`` (``visualization_msgs/msg/Marker``, LINE_STRIP): the same
  points drawn as wide as the outer tube, green for ``ok``, orange for
  ``suspect``; frames that failed have an empty path and a DELETEALL marker;
* ``/tf``: ``world`` to each camera's optical frame (``<camera>_optical``,
  OpenCV convention: x right, y down, z forward) and to ``robot_base``
  (x along the insertion axis).

ROS works in metres: every length here (points, translations, marker
width) is the run's millimetres / 1000.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from recon.calibration_io import rig_rectification, ros_distortion
from rig.bench.report import load_run
from rig.session import Session

__all__ = ["export_mcap", "TOPIC_BACKBONE", "TOPIC_TUBE", "MSGDEFS"]

TOPIC_BACKBONE = "/ctr/backbone"
TOPIC_TUBE = "/ctr/tube"
_SEP = "\n" + "=" * 80 + "\n"

# ROS 2 Humble message definitions, each followed by the definitions it uses (the ros2msg schema encoding).
_TIME = "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec"
_DURATION = "MSG: builtin_interfaces/Duration\nint32 sec\nuint32 nanosec"
_HEADER = "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id"
_POINT = "MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z"
_QUAT = "MSG: geometry_msgs/Quaternion\nfloat64 x\nfloat64 y\nfloat64 z\nfloat64 w"
_VEC3 = "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z"
_POSE = "MSG: geometry_msgs/Pose\nPoint position\nQuaternion orientation"
_POSE_STAMPED = "MSG: geometry_msgs/PoseStamped\nstd_msgs/Header header\nPose pose"
_TRANSFORM = "MSG: geometry_msgs/Transform\nVector3 translation\nQuaternion rotation"
_TRANSFORM_STAMPED = "MSG: geometry_msgs/TransformStamped\nstd_msgs/Header header\nstring child_frame_id\nTransform transform"
_COLOR = "MSG: std_msgs/ColorRGBA\nfloat32 r\nfloat32 g\nfloat32 b\nfloat32 a"
_ROI = "MSG: sensor_msgs/RegionOfInterest\nuint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify"


def _msgdef(body: str, *deps: str) -> str:
    return _SEP.join((body,) + deps)


#: Datatype -> ros2msg definition text (with its dependencies) of every message this module writes.
MSGDEFS = {
    "sensor_msgs/msg/CompressedImage": _msgdef("std_msgs/Header header\nstring format\nuint8[] data", _HEADER, _TIME),
    "sensor_msgs/msg/CameraInfo": _msgdef(
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\nfloat64[] d\nfloat64[9] k\n"
        "float64[9] r\nfloat64[12] p\nuint32 binning_x\nuint32 binning_y\nsensor_msgs/RegionOfInterest roi",
        _HEADER, _TIME, _ROI),
    "nav_msgs/msg/Path": _msgdef("std_msgs/Header header\ngeometry_msgs/PoseStamped[] poses",
                                 _HEADER, _TIME, _POSE_STAMPED, _POSE, _POINT, _QUAT),
    "visualization_msgs/msg/Marker": _msgdef(
        "int32 ARROW=0\nint32 LINE_STRIP=4\nint32 ADD=0\nint32 DELETE=2\nint32 DELETEALL=3\n"
        "std_msgs/Header header\nstring ns\nint32 id\nint32 type\nint32 action\ngeometry_msgs/Pose pose\n"
        "geometry_msgs/Vector3 scale\nstd_msgs/ColorRGBA color\nbuiltin_interfaces/Duration lifetime\nbool frame_locked\n"
        "geometry_msgs/Point[] points\nstd_msgs/ColorRGBA[] colors\nstring text\nstring mesh_resource\n"
        "bool mesh_use_embedded_materials",
        _HEADER, _TIME, _POSE, _POINT, _QUAT, _VEC3, _COLOR, _DURATION),
    "tf2_msgs/msg/TFMessage": _msgdef("geometry_msgs/TransformStamped[] transforms",
                                      _TRANSFORM_STAMPED, _HEADER, _TIME, _TRANSFORM, _VEC3, _QUAT),
}

_COLORS = {"ok": (0.2, 0.8, 0.3, 1.0), "suspect": (1.0, 0.55, 0.1, 1.0)}
_IDENTITY_POSE = {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}


def _stamp(t_ns: int) -> dict:
    return {"sec": int(t_ns // 1_000_000_000), "nanosec": int(t_ns % 1_000_000_000)}


def _header(t_ns: int, frame_id: str) -> dict:
    return {"stamp": _stamp(t_ns), "frame_id": frame_id}


def _quaternion(R: np.ndarray) -> dict:
    x, y, z, w = Rotation.from_matrix(np.asarray(R, float)).as_quat()
    return {"x": float(x), "y": float(y), "z": float(z), "w": float(w)}


def _point_m(p_mm) -> dict:
    return {"x": float(p_mm[0]) / 1000.0, "y": float(p_mm[1]) / 1000.0, "z": float(p_mm[2]) / 1000.0}


def _transform(t_ns: int, child: str, T_world_child: np.ndarray) -> dict:
    """A ``world`` -> ``child`` TransformStamped from ``T_world_child`` (4x4, mm)."""
    return {"header": _header(t_ns, "world"), "child_frame_id": child,
            "transform": {"translation": _point_m(T_world_child[:3, 3]), "rotation": _quaternion(T_world_child[:3, :3])}}


def _base_frame(rig) -> np.ndarray:
    """``T_world_base`` (4x4, mm): at the robot base, x along the insertion axis."""
    x = np.asarray(rig.insertion_axis_world, float)
    helper = np.array([0.0, 0.0, 1.0]) if abs(x[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    y = np.cross(helper, x)
    y /= np.linalg.norm(y)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, np.cross(x, y)], axis=1)
    T[:3, 3] = rig.base_point_world_mm
    return T


def _rectification(rig) -> dict:
    """Each camera's (R, P) of the rectified top/side pair; R = I, P = [K | 0] for other rigs."""
    if set(rig.names) == {"side", "top"}:
        return rig_rectification(rig)
    return {n: (np.eye(3), np.hstack([rig[n].K, np.zeros((3, 1))])) for n in rig.names}


def _camera_info(cam, t_ns: int, name: str, R: np.ndarray, P: np.ndarray) -> dict:
    model, D = ros_distortion(cam)
    return {"header": _header(t_ns, f"{name}_optical"), "height": int(cam.height), "width": int(cam.width),
            "distortion_model": model, "d": D, "k": np.asarray(cam.K, float).ravel().tolist(),
            "r": np.asarray(R, float).ravel().tolist(), "p": np.asarray(P, float).ravel().tolist(), "binning_x": 0, "binning_y": 0,
            "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False}}


def _image(png: bytes, t_ns: int, name: str) -> dict:
    """The session's PNG file as it is (no re-encoding)."""
    return {"header": _header(t_ns, f"{name}_optical"), "format": "png", "data": png}


def _path(points_mm: np.ndarray, t_ns: int) -> dict:
    """The backbone as a Path in ``world``, each pose's x axis along the tangent."""
    poses = []
    if len(points_mm) >= 2:
        tangent = np.gradient(points_mm, axis=0)
        for p, t in zip(points_mm, tangent):
            n = np.linalg.norm(t)
            q = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
            if n > 0:
                # Shortest rotation taking x onto the tangent.
                r, _ = Rotation.align_vectors([t / n], [[1.0, 0.0, 0.0]])
                x, y, z, w = r.as_quat()
                q = {"x": float(x), "y": float(y), "z": float(z), "w": float(w)}
            poses.append({"header": _header(t_ns, "world"), "pose": {"position": _point_m(p), "orientation": q}})
    return {"header": _header(t_ns, "world"), "poses": poses}


def _marker(points_mm: np.ndarray, t_ns: int, status: str, width_mm: float) -> dict:
    color = _COLORS.get(status, _COLORS["suspect"])
    drawn = status in _COLORS and len(points_mm) >= 2
    return {"header": _header(t_ns, "world"), "ns": "ctr", "id": 0, "type": 4, "action": 0 if drawn else 3,
            "pose": _IDENTITY_POSE, "scale": {"x": width_mm / 1000.0, "y": 0.0, "z": 0.0},
            "color": dict(zip("rgba", color)), "lifetime": {"sec": 0, "nanosec": 0}, "frame_locked": False,
            "points": [_point_m(p) for p in points_mm] if drawn else [], "colors": [], "text": status,
            "mesh_resource": "", "mesh_use_embedded_materials": False}


def _tube_width_mm(run) -> float:
    params = run.summary.get("params") or {}
    r = params.get("outer_tube_radius_mm")
    return 2.0 * float(r) if r else 1.0


def export_mcap(run_dir, out_path, images: bool = True, progress=None) -> dict:
    """Write the run in ``run_dir`` as an MCAP file of ROS 2 messages at ``out_path``.

    Parameters
    ----------
    run_dir : path
        Output directory of ``ctr-bench run`` / ``reconstruct`` (holds summary.json).
    out_path : path
        The ``.mcap`` file to write (replaced atomically).
    images : bool
        Also write the camera images (PNG); they need the run's session.
    progress : callable(done, total), optional

    Returns
    -------
    dict
        Messages written per topic.

    Raises
    ------
    ValueError
        No summary.json, no rig calibration, or images wanted without the session.
    OSError
        A frame's image file is missing or unreadable (nothing is written then).
    """
    from mcap_ros2.writer import Writer

    run_dir, out_path = Path(run_dir), Path(out_path)
    if not (run_dir / "summary.json").exists():
        raise ValueError(f"{run_dir}: no summary.json (not an output directory of ctr-bench run or reconstruct)")
    run = load_run(run_dir)
    if run.rig is None:
        raise ValueError(f"{run_dir}: the run's session (with its rig.json) is not found, so the cameras are unknown")
    if images and run.session_dir is None:
        raise ValueError(f"{run_dir}: the run's session is not found, so there are no images to export (--no-images "
                         "exports the rest)")
    session = Session(run.session_dir) if images else None
    counts = {}
    tmp = out_path.with_name(f".{out_path.name}.tmp")
    with open(tmp, "wb") as f:
        writer = Writer(f)
        schemas = {k: writer.register_msgdef(k, v) for k, v in MSGDEFS.items()}

        def put(topic, kind, msg, t_ns):
            writer.write_message(topic, schemas[kind], msg, log_time=t_ns, publish_time=t_ns)
            counts[topic] = counts.get(topic, 0) + 1

        frames = {r["frame"]: r for r in run.records}
        width_mm = _tube_width_mm(run)
        T_base = _base_frame(run.rig)
        rect = _rectification(run.rig)
        for k, (index, rec) in enumerate(sorted(frames.items())):
            t_ns = int(round(float(rec.get("t_s") or 0.0) * 1e9))
            tfs = [_transform(t_ns, f"{n}_optical", run.rig[n].T_world_cam) for n in run.rig.names]
            put("/tf", "tf2_msgs/msg/TFMessage", {"transforms": tfs + [_transform(t_ns, "robot_base", T_base)]}, t_ns)
            for n in run.rig.names:
                put(f"/{n}/camera_info", "sensor_msgs/msg/CameraInfo", _camera_info(run.rig[n], t_ns, n, *rect[n]), t_ns)
            if session is not None:
                for n in session.cameras:
                    png = session.frame_path(index, n).read_bytes()
                    put(f"/{n}/image/compressed", "sensor_msgs/msg/CompressedImage", _image(png, t_ns, n), t_ns)
            pts = run.backbones.get(index, np.zeros((0, 3))) if rec.get("status") in _COLORS else np.zeros((0, 3))
            put(TOPIC_BACKBONE, "nav_msgs/msg/Path", _path(pts, t_ns), t_ns)
            put(TOPIC_TUBE, "visualization_msgs/msg/Marker", _marker(pts, t_ns, str(rec.get("status")), width_mm), t_ns)
            if progress is not None:
                progress(k + 1, len(frames))
        writer.finish()
    tmp.replace(out_path)
    return counts
