"""Model verification and calibration (issue 9): verify and fit on synthetic sessions.

The sessions here are written directly (tiny blank images, exact ground truth)
so that the tests do not depend on rendering or reconstruction accuracy: the
"reconstruction" is the true backbone plus 0.1 mm of noise. The true robot is
scenes/plastic.toml's (a 3D-printed plastic inner tube) and the session carries
the nominal robot of scenes/plastic-nominal.toml and commanded joints 6 deg off
the true inner rotations.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from rig.cli import main
from rig.scenefiles import scenes_dir
from rig.session import SessionWriter
from twin.kinematics import solve
from twin.modelfit import (
    Frame,
    JointOffsets,
    ModelFitError,
    ModelState,
    aggregate,
    fit,
    load_robot_file,
    parse_params,
    robot_to_toml,
    split_holdout,
    verify,
)
from twin.robot import Joints
from twin.robotfile import robot_to_dict
from twin.scene import load_scene, scene_from_dict

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

SCENES = scenes_dir()
ROT_OFFSET = 6.0        # true inner rotation = recorded + 6 deg
NOISE_MM = 0.1


@pytest.fixture(scope="module")
def plastic():
    return load_scene(SCENES / "plastic.toml")


@pytest.fixture(scope="module")
def nominal():
    return load_robot_file(SCENES / "plastic-nominal.toml")


def _recorded(j: Joints) -> Joints:
    return Joints(j.extension_mm, (j.rotation_deg[0], j.rotation_deg[1] - ROT_OFFSET))


def _noisy(bb, rng, step=5):
    """Every ``step``-th true sample (0.5 mm) and the tip, plus isotropic noise."""
    q = np.vstack([bb.p_world_mm[:-1:step], bb.p_world_mm[-1:]])
    return q + rng.normal(0.0, NOISE_MM, q.shape)


def write_session(directory: Path, scene, model: str, robot_meta: dict | None, frames=None, no_joints=()) -> Path:
    """A twin-like session without images worth the name: joints, nominal robot, exact truth."""
    rig = scene.rig
    meta = {"scene_name": "synthetic"}
    if robot_meta is not None:
        meta["robot"] = robot_meta
    blank = {c: np.zeros((16, 16), np.uint8) for c in rig.names}
    joints = scene.joints if frames is None else [scene.joints[i] for i in frames]
    with SessionWriter(directory, rig, source="twin", n_tubes=scene.robot.n_tubes, meta=meta) as w:
        for i, j in enumerate(joints):
            bb = solve(scene.robot, j, model, 0.1)
            w.add_frame(i, blank, t_s=float(i), joints=None if i in no_joints else _recorded(j),
                        truth={"s_mm": bb.s_mm, "backbone_world_mm": bb.p_world_mm, "tip_world_mm": bb.tip_world_mm})
    return directory


def write_recon(directory: Path, session: Path, backbones: dict) -> Path:
    """A reconstruction output directory (docs/outputs.md) holding ``backbones``."""
    directory.mkdir(parents=True, exist_ok=True)
    summary = {"format": "ctr-bench-summary", "version": 1, "method": "synthetic", "session": str(session),
               "per_frame": [{"frame": i, "status": "ok"} for i in sorted(backbones)]}
    (directory / "summary.json").write_text(json.dumps(summary))
    np.savez(directory / "backbones.npz", frames=np.array(sorted(backbones)),
             **{f"frame_{i:06d}": p for i, p in backbones.items()})
    return directory


@pytest.fixture(scope="module")
def bending_data(tmp_path_factory, plastic, nominal):
    """Session (nominal robot, bending model truth) and a noisy 'reconstruction' of it."""
    root = tmp_path_factory.mktemp("bending")
    nom = ModelState(nominal.robot, "bending")
    session = write_session(root / "session", plastic, "bending", robot_to_dict(nom.robot, "bending"))
    rng = np.random.default_rng(9)
    bbs = {i: _noisy(solve(plastic.robot, j, "bending", 0.1), rng) for i, j in enumerate(plastic.joints)}
    recon = write_recon(root / "recon", session, bbs)
    true_file = root / "true.toml"
    true_file.write_text(robot_to_toml(ModelState(plastic.robot, "bending", JointOffsets(np.zeros(2), np.array([0.0, ROT_OFFSET])))))
    return {"root": root, "session": session, "recon": recon, "true": true_file}


def test_verify_ground_truth_with_true_robot_is_exact(bending_data, tmp_path, capsys):
    # the session itself: its ground truth is the measurement
    out = tmp_path / "v"
    assert main(["verify", str(bending_data["session"]), "--robot", str(bending_data["true"]), "--out", str(out)]) == 0
    doc = json.loads((out / "verify.json").read_text())
    agg = doc["aggregate"]
    assert doc["measured"] == "ground truth" and agg["ok_frames"] == 25
    assert agg["tip_error_mm_max"] < 1e-6
    assert agg["mean_error_mm_max"] < 0.005
    assert agg["along_error_mm_rms"] < 0.02  # arc lengths of a measurement are taken along a smoothed copy
    for name in ("verify.csv", "along_arc_length.csv", "per_frame_errors.png", "error_along_arc_length.png", "backbones.png"):
        assert (out / name).stat().st_size > 0
    assert "tip error mean" in capsys.readouterr().out


def test_verify_nominal_model_shows_its_error(bending_data, tmp_path):
    out = tmp_path / "v"
    assert main(["verify", str(bending_data["recon"]), "--model", "bending", "--out", str(out), "--no-plots"]) == 0
    agg = json.loads((out / "verify.json").read_text())["aggregate"]
    assert agg["tip_error_mm_mean"] > 2.0  # 16 % too much precurvature and a 6 deg offset: millimetres


def test_fit_recovers_precurvature_and_rotation_offset(bending_data, plastic, tmp_path, capsys):
    out = tmp_path / "robot_fitted.toml"
    rc = main(["fit", str(bending_data["recon"]), "--model", "bending", "--fit-params",
               "inner.precurvature_per_mm,rotation_offset_deg.inner,stiffness_ratio", "--holdout-every", "4", "--out", str(out)])
    assert rc == 0
    rep = json.loads(out.with_suffix(".json").read_text())
    got = {p["name"]: p for p in rep["parameters"]}
    kappa = got["inner.precurvature_per_mm"]
    assert kappa["value"] == pytest.approx(plastic.robot.tubes[1].precurvature_per_mm, rel=0.02)
    assert got["rotation_offset_deg.inner"]["value"] == pytest.approx(ROT_OFFSET, abs=1.0)
    lo, hi = kappa["ci95"]
    assert lo < kappa["value"] < hi and hi - lo < 0.02 * kappa["value"]
    # held-out frames (every 4th) are predicted better after the fit, down to the noise
    held = rep["held_out"]
    assert len(rep["held_out_frames"]) == 6 and not set(rep["held_out_frames"]) & set(rep["fit_frames"])
    assert held["fitted"]["mean_error_mm_mean"] < 0.5 * held["nominal"]["mean_error_mm_mean"]
    assert held["fitted"]["tip_error_mm_mean"] < 0.5
    assert held["nominal"]["tip_error_mm_mean"] > 2.0
    # the fitted robot file reads back (with its offsets) and is a scene's [robot] table
    st = load_robot_file(out)
    assert st.offsets.rotation_deg[1] == pytest.approx(got["rotation_offset_deg.inner"]["value"])
    data = tomllib.loads((SCENES / "plastic.toml").read_text())
    data["robot"] = tomllib.loads(out.read_text())["robot"]
    scene = scene_from_dict(data, "fitted")
    assert scene.robot.tubes[1].precurvature_per_mm == pytest.approx(kappa["value"])
    assert "95% CI" in capsys.readouterr().out


def test_compliant_fit_recovers_and_improves_held_out(plastic, nominal):
    # compliant truth and model, few frames to keep it quick
    rng = np.random.default_rng(3)
    idx = [2, 5, 7, 9, 11, 13, 15, 18, 20, 23]
    frames = [Frame(i, _recorded(plastic.joints[i]), _noisy(solve(plastic.robot, plastic.joints[i], "compliant", 0.1), rng)) for i in idx]
    train, held = split_holdout(frames, 5)
    nom = ModelState(nominal.robot, "compliant")
    res = fit(train, nom, ["inner.precurvature_per_mm", "rotation_offset_deg.inner"], ds_mm=0.5)
    vals = dict(zip(res.names, res.values))
    assert vals["inner.precurvature_per_mm"] == pytest.approx(0.0140, rel=0.02)
    assert vals["rotation_offset_deg.inner"] == pytest.approx(ROT_OFFSET, abs=1.0)
    before = aggregate(verify(held, nom, 0.5))
    after = aggregate(verify(held, res.state, 0.5))
    assert after["mean_error_mm_mean"] < 0.5 * before["mean_error_mm_mean"]


def test_parameter_names_and_identifiability(nominal):
    st = ModelState(nominal.robot, "compliant")
    names = [p.name for p in parse_params("base.position_mm,0.precurvature_per_mm,insertion_offset_mm.inner", st)]
    assert names == ["base.position_mm[x]", "base.position_mm[y]", "base.position_mm[z]", "outer.precurvature_per_mm", "insertion_offset_mm.inner"]
    for bad, msg in [
        ("inner.stiffness", "unknown parameter 'inner.stiffness'"),
        ("middle.precurvature_per_mm", "no tube 'middle'"),
        ("outer.youngs_modulus_gpa,inner.youngs_modulus_gpa", "only on ratios of E I"),
        ("stiffness_ratio,inner.youngs_modulus_gpa", "only E I ratios"),
    ]:
        with pytest.raises(ModelFitError, match=msg):
            parse_params(bad, st)
    with pytest.raises(ModelFitError, match="bending model does not depend"):
        parse_params("inner.poisson_ratio", ModelState(nominal.robot, "bending"))


def _err(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


def test_bad_inputs_give_one_line_errors(bending_data, plastic, nominal, tmp_path, capsys):
    recon, out = str(bending_data["recon"]), str(tmp_path / "r.toml")
    assert main(["fit", recon, "--fit-params", "inner.wobble", "--out", out]) == 2
    assert "unknown parameter 'inner.wobble'" in _err(capsys)
    # frames without joint values
    s = write_session(tmp_path / "nojoints", plastic, "bending", robot_to_dict(nominal.robot, "bending"), frames=[0, 1], no_joints=(0, 1))
    assert main(["verify", str(s)]) == 2
    assert "no frame has both joint values and a measured backbone (2 of 2 frames without joint values" in _err(capsys)
    # the session summary.json names is gone
    r = write_recon(tmp_path / "orphan", tmp_path / "gone", {0: np.zeros((3, 3))})
    assert main(["verify", str(r)]) == 2
    e = _err(capsys)
    assert "its session" in e and "was not found" in e
    assert main(["verify", str(r), "--session", str(tmp_path / "gone")]) == 2
    assert "not a directory" in _err(capsys)
    # neither a reconstruction nor a session; missing robot file; no nominal robot
    assert main(["verify", str(tmp_path)]) == 2
    assert "neither a reconstruction output directory" in _err(capsys)
    assert main(["verify", recon, "--robot", str(tmp_path / "nope.toml")]) == 2
    assert "robot file not found" in _err(capsys)
    s2 = write_session(tmp_path / "norobot", plastic, "bending", None, frames=[0])
    assert main(["verify", str(s2)]) == 2
    assert "pass --robot" in _err(capsys)


def test_believed_session_records_nominal_robot_and_commanded_joints(tmp_path):
    from rig.bench.scenes import render_believed_session
    from rig.session import Session

    out = render_believed_session(SCENES / "plastic.toml", tmp_path / "s", SCENES / "plastic-nominal.toml",
                                  {"rotation_deg": [0.0, ROT_OFFSET]}, frames=2, background_frames=0)
    s = Session(out)
    assert s.meta["robot"]["tubes"][1]["precurvature_per_mm"] == pytest.approx(0.016667)
    assert s.meta["true_robot"]["tubes"][1]["precurvature_per_mm"] == pytest.approx(0.0140)
    for fr in s.frames:
        t = s.truth(fr.index)
        assert t["rotation_deg"][1] - fr.rotation_deg[1] == pytest.approx(ROT_OFFSET)
        assert np.allclose(t["extension_mm"], fr.extension_mm)
