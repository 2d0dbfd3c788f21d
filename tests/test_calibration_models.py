"""Calibration with OpenCV's longer distortion models, and the calibration formats of other tools.

Corners are projected through known cameras (no rendering), so each check is about the
model and the file formats alone: the rational, thin-prism and tilted models are
recovered by ``calibrate_camera`` and by the joint refinement; OpenCV ``stereo_calib``
files and a Kalibr camchain of one rig import to that rig; the ROS export is a
rectified stereo pair; sources that disagree are refused with both named.
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml

from recon.calibration import BoardSpec, CalibrationParams, Detection, calibrate_camera, parse_terms, refine_jointly
from recon.calibration_io import load_kalibr_camchain, load_ros_camera_info, load_stereo_calib, ros_stereo_rectification
from recon.camera import Camera
from recon.geometry import invert_transform, look_at, rotation_matrix
from recon.rigcal import load_rig_calibration

BOARD = BoardSpec.parse("9x6", 8.0)
K = np.array([[1400.0, 0.0, 650.0], [0.0, 1390.0, 478.0], [0.0, 0.0, 1.0]])
DIST = {
    8: [0.30, -0.10, 0.0008, -0.0006, 0.01, 0.50, -0.05, 0.01],
    14: [0.30, -0.10, 0.0008, -0.0006, 0.01, 0.50, -0.05, 0.01, 0.001, -0.0003, -0.0012, 0.0002, 0.01, -0.008],
}


def _board_poses(n: int, seed: int) -> list:
    """``T_cam_board`` (mm) of ``n`` board placements filling a 1280x960 view at 200-320 mm, tilted up to 35 deg."""
    rng = np.random.default_rng(seed)
    poses = []
    for _ in range(n):
        T_cam_board = np.eye(4)
        T_cam_board[:3, :3] = rotation_matrix(rng.normal(size=3), np.radians(rng.uniform(5, 35)))
        z = rng.uniform(200.0, 320.0)
        T_cam_board[:3, 3] = [rng.uniform(-0.3, 0.3) * z - 32.0, rng.uniform(-0.22, 0.22) * z - 20.0, z]
        poses.append(T_cam_board)
    return poses


def _detections(cam: Camera, poses: list, prefix: str) -> list:
    obj = BOARD.object_points()
    out = []
    for i, T_cam_board in enumerate(poses):
        uv, _ = cam.with_pose(T_cam_board).project(obj)
        out.append(Detection(f"{prefix}/{i:03d}.png", cam.image_size, uv, oriented=True))
    return out


def _distortion_error_px(a: Camera, b: Camera) -> float:
    """Largest difference (px) between two cameras' undistortion over a grid covering the image."""
    uu, vv = np.meshgrid(np.linspace(0, a.width - 1, 33), np.linspace(0, a.height - 1, 25))
    uv = np.stack([uu.ravel(), vv.ravel()], 1)
    return float(np.abs(a.undistort_pixels(uv) - b.undistort_pixels(uv)).max())


def _held_out_error_px(cal, truth: Camera, seed: int) -> float:
    """Largest reprojection error (px) on board views the calibration did not see, each posed by solvePnP with
    the calibrated camera: how well the model describes the lens, whatever the principal point and tilt trade."""
    obj = BOARD.object_points()
    worst = 0.0
    for T_cam_board in _board_poses(6, seed):
        uv, _ = truth.with_pose(T_cam_board).project(obj)
        ok, rvec, tvec = cv2.solvePnP(obj, uv, cal.K, cal.dist, flags=cv2.SOLVEPNP_ITERATIVE)
        back, _ = cv2.projectPoints(obj, rvec, tvec, cal.K, cal.dist)
        worst = max(worst, float(np.abs(back[:, 0, :] - uv).max()))
    return worst


@pytest.mark.parametrize("model", [8, 14])
def test_calibrate_camera_recovers_the_longer_models(model):
    truth = Camera("side", 1280, 960, K, np.array(DIST[model]))
    dets = _detections(truth, _board_poses(25, seed=model), "side")
    terms = "k1 k2 p1 p2 k3 k4 k5 k6" + (" s1 s2 s3 s4 tau_x tau_y" if model == 14 else "")
    cal = calibrate_camera(dets, BOARD, "side", CalibrationParams(distortion_model=model, distortion=terms))
    assert cal.dist.size == model and cal.rms_px < 1e-3
    assert _held_out_error_px(cal, truth, seed=100 + model) < 0.01
    if model == 8:  # with thin prism and tilt the principal point trades against them: only the 8-term K is pinned down
        assert np.abs(cal.K - K).max() < 0.5


