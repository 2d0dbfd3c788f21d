"""Inputs that must work (issue 13): a robot entering across the image border, binary-mask sessions.

Each case is a wide-suite draw (twin/scenegen.py) with its classes fixed: a
camera session whose base is outside the view, and masks-only sessions (robot
white on black, or black on white, with uniform background frames) with the
base in view and outside it. Draws are taken in order from a fixed seed and
kept when the thinnest tube is at least 5 px wide everywhere (the methods
refuse tubes under 4 px: that limit has its own tests) and the sensor is at
most 0.52 MP (CI time). Both methods must reconstruct every frame, within
their bounds on what both cameras see: fast 2 pixel footprints mean and
5 at the tip, paper one voxel mean.
"""
from __future__ import annotations

import numpy as np
import pytest

from recon.errors import FrameError
from recon.metrics import backbone_errors
from rig.bench.widebench import frame_footprint_mm

CASES = {
    "camera, base outside": {"backdrop": "wood", "base": "outside", "tubes": "2", "input": "camera"},
    "masks, base in view": {"backdrop": "plain", "base": "in-view-bare", "tubes": "2", "input": "masks"},
    "masks, base outside": {"backdrop": "plain", "base": "outside", "tubes": "3", "input": "masks"},
}
MIN_WIDTH_PX = 5.0
MAX_PIXELS = 520_000


def _thinnest_px(scene) -> float:
    from twin.kinematics import solve

    od = min(t.outer_diameter_mm for t in scene.robot.tubes)
    widths = []
    for j in scene.joints:
        pts = solve(scene.robot, j, scene.model).p_world_mm
        for cam in scene.rig.cameras.values():
            z = cam.world_to_camera(pts)[:, 2]
            widths.append(float(np.min(od * np.sqrt(cam.K[0, 0] * cam.K[1, 1]) / z)))
    return min(widths)


def _draw(classes: dict, seed: int = 31):
    from twin.scene import scene_from_dict
    from twin.scenegen import draw_wide

    for attempt in range(400):
        rng = np.random.default_rng(np.random.SeedSequence([seed, attempt]))
        data = draw_wide(rng, f"case-{attempt}", dict(classes), MAX_PIXELS)
        if data is None:
            continue
        scene = scene_from_dict(data, source=f"case {attempt}")
        if _thinnest_px(scene) >= MIN_WIDTH_PX:
            return scene.with_frames(scene.joints[:2])
    raise AssertionError(f"no draw with tubes >= {MIN_WIDTH_PX} px for {classes}")


@pytest.fixture(scope="module", params=list(CASES))
def rendered(request):
    from twin.simulator import Twin

    scene = _draw(CASES[request.param])
    with Twin(scene) as tw:
        bgs = [tw.background(i) for i in range(6)]
        frames = [tw.frame(i) for i in range(len(scene.joints))]
    stacks = {n: np.stack([b.images[n] for b in bgs]) for n in bgs[0].images}
    return request.param, scene, stacks, frames


@pytest.mark.parametrize("rendered", [c for c in CASES if c.startswith("masks")], indirect=True)
def test_masks_are_binary_with_uniform_backgrounds(rendered):
    name, scene, stacks, frames = rendered
    for cam, stack in stacks.items():
        assert len(np.unique(stack)) == 1, cam
        assert set(np.unique(frames[0].images[cam])) <= {0, 255}, cam


@pytest.mark.parametrize("rendered", [c for c in CASES if "base outside" in c], indirect=True)
def test_base_outside_really_enters_at_the_border(rendered):
    """The robot's silhouette runs into an image border in every view (the scene generator's rule)."""
    name, scene, _, frames = rendered
    for cam, lab in frames[0].labels.items():
        border = np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]])
        assert (border > 0).any(), cam


#: Known failures, measured (strict: the test fails once the method gets these right, so the mark goes).
KNOWN = {
    ("camera, base outside", "paper"): "top: no silhouette (no region as wide as a tube: the widest 5.4 px, the tube 7.8 px)",
    ("camera, base outside", "fast"): "the views disagree on the tip (side's ends 67 px short of top's tip): cut to "
                                      "what both see, suspect, 22.6 mm short (mean 2.4 mm > 2 px footprints)",
}


@pytest.mark.parametrize("method", ["paper", "fast"])
def test_every_frame_reconstructed_within_bounds(rendered, method, request):
    from dataclasses import replace

    from recon.methods import get_method, prepare

    name, scene, stacks, frames = rendered
    if (name, method) in KNOWN:
        request.applymarker(pytest.mark.xfail(strict=True, reason=f"issue 13, open: {KNOWN[(name, method)]}"))
    t = scene.robot.tubes
    params = replace(get_method(method).params_type(), outer_tube_radius_mm=t[0].outer_diameter_mm / 2,
                     inner_tube_radius_mm=t[-1].outer_diameter_mm / 2)
    rec = prepare(method, scene.rig, stacks, params)
    for fr in frames:
        try:
            r = rec(fr.images)
        except FrameError as exc:
            pytest.fail(f"{name}: {method} refused a frame: {exc}")
        e = backbone_errors(r.points_world_mm, fr.backbone.p_world_mm, scene.rig)
        px = frame_footprint_mm(scene.rig, fr.backbone.p_world_mm)
        if method == "paper":
            assert e["mean_error_mm"] <= float(np.max(r.voxel_size_mm)), (name, e)
        else:
            assert e["mean_error_mm"] <= 2.0 * px and e["tip_error_mm"] <= 5.0 * px, (name, e, px)


@pytest.mark.parametrize("rendered", ["camera, base outside"], indirect=True)
def test_a_cut_to_what_both_views_see_is_left_to_the_self_check_which_flags_it_here(rendered):
    """The fast method's known failure above: the side view loses the tube before its tip, and the backbone is
    cut to what both views see, 22 mm short. Its doubt is one the images answer (``check_answers_doubt``),
    and here they do: the top view's tube beyond the cut is left unexplained, so the frame stays suspect."""
    from dataclasses import replace

    from recon.methods import get_method, prepare
    from recon.selfcheck import check_backbone, prepare_selfcheck

    name, scene, stacks, frames = rendered
    t = scene.robot.tubes
    radii = (t[0].outer_diameter_mm / 2, t[-1].outer_diameter_mm / 2)
    params = replace(get_method("fast").params_type(), outer_tube_radius_mm=radii[0], inner_tube_radius_mm=radii[1])
    rec = prepare("fast", scene.rig, stacks, params)
    cut = [(fr, r) for fr, r in ((fr, rec(fr.images)) for fr in frames) if r.suspect_reason]
    assert cut and all(r.suspect_reason.startswith("the views disagree on the tip") for _, r in cut), cut
    assert all(r.check_answers_doubt for _, r in cut)
    model = prepare_selfcheck(scene.rig, stacks)
    verdicts = [check_backbone(model, fr.images, r.points_world_mm, radii) for fr, r in cut]
    assert not any(v.ok for v in verdicts) and all("not explained" in v.reason for v in verdicts), verdicts
