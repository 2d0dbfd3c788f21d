"""Bad frames through ``reconstruct_session``: one-line reasons, the run goes on, nothing written is lost.

One small twin session is rendered (8 background pairs, a normal frame, a
frame whose tip leaves the view, a frame without the robot); the other bad
frames are corruptions of the normal one written with the session writer
(two robots, an all-black image, a wrong image size, an unreadable PNG).
Of the two robots, the one joined to the base the cameras see is the robot:
that frame is reconstructed, not refused.
"""
from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from recon.background import EigenBackgroundParams
from rig.bench.reconstruct import format_table, reconstruct_session
from rig.session import Session, SessionError, SessionWriter
from twin.record import truth_arrays
from twin.robotfile import robot_to_dict
from twin.robot import Joints

N_BACKGROUND = 8


@pytest.fixture(scope="module")
def rendered(paper_twin, paper_scene):
    """Background images, and frames: normal, tip out of the view, no robot."""
    tw = paper_twin
    backgrounds = [tw.background(i).images for i in range(N_BACKGROUND)]
    normal = tw.frame(3)
    # The inner tube pushed 200 mm out: its tip runs far past the right border.
    leaving = tw.frame(1, joints=Joints((50.0, 200.0), (0.0, 0.0)))
    absent = tw.background(N_BACKGROUND + 5)  # robot-free, with its own jitter and noise
    return backgrounds, normal, leaving, absent


def _writer(directory, scene):
    meta = {"scene": scene.source, "scene_name": scene.name, "robot": robot_to_dict(scene.robot, scene.model)}
    return SessionWriter(directory, scene.rig, source="twin", n_tubes=scene.robot.n_tubes, meta=meta)


def _two_robots(frame, camera: str, shift_px: int) -> np.ndarray:
    """``camera``'s image with a second copy of the robot, ``shift_px`` rows lower."""
    img = frame.images[camera].copy()
    mask = cv2.dilate((frame.labels[camera] > 0).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    ys, xs = np.nonzero(mask)
    img[ys + shift_px, xs] = frame.images[camera][ys, xs]
    return img


@pytest.fixture(scope="module")
def bad_session(tmp_path_factory, rendered, paper_scene):
    backgrounds, normal, leaving, absent = rendered
    d = tmp_path_factory.mktemp("bad") / "session"
    good = normal.images
    frames = [
        ("ok", good, normal),
        ("leaving", leaving.images, leaving),
        ("absent", absent.images, None),
        ("two blobs", {**good, "side": _two_robots(normal, "side", 200)}, normal),
        ("black", {**good, "side": np.zeros_like(good["side"])}, normal),
        ("size", {**good, "top": cv2.resize(good["top"], (512, 384), interpolation=cv2.INTER_AREA)}, normal),
        ("unreadable", good, normal),
        ("ok again", good, normal),
    ]
    with _writer(d, paper_scene) as w:
        for i, imgs in enumerate(backgrounds):
            w.add_background(i, imgs)
        for i, (_, imgs, truth_frame) in enumerate(frames):
            w.add_frame(
                i,
                imgs,
                t_s=10.0 * i,
                joints=truth_frame.joints if truth_frame is not None else None,
                truth=truth_arrays(truth_frame) if truth_frame is not None else None,
            )
    (d / "frames" / "side" / "000006.png").write_bytes(b"this is not a PNG file")
    return d


@pytest.fixture(scope="module")
def result(bad_session, tmp_path_factory):
    out = tmp_path_factory.mktemp("bad_out")
    return reconstruct_session(bad_session, out), out


def test_each_bad_frame_fails_with_a_one_line_reason(result, bad_session):
    summary, _ = result
    recs = {r["frame"]: r for r in summary["per_frame"]}
    assert summary["frames"] == 8 and summary["failed_frames"] == 5
    for r in summary["per_frame"]:
        if r["status"] == "failed":
            assert r["reason"] and "\n" not in r["reason"], r
    assert recs[0]["status"] == "ok" and recs[7]["status"] == "ok"
    assert recs[1]["reason"] == "side: robot leaves the view at the right border"
    assert recs[2]["reason"].startswith("side: no silhouette (")
    assert recs[3]["status"] == "ok", recs[3]  # the copy 200 px below is not joined to the base
    assert recs[4]["reason"] == "side: all-black frame"
    assert recs[5]["reason"] == "top: image is 512x384 but the calibration is 1024x768"
    bad_png = bad_session / "frames" / "side" / "000006.png"
    assert recs[6]["reason"] == f"{bad_png}: unreadable image (not a valid PNG)"


def test_good_frames_around_the_bad_ones_are_kept(result):
    summary, out = result
    recs = {r["frame"]: r for r in summary["per_frame"]}
    ok = [i for i, r in recs.items() if r["status"] == "ok"]
    assert ok == [0, 3, 7]
    for i in ok:
        voxel = max(recs[i]["voxel_size_mm"])
        assert recs[i]["mean_error_mm"] <= voxel
        assert (out / "frames" / f"{i:06d}.csv").exists()
    assert sorted(p.name for p in (out / "frames").iterdir()) == ["000000.csv", "000003.csv", "000007.csv"]
    with np.load(out / "backbones.npz") as z:
        assert list(z["frames"]) == [0, 3, 7]
    on_disk = json.loads((out / "summary.json").read_text())
    assert [r["status"] for r in on_disk["per_frame"]] == [r["status"] for r in summary["per_frame"]]
    table = format_table(summary)
    assert "failed: side: all-black frame" in table
    assert "8 frames, 5 failed" in table


def test_too_few_background_frames_is_a_set_up_error(bad_session, tmp_path):
    d = tmp_path / "session"
    shutil.copytree(bad_session, d)
    k = EigenBackgroundParams().k
    for cam in Session(d).cameras:
        for p in sorted((d / "background" / cam).glob("*.png"))[k - 2 :]:
            p.unlink()
    with pytest.raises(SessionError) as err:
        reconstruct_session(d, tmp_path / "out")
    msg = str(err.value)
    assert "\n" not in msg
    assert msg == f"{d / 'background' / 'side'}: need at least k+1={k + 1} background frames, got {k - 2}"


def test_summary_json_writes_non_finite_figures_as_null(tmp_path):
    """JSON has no NaN or inf: an unknown figure or a limit that is off is null, never an aborted write."""
    from rig.rundir import write_json_atomic

    path = tmp_path / "summary.json"
    write_json_atomic(path, {"limit": float("inf"), "fig": np.float64("nan"), "pts": np.array([1.0, -np.inf]), "n": np.int64(3),
                             "nested": [{"x": float("nan")}, (2.5,)]})
    assert json.loads(path.read_text()) == {"limit": None, "fig": None, "pts": [1.0, None], "n": 3, "nested": [{"x": None}, [2.5]]}
