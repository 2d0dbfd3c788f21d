"""Backbone error metrics on known geometry."""
import numpy as np
import pytest

from recon.metrics import backbone_errors, point_to_polyline_distances


def x_line(x0, x1, n, offset=(0.0, 0.0, 0.0)):
    return np.stack([np.linspace(x0, x1, n), np.zeros(n), np.zeros(n)], axis=1) + np.asarray(offset)


def test_parallel_offset_lines():
    true = x_line(0, 50, 11)
    recon = x_line(0, 50, 137, offset=(0.0, 0.3, 0.4))  # 0.5 mm off, sampled differently
    e = backbone_errors(recon, true)
    assert e["mean_error_mm"] == pytest.approx(0.5)
    assert e["max_error_mm"] == pytest.approx(0.5)
    assert e["tip_error_mm"] == pytest.approx(0.5)
    assert e["length_error_mm"] == pytest.approx(0.0, abs=1e-9)


def test_short_reconstruction():
    true = x_line(0, 50, 51)
    recon = x_line(0, 40, 41)
    e = backbone_errors(recon, true)
    assert e["tip_error_mm"] == pytest.approx(10.0)
    assert e["length_error_mm"] == pytest.approx(-10.0)
    assert e["max_error_mm"] == pytest.approx(10.0)  # Hausdorff: the true tip is 10 mm from recon
    # recon -> true: 41 zeros; true -> recon: 0 for x <= 40, then 1..10.
    assert e["mean_error_mm"] == pytest.approx(sum(range(1, 11)) / (41 + 51))


def test_point_to_segment_not_point_to_vertex():
    poly = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [10.0, 10.0, 0.0]])
    pts = np.array([[5.0, 2.0, 0.0], [12.0, 5.0, 0.0], [-3.0, 4.0, 0.0], [5.0, 5.0, 0.0]])
    np.testing.assert_allclose(point_to_polyline_distances(pts, poly), [2.0, 2.0, 5.0, 5.0])


def test_against_dense_sampling():
    rng = np.random.default_rng(0)
    poly = np.cumsum(rng.normal(size=(30, 3)), axis=0)
    pts = rng.normal(scale=3.0, size=(200, 3)) + poly.mean(axis=0)
    t = np.linspace(0.0, 1.0, 2001)[:, None]
    dense = np.concatenate([a + t * (b - a) for a, b in zip(poly[:-1], poly[1:])])
    brute = np.linalg.norm(pts[:, None] - dense[None], axis=2).min(axis=1)
    np.testing.assert_allclose(point_to_polyline_distances(pts, poly), brute, atol=2e-3)


def test_degenerate_inputs():
    one = np.array([[1.0, 2.0, 2.0]])
    np.testing.assert_allclose(point_to_polyline_distances(np.zeros((1, 3)), one), [3.0])
    dup = np.array([[0.0, 0, 0], [0.0, 0, 0], [1.0, 0, 0]])  # zero-length segment
    np.testing.assert_allclose(point_to_polyline_distances(np.array([[0.5, 1.0, 0.0]]), dup), [1.0])
    with pytest.raises(ValueError):
        backbone_errors(np.zeros((0, 3)), one)


def test_only_what_both_cameras_see_is_scored():
    """A robot entering across the border: its unseen part is neither required nor judged."""
    from recon.camera import Camera
    from recon.geometry import look_at
    from recon.metrics import seen_by_all
    from recon.rigcal import RigCalibration

    K = np.array([[1000.0, 0, 319.5], [0, 1000.0, 239.5], [0, 0, 1.0]])
    side = Camera("side", 640, 480, K, np.zeros(5), look_at([0, -300, 0], [0, 0, 0], [0, 0, -1]))
    top = Camera("top", 640, 480, K, np.zeros(5), look_at([0, 0, 300], [0, 0, 0], [0, -1, 0]))
    rig = RigCalibration(cameras={"side": side, "top": top}, base_point_world_mm=np.array([-200.0, 0, 0]),
                         insertion_axis_world=np.array([1.0, 0, 0]))
    x = np.linspace(-200.0, 80.0, 281)  # the views span x within about +-96 mm
    truth = np.stack([x, np.zeros_like(x), np.zeros_like(x)], 1)
    seen = seen_by_all(rig, truth)
    assert not seen[0] and seen[-1] and 0.3 < seen.mean() < 0.8
    # Exactly the seen part, plus a wrong straight extrapolation to the unseen base.
    visible = truth[seen]
    wrong_base = np.array([[-200.0, 40.0, 0.0]])
    recon = np.concatenate([wrong_base, visible])
    e = backbone_errors(recon, truth, rig)
    assert e["mean_error_mm"] < 1e-9 and e["max_error_mm"] < 1e-9
    assert e["scored_fraction"] == pytest.approx(seen.mean())
    # Without the rig the unseen part counts: the same reconstruction reads 40 mm wrong.
    assert backbone_errors(recon, truth)["max_error_mm"] > 30.0
    # A reconstruction that stops short inside the view is still penalized.
    short = visible[: len(visible) // 2]
    assert backbone_errors(short, truth, rig)["max_error_mm"] > 40.0
