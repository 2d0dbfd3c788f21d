"""Scene files: the paper scene loads; every kind of mistake names the file and the key."""
import re

import numpy as np
import pytest

from rig.scenefiles import scene_path
from twin.scene import SceneError, load_scene

PAPER = scene_path("paper.toml").read_text()


def test_paper_scene_matches_the_paper(paper_scene):
    assert len(paper_scene.joints) == 20 and paper_scene.background_frames >= 30
    ext = np.array([j.extension_mm[1] for j in paper_scene.joints])
    rot = np.array([j.rotation_deg[1] for j in paper_scene.joints])
    # inserted in steps, then rotated in steps (Fig. 8)
    assert np.all(np.diff(ext[:10]) > 0) and np.all(rot[:10] == 0)
    assert np.all(np.diff(rot[10:]) > 0) and np.all(ext[10:] == ext[9])
    side = paper_scene.rig["side"]
    # ~0.12 mm per pixel at the robot with a 12 mm lens at 300 mm and 4.65 um pixels
    assert 0.10 < side.mm_per_pixel_at([45, 0, 0]) < 0.13
    assert (side.width, side.height) == (1024, 768)


def _write(tmp_path, text):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    "old, new, key, why",
    [
        ('name = "outer"', 'name = "outer"\ncolour = 3', "robot.tubes[0].colour", "unknown key"),
        ("outer_diameter_mm = 1.6", 'outer_diameter_mm = "big"', "robot.tubes[0].outer_diameter_mm", "must be a number"),
        ("outer_diameter_mm = 1.6", "outer_diameter_mm = -1.6", "robot.tubes[0].outer_diameter_mm", "must be > 0"),
        ("outer_diameter_mm = 1.0", "outer_diameter_mm = 1.4", "robot.tubes[1].outer_diameter_mm", "wider than the bore"),
        ("inner_diameter_mm = 0.7", "inner_diameter_mm = 1.2", "robot.tubes[1].inner_diameter_mm", "must be smaller than outer_diameter_mm"),
        ('model = "bending"', 'model = "magic"', "robot.model", 'must be "bending" or "compliant"'),
        ("width = 1024", "width = 1024.5", "image.width", "must be an integer"),
        ("jitter_px = 0.3", "jitter_px = -0.3", "noise.jitter_px", "must be >= 0"),
        ("extension_mm_to = [50.0, 100.0]", "extension_mm_to = [50.0, 400.0]", "sequence.steps[0].extension_mm_from", "must be in"),
        ("rotation_deg_from = [0.0, 0.0]", "rotation_deg_from = [0.0]", "sequence.steps[0].rotation_deg_from", "list of 2 numbers"),
    ],
)
def test_errors_name_file_and_key(tmp_path, old, new, key, why):
    assert old in PAPER
    path = _write(tmp_path, PAPER.replace(old, new, 1))
    with pytest.raises(SceneError) as err:
        load_scene(path)
    msg = str(err.value)
    assert msg.startswith(str(path)), msg
    assert key in msg and why in msg, msg
    assert "\n" not in msg


def test_missing_file_and_bad_toml(tmp_path):
    with pytest.raises(SceneError, match="scene file not found"):
        load_scene(tmp_path / "nope.toml")
    with pytest.raises(SceneError, match=re.escape(str(tmp_path / "bad.toml")) + ": not valid TOML"):
        load_scene(_write(tmp_path, "[robot\n"))


def test_cli_reports_scene_errors_in_one_line(tmp_path, capsys):
    from rig.cli import main

    path = _write(tmp_path, PAPER.replace("outer_diameter_mm = 1.6", "outer_diameter_mm = -1.6", 1))
    code = main(["render", str(path), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert err.count("\n") == 0 and "outer_diameter_mm: must be > 0" in err
    assert not (tmp_path / "out" / "session.json").exists()
