"""The twin renders what its ground truth says: silhouettes, areas, reproducibility, meshes; only its renderer needs OpenGL."""
import json
import os
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from twin.gl import available_platforms
from twin.groundtruth import extend_to_mesh_start, inside_fraction, projected_tube_area_px
from twin.mesh import ring_samples, tube_meshes
from twin.simulator import Twin

#: Imports the modules named on the command line, then prints what of OpenGL they brought in.
_PROBE = """
import importlib, json, os, sys
for name in sys.argv[1:]:
    importlib.import_module(name)
print(json.dumps({"opengl": "OpenGL" in sys.modules, "platform": os.environ.get("PYOPENGL_PLATFORM")}))
"""


def _fresh_import(*modules) -> dict:
    """What importing ``modules`` does in a fresh, isolated interpreter (``-I``: no PYTHON* variables, no user site,
    no working directory on the path), with no OpenGL platform chosen beforehand."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYOPENGL_PLATFORM", "CTR_BENCH_GL")}
    out = subprocess.run([sys.executable, "-I", "-c", _PROBE, *modules], env=env, capture_output=True, text=True,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_kinematics_scene_and_fit_import_no_opengl():
    # fit, verify and experiment need only these: they must start on a machine without EGL or OSMesa.
    assert _fresh_import("twin", "twin.kinematics", "twin.scene", "twin.modelfit", "twin.robot",
                         "twin.robotfile") == {"opengl": False, "platform": None}


@pytest.mark.skipif(not available_platforms(), reason="no offscreen OpenGL library on this machine")
def test_the_renderer_chooses_the_platform_at_its_import():
    seen = _fresh_import("twin.render")
    assert seen["opengl"] and seen["platform"] in available_platforms()


@pytest.fixture(scope="module")
def frames(paper_twin, paper_scene):
    # one inserted, one rotated frame of the paper's sequence
    return [paper_twin.frame(i) for i in (4, 15)]


def test_backbone_projects_inside_rendered_silhouette(frames):
    for f in frames:
        for name, frac in inside_fraction(f).items():
            assert frac >= 0.99, f"{name}: only {frac:.3f} of the backbone inside the silhouette"


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
            ext = extend_to_mesh_start(f.backbone)
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


def _polyline_distance(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Distance (mm) of each of ``points`` (n, 3) from the polyline ``poly`` (m, 3)."""
    a, b = poly[:-1], poly[1:]
    ab = b - a
    t = np.clip(np.einsum("pkd,kd->pk", points[:, None] - a[None], ab) / np.maximum((ab * ab).sum(1), 1e-18), 0.0, 1.0)
    near = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(points[:, None] - near, axis=2).min(axis=1)


@given(st.floats(0.0, 0.2), st.floats(5.0, 150.0), st.floats(0.001, 0.02), st.floats(1.0, 4.0))
def test_tube_rings_follow_the_backbone_within_the_tolerance(kappa_per_mm, length_mm, tolerance_mm, max_step_mm):
    """A planar arc (curvature ``kappa``) sampled every 0.5 mm: the kept rings' polyline passes within the
    tolerance of every sample, its steps are at most ``max_step_mm``, and the ends and their neighbours stay.
    Fails if the greedy walk keeps a chord that a dropped sample bulges past, or never drops one."""
    s = np.linspace(0.0, length_mm, int(np.ceil(length_mm / 0.5)) + 1)
    if kappa_per_mm == 0.0:
        pts = np.stack([np.zeros_like(s), np.zeros_like(s), s], axis=1)
    else:
        pts = np.stack([(1 - np.cos(kappa_per_mm * s)) / kappa_per_mm, np.zeros_like(s), np.sin(kappa_per_mm * s) / kappa_per_mm], axis=1)
    keep = ring_samples(pts, tolerance_mm, max_step_mm)
    n = len(pts)
    assert keep[0] == 0 and keep[-1] == n - 1 and np.all(np.diff(keep) > 0)
    assert {1, n - 2} <= set(keep.tolist()) or n <= 3
    assert _polyline_distance(pts, pts[keep]).max() <= tolerance_mm + 1e-12
    assert np.linalg.norm(np.diff(pts[keep], axis=0), axis=1).max() <= max_step_mm + 1e-9
    # Where one chord of the step would do (the sagitta of max_step_mm within the tolerance), it is taken.
    if kappa_per_mm * max_step_mm**2 / 8 < 0.5 * tolerance_mm and n > 3 + 4 * max_step_mm:
        assert len(keep) <= 4 + np.ceil((length_mm - 1.0) / (max_step_mm - 0.5))


def test_background_frames_have_no_robot(paper_twin):
    b = paper_twin.background(0)
    assert b.labels is None and b.joints is None
    assert b.images["side"].shape == (768, 1024) and b.images["side"].dtype == np.uint8


def test_tube_normals_are_trimeshs_angle_weighted_normals(paper_scene):
    """The renderer's smooth normals equal trimesh's (angle-weighted face normals), caps and bends included.

    Fails if the faces' angles are not the weights (e.g. plain sums), or a corner's angle is taken at the wrong vertex.
    """
    from twin.kinematics import solve
    from twin.mesh import vertex_normals

    joints = paper_scene.joints[len(paper_scene.joints) // 2]
    for _, m in tube_meshes(solve(paper_scene.robot, joints, paper_scene.model), paper_scene.robot, joints, sides=7):
        assert np.abs(vertex_normals(m.vertices, m.faces) - m.vertex_normals).max() < 1e-12
