"""The shared camera model: projection, distortion, back-projection."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from recon.camera import Camera, distort_normalized, undistort_normalized
from recon.geometry import invert_transform, look_at


def _camera(dist=(-0.08, 0.05, 0.001, -0.0015, 0.0)):
    K = np.array([[2580.0, 0, 515.5], [0, 2580.0, 380.5], [0, 0, 1]])
    return Camera("side", 1024, 768, K, np.array(dist), look_at([45, -300, 0], [45, 0, 0], [0, 0, -1]))


def test_look_at_axes_follow_opencv_convention():
    T = look_at([45, -300, 0], [45, 0, 0], [0, 0, -1])
    R_world_cam = invert_transform(T)[:3, :3]
    np.testing.assert_allclose(R_world_cam[:, 2], [0, 1, 0], atol=1e-12)  # z forward = +y world
    np.testing.assert_allclose(R_world_cam[:, 1], [0, 0, -1], atol=1e-12)  # y down = -z world
    np.testing.assert_allclose(R_world_cam[:, 0], [1, 0, 0], atol=1e-12)  # x right = +x world


def test_target_projects_to_principal_point_without_distortion():
    cam = _camera(dist=(0, 0, 0, 0, 0))
    uv, z = cam.project([[45.0, 0.0, 0.0]])
    np.testing.assert_allclose(uv[0], [515.5, 380.5], atol=1e-9)
    assert z[0] == pytest.approx(300.0)


def test_distortion_matches_opencv():
    import cv2

    cam = _camera()
    pts = np.random.default_rng(0).uniform([-10, -40, -40], [100, 40, 40], (50, 3))
    uv, _ = cam.project(pts)
    R = cam.T_cam_world[:3, :3]
    rvec, _ = cv2.Rodrigues(R)
    ref, _ = cv2.projectPoints(pts, rvec, cam.T_cam_world[:3, 3], cam.K, cam.dist)
    np.testing.assert_allclose(uv, ref[:, 0, :], atol=1e-6)


@settings(max_examples=60, deadline=None)
@given(
    st.floats(-0.3, 0.3), st.floats(-0.3, 0.3),
    st.floats(-0.2, 0.2), st.floats(-0.1, 0.1), st.floats(-0.005, 0.005), st.floats(-0.005, 0.005),
)
def test_undistort_inverts_distort(x, y, k1, k2, p1, p2):
    dist = np.array([k1, k2, p1, p2, 0.0])
    xy = np.array([[x, y]])
    np.testing.assert_allclose(undistort_normalized(distort_normalized(xy, dist), dist), xy, atol=1e-9)


def test_rays_pass_through_projected_points():
    cam = _camera()
    pts = np.random.default_rng(1).uniform([0, -30, -30], [90, 30, 30], (40, 3))
    uv, _ = cam.project(pts)
    origin, d = cam.rays(uv)
    v = pts - origin
    # distance of each point from its ray
    perp = v - (v * d).sum(1, keepdims=True) * d
    assert np.abs(np.linalg.norm(perp, axis=1)).max() < 1e-6


def test_bad_shapes_are_named():
    with pytest.raises(ValueError, match="K must be 3x3"):
        Camera("top", 10, 10, np.eye(2))
    with pytest.raises(ValueError, match="points_world_mm"):
        _camera().project(np.zeros((3, 2)))
