"""The robot description's one owner (``twin.robotfile``): robot files, scene robot tables and session.json's robot."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from rig.scenefiles import scenes_dir
from twin.robotfile import (
    read_robot_file,
    robot_file_toml,
    robot_from_dict,
    robot_from_toml,
    robot_to_dict,
)
from twin.scene import SceneError, load_scene

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

SCENES = scenes_dir()


@pytest.fixture(scope="module")
def plastic():
    return load_scene(SCENES / "plastic.toml")


def _same_robot(a, b):
    assert a.tubes == b.tubes
    assert np.allclose(a.T_world_base, b.T_world_base, atol=1e-12)


def test_robot_file_round_trips_with_numpy_offsets_and_a_fit_table(plastic, tmp_path):
    fit_table = {"from": "out/run", "rms_mm": np.float64(0.12), "inner.precurvature_per_mm": np.float64(0.0141),
                 "base.position_mm": np.array([1.0, 2.0, 3.0]), "inner.precurvature_per_mm.ci95": [0.0139, np.nan]}
    text = robot_file_toml(plastic.robot, "compliant", np.array([0.5, -0.25]), np.array([0.0, 6.0]),
                           header="fitted\nby a test", fit_table=fit_table)
    assert text.startswith("# fitted\n# by a test\n")
    path = tmp_path / "robot.toml"
    path.write_text(text)
    rf = read_robot_file(path)
    _same_robot(rf.robot, plastic.robot)
    assert rf.model == "compliant"
    assert rf.insertion_offset_mm.tolist() == [0.5, -0.25] and rf.rotation_offset_deg.tolist() == [0.0, 6.0]
    fit = tomllib.loads(text)["fit"]
    # a non-finite number of the record is text, never read back as a value
    assert fit["inner.precurvature_per_mm.ci95"] == [0.0139, "nan"] and fit["base.position_mm"] == [1.0, 2.0, 3.0]


def test_robot_table_of_a_scene_is_the_scenes_robot(plastic):
    data = tomllib.loads((SCENES / "plastic.toml").read_text())
    robot, model = robot_from_toml(data, "plastic.toml")
    _same_robot(robot, plastic.robot)
    assert model == plastic.model
    # ...and a written robot file's [robot] table makes the same scene robot
    data["robot"] = tomllib.loads(robot_file_toml(robot, model, [0.0, 0.0], [0.0, 0.0]))["robot"]
    _same_robot(robot_from_toml(data, "copy")[0], plastic.robot)


def test_session_json_form_round_trips(plastic):
    robot, model = robot_from_dict(robot_to_dict(plastic.robot, plastic.model))
    _same_robot(robot, plastic.robot)
    assert model == plastic.model
    with pytest.raises(LookupError, match=r"^s\.json: robot: not a valid robot description"):
        robot_from_dict({"model": "bending"}, "s.json", LookupError)  # the caller's error class


@pytest.mark.parametrize("text, where", [
    ("[robot]\n", "robot.tubes: at least one"),
    ('[robot]\nmodel = "bending"\n[[robot.tubes]]\nname = "a"\n', "robot.tubes[0].outer_diameter_mm: missing"),
    ("[robot]\n[[robot.tubes]]\nname = 'a'\nouter_diameter_mm = 1.0\ninner_diameter_mm = 0.5\nlength_mm = 100.0\n"
     "curved_length_mm = 10.0\nprecurvature_per_mm = 0.01\n[actuator]\nrotation_offset_deg = [0.0, 1.0]\n",
     "actuator.rotation_offset_deg: must be a list of 1 numbers"),
    ("[robot]\n[[robot.tubes]]\nname = 'a'\nouter_diameter_mm = 1.0\ninner_diameter_mm = 0.5\nlength_mm = 100.0\n"
     "curved_length_mm = 10.0\nprecurvature_per_mm = 0.01\n[camera]\n", "camera: unknown key"),
    ("not toml [", "not valid TOML"),
])
def test_bad_robot_files_are_one_line_errors_naming_file_and_key(tmp_path, text, where):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(SceneError) as err:
        read_robot_file(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: {where}") and "\n" not in msg, msg


def test_missing_robot_file(tmp_path):
    with pytest.raises(SceneError, match="robot file not found"):
        read_robot_file(tmp_path / "none.toml")
