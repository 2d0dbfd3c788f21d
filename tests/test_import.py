"""``ctr-bench import``: sessions from a lab's own image folders and videos (docs/import.md).

The lab recording is made from a small twin session (2 robot frames, 6 background
frames): its PNGs renamed as a lab's tools name them (times in the names, the top
camera in colour), written into a video, or turned into masks from the ground
truth labels. An imported session must hold the same pixels and reconstruct as
well as the twin's; joints stay empty unless a CSV gives them; every bad input is
one line naming it.
"""
from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from recon.metrics import backbone_errors
from rig.cli import main as cli
from rig.session import Session
from rig.scenefiles import scenes_dir

ROOT = Path(__file__).resolve().parents[1]
SCENES = scenes_dir()
SCENE = SCENES / "paper.toml"
N_BG, N_FR = 6, 2
TIME_ARGS = ["--time-from-name", r"img_\d+_(\d+)_us", "--time-unit", "us"]


def _t_us(cam: str, i: int) -> int:
    """The lab's clock in the file names: 10 Hz from 1 s, the top camera 250 us late."""
    return 1_000_000 + 100_000 * i + (250 if cam == "top" else 0)


@pytest.fixture(scope="module")
def twin(tmp_path_factory):
    """scenes/paper.toml's first robot frames and a few background frames, rendered into a session."""
    from dataclasses import replace

    from rig.bench.scenes import render_scene_to
    from twin.scene import load_scene

    scene = load_scene(SCENE)
    scene = replace(scene.with_frames(scene.joints[:N_FR]), background_frames=N_BG)
    return render_scene_to(scene, tmp_path_factory.mktemp("import-twin") / "session", quiet=True)


def _twin_images(twin: Path, cam: str) -> list:
    """The twin's background then robot frames of ``cam`` (mono uint8), in recording order."""
    paths = sorted((twin / "background" / cam).glob("*.png")) + sorted((twin / "frames" / cam).glob("*.png"))
    return [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in paths]


@pytest.fixture(scope="module")
def lab(twin, tmp_path_factory):
    """The twin's frames as a lab records them: one folder per camera, background first, the top camera in colour."""
    d = tmp_path_factory.mktemp("lab")
    for cam in ("side", "top"):
        (d / cam).mkdir()
        for i, img in enumerate(_twin_images(twin, cam)):
            if cam == "top":
                img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
            cv2.imwrite(str(d / cam / f"img_{i}_{_t_us(cam, i)}_us.png"), img)
    return d


def _import(out: Path, *args) -> int:
    return cli(["import", *map(str, args), "--out", str(out), "--quiet"])


def _lab_args(twin, lab) -> list:
    return ["--side", f"{lab}/side/*.png", "--top", lab / "top", "--background-frames", f"0-{N_BG - 1}",
            "--calibration", twin / "rig.json", *TIME_ARGS]


def _reconstruct(session: Path, out: Path) -> dict:
    assert cli(["reconstruct", str(session), "--out", str(out), "--quiet", "--no-report"]) in (0, 1)
    return json.loads((out / "summary.json").read_text())


def _errors_vs_truth(twin: Path, rec: Path) -> list:
    """Per frame: backbone_errors of the reconstruction against the twin's ground truth."""
    s = Session(twin)
    with np.load(rec / "backbones.npz") as z:
        return [backbone_errors(z[f"frame_{i:06d}"], s.truth(i)["backbone_world_mm"]) for i in range(N_FR)]