def test_the_plumb_bob_model_falls_short_on_a_strongly_rational_lens():
    """On a lens of strong rational distortion the 5-term model leaves held-out error the 8-term one does not:
    ``--model 8`` really switches OpenCV's rational model on."""
    truth = Camera("side", 1280, 960, K, np.array([2.0, 0, 0, 0, 0, 2.5, 0, 0]))
    dets = _detections(truth, _board_poses(25, seed=8), "side")
    five = calibrate_camera(dets, BOARD, "side", CalibrationParams(distortion_model=5))
    eight = calibrate_camera(dets, BOARD, "side", CalibrationParams(distortion_model=8, distortion="k1 k2 p1 p2 k3 k4 k5 k6"))
    assert _held_out_error_px(five, truth, seed=3) > 0.01 > 0.001 > _held_out_error_px(eight, truth, seed=3)


def test_joint_refinement_with_the_tilted_model():
    top = Camera("top", 1280, 960, K, np.array(DIST[14]))
    side = Camera("side", 1280, 960, K * [[1.01], [1.01], [1]], np.array(DIST[8] + [0.0] * 6))
    T_side_top = np.eye(4)
    T_side_top[:3, :3] = rotation_matrix([0, 1, 0], np.radians(8.0))
    T_side_top[:3, 3] = [-40.0, 2.0, 5.0]
    poses = _board_poses(10, seed=3)
    obj = BOARD.object_points()
    obs = []
    for i, T_top_board in enumerate(poses):
        views = [("top", top.with_pose(T_top_board).project(obj)[0]), ("side", side.with_pose(T_side_top @ T_top_board).project(obj)[0])]
        obs.append({"frame": f"stereo/{i}", "ref": "top", "T_ref_board": T_top_board, "views": views})
    K0 = K.copy()
    K0[0, 2] += 3.0
    start = {"top": (K0, np.zeros(14)), "side": (K0, np.zeros(8))}
    models = {"top": " ".join(parse_terms("k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4 tau_x tau_y", 14)),
              "side": " ".join(parse_terms("k1 k2 p1 p2 k3 k4 k5 k6", 8))}
    sol = refine_jointly(start, obs, T_side_top @ _nudge(), BOARD, models)
    assert sol["cams"]["top"][1].size == 14 and sol["cams"]["side"][1].size == 8
    assert max(float(e.max()) for es in sol["errors"].values() for e in es) < 1e-3
    for name, cam in (("top", top), ("side", side)):
        Kf, D = sol["cams"][name]
        assert _distortion_error_px(Camera(name, 1280, 960, Kf, D), cam) < 0.05
    assert np.abs(sol["T_side_top"][:3, 3] - T_side_top[:3, 3]).max() < 0.01


def test_joint_refinement_names_its_bad_input():
    T_top_board = _board_poses(1, seed=1)[0]
    good = [{"frame": "stereo/0", "ref": "top", "T_ref_board": T_top_board,
             "views": [("top", np.zeros((BOARD.n_corners, 2))), ("side", np.zeros((BOARD.n_corners, 2)))]}]
    short = [{**good[0], "views": [("top", np.zeros((5, 2)))]}]
    start = {"top": (K, np.zeros(5)), "side": (K, np.zeros(5))}
    cases = [
        (({"top": start["top"]}, good, np.eye(4)), {}, "cams has no 'side' camera"),
        ((start, short, np.eye(4)), {}, r"observation 'stereo/0': a view must be .*\(54, 2\)"),
        ((start, good, np.eye(3)), {}, "T_side_top must be 4x4"),
        ((start, [], np.eye(4)), {}, "no observations"),
        ((start, good, np.eye(4)), {"models": {"top": "k1 k9"}}, r"models\['top'\]: unknown distortion terms k9"),
    ]
    for (cams, obs, T_side_top), kw, message in cases:
        with pytest.raises(ValueError, match=message) as err:
            refine_jointly(cams, obs, T_side_top, BOARD, **kw)
        assert "\n" not in str(err.value)


def _nudge() -> np.ndarray:
    """The error put on the starting ``T_side_top``: ``T_top_top0`` (4x4, mm), 0.3 deg about x and 0.6 mm."""
    T_top_top0 = np.eye(4)
    T_top_top0[:3, :3] = rotation_matrix([1, 0, 0], np.radians(0.3))
    T_top_top0[:3, 3] = [0.5, -0.3, 0.2]
    return T_top_top0


