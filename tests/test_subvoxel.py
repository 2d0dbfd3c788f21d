"""Sub-voxel refinement of a carved backbone (recon.subvoxel) against drawn centerlines."""
import cv2
import numpy as np
import pytest
from drawn_tubes import paper_rig, paper_robot

from recon.metrics import backbone_errors
from recon.subvoxel import SubvoxelParams, refine_backbone


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
    short = truth[s <= 85.0]  # 10 mm short: more than 2 voxels of 1 mm
    refined = refine_backbone(cams, lines, short, 1.0, SubvoxelParams(iterations=0))
    t = short[-1] - short[-5]
    moved = float((refined[-1] - short[-1]) @ t / np.linalg.norm(t))
    assert 1.8 <= moved <= 2.01, moved  # the cap (the pixel grid can end the walk a pixel short)


def test_views_without_centerline_leave_the_backbone_as_it_is(scene):
    cams, lines, s, truth = scene
    empty = [np.zeros_like(lines[0]), np.zeros_like(lines[1])]
    np.testing.assert_array_equal(refine_backbone(cams, empty, truth, 1.0), truth)
