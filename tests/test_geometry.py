"""recon.geometry: rigid transforms named T_<to>_<from> and arc length / resampling / closest points of polylines."""
import numpy as np
import pytest

from recon.geometry import (
    arc_length,
    closest_arc_length,
    compose,
    interp_rows,
    invert_transform,
    look_at,
    make_transform,
    points_at_arc_length,
    resample_arc,
    resample_polyline,
    rotation_from_rotvec,
    rotation_matrix,
    transform_directions,
    transform_points,
)


def _random_transform(rng) -> np.ndarray:
    return make_transform(rotation_matrix(rng.normal(size=3), rng.uniform(-np.pi, np.pi)), rng.normal(scale=100.0, size=3))


# ----------------------------------------------------------------------------- transforms
def test_invert_composed_with_transform_is_identity():
    rng = np.random.default_rng(0)
    for _ in range(20):
        T_a_b = _random_transform(rng)
        T_b_a = invert_transform(T_a_b)
        np.testing.assert_allclose(compose(T_b_a, T_a_b), np.eye(4), atol=1e-12)
        np.testing.assert_allclose(compose(T_a_b, T_b_a), np.eye(4), atol=1e-12)
        np.testing.assert_allclose(T_b_a, np.linalg.inv(T_a_b), atol=1e-12)
        np.testing.assert_array_equal(T_b_a[3], [0, 0, 0, 1])


def test_compose_is_associative_and_chains_frames():
    rng = np.random.default_rng(1)
    T_a_b, T_b_c, T_c_d = (_random_transform(rng) for _ in range(3))
    T_a_d = compose(T_a_b, T_b_c, T_c_d)
    np.testing.assert_allclose(T_a_d, compose(compose(T_a_b, T_b_c), T_c_d), atol=1e-12)
    np.testing.assert_allclose(T_a_d, compose(T_a_b, compose(T_b_c, T_c_d)), atol=1e-12)
    # a point of frame d reaches frame a through c and b
    p_d = rng.normal(size=(5, 3))
    p_a = transform_points(T_a_b, transform_points(T_b_c, transform_points(T_c_d, p_d)))
    np.testing.assert_allclose(transform_points(T_a_d, p_d), p_a, atol=1e-9)
    # the order matters: the chain is not commutative
    assert not np.allclose(compose(T_c_d, T_b_c, T_a_b), T_a_d)
    np.testing.assert_array_equal(compose(T_a_b), T_a_b)
    with pytest.raises(ValueError):
        compose()


def test_transform_points_and_directions():
    T_a_b = make_transform(rotation_matrix([0, 0, 1], np.pi / 2), [10.0, 0.0, 0.0])
    # x_b -> y_a, then shifted by the origin of b in a
    np.testing.assert_allclose(transform_points(T_a_b, [[1.0, 0.0, 0.0]]), [[10.0, 1.0, 0.0]], atol=1e-12)
    np.testing.assert_allclose(transform_points(T_a_b, [0.0, 0.0, 0.0]), [10.0, 0.0, 0.0])
    np.testing.assert_allclose(transform_directions(T_a_b, [[2.0, 0.0, 0.0]]), [[0.0, 2.0, 0.0]], atol=1e-12)
    # round trip through the inverse
    p_b = np.random.default_rng(2).normal(size=(4, 3))
    np.testing.assert_allclose(transform_points(invert_transform(T_a_b), transform_points(T_a_b, p_b)), p_b, atol=1e-12)


def test_rotation_matrix_rodrigues():
    R = rotation_matrix([0, 0, 2.0], np.pi / 2)  # the axis' length does not matter
    np.testing.assert_allclose(R @ [1.0, 0, 0], [0, 1.0, 0], atol=1e-15)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-15)
    assert np.isclose(np.linalg.det(R), 1.0)
    np.testing.assert_array_equal(rotation_matrix([0, 0, 0], 1.0), np.eye(3))
    v = np.array([0.3, -0.2, 0.5])
    np.testing.assert_allclose(rotation_from_rotvec(v), rotation_matrix(v, np.linalg.norm(v)), atol=1e-15)
    np.testing.assert_array_equal(rotation_from_rotvec(np.zeros(3)), np.eye(3))


def test_look_at_frames():
    eye, target = np.array([45.0, -300.0, 0.0]), np.array([45.0, 0.0, 0.0])
    T_cam_world = look_at(eye, target, [0, 0, -1])
    # the eye is the camera's origin, the target lies on its +z axis
    np.testing.assert_allclose(transform_points(T_cam_world, eye), [0, 0, 0], atol=1e-12)
    np.testing.assert_allclose(transform_points(T_cam_world, target), [0, 0, 300.0], atol=1e-12)
    # image down (+y) is world -z, image right (+x) = y cross z
    np.testing.assert_allclose(transform_directions(T_cam_world, [0, 0, -1.0]), [0, 1.0, 0], atol=1e-12)
    with pytest.raises(ValueError, match="parallel"):
        look_at(eye, target, [0, 1, 0])


# ----------------------------------------------------------------------------- polylines
def test_arc_length_of_known_polyline():
    pts = np.array([[0.0, 0, 0], [3, 4, 0], [3, 4, 12], [3, 4, 12]])
    np.testing.assert_array_equal(arc_length(pts), [0.0, 5.0, 17.0, 17.0])
    np.testing.assert_array_equal(arc_length(pts[:1]), [0.0])
    # 2-D (pixel) curves too
    np.testing.assert_allclose(arc_length(np.array([[0.0, 0], [1, 1]])), [0.0, np.sqrt(2)])


