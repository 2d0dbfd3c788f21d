"""The scene generator: reproducible, within its stated ranges, and every class renders with truth that matches its images."""
from __future__ import annotations

import json

import numpy as np
import pytest

from rig.scenefiles import scene_path
from twin.scene import SceneError, read_toml, scene_from_dict
from twin.scenegen import (ANGLE_DEG, DISTANCE_MM, IMAGE_SIZES, camera_angle_deg, generate_suite, shrink_images,
                           unit_corners_world_mm, view_problem)
from twin.simulator import Twin
from twin.textures import KINDS


@pytest.fixture(scope="module")
def suite():
    return generate_suite("wide", 120, 11)


def _tiny(data: dict, max_side_px: int = 480, frames: int = 1) -> dict:
    """A quick-render copy: smaller images (same geometry), one frame, one background frame."""
    w, h = data["image"]["width"], data["image"]["height"]
    d = shrink_images(data, max_side_px / max(w, h))
    d["sequence"]["steps"] = d["sequence"]["steps"][:frames]
    d["sequence"]["background_frames"] = 1
    return d


def _pick(suite, **classes):
    """The first scene with these classes whose images are at most 1 MP (thin tubes stay >= 1.4 px when shrunk)."""
    for s in suite:
        small = s.data["image"]["width"] <= 1024
        if small and all(s.classes[k] == v for k, v in classes.items()):
            return s
    pytest.skip(f"no scene with {classes} in the suite")


def test_same_suite_seed_same_scenes_and_other_seed_others():
    a = generate_suite("wide", 4, 3)
    b = generate_suite("wide", 4, 3)
    assert [s.data for s in a] == [s.data for s in b]
    assert [s.name for s in a] == ["wide-3-0", "wide-3-1", "wide-3-2", "wide-3-3"]
    # scene k does not depend on how many scenes are drawn
    assert generate_suite("wide", 2, 3)[1].data == a[1].data
    assert generate_suite("wide", 1, 4)[0].data != a[0].data


def test_draws_respect_the_stated_ranges(suite):
    angles = []
    for s in suite:
        sc = scene_from_dict(s.data, source=s.name)
        assert sc.classes == s.classes
        angle = camera_angle_deg(sc)
        angles.append(angle)
        assert ANGLE_DEG[0] <= angle <= ANGLE_DEG[1], s.name
        assert (sc.rig["side"].width, sc.rig["side"].height) in IMAGE_SIZES
        for name, cam in sc.rig.cameras.items():
            rig = s.data["rig"][name]
            assert DISTANCE_MM[0] <= rig["distance_mm"] <= DISTANCE_MM[1]
            assert abs(cam.dist[0]) <= 0.25
            assert np.linalg.norm(rig["rotation_deg"]) <= 5.0 + 1e-9
        assert 2 <= sc.robot.n_tubes <= 3
        assert all(0.5 <= t.outer_diameter_mm <= 3.0 for t in sc.robot.tubes)
        assert 30.0 * 0.6 - 1e-6 <= max(j.extension_mm[-1] for j in sc.joints) <= 200.0
        assert view_problem(sc, s.classes["base"]) is None, s.name
        if s.classes["input"] == "masks":
            assert sc.image_kind == "masks" and sc.color == "mono"
        _assert_backdrop_fills_views(sc)
    assert min(angles) < 75 and max(angles) > 105  # the range is used, not just allowed
    for key, values in (("base", {"in-view-unit", "in-view-bare", "outside"}), ("tubes", {"2", "3"}),
                        ("input", {"camera", "masks"}), ("camera_angle", {"45-75", "75-105", "105-135"}),
                        ("resolution", {"<0.5MP", "0.5-2MP", ">2MP"})):
        assert {s.classes[key] for s in suite} == values, key


