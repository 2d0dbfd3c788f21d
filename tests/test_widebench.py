"""The wide benchmark's bookkeeping: footprints, silent-wrong and flagged counts, per-class tables."""
from __future__ import annotations

import numpy as np
import pytest

from recon.camera import Camera
from recon.geometry import look_at
from recon.rigcal import RigCalibration
from rig.bench import widebench as W


def _rig(distance_mm=300.0, f_px=2000.0):
    K = np.array([[f_px, 0, 511.5], [0, f_px, 383.5], [0, 0, 1.0]])
    side = Camera("side", 1024, 768, K, np.zeros(5), look_at([0, -distance_mm, 0], [0, 0, 0], [0, 0, -1]))
    top = Camera("top", 1024, 768, K, np.zeros(5), look_at([0, 0, distance_mm], [0, 0, 0], [0, -1, 0]))
    return RigCalibration(cameras={"side": side, "top": top}, base_point_world_mm=np.zeros(3),
                          insertion_axis_world=np.array([1.0, 0, 0]))


def test_footprint_is_depth_over_focal_length():
    rig = _rig(300.0, 2000.0)
    pts = np.zeros((5, 3))
    assert W.frame_footprint_mm(rig, pts) == pytest.approx(300.0 / 2000.0)
    # Points nearer to one camera and further from the other: the mean of both footprints.
    pts[:, 1] = -50.0  # 250 mm from side, 300 from top
    assert W.frame_footprint_mm(rig, pts) == pytest.approx((250.0 + 300.0) / 2 / 2000.0)


class _Session:
    def __init__(self, rig, truths):
        self.rig = rig
        self._truths = truths

    def truth(self, i):
        return self._truths.get(i)


def _summary(records):
    return {"per_frame": records}


def test_silent_wrong_counts_ok_frames_beyond_ten_footprints_only():
    rig = _rig(300.0, 2000.0)  # footprint 0.15 mm at the origin
    truth = {i: {"backbone_world_mm": np.zeros((4, 3))} for i in range(5)}
    recs = [
        {"frame": 0, "status": "ok", "mean_error_mm": 0.05, "max_error_mm": 0.3, "tip_error_mm": 0.1, "ms": 3.0},
        {"frame": 1, "status": "ok", "mean_error_mm": 1.0, "max_error_mm": 1.6, "tip_error_mm": 1.5, "ms": 4.0},
        {"frame": 2, "status": "suspect", "mean_error_mm": 1.0, "max_error_mm": 9.0, "tip_error_mm": 8.0, "ms": 5.0,
         "selfcheck": {"reason": "top: 40 % off foreground"}},
        {"frame": 3, "status": "suspect", "mean_error_mm": 0.05, "max_error_mm": 0.2, "tip_error_mm": 0.1, "ms": 3.0},
        {"frame": 4, "status": "failed", "reason": "no silhouette"},
    ]
    rows = W.score_run(_summary(recs), _Session(rig, truth), "s", "fast", {"backdrop": "photo"})
    assert [r["silent_wrong"] for r in rows] == [False, True, False, False, False]
    assert rows[1]["max_error_px"] == pytest.approx(1.6 / 0.15)
    a = W.aggregate(rows)
    assert (a["frames"], a["ok"], a["flagged"], a["failed"], a["silent_wrong"]) == (5, 2, 2, 1, 1)
    # Frames 0 and 3 are good (max <= 10 px); frame 3 was flagged although good.
    assert (a["good"], a["good_flagged"]) == (2, 1)
    assert a["reconstructed_fraction"] == pytest.approx(0.8)
    assert a["mean_error_px_median"] == pytest.approx(np.median([0.05, 1.0, 1.0, 0.05]) / 0.15)
    assert a["ms_per_pair_median"] == pytest.approx(3.5)


def test_tables_and_json_break_down_by_class():
    rig = _rig()
    truth = {0: {"backbone_world_mm": np.zeros((4, 3))}}
    rows = []
    for scene, backdrop in (("a", "plain"), ("b", "photo"), ("c", "photo")):
        rec = {"frame": 0, "status": "ok", "mean_error_mm": 0.01, "max_error_mm": 0.02, "tip_error_mm": 0.02, "ms": 2.0}
        rows += W.score_run(_summary([rec]), _Session(rig, truth), scene, "fast", {"backdrop": backdrop, "tubes": "2"})
    report = {"suite": "wide", "n": 3, "seed": 1, "methods": {"fast": W.aggregate(rows), "icp": {"skipped": "not installed"}},
              "classes": {"fast": W._by_class(rows)}, "worst": W._worst(rows)}
    assert report["classes"]["fast"]["backdrop"]["photo"]["frames"] == 2
    js = W.json_summary(report)
    assert set(W.JSON_KEYS) <= set(js["fast"])
    assert js["icp"] == {"skipped": "not installed"}
    text = W.format_suite(report)
    assert "backdrop=photo" in text and "icp: skipped: not installed" in text


@pytest.mark.parametrize("argv, message", [
    (["scenes/paper.toml"], "give either a SCENE or --suite, not both"),
    (["--n", "0"], "--n must be >= 1, got 0"),
    (["--seed", "-1"], "--seed must be >= 0, got -1"),
    (["--max-megapixels", "0.1"], "--max-megapixels must be >= 0.3072"),
])
def test_bad_suite_options_are_one_line_errors(argv, message, capsys):
    from rig.cli import main

    assert main(["bench", "--suite", "wide", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