def test_points_at_arc_length_and_interp_rows():
    pts = np.array([[0.0, 0, 0], [10, 0, 0], [10, 10, 0]])
    got = points_at_arc_length(pts, np.array([0.0, 5.0, 10.0, 15.0, 20.0, 25.0, -1.0]))
    np.testing.assert_allclose(got, [[0, 0, 0], [5, 0, 0], [10, 0, 0], [10, 5, 0], [10, 10, 0], [10, 10, 0], [0, 0, 0]])
    np.testing.assert_allclose(interp_rows(np.array([0.5]), np.array([0.0, 1.0]), np.array([[0.0, 2.0], [4.0, 6.0]])), [[2.0, 4.0]])


@pytest.mark.parametrize("step", [0.5, 0.7, 3.0, 100.0])
def test_resample_end_keeps_endpoints_and_step(step):
    pts = np.array([[0.0, 0, 0], [10, 0, 0], [10, 7.3, 0]])  # 17.3 mm
    out, s = resample_arc(pts, step)
    np.testing.assert_array_equal(out[0], pts[0])
    np.testing.assert_allclose(out[-1], pts[-1], atol=1e-12)
    np.testing.assert_allclose(np.diff(s)[:-1], step)  # every step whole, the last one shorter or equal
    assert 0.0 < np.diff(s)[-1] <= step + 1e-12
    assert s[-1] == pytest.approx(17.3)
    np.testing.assert_array_equal(resample_polyline(pts, step), out)
    # the samples lie on the polyline at their arc lengths
    np.testing.assert_allclose(out, points_at_arc_length(pts, s), atol=1e-12)


def test_resample_whole_steps_gets_no_sliver():
    pts = np.array([[0.0, 0], [3.0, 0]])
    out = resample_polyline(pts, 0.5)
    assert len(out) == 7
    np.testing.assert_allclose(np.diff(out[:, 0]), 0.5)


def test_resample_steps_and_spread_modes():
    pts = np.array([[0.0, 0], [10.0, 0]])
    out, s = resample_arc(pts, 3.0, mode="steps")
    np.testing.assert_allclose(s, [0, 3, 6, 9])  # the end only on a step
    np.testing.assert_allclose(out[:, 0], s)
    out, s = resample_arc(pts, 3.0, mode="spread")
    np.testing.assert_allclose(s, [0, 10 / 3, 20 / 3, 10])  # floor(10 / 3) + 1 points, spread evenly
    np.testing.assert_allclose(out[-1], pts[-1])
    with pytest.raises(ValueError, match="mode"):
        resample_arc(pts, 1.0, mode="nope")


def test_resample_zero_length():
    pts = np.array([[1.0, 2, 3], [1.0, 2, 3]])
    for mode in ("end", "steps"):
        out, s = resample_arc(pts, 0.5, mode)
        np.testing.assert_array_equal(out, pts[:1])
        np.testing.assert_array_equal(s, [0.0])
    out, s = resample_arc(pts, 0.5, "spread")
    np.testing.assert_array_equal(out, pts)
    np.testing.assert_array_equal(s, [0.0, 0.0])


def test_closest_arc_length_known_case():
    line = np.array([[0.0, 0, 0], [10, 0, 0], [10, 10, 0]])
    s, d = closest_arc_length(np.array([[5.0, 1, 0], [11, 5, 0], [-1, 0, 0], [10, 10, 3], [4, 0, 0]]), line)
    np.testing.assert_allclose(s, [5.0, 15.0, 0.0, 20.0, 4.0])
    np.testing.assert_allclose(d, [1.0, 1.0, 1.0, 3.0, 0.0])
    # a single vertex: arc length 0, distance to it
    s, d = closest_arc_length([[3.0, 4, 0]], line[:1])
    np.testing.assert_array_equal(s, [0.0])
    np.testing.assert_allclose(d, [5.0])
    # given vertex arc lengths (a model's own parameter) are interpolated along the closest segment
    s, _ = closest_arc_length(np.array([[5.0, 1, 0], [11, 5, 0]]), line, s_vertices=[100.0, 120.0, 130.0])
    np.testing.assert_allclose(s, [110.0, 125.0])


def test_closest_arc_length_zero_length_segment_and_chunks(monkeypatch):
    import recon.geometry as geometry

    line = np.array([[0.0, 0, 0], [0, 0, 0], [10, 0, 0]])  # a repeated vertex
    s, d = closest_arc_length(np.array([[-2.0, 0, 0], [6, 2, 0]]), line)
    np.testing.assert_allclose(s, [0.0, 6.0])
    np.testing.assert_allclose(d, [2.0, 2.0])
    # the chunked search gives the same answer as one pass
    rng = np.random.default_rng(3)
    poly, pts = np.cumsum(rng.normal(size=(30, 3)), axis=0), rng.normal(scale=5, size=(50, 3))
    want = closest_arc_length(pts, poly)
    monkeypatch.setattr(geometry, "_CLOSEST_CHUNK", 29 * 7)
    got = closest_arc_length(pts, poly)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