@pytest.mark.parametrize("bad, why", [("k1 k2 p1", "together"), ("k1 k4", "not in the 5-coefficient model"), ("k1 s1", "not in")])
def test_term_sets_are_checked(bad, why):
    with pytest.raises(ValueError, match=why):
        CalibrationParams(distortion_model=5, distortion=bad)


# ----------------------------------------------------------------------------- formats
@pytest.fixture()
def rig_parts():
    """A rig's cameras (radtan distortion, which every format can carry) and T_side_top (mm)."""
    top = Camera("top", 1280, 960, K, np.array([-0.12, 0.05, 0.0007, -0.0004, 0.0]))
    side = Camera("side", 1280, 960, K * [[0.98], [0.98], [1]], np.array([-0.08, 0.02, -0.0003, 0.0005, 0.0]))
    T_top_world = look_at([45.0, 0.0, 300.0], [45.0, 0.0, 0.0], [0.0, -1.0, 0.0])
    T_side_world = look_at([45.0, -300.0, 0.0], [45.0, 0.0, 0.0], [0.0, 0.0, -1.0])
    return top, side, T_side_world @ invert_transform(T_top_world), T_top_world


def _write_stereo_calib(folder, top, side, T_side_top, square_mm: float):
    """The two files of OpenCV's samples/cpp/stereo_calib.cpp (camera 1 = top; T in squares; 8 coefficients)."""
    fs = cv2.FileStorage(str(folder / "intrinsics.yml"), cv2.FILE_STORAGE_WRITE)
    for i, c in ((1, top), (2, side)):
        fs.write(f"M{i}", c.K)
        fs.write(f"D{i}", np.concatenate([c.dist, [0.0, 0.0, 0.0]]).reshape(1, 8))
    fs.release()
    R1, R2, P1, P2 = (np.eye(3), np.eye(3), np.eye(3, 4), np.eye(3, 4))
    fs = cv2.FileStorage(str(folder / "extrinsics.yml"), cv2.FILE_STORAGE_WRITE)
    for key, m in (("R", T_side_top[:3, :3]), ("T", T_side_top[:3, 3:4] / square_mm), ("R1", R1), ("R2", R2), ("P1", P1),
                   ("P2", P2), ("Q", np.eye(4))):
        fs.write(key, m)
    fs.release()


def _write_kalibr(path, top, side, T_side_top, swap=False):
    def cam(c):
        return {"camera_model": "pinhole", "intrinsics": [float(c.K[0, 0]), float(c.K[1, 1]), float(c.K[0, 2]), float(c.K[1, 2])],
                "distortion_model": "radtan", "distortion_coeffs": [float(v) for v in c.dist[:4]],
                "resolution": [c.width, c.height], "rostopic": f"/{c.name}/image_raw", "cam_overlaps": [0, 1]}

    T_cam1_cam0_m = T_side_top.copy() if not swap else invert_transform(T_side_top)
    T_cam1_cam0_m[:3, 3] /= 1000.0
    first, second = (top, side) if not swap else (side, top)
    doc = {"cam0": cam(first), "cam1": {**cam(second), "T_cn_cnm1": T_cam1_cam0_m.tolist()}}
    path.write_text(yaml.safe_dump(doc, sort_keys=False))


def test_stereo_calib_and_kalibr_import_to_the_same_rig(rig_parts, tmp_path, capsys):
    from recon.calibration_io import save_world_file
    from rig.cli import main

    top, side, T_side_top, T_top_world = rig_parts
    _write_stereo_calib(tmp_path, top, side, T_side_top, square_mm=8.0)
    _write_kalibr(tmp_path / "camchain.yaml", top, side, T_side_top, swap=True)
    save_world_file(tmp_path / "world.yaml", T_top_world)
    a, b = tmp_path / "a" / "rig.json", tmp_path / "b" / "rig.json"
    assert main(["calibrate", "--import-stereo-calib", str(tmp_path / "intrinsics.yml"), str(tmp_path / "extrinsics.yml"),
                 "--image-size", "1280", "960", "--t-unit-mm", "8", "--world-from", str(tmp_path / "world.yaml"), "--out", str(a)]) == 0
    assert main(["calibrate", "--import-kalibr", str(tmp_path / "camchain.yaml"), "--kalibr-cams", "cam1", "cam0",
                 "--world-from", str(tmp_path / "world.yaml"), "--out", str(b)]) == 0
    ra, rb = load_rig_calibration(a), load_rig_calibration(b)
    for name, truth, T_cam_world in (("top", top, T_top_world), ("side", side, T_side_top @ T_top_world)):
        for r in (ra, rb):
            np.testing.assert_allclose(r[name].K, truth.K, atol=1e-9)
            np.testing.assert_allclose(r[name].dist[:5], truth.dist, atol=1e-12)
            np.testing.assert_allclose(r[name].T_cam_world, T_cam_world, atol=1e-9)
    # the exports: a rectified ROS pair that PyYAML and the ROS reader take back
    for name in ("top", "side"):
        doc = yaml.safe_load((a.parent / f"rig_ros_{name}.yaml").read_text())
        assert doc["distortion_model"] == "plumb_bob" and len(doc["distortion_coefficients"]["data"]) == 5
        np.testing.assert_allclose(load_ros_camera_info(a.parent / f"rig_ros_{name}.yaml").K, ra[name].K)
    capsys.readouterr()