def _assert_backdrop_fills_views(sc):
    """Every border pixel's ray (with distortion) meets its camera's backdrop plane inside the plane."""
    from twin.backdrop import backdrop_planes

    planes = backdrop_planes(sc)
    for cam, plane in zip(sc.rig.cameras.values(), planes):
        w, h = cam.width, cam.height
        u = np.linspace(-0.5, w - 0.5, 50)
        v = np.linspace(-0.5, h - 0.5, 50)
        border = np.concatenate([np.stack([u, np.full(50, -0.5)], 1), np.stack([u, np.full(50, h - 0.5)], 1),
                                 np.stack([np.full(50, -0.5), v], 1), np.stack([np.full(50, w - 0.5), v], 1)])
        origin, dirs = cam.rays(border)
        t = ((plane.center_mm - origin) @ plane.normal) / (dirs @ plane.normal)
        assert np.all(t > 0), f"{sc.name} {cam.name}: plane behind the camera"
        hits = origin + t[:, None] * dirs - plane.center_mm
        assert np.all(np.abs(hits @ plane.u_axis) < plane.size_u_mm / 2), f"{sc.name} {cam.name}: view beyond the backdrop"
        assert np.all(np.abs(hits @ plane.v_axis) < plane.size_v_mm / 2), f"{sc.name} {cam.name}: view beyond the backdrop"


def test_the_robot_stays_in_front_of_every_backdrop_plane(suite):
    """Every backbone point of every frame (and the actuation unit, where there is one) lies at least 10 mm in
    front of each camera's backdrop plane: a robot through the wall is hidden in the images while its truth
    says it is there (seen: wide-3-6, the robot 20 mm behind the side camera's plane in every frame; wide-5-0
    frame 2, its last 6 mm)."""
    from twin.backdrop import backdrop_planes, robot_points_mm

    close = []
    for g in suite:
        sc = scene_from_dict(g.data, source=g.name)
        pts, _ = robot_points_mm(sc, step=1)
        if g.data["backdrop"]["actuation_unit"]:
            pts = np.concatenate([pts, unit_corners_world_mm(sc)])
        for cam, plane in zip(sc.rig.cameras.values(), backdrop_planes(sc)):
            nearest_mm = float(((pts - plane.center_mm) @ plane.normal).min())
            if nearest_mm < 10.0:
                close.append(f"{sc.name} {cam.name}: {nearest_mm:.1f} mm")
    assert not close, f"robot points less than 10 mm in front of a backdrop plane: {close}"


def _inside_silhouette(frame) -> dict:
    """Per camera: fraction of in-image true backbone points on the label mask dilated by 1 px."""
    import cv2

    out = {}
    for name, labels in frame.labels.items():
        mask = cv2.dilate((labels > 0).astype(np.uint8), np.ones((3, 3), np.uint8))
        uv = np.rint(frame.centerline_px[name]).astype(int)
        h, w = labels.shape
        ok = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
        out[name] = float(mask[uv[ok, 1], uv[ok, 0]].mean())
    return out


def _touches_border(labels: np.ndarray) -> bool:
    return bool(labels[0].any() or labels[-1].any() or labels[:, 0].any() or labels[:, -1].any())


@pytest.mark.parametrize(
    "classes",
    [{"base": "in-view-unit"}, {"base": "in-view-bare"}, {"base": "outside"}, {"tubes": "3"}, {"input": "masks"},
     {"camera_angle": "45-75"}, {"camera_angle": "105-135"}],
    ids=lambda c: "-".join(f"{k}={v}" for k, v in c.items()),
)
def test_each_class_renders_with_truth_on_its_silhouettes(suite, classes):
    s = _pick(suite, **classes)
    sc = scene_from_dict(_tiny(s.data), source=s.name)
    with Twin(sc) as tw:
        f = tw.frame(0)
        bg = tw.background(0)
    for name, frac in _inside_silhouette(f).items():
        assert frac >= 0.99, f"{s.name} {name}: {frac:.3f} of the backbone on the silhouette"
    for name, labels in f.labels.items():
        assert labels.any(), f"{s.name} {name}: no robot in the image"
        assert _touches_border(labels) == (s.classes["base"] == "outside"), f"{s.name} {name}"
    if sc.image_kind == "masks":
        robot = 255 if sc.mask_polarity == "robot-white" else 0
        for name, img in f.images.items():
            assert img.ndim == 2 and set(np.unique(img)) <= {0, 255}
            assert np.array_equal(img == robot, f.labels[name] > 0)
            assert np.all(bg.images[name] == 255 - robot)


