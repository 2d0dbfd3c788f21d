"""The paper method's cut behind the robot base (``PaperParams.cut_behind_base``)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from recon.camera import Camera
from recon.errors import FrameError
from recon.geometry import look_at
from recon.methods import prepare
from recon.paper import PaperParams, behind_base_pixels
from rig.scenefiles import scene_path

K = np.array([[2580.0, 0, 511.5], [0, 2580.0, 383.5], [0, 0, 1]])
BASE, AXIS = np.zeros(3), np.array([1.0, 0.0, 0.0])


def _side(eye=(45.0, -300.0, 0.0), target=(45.0, 0.0, 0.0)):
    return Camera("side", 1024, 768, K, np.zeros(5), look_at(eye, target, [0, 0, -1]))


def test_the_cut_is_the_half_plane_behind_the_projected_base():
    cam = _side()
    idx = behind_base_pixels(cam, BASE, AXIS, margin_px=8.0)
    mask = np.zeros(768 * 1024, bool)
    mask[idx] = True
    mask = mask.reshape(768, 1024)
    uv, _ = cam.project(np.array([BASE, [5.0, 0.0, 0.0]]))
    (u0, v0), (ua, _) = uv  # the base; the robot runs towards +u here
    assert ua > u0
    row = int(round(v0))
    assert mask[row, : int(u0 - 8.5)].all()  # behind the base, beyond the margin
    assert not mask[row, int(np.ceil(u0 - 7.5)) :].any()  # the margin and the robot's side
    assert mask[:, 0].all() and not mask[:, -1].any()  # a line across the image, not a box


def test_no_cut_when_the_camera_looks_along_the_insertion_axis():
    # Looking down the axis the base plane is seen face on: no line separates robot from clutter.
    cam = _side(eye=(-300.0, 0.0, 0.0), target=(0.0, 0.0, 0.0))
    assert behind_base_pixels(cam, BASE, AXIS, margin_px=8.0) is None


SCENE = scene_path("tune", "dim-flicker.toml")


@pytest.fixture(scope="module")
def dim_session(tmp_path_factory):
    from rig.bench.tune import load_tune_sessions

    (s,) = load_tune_sessions([SCENE], tmp_path_factory.mktemp("cache"), log=lambda *_: None)
    return s


def test_a_low_threshold_no_longer_joins_the_actuation_unit(dim_session):
    """At threshold 0.06 on a dim scene, jitter edges of the pin vise and actuation unit join the robot's
    silhouette and run it off the left border; with the cut every frame is reconstructed within a voxel."""
    s = dim_session
    base = PaperParams()
    base = replace(base, silhouette=replace(base.silhouette, threshold=0.06))
    rec = prepare("paper", s.rig, s.backgrounds, replace(base, cut_behind_base=False))
    reasons = []
    for im in s.frames:
        try:
            rec(im)
        except FrameError as exc:
            reasons.append(str(exc))
    # The region runs off the left border (and, with the hysteresis and pieces grouping of issue 13, it
    # may flood on to other borders too: the message then names them all).
    assert any("robot leaves the view at the left" in r for r in reasons), reasons
    from recon.metrics import backbone_errors

    rec = prepare("paper", s.rig, s.backgrounds, base)
    for im, truth in zip(s.frames, s.truths):
        r = rec(im)
        assert backbone_errors(r.points_world_mm, truth)["mean_error_mm"] <= float(np.max(r.voxel_size_mm))
