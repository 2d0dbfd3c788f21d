"""One scoring of a frame (issue 16, item 2): :func:`rig.scoring.score_frame`, over what every camera sees.

The true backbone of the scene below runs from x = -200 mm to 40 mm; the tiny rig's
two cameras see x from about -85 mm on. The "reconstruction" is the truth with a
30 mm wrong tail where no camera sees it: scored over what every camera sees it is
right (0 mm), scored over every point it would be 30 mm off. ``tune``, ``bench``
and ``reconstruct`` must all say 0 mm, as ``score_frame`` does.
"""
from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import pytest

from recon.methods import METHODS, Method
from recon.metrics import backbone_errors, seen_by_all
from rig.bench import compare
from rig.bench.tune import TuneSession, evaluate
from rig.scoring import score_frame
from tiny_session import H, W, tiny_rig

WRONG_MM = 30.0


def _truth() -> np.ndarray:
    s = np.linspace(-200.0, 40.0, 121)
    return np.stack([s, np.zeros_like(s), np.zeros_like(s)], axis=1)


def _recon() -> np.ndarray:
    """The truth, 30 mm off (in y) where no camera sees it."""
    pts = _truth()
    pts[pts[:, 0] < -100.0, 1] += WRONG_MM
    return pts


def test_the_scene_has_a_part_no_camera_sees():
    seen = seen_by_all(tiny_rig(), _truth())
    assert seen.any() and not seen.all() and not seen[_truth()[:, 0] < -100.0].any()


def test_score_frame_counts_what_every_camera_sees():
    rig = tiny_rig()
    errs = score_frame(_recon(), {"backbone_world_mm": _truth()}, rig)
    assert errs["max_error_mm"] == pytest.approx(0.0, abs=1e-9) and errs["mean_error_mm"] == pytest.approx(0.0, abs=1e-9)
    assert 0.0 < errs["scored_fraction"] < 1.0
    assert backbone_errors(_recon(), _truth())["max_error_mm"] == pytest.approx(WRONG_MM)  # what the rig-less score said
    # a method's result, a truth dict or the truth array: the same figures
    assert score_frame(SimpleNamespace(points_world_mm=_recon()), _truth(), rig) == errs


def test_score_frame_refuses_what_it_cannot_score():
    rig = tiny_rig()
    with pytest.raises(TypeError, match="the rig is needed"):
        score_frame(_recon(), _truth(), None)
    with pytest.raises(ValueError, match="no backbone_world_mm"):
        score_frame(_recon(), {"centerline_px_side": np.zeros((3, 2))}, rig)
    with pytest.raises(ValueError, match="seen by every camera"):
        score_frame(_recon()[:10], _truth()[:10], rig)  # all of it beyond the views


@dataclass(frozen=True)
class _Params:
    outer_tube_radius_mm: float = 0.8
    inner_tube_radius_mm: float = 0.5


def _answering(pts):
    """A method that returns ``pts`` for every frame."""
    def prepare(rig, backgrounds, params):
        return lambda images: SimpleNamespace(points_world_mm=pts, jump_flag=False)
    return Method("score-test", _Params, prepare, "test: a fixed backbone")


def test_tune_and_bench_score_as_score_frame(monkeypatch):
    rig = tiny_rig()
    images = {c: np.full((H, W), 200, np.uint8) for c in rig.names}
    backgrounds = {c: np.stack([images[c]] * 6) for c in rig.names}
    monkeypatch.setitem(METHODS, "score-test", _answering(_recon()))
    expected = score_frame(_recon(), _truth(), rig)

    session = TuneSession("tiny", rig, backgrounds, [images, images], [_truth(), _truth()], (0.8, 0.5), 1.0)
    ev = evaluate("score-test", _Params(), [session])
    assert ev.failures == 0 and ev.mean_error_mm == pytest.approx(expected["mean_error_mm"], abs=1e-12)
    assert ev.max_error_mm == pytest.approx(expected["max_error_mm"], abs=1e-12)

    data = {"rig": rig, "backgrounds": backgrounds, "frames": [images, images], "truths": [_truth(), _truth()],
            "truth_notes": [None, None]}
    out = compare.run_method("score-test", data, repeats=1, memory=False)
    assert out["scored_frames"] == 2 and out["mean_error_mm"] == pytest.approx(expected["mean_error_mm"], abs=1e-12)
    assert out["max_error_mm"] == pytest.approx(expected["max_error_mm"], abs=1e-12) and not out["score_notes"]


def test_a_frame_no_camera_sees_is_unscored_in_bench_and_failed_in_tune(monkeypatch):
    rig = tiny_rig()
    images = {c: np.full((H, W), 200, np.uint8) for c in rig.names}
    backgrounds = {c: np.stack([images[c]] * 6) for c in rig.names}
    monkeypatch.setitem(METHODS, "score-test", _answering(_recon()[:10]))  # wholly beyond the views

    ev = evaluate("score-test", _Params(), [TuneSession("tiny", rig, backgrounds, [images], [_truth()], (0.8, 0.5), 1.0)],
                  failure_penalty_mm=7.0)
    assert ev.failures == 1 and ev.penalized_error_mm == 7.0

    data = {"rig": rig, "backgrounds": backgrounds, "frames": [images], "truths": [_truth()], "truth_notes": [None]}
    out = compare.run_method("score-test", data, repeats=1, memory=False)
    assert out["failed_frames"] == 0 and out["scored_frames"] == 0 and out["mean_error_mm"] is None
    assert out["score_notes"] == ["not scored: frame 0: backbone_errors: no part of the backbone is seen by every camera"]
