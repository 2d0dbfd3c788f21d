"""The paper's method on inputs the twin's own scene does not have (issue 13).

Binary masks of a long robot with all-zero background frames, cameras far from
orthogonal, and a stretch of tube that matches the backdrop. Frames are drawn
directly (discs along a known backbone), not rendered, to keep the tests fast.
"""
import cv2
import numpy as np
import pytest

from recon.camera import Camera
from recon.errors import FrameError
from recon.geometry import look_at
from recon.metrics import backbone_errors
from recon.paper import PaperParams, prepare_paper, reconstruct_paper
from recon.rigcal import RigCalibration

OUTER_MM, INNER_MM = 0.8, 0.5


def orbit_rig(angle_deg, width, height, f_px, distance_mm, target, base=(0.0, 0.0, 0.0)):
    """Top camera above ``target``; side camera swung about the x axis so the optical axes are ``angle_deg`` apart."""
    K = np.array([[f_px, 0.0, (width - 1) / 2], [0.0, f_px, (height - 1) / 2], [0.0, 0.0, 1.0]])
    target = np.asarray(target, float)
    top = Camera("top", width, height, K, T_cam_world=look_at(target + [0, 0, distance_mm], target, [0, -1, 0]))
    a = np.deg2rad(angle_deg)
    eye = target + distance_mm * np.array([0.0, -np.sin(a), np.cos(a)])
    side = Camera("side", width, height, K, T_cam_world=look_at(eye, target, [0, 0, -1]))
    return RigCalibration({"side": side, "top": top}, base_point_world_mm=list(base), insertion_axis_world=[1, 0, 0])


def backbone(length_mm, straight_mm, radius_mm, n=None):
    """Along +x for ``straight_mm``, then bending (radius ``radius_mm``) about (0, 0.6, 0.8)."""
    n = n or int(length_mm * 20)
    s = np.linspace(0.0, length_mm, n)
    ds = s[1] - s[0]
    pts = np.zeros((n, 3))
    d = np.array([1.0, 0.0, 0.0])
    axis = np.array([0.0, 0.6, 0.8])
    for i in range(1, n):
        if s[i] > straight_mm:
            d = d + ds / radius_mm * np.cross(axis, d)
            d /= np.linalg.norm(d)
        pts[i] = pts[i - 1] + d * ds
    return s, pts


def draw_mask(cam, s, pts, outer_length_mm, keep=None):
    """uint8 mask (255 on the robot) of discs of the tube radii along the backbone."""
    uv, z = cam.project(pts)
    mask = np.zeros((cam.height, cam.width), np.uint8)
    r = np.where(s <= outer_length_mm, OUTER_MM, INNER_MM) * cam.K[0, 0] / z
    sel = np.ones(len(s), bool) if keep is None else keep
    for (u, v), rr in zip(np.round(uv[sel] * 16).astype(int), np.round(r[sel] * 16).astype(int)):
        cv2.circle(mask, (int(u), int(v)), int(rr), 255, -1, cv2.LINE_8, 4)
    return mask


def test_binary_masks_of_a_long_robot_full_length():
    """0/1 masks, all-zero backgrounds, 75 degrees between the cameras, a 190 mm robot: all of it."""
    rig = orbit_rig(75.0, 1400, 1000, 2000.0, 380.0, target=(95.0, 0.0, 0.0), base=(0.0, 0.0, 0.0))
    s, pts = backbone(190.0, 110.0, 120.0)
    pts = pts + np.array([2.0, 0.0, 0.0])  # base inside both views, no actuation unit
    bg = {n: np.zeros((6, c.height, c.width), np.uint8) for n, c in rig.cameras.items()}
    model = prepare_paper(rig, bg, PaperParams())
    frames = {n: (draw_mask(c, s, pts, 120.0) > 0).astype(np.uint8) for n, c in rig.cameras.items()}
    with np.errstate(all="raise"):  # no numpy warnings on masks
        rec = reconstruct_paper(model, frames, PaperParams())
    voxel = float(rec.voxel_size_mm.max())
    e = backbone_errors(rec.points_world_mm, pts)
    assert e["mean_error_mm"] <= voxel
    assert abs(e["length_error_mm"]) <= 2 * voxel
    assert e["tip_error_mm"] <= 2 * voxel


@pytest.mark.parametrize("angle_deg", [60.0, 120.0])
def test_non_orthogonal_cameras(angle_deg):
    rig = orbit_rig(angle_deg, 1024, 768, 2580.0, 300.0, target=(45.0, 0.0, 0.0))
    s, pts = backbone(95.0, 35.0, 60.0)
    rng = np.random.default_rng(1)
    yy, xx = np.mgrid[0:768, 0:1024].astype(np.float32)
    backdrop = 130 + 40 * np.sin(xx / 90.0) * np.cos(yy / 70.0)

    def frame(cam, robot):
        img = backdrop * (1 + 0.05 * rng.standard_normal()) + rng.normal(0, 2.0, backdrop.shape)
        if robot:
            img[draw_mask(cam, s, pts, 60.0) > 0] = 40.0
        return np.clip(img, 0, 255).astype(np.uint8)

    bg = {n: np.stack([frame(c, False) for _ in range(8)]) for n, c in rig.cameras.items()}
    model = prepare_paper(rig, bg, PaperParams())
    rec = reconstruct_paper(model, {n: frame(c, True) for n, c in rig.cameras.items()}, PaperParams())
    voxel = float(rec.voxel_size_mm.max())
    e = backbone_errors(rec.points_world_mm, pts)
    assert e["mean_error_mm"] <= voxel
    assert e["tip_error_mm"] <= 2 * voxel
    assert abs(e["length_error_mm"]) <= 2 * voxel


def test_stretch_matching_the_backdrop_keeps_the_rest_of_the_robot():
    """5 mm of the inner tube as bright as the backdrop: the tube beyond it is still reconstructed (or the frame fails)."""
    rig = orbit_rig(90.0, 1024, 768, 2580.0, 300.0, target=(45.0, 0.0, 0.0))
    s, pts = backbone(95.0, 35.0, 60.0)
    rng = np.random.default_rng(2)
    backdrop = np.full((768, 1024), 150.0, np.float32)
    hidden = (s > 70.0) & (s < 75.0)

    def frame(cam, robot):
        img = backdrop * (1 + 0.03 * rng.standard_normal()) + rng.normal(0, 2.0, backdrop.shape)
        if robot:
            img[draw_mask(cam, s, pts, 60.0, keep=~hidden) > 0] = 60.0
        return np.clip(img, 0, 255).astype(np.uint8)

    bg = {n: np.stack([frame(c, False) for _ in range(8)]) for n, c in rig.cameras.items()}
    model = prepare_paper(rig, bg, PaperParams())
    try:
        rec = reconstruct_paper(model, {n: frame(c, True) for n, c in rig.cameras.items()}, PaperParams())
    except FrameError:
        return  # refusing is allowed; a silently short backbone is not
    voxel = float(rec.voxel_size_mm.max())
    e = backbone_errors(rec.points_world_mm, pts)
    assert e["tip_error_mm"] <= 2 * voxel
    assert abs(e["length_error_mm"]) <= 2 * voxel