# ============================================================================ PNG folders, end to end
def test_png_folders_import_and_reconstruct(twin, lab, tmp_path):
    out = tmp_path / "lab-session"
    assert _import(out, *_lab_args(twin, lab), "--tube-diameters-mm", "1.6,1.0") == 0
    s, t = Session(out), Session(twin)
    assert s.meta["source"] == "rig" and s.meta["background_frames"] == N_BG and len(s.frames) == N_FR
    for cam in ("side", "top"):
        assert np.array_equal(s.background_stack(cam), t.background_stack(cam))
        for i in range(N_FR):
            img = s.frame_images(i, mono=False)[cam]
            assert img.ndim == 2 and np.array_equal(img, t.frame_images(i)[cam])     # colour stored as mono
    # times from the names, since the first input frame (a background frame); skew from the two clocks
    assert [f.t_s for f in s.frames] == pytest.approx([0.600125, 0.700125], abs=1e-6)
    assert [f.skew_ms for f in s.frames] == pytest.approx([0.25, 0.25], abs=1e-3)
    assert s.robot_tube_radii_mm == (0.8, 0.5)
    # no --joints: the joint columns exist (2 tubes) and stay empty
    with open(out / "frames.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert all(f.extension_mm is None for f in s.frames)
    assert [r["extension_1_mm"] for r in rows] == ["", ""] and [r["rotation_0_deg"] for r in rows] == ["", ""]
    with open(out / "sources.csv", newline="") as fh:
        src = list(csv.DictReader(fh))
    assert src[N_BG]["kind"] == "frame" and src[N_BG]["side"].endswith(f"img_{N_BG}_{_t_us('side', N_BG)}_us.png")
    summary = _reconstruct(out, tmp_path / "rec")
    assert summary["frames"] == N_FR and summary["failed_frames"] == 0
    for e in _errors_vs_truth(twin, tmp_path / "rec"):
        assert e["tip_error_mm"] < 0.5 and e["mean_error_mm"] < 0.2


def test_joints_csv_by_frame_and_by_time(twin, lab, tmp_path):
    truth = Session(twin).frames
    by_frame = tmp_path / "joints.csv"
    by_frame.write_text("frame,extension_0_mm,rotation_0_deg,extension_1_mm,rotation_1_deg\n"
                        f"1,{truth[1].extension_mm[0]},{truth[1].rotation_deg[0]},{truth[1].extension_mm[1]},{truth[1].rotation_deg[1]}\n")
    out = tmp_path / "a"
    assert _import(out, *_lab_args(twin, lab), "--joints", by_frame, "--robot", SCENE) == 0
    s = Session(out)
    assert s.frames[0].extension_mm is None                        # no row: unknown, not invented
    assert s.frames[1].extension_mm == truth[1].extension_mm and s.frames[1].rotation_deg == truth[1].rotation_deg
    assert s.meta["robot"]["tubes"][1]["length_mm"] == 260.0       # the scene's [robot] table, in full
    # by time: the nearest frame within half a frame interval (0.05 s); 5.0 s matches no frame
    by_time = tmp_path / "joints-t.csv"
    by_time.write_text(" t_s , extension_0_mm,rotation_0_deg,extension_1_mm,rotation_1_deg\n"
                       "0.61,50,0,55,0\n0.69,50,0,60,10\n5.0,1,1,1,1\n")
    out = tmp_path / "b"
    assert _import(out, *_lab_args(twin, lab), "--joints", by_time) == 0
    s = Session(out)
    assert s.n_tubes == 2 and [f.extension_mm for f in s.frames] == [(50.0, 55.0), (50.0, 60.0)]
    assert s.frames[1].rotation_deg == (0.0, 10.0)


def test_verify_refuses_frames_without_joints(twin, lab, tmp_path, capsys):
    out = tmp_path / "no-joints"
    assert _import(out, *_lab_args(twin, lab), "--robot", SCENE) == 0
    _reconstruct(out, tmp_path / "rec")
    capsys.readouterr()
    assert cli(["verify", str(tmp_path / "rec"), "--no-plots"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no frame has both joint values" in err and f"{N_FR} of {N_FR} frames without joint values" in err
    # diameters only: verify asks for a robot instead of failing on a partial one
    out = tmp_path / "diameters"
    assert _import(out, *_lab_args(twin, lab), "--tube-diameters-mm", "1.6,1.0") == 0
    _reconstruct(out, tmp_path / "rec2")
    capsys.readouterr()
    assert cli(["verify", str(tmp_path / "rec2"), "--no-plots"]) == 2
    assert "records only the tube diameters" in capsys.readouterr().err


# ============================================================================ video, masks, printf
def _write_video(path: Path, images: list, fps: float = 15.0) -> Path:
    h, w = images[0].shape
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (w, h))
    assert vw.isOpened()
    for img in images:
        vw.write(cv2.cvtColor(img, cv2.COLOR_GRAY2BGR))
    vw.release()
    return path


def test_video_import(twin, tmp_path):
    videos = {cam: _write_video(tmp_path / f"{cam}.avi", _twin_images(twin, cam)) for cam in ("side", "top")}
    out = tmp_path / "video-session"
    assert _import(out, "--side", videos["side"], "--top", videos["top"], "--background-frames", f"0-{N_BG - 1}",
                   "--calibration", twin / "rig.json", "--robot", SCENE) == 0
    s, t = Session(out), Session(twin)
    assert len(s.frames) == N_FR and s.meta["background_frames"] == N_BG
    assert [f.t_s for f in s.frames] == pytest.approx([N_BG / 15.0, (N_BG + 1) / 15.0], abs=1e-6)   # container times
    assert "CAP_PROP_POS_MSEC" in s.meta["import"]["times"]["side"]
    assert all(f.extension_mm is None for f in s.frames)
    for i in range(N_FR):
        for cam in ("side", "top"):
            img = s.frame_images(i, mono=False)[cam]
            assert img.shape == (768, 1024) and img.dtype == np.uint8
            assert np.mean(np.abs(img.astype(float) - t.frame_images(i)[cam])) < 3.0    # MJPG is lossy
    summary = _reconstruct(out, tmp_path / "rec")
    assert summary["failed_frames"] == 0
    for e in _errors_vs_truth(twin, tmp_path / "rec"):
        assert e["tip_error_mm"] < 1.0


def test_masks_printf_pattern_and_fps(twin, tmp_path):
    """Silhouettes from the truth labels (robot white), numbered from 1, no background frames."""
    t = Session(twin)
    for cam in ("side", "top"):
        (tmp_path / cam).mkdir()
        for i in range(N_FR):
            mask = np.where(t.truth(i)[f"labels_{cam}"] > 0, 200, 30).astype(np.uint8)   # binarised at 128
            cv2.imwrite(str(tmp_path / cam / f"mask_{i + 1:03d}.png"), mask)
    out = tmp_path / "masks-session"
    assert _import(out, "--side", tmp_path / "side" / "mask_%03d.png", "--top", tmp_path / "top" / "mask_%d.png",
                   "--masks", "--fps", 10, "--calibration", twin / "rig.json", "--robot", SCENE) == 0
    s = Session(out)
    assert s.meta["image_kind"] == "masks" and s.meta["mask_polarity"] == "robot-white"
    assert [f.t_s for f in s.frames] == pytest.approx([0.0, 0.1])
    bg = s.background_stack("side")
    assert bg.shape[0] == 6 and not bg.any()                        # uniform: no robot
    img = s.frame_images(0)["side"]
    assert set(np.unique(img)) == {0, 255} and np.array_equal(img > 0, t.truth(0)["labels_side"] > 0)
    summary = _reconstruct(out, tmp_path / "rec")
    assert summary["failed_frames"] == 0
    for e in _errors_vs_truth(twin, tmp_path / "rec"):
        assert e["mean_error_mm"] < 0.3


def test_opencv_stereo_calibration(twin, lab, tmp_path):
    from recon.calibration_io import export_rig_opencv, save_world_file
    from recon.rigcal import load_rig_calibration

    rig = load_rig_calibration(twin / "rig.json")
    stereo = export_rig_opencv(rig, tmp_path / "cal")[0]
    args = [a for a in _lab_args(twin, lab)]
    i = args.index("--calibration")
    args[i:i + 2] = ["--import-opencv", stereo]
    out = tmp_path / "cv"
    assert _import(out, *args) == 0
    got = Session(out).rig
    for cam in ("side", "top"):
        assert np.allclose(got[cam].K, rig[cam].K) and np.allclose(got[cam].T_cam_world, rig[cam].T_cam_world, atol=1e-6)
    # a world file with another world frame than the stereo file's: refused, not silently preferred
    T = rig["top"].T_cam_world.copy()
    T[0, 3] += 5.0
    save_world_file(tmp_path / "w.yaml", T)
    assert _import(tmp_path / "cv2", *args, "--world-from", tmp_path / "w.yaml") == 2
    assert not (tmp_path / "cv2").exists()


# ============================================================================ errors
def _copy_lab(lab: Path, dst: Path, drop_top: int = 0) -> Path:
    shutil.copytree(lab, dst)
    for p in sorted((dst / "top").iterdir())[:drop_top]:
        p.unlink()
    return dst


def _fail(out: Path, args: list, capsys) -> str:
    capsys.readouterr()
    assert _import(out, *args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err and err.startswith("ctr-bench import: error: ")
    assert not out.exists()                                          # nothing half written
    return err


def test_unequal_counts_name_both_inputs(twin, lab, tmp_path, capsys):
    short = _copy_lab(lab, tmp_path / "lab", drop_top=1)
    args = _lab_args(twin, short)
    err = _fail(tmp_path / "out", args, capsys)
    assert f"--side '{short}/side/*.png' has {N_BG + N_FR}" in err and f"--top '{short}/top' has {N_BG + N_FR - 1}" in err


@pytest.mark.parametrize("case, expect", [
    ("no-match", "matches no image files"),
    ("missing-video", "missing.avi: not found"),
    ("no-times", "image files carry no times: give --fps"),
    ("no-background", "no background frames"),
    ("background-range", "--background-frames: frame 99 is past the end"),
    ("bad-size", "image is 1024x768 but the calibration says 1000x768"),
    ("bad-regex-match", "finds no number in the file name"),
])
def test_bad_inputs_are_one_line_errors(twin, lab, tmp_path, capsys, case, expect):
    args = _lab_args(twin, lab)
    if case == "no-match":
        args[1] = f"{lab}/side/*.jpg"
    elif case == "missing-video":
        args[1] = tmp_path / "missing.avi"
    elif case == "no-times":
        args = args[:-4]
    elif case == "no-background":
        args = args[:4] + args[6:]
    elif case == "background-range":
        args[5] = "0-5,99"
    elif case == "bad-size":
        cal = json.loads((twin / "rig.json").read_text())
        cal["cameras"]["side"]["width"] = 1000
        (tmp_path / "rig.json").write_text(json.dumps(cal))
        args[7] = tmp_path / "rig.json"
    elif case == "bad-regex-match":
        args[9] = r"frame_(\d+)"
    assert expect in _fail(tmp_path / "out", args, capsys)


@pytest.mark.parametrize("text, expect", [
    ("frame,extension_0_mm,rotation_0_deg,extension_1_mm,rotation_1_deg\n0,50,0,abc,0\n",
     "joints.csv:2: extension_1_mm: 'abc' is not a number"),
    ("frame,extension_0_mm,rotation_0_deg,extension_1_mm\n0,50,0,55\n", "missing column rotation_1_deg"),
    ("frame,extension_0_mm,rotation_0_deg\n0,50,0\n", "joint columns for 1 tube(s), but the robot has 2"),
    ("frame,extension_0_mm,rotation_0_deg,extension_1_mm,rotation_1_deg\n7,50,0,55,0\n",
     "joints.csv:2: frame 7, but the import has 2 robot frames"),
    ("index,extension_0_mm\n0,50\n", "needs a 'frame' or a 't_s' column"),
    ("t_s,extension_0_mm,rotation_0_deg,extension_1_mm,rotation_1_deg\n100,50,0,55,0\n", "no row's t_s is within"),
])
def test_bad_joints_csv(twin, lab, tmp_path, capsys, text, expect):
    (tmp_path / "joints.csv").write_text(text)
    args = _lab_args(twin, lab) + ["--joints", tmp_path / "joints.csv", "--robot", SCENE]
    assert expect in _fail(tmp_path / "out", args, capsys)


def test_existing_output_is_never_overwritten(twin, lab, tmp_path, capsys):
    out = tmp_path / "s"
    assert _import(out, *_lab_args(twin, lab)) == 0
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    capsys.readouterr()
    assert _import(out, *_lab_args(twin, lab), "--fps", "30") == 2
    assert "already holds a session" in capsys.readouterr().err
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    assert _import(other, *_lab_args(twin, lab)) == 2
    assert "not an empty folder" in capsys.readouterr().err and (other / "notes.txt").read_text() == "mine"


def test_unreadable_frame_midway_removes_the_partial_session(twin, lab, tmp_path, capsys):
    bad = _copy_lab(lab, tmp_path / "lab")
    last = sorted((bad / "top").iterdir(), key=lambda p: int(p.name.split("_")[1]))[-1]
    last.write_bytes(b"not a png")
    empty = tmp_path / "empty"
    empty.mkdir()
    capsys.readouterr()
    assert _import(empty, *_lab_args(twin, bad)) == 2
    err = capsys.readouterr().err
    assert f"{last}: not an image OpenCV can decode" in err
    assert empty.is_dir() and not any(empty.iterdir())               # the user's empty folder, as it was