def test_stereo_calib_with_side_as_camera_1(rig_parts, tmp_path):
    top, side, T_side_top, _ = rig_parts
    _write_stereo_calib(tmp_path, side, top, invert_transform(T_side_top), square_mm=1.0)
    st = load_stereo_calib(tmp_path / "intrinsics.yml", tmp_path / "extrinsics.yml", (1280, 960), first="side")
    np.testing.assert_allclose(st["T_side_top"], T_side_top, atol=1e-9)
    np.testing.assert_allclose(st["side"].K, side.K)


def test_ros_rectification_is_opencv_s(rig_parts):
    top, side, T_side_top, _ = rig_parts
    rect = ros_stereo_rectification(top, side, T_side_top)
    R1, R2, P1, P2, *_ = cv2.stereoRectify(top.K, top.dist, side.K, side.dist, (1280, 960), T_side_top[:3, :3],
                                           T_side_top[:3, 3:4] / 1000.0, flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
    first, second = (rect["top"], rect["side"]) if not np.any(rect["top"][1][:2, 3]) else (rect["side"], rect["top"])
    assert not np.any(first[1][:2, 3]) and second[1][:2, 3].sum() < 0  # the second camera's Tx or Ty is -f' B
    np.testing.assert_allclose(abs(second[1][:2, 3].sum()), abs(P2[:2, 3].sum()), rtol=1e-9)


def test_import_conflicts_and_format_errors(rig_parts, tmp_path, capsys):
    from recon.calibration_io import save_world_file
    from rig.cli import main

    top, side, T_side_top, T_top_world = rig_parts
    _write_kalibr(tmp_path / "camchain.yaml", top, side, T_side_top)
    moved = T_side_top.copy()
    moved[0, 3] += 2.0
    save_world_file(tmp_path / "world.yaml", T_top_world, moved)
    out = str(tmp_path / "rig.json")
    cases = [
        (["--import-kalibr", str(tmp_path / "camchain.yaml"), "--world-from", str(tmp_path / "world.yaml")],
         "world.yaml: T_side_top differs from the one of"),
        (["--import-kalibr", str(tmp_path / "camchain.yaml"), "--image-size", "640", "480", "--world-from", str(tmp_path / "world.yaml")],
         "resolution 1280x960 disagrees with --image-size"),
        (["--import-stereo-calib", str(tmp_path / "nope.yml"), str(tmp_path / "nope2.yml"), "--world-from", str(tmp_path / "world.yaml")],
         "the files hold no image size"),
        (["--import-kalibr", str(tmp_path / "camchain.yaml"), "--kalibr-cams", "cam0", "cam2", "--world-from", str(tmp_path / "world.yaml")],
         "not neighbours"),
    ]
    for argv, message in cases:
        assert main(["calibrate", *argv, "--out", out]) == 2
        err = capsys.readouterr().err.strip()
        assert message in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "rig.json").exists()
    doc = yaml.safe_load((tmp_path / "camchain.yaml").read_text())
    doc["cam0"]["distortion_model"] = "equidistant"
    (tmp_path / "fisheye.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(ValueError, match="fisheye.yaml: cam0: distortion_model 'equidistant'"):
        load_kalibr_camchain(tmp_path / "fisheye.yaml")


def test_ros_cannot_carry_the_tilted_model(tmp_path):
    from recon.calibration_io import save_ros_camera_info

    cam = Camera("top", 1280, 960, K, np.array(DIST[14]))
    with pytest.raises(ValueError, match="no ROS camera_info model"):
        save_ros_camera_info(tmp_path / "x.yaml", cam)
    save_ros_camera_info(tmp_path / "r.yaml", Camera("top", 1280, 960, K, np.array(DIST[8])))
    back = load_ros_camera_info(tmp_path / "r.yaml")
    assert yaml.safe_load((tmp_path / "r.yaml").read_text())["distortion_model"] == "rational_polynomial"
    np.testing.assert_allclose(back.dist, DIST[8])
