"""The twin renders what its ground truth says: silhouettes, areas, reproducibility, meshes."""
from dataclasses import replace

import numpy as np
import pytest

from twin.mesh import tube_meshes
from twin.simulator import Twin


def projected_tube_area_px(camera, backbone, s_min_mm=-np.inf):
    """Analytic image area (px) of the tubes: projected length times projected diameter.

    The diameter is measured by projecting two surface points across the tube,
    perpendicular to both the tangent and the viewing ray, so perspective and lens
    distortion are included.
    """
    keep = backbone.s_mm >= s_min_mm
    p = backbone.p_world_mm[keep]
    r = backbone.outer_radius_mm[keep]
    t = backbone.R_world_body[keep][:, :, 2]
    view = p - camera.center_world_mm
    n = np.cross(t, view)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    a, _ = camera.project(p + r[:, None] * n)
    b, _ = camera.project(p - r[:, None] * n)
    width = np.linalg.norm(a - b, axis=1)
    c, _ = camera.project(p)
    seg = np.linalg.norm(np.diff(c, axis=0), axis=1)
    return float(np.sum(seg * 0.5 * (width[1:] + width[:-1])))


@pytest.fixture(scope="module")
def frames(paper_twin, paper_scene):
    # one inserted, one rotated frame of the paper's sequence
    return [paper_twin.frame(i) for i in (4, 15)]


def test_backbone_projects_inside_rendered_silhouette(frames):
    for f in frames:
        for name, labels in f.labels.items():
            uv = np.rint(f.centerline_px[name]).astype(int)
            inside = labels[uv[:, 1], uv[:, 0]] > 0
            assert inside.mean() >= 0.99, f"{name}: only {inside.mean():.3f} of the backbone inside the silhouette"


def test_outer_and_inner_labels_where_the_model_says(frames):
    for f in frames:
        bb = f.backbone
        for name, labels in f.labels.items():
            uv = np.rint(f.centerline_px[name]).astype(int)
            lab = labels[uv[:, 1], uv[:, 0]]
            # away from the transition (1 mm), the label is the outermost tube there
            ext0 = f.joints.extension_mm[0]
            far = np.abs(bb.s_mm - ext0) > 1.0
            agree = lab[far] == bb.outermost_tube[far] + 1
            assert agree.mean() > 0.99


def test_mask_area_matches_projected_tube_area(paper_scene):
    # Without the actuation unit the whole swept tube (from 8 mm inside the base) is visible.
    scene = replace(paper_scene, dressing=replace(paper_scene.dressing, actuation_unit=False))
    with Twin(scene) as tw:
        for i in (2, 12):
            f = tw.frame(i)
            bb = tw.backbone(f.joints)
            # extend the backbone back to s = -8 mm, where the mesh starts
            t0 = bb.R_world_body[0][:, 2]
            s_back = np.linspace(-8.0, 0.0, 81)[:-1]
            ext = replace(
                bb,
                s_mm=np.concatenate([s_back, bb.s_mm]),
                p_world_mm=np.concatenate([bb.p_world_mm[0] + s_back[:, None] * t0, bb.p_world_mm]),
                R_world_body=np.concatenate([np.repeat(bb.R_world_body[:1], len(s_back), 0), bb.R_world_body]),
                outer_radius_mm=np.concatenate([np.full(len(s_back), bb.outer_radius_mm[0]), bb.outer_radius_mm]),
                outermost_tube=np.concatenate([np.zeros(len(s_back), int), bb.outermost_tube]),
            )
            for name, cam in f.cameras.items():
                area = (f.labels[name] > 0).sum()
                expected = projected_tube_area_px(cam, ext)
                assert area == pytest.approx(expected, rel=0.03), f"frame {i} {name}: {area} px vs {expected:.0f} px"


def test_same_seed_same_images_bit_for_bit(paper_scene, paper_twin):
    a = paper_twin.frame(7)
    b0 = paper_twin.background(3)
    with Twin(paper_scene) as other:
        b = other.frame(7)
        b1 = other.background(3)
    for name in a.images:
        assert np.array_equal(a.images[name], b.images[name])
        assert np.array_equal(b0.images[name], b1.images[name])


def test_other_seed_other_noise(paper_scene, paper_twin):
    a = paper_twin.background(0)
    with Twin(replace(paper_scene, seed=paper_scene.seed + 1)) as other:
        b = other.background(0)
    diff = np.abs(a.images["side"].astype(int) - b.images["side"].astype(int))
    assert diff.mean() > 0.5


def test_jitter_moves_cameras_but_not_the_nominal_rig(paper_scene, frames):
    for f in frames:
        for name, cam in f.cameras.items():
            nominal = paper_scene.rig[name]
            d = np.abs(cam.T_cam_world - nominal.T_cam_world).max()
            assert 0 < d < 1.0


def test_tube_meshes_are_watertight_with_a_step(paper_scene, paper_twin):
    joints = paper_scene.joints[9]
    bb = paper_twin.backbone(joints)
    ms = tube_meshes(bb, paper_scene.robot, joints)
    assert [i for i, _ in ms] == [0, 1]
    for i, m in ms:
        assert m.is_watertight and m.volume > 0
        r = paper_scene.robot.tubes[i].outer_radius_mm
        length = joints.extension_mm[i] - m.vertices[:, 0].min()
        assert m.volume == pytest.approx(np.pi * r * r * length, rel=0.05)


def test_background_frames_have_no_robot(paper_twin):
    b = paper_twin.background(0)
    assert b.labels is None and b.joints is None
    assert b.images["side"].shape == (768, 1024) and b.images["side"].dtype == np.uint8