@pytest.mark.parametrize("kind", KINDS)
def test_every_backdrop_kind_fills_both_views(suite, kind):
    s = _pick(suite, camera_angle="105-135")
    d = _tiny(s.data, max_side_px=200)
    d["backdrop"].update(kind=kind, texture_px=256, clutter=2)
    d["image"].pop("kind", None)
    if kind == "photo":
        d["backdrop"]["photo"] = "brick"
    sc = scene_from_dict(d, source=s.name)
    with Twin(sc) as tw:
        bg = tw.background(0)
        depth = {n: tw.renderer._set_view(c)[1] for n, c in sc.rig.cameras.items()}
    for name, img in bg.images.items():
        # the backdrop is behind every pixel (no black holes where the set ends)
        assert np.all(depth[name] > 0), f"{kind} {name}: {np.mean(depth[name] <= 0):.3f} of the view shows no set"
        if kind not in ("plain",):
            assert img.std() > 1.0, f"{kind} {name}: a flat image"


def test_new_keys_at_their_defaults_render_as_before():
    data = read_toml(scene_path("paper.toml"), "scene")
    data = _tiny(data, max_side_px=256)
    explicit = json.loads(json.dumps(data))
    explicit["image"].update(kind="camera", mask_polarity="robot-white")
    explicit["backdrop"].update(planes="floor-wall", clutter=0, texture_px=256, pattern_scale=1.0)
    explicit["noise"].update(gain=1.0, vignetting=0.0, jpeg_quality=0.0)
    for cam in ("side", "top"):
        explicit["rig"][cam].update(orbit_deg=[0.0, 0.0, 0.0], distance_mm=300.0)
    images = []
    for d in (data, explicit):
        with Twin(scene_from_dict(d)) as tw:
            images.append(tw.frame(0).images)
    for name in images[0]:
        assert np.array_equal(images[0][name], images[1][name])


@pytest.mark.parametrize(
    "section, key, value, why",
    [
        ("rig.side", "orbit_deg", [0.0, 200.0, 0.0], "must be within [-180, 180] deg"),
        ("rig.top", "distance_mm", -5.0, "must be > 0"),
        ("backdrop", "kind", "marble", "must be one of"),
        ("backdrop", "photo", "eagle", "must be one of"),
        ("backdrop", "planes", "sky", 'must be "floor-wall" or "per-camera"'),
        ("backdrop", "clutter", 99, "must be in [0, 50]"),
        ("image", "kind", "depth", 'must be "camera" or "masks"'),
        ("noise", "jpeg_quality", 120.0, "must be in [0, 100]"),
        ("classes", "tubes", 3, "must be a string"),
        ("rig.side", "orbit", [1.0, 2.0, 3.0], "unknown key"),
    ],
)
def test_new_keys_are_checked_in_one_line(section, key, value, why):
    data = read_toml(scene_path("paper.toml"), "scene")
    table = data
    for part in section.split("."):
        table = table.setdefault(part, {})
    table[key] = value
    with pytest.raises(SceneError) as err:
        scene_from_dict(data, source="x.toml")
    msg = str(err.value)
    assert msg.startswith(f"x.toml: {section}.{key}: ") and why in msg and "\n" not in msg, msg


def test_masks_need_mono_images():
    data = read_toml(scene_path("paper.toml"), "scene")
    data["image"].update(kind="masks", color="rgb")
    with pytest.raises(SceneError, match=r"image.color: must be \"mono\""):
        scene_from_dict(data, source="x.toml")


def test_cli_writes_scenes_and_index(tmp_path, capsys):
    from rig.cli import main

    out = tmp_path / "wide"
    assert main(["scenes", "generate", "--suite", "wide", "--n", "2", "--seed", "5", "--out", str(out)]) == 0
    index = json.loads((out / "index.json").read_text())
    assert [e["name"] for e in index] == ["wide-5-0", "wide-5-1"]
    for entry, s in zip(index, generate_suite("wide", 2, 5)):
        data = read_toml(out / entry["file"], "scene")
        assert data == s.data and entry["classes"] == s.classes
        scene_from_dict(data, source=entry["file"])
    for bad in (["--n", "zero"], ["--n", "0"], ["--seed", "-2"], ["--suite", "narrow"]):
        code = main(["scenes", "generate", "--out", str(tmp_path / "x"), *bad])
        err = capsys.readouterr().err.strip()
        assert code == 2 and err.count("\n") == 0 and err.startswith("ctr-bench scenes: error: "), err
