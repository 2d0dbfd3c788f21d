"""Sub-voxel refinement of a carved backbone (recon.subvoxel) against drawn centerlines."""
import cv2
import numpy as np
import pytest
from drawn_tubes import paper_rig, paper_robot

from recon.metrics import backbone_errors
from recon.geometry import look_at, resample_polyline
from recon.subvoxel import SubvoxelParams, _silhouette_reach_mm, refine_backbone


def centerline_image(cam, pts):
    img = np.zeros((cam.height, cam.width), np.uint8)
    uv = cam.project(pts)[0]
    cv2.polylines(img, [np.round(uv * 16).astype(np.int32)], False, 1, thickness=1, lineType=cv2.LINE_8, shift=4)
    return img


@pytest.fixture(scope="module")
def scene():
    rig = paper_rig()
    s, truth = paper_robot(400)
    cams = [rig["side"], rig["top"]]
    return cams, [centerline_image(c, truth) for c in cams], s, truth


def test_an_offset_short_backbone_is_moved_onto_the_centerlines_and_to_the_tip(scene):
    cams, lines, s, truth = scene
    voxel_mm = np.array([1.0, 0.4, 0.4])
    short = truth[s <= 93.5]  # the carving's last column: 1.5 mm short
    carved = short + np.array([0.0, 0.25, -0.2])  # a lopsided cloud: 0.32 mm off
    before = backbone_errors(carved, truth)
    refined = refine_backbone(cams, lines, carved, voxel_mm)
    after = backbone_errors(refined, truth)
    assert before["mean_error_mm"] > 0.25 and before["tip_error_mm"] > 1.0
    # The centerlines are pixel chains (0.12 mm per px here): the tip within 2 px, from 12.
    assert after["mean_error_mm"] < 0.06, after
    assert after["tip_error_mm"] < 0.25, after


def test_a_tip_beyond_the_centerlines_is_cut_back(scene):
    cams, lines, s, truth = scene
    t = truth[-1] - truth[-2]
    long = np.vstack([truth, truth[-1] + np.outer(np.linspace(0.2, 1.2, 6), t / np.linalg.norm(t))])
    refined = refine_backbone(cams, lines, long, 1.0)
    assert np.linalg.norm(refined[-1] - truth[-1]) < 0.25
    assert backbone_errors(refined, truth)["max_error_mm"] < 0.25


def test_the_tip_moves_at_most_its_cap(scene):
    cams, lines, s, truth = scene
    short = truth[s <= 85.0]  # 10 mm short: more than 6 voxels of 1 mm
    refined = refine_backbone(cams, lines, short, 1.0, SubvoxelParams(iterations=0))
    t = short[-1] - short[-5]
    moved = float((refined[-1] - short[-1]) @ t / np.linalg.norm(t))
    assert 5.8 <= moved <= 6.01, moved  # the cap (the pixel grid can end the walk a pixel short)


def test_views_without_centerline_leave_the_backbone_as_it_is(scene):
    cams, lines, s, truth = scene
    empty = [np.zeros_like(lines[0]), np.zeros_like(lines[1])]
    np.testing.assert_array_equal(refine_backbone(cams, empty, truth, 1.0), truth)


def tube_silhouette(cam, pts, radius_mm):
    """The silhouette (uint8 0/1) of a tube of ``radius_mm`` around ``pts`` with a flat end face at the last point:
    its surface, sampled every 0.05 mm along and every 10 degrees around, projected and closed."""
    p = resample_polyline(pts, 0.05)
    t = np.gradient(p, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    e1 = np.cross(t, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(t, e1)
    a = np.deg2rad(np.arange(0, 360, 10))[None, :, None]
    side = p[:, None] + radius_mm * (np.cos(a) * e1[:, None] + np.sin(a) * e2[:, None])
    rho = np.linspace(0.0, radius_mm, 8)[:, None, None]
    face = p[-1] + rho * (np.cos(a) * e1[-1] + np.sin(a) * e2[-1])
    uv = cam.project(np.concatenate([side.reshape(-1, 3), face.reshape(-1, 3)]))[0]
    img = np.zeros((cam.height, cam.width), np.uint8)
    iu, iv = np.rint(uv).astype(int).T
    ok = (iu >= 0) & (iu < cam.width) & (iv >= 0) & (iv < cam.height)
    img[iv[ok], iu[ok]] = 1
    return cv2.morphologyEx(img, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))


def test_a_centerline_eroded_short_of_the_tip_leaves_the_tip_to_the_silhouettes(scene):
    # The paper method's two-disk erosion ends a thin tube's centerline up to 16 px before its tip
    # (wide-4-15 frame 2: the carved and refined tip 8.5 footprints short on a plain backdrop). The
    # silhouettes run to the tip: the tip moves to where they end along the tangent.
    cams, _, s, truth = scene
    eroded = [centerline_image(c, truth[s <= 93.0]) for c in cams]  # 2 mm (16 px) short
    sils = [tube_silhouette(c, truth, 0.5) for c in cams]
    short = truth[s <= 92.0]
    from_lines = refine_backbone(cams, eroded, short, 1.0)
    from_sils = refine_backbone(cams, eroded, short, 1.0, silhouettes=sils, tip_radius_mm=0.5)
    assert np.linalg.norm(from_lines[-1] - truth[-1]) > 1.5
    assert np.linalg.norm(from_sils[-1] - truth[-1]) < 0.25, from_sils[-1] - truth[-1]
    assert backbone_errors(from_sils, truth)["max_error_mm"] < 0.25


@pytest.mark.parametrize("toward", [0.0, 0.5, 0.8])
def test_the_end_face_beyond_the_tip_is_not_taken_for_tube(toward):
    # A thick tube (2 mm radius) ending at the origin, its tangent turned towards the camera by
    # |t . ray| = toward: the flat end face reaches 2 * toward mm beyond the tip in the image
    # (wide-2-14 frame 1: a tube 17 px in radius, the silhouette's end 7.5 px beyond the tip).
    from recon.camera import Camera

    cam = Camera("c", 1024, 768, np.array([[1500.0, 0, 512], [0, 1500.0, 384], [0, 0, 1]]),
                 T_cam_world=look_at([0, 0, 300], [0, 0, 0], [0, -1, 0]))
    t = np.array([np.sqrt(1 - toward**2), 0.0, toward])  # +z is towards the camera
    pts = -np.outer(np.linspace(30.0, 0.0, 301), t)
    sil = tube_silhouette(cam, pts, 2.0)
    reach_mm, speed = _silhouette_reach_mm(cam, sil, pts[-1], t, 10.0, tip_radius_mm=2.0)
    assert abs(reach_mm) * speed < 1.5, (reach_mm, speed)
    blind, _ = _silhouette_reach_mm(cam, sil, pts[-1], t, 10.0)
    assert blind * speed > 2.0 * 1500 / 300 * toward - 1.5
