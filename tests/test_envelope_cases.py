"""Property tests on the four cases outside the drawn envelope (docs/envelope.md, "Outside the drawn envelope").

A tube pointing at a camera, a tube in an epipolar plane (x = const in the paper rig), a
robot folding back over itself, a backdrop as gray as the tubes. The borders asserted here
were measured by ``scripts/measure_envelope.py`` (numbers in docs/envelope.md): inside a
border the method is accurate; beyond it a FrameError is acceptable, a wrong shape is not.
Where a method returns a wrong shape beyond a border, the test says so (xfail, with the
measured cause) rather than widening its bounds.

Each example renders a twin scene (~4.5 s: the renderer's set-up, 6 background pairs, one
frame pair), so the "ci" profile draws one example per test and the tests that share a set
(the pointing and epipolar cases; the fold cases) share its background frames, and both
methods share each drawn scene.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import strategies as S

from recon.errors import FrameError  # noqa: E402
from recon.metrics import backbone_errors  # noqa: E402

#: Background frames depend on the seed, so examples that share them use the paper's.
PAPER_SEED = st.just(None)

_FAST_MISSING = pytest.mark.skipif(not S.method_available("fast"), reason="recon.fast is not importable or registers no 'fast' method")


def _fast(*marks):
    return pytest.param("fast", marks=[_FAST_MISSING, *marks])


# ============================================================================= rendering, shared
_BACKGROUNDS: dict = {}
_SCENES: dict = {}


def _set_key(data: dict) -> str:
    """What a scene's background frames depend on: everything but the robot, its material and the joints.

    The actuation unit moves with the robot base, so with the unit the base pose counts too.
    """
    d = {k: v for k, v in data.items() if k not in ("robot", "sequence")}
    backdrop = {k: v for k, v in d.get("backdrop", {}).items() if not k.startswith("robot_")}
    d["backdrop"] = backdrop
    if backdrop.get("actuation_unit", True):
        d["unit_pose"] = [data["robot"].get(k) for k in ("base_position_mm", "insertion_axis", "bend_axis")]
    return json.dumps(d, sort_keys=True)


def rendered(data: dict) -> tuple:
    """``(scene, background stacks, frame)`` of a one-frame scene dict, rendered once per dict.

    Background frames are shared by scenes with the same set (:func:`_set_key`): the twin
    renders them without the robot, from the scene's seed, bit for bit the same.
    """
    from twin.scene import scene_from_dict
    from twin.simulator import Twin

    key = json.dumps(data, sort_keys=True)
    if key not in _SCENES:
        scene = scene_from_dict(data, source="<envelope case>")
        set_key = _set_key(data)
        with Twin(scene) as tw:
            if set_key not in _BACKGROUNDS:
                bgs = [tw.background(i) for i in range(scene.background_frames)]
                _BACKGROUNDS[set_key] = {n: np.stack([b.images[n] for b in bgs]) for n in bgs[0].images}
            frame = tw.frame(0)
        _SCENES[key] = (scene, _BACKGROUNDS[set_key], frame)
    return _SCENES[key]


# ============================================================================= outcomes
def accuracy_bounds(method: str, result, scene) -> dict:
    """Bounds (mm) on the mean, tip and length errors of an accurate reconstruction.

    The mean and tip bounds are tests/test_properties.py's: paper, one voxel edge on the mean;
    fast, 1.5 pixel footprints on the mean and 3 on the tip. Both also keep the arc length
    within 3 of their tip-scale unit (paper: 3 voxel edges; fast: 9 footprints): near an
    epipolar plane the paper method's backbone wanders within its voxel-thick slab, within
    the mean bound but tens of mm too long.
    """
    if method == "paper":
        voxel = float(np.max(result.voxel_size_mm))
        return {"mean_error_mm": voxel, "tip_error_mm": np.inf, "length_error_mm": 3 * voxel}
    px = S.mm_per_px(scene)
    return {"mean_error_mm": 1.5 * px, "tip_error_mm": 3 * px, "length_error_mm": 9 * px}


def scored(method: str, scene, stacks: dict, frame, clip_to_base: bool) -> tuple:
    """Reconstruct ``frame`` with ``method``: ``(errors, bounds)`` (mm); FrameError propagates.

    ``clip_to_base``: score only the points beyond the base plane (scenes without the
    actuation unit, see :func:`strategies.beyond_base`).
    """
    from recon.methods import prepare

    r = prepare(method, scene.rig, stacks, S.params_for(method, scene))(frame.images)
    pts = S.beyond_base(r.points_world_mm, scene.rig) if clip_to_base else r.points_world_mm
    assert len(pts) >= 2, f"{method}: no reconstructed point beyond the base plane"
    return backbone_errors(pts, frame.backbone.p_world_mm), accuracy_bounds(method, r, scene)


def _assert_within(e: dict, bounds: dict, what) -> None:
    bad = {k: (round(e[k], 3), round(b, 3)) for k, b in bounds.items() if not abs(e[k]) <= b}
    assert not bad, f"{what}: error (mm) > bound: {bad}; all errors {e}"


def assert_accurate(method: str, data: dict, clip_to_base: bool = False) -> None:
    """The method reconstructs the scene within :func:`accuracy_bounds` (no FrameError)."""
    scene, stacks, frame = rendered(data)
    e, bounds = scored(method, scene, stacks, frame, clip_to_base)
    _assert_within(e, bounds, (method, frame.joints))


def assert_frame_error_or_accurate(method: str, data: dict, clip_to_base: bool = False) -> None:
    """The method raises FrameError with a reason, or reconstructs the scene accurately: never a wrong shape."""
    scene, stacks, frame = rendered(data)
    try:
        e, bounds = scored(method, scene, stacks, frame, clip_to_base)
    except FrameError as exc:
        assert str(exc).strip(), "FrameError without a reason"
        return
    _assert_within(e, bounds, (method, "returned a shape instead of a FrameError", frame.joints))


EXAMPLES = S.examples(1, 12)


# ============================================================================= (a) pointing at a camera
@pytest.mark.parametrize("method", ["paper", _fast()])
@settings(phases=S.NO_SHRINK, max_examples=EXAMPLES)
@given(data=S.pointing_dicts(5.0, 90.0, seeds=PAPER_SEED))
def test_tube_at_5_deg_or_more_to_a_camera_axis_is_accurate(method, data):
    """A straight robot at 5-90 deg to either camera's optical axis (at 5 deg the camera sees
    5 mm of it, ~45 px) is reconstructed accurately by both methods."""
    assert_accurate(method, data, clip_to_base=True)


@pytest.mark.parametrize("method", [
    "paper",
    _fast(pytest.mark.xfail(strict=False, reason="measured: at 3 deg to the side camera's axis the fast method returns a "
                            "backbone missing 6.5 mm at the base end (mean 0.34 mm > 0.18 mm), no FrameError; at "
                            "0-2 deg it raises FrameError ('no tube edges found', 'robot too short in the image'). "
                            "Re-measured after issue 13: right at 2.5 deg, wrong at 3.0 and 3.5 deg; the ci "
                            "profile's draws miss those angles and pass")),
])
@settings(phases=S.NO_SHRINK, max_examples=EXAMPLES)
@given(data=S.pointing_dicts(0.0, 4.0, seeds=PAPER_SEED))
def test_tube_end_on_to_a_camera_is_a_frame_error_or_right(method, data):
    """0-4 deg from a camera's axis (end on: a blob ~14 px across): a FrameError or the right shape."""
    assert_frame_error_or_accurate(method, data, clip_to_base=True)


# ============================================================================= (b) along an epipolar plane
@pytest.mark.parametrize("method", ["paper", _fast()])
@settings(phases=S.NO_SHRINK, max_examples=EXAMPLES)
@given(data=S.epipolar_dicts(20.0, 90.0, seeds=PAPER_SEED))
def test_tube_at_20_deg_or_more_to_the_epipolar_planes_is_accurate(method, data):
    """A straight robot at 20-90 deg to the epipolar planes x = const (90: along x, the paper's
    insertion axis) is reconstructed accurately, arc length included."""
    assert_accurate(method, data, clip_to_base=True)


@pytest.mark.parametrize("method", [
    pytest.param("paper", marks=pytest.mark.xfail(strict=False, reason=(
        "measured: carving cannot place a tube within ~15 deg of an epipolar plane along it; the backbone wanders "
        "through the carved slab: at 5-15 deg mean within one voxel (0.15-0.49 mm) but length +2.6 to +45 mm (60 mm "
        "robot), at 0-3 deg mean 1.1-6.8 mm > ~0.53 mm voxel and length +52 to +225 mm; never a FrameError"))),
    _fast(pytest.mark.xfail(strict=False, reason=(
        "measured: accurate down to 5 deg; at 0-3 deg the epipolar match is degenerate and the fast method returns "
        "mean 0.18-3.6 mm > 0.175 mm (1.5 px), no FrameError. Re-measured after issue 13: right at 0.5 deg, wrong "
        "at 1.5 and 3 deg; the ci profile's draws miss those and pass"))),
])
@settings(phases=S.NO_SHRINK, max_examples=EXAMPLES)
@given(data=S.epipolar_dicts(0.0, 15.0, seeds=PAPER_SEED))
def test_tube_near_an_epipolar_plane_is_a_frame_error_or_right(method, data):
    """0-15 deg from the epipolar planes: a FrameError or the right shape (arc length included)."""
    assert_frame_error_or_accurate(method, data, clip_to_base=True)


# ============================================================================= (c) folding back over itself
@pytest.mark.parametrize("method", [
    "paper",
    _fast(pytest.mark.xfail(strict=False, reason=(
        "measured: where the side view's path folds back onto itself the fast method loses the returning leg: for "
        "bends of 90-240 deg a backbone 0.3-17 mm short, tip error 1.0-14.6 mm > 0.35 mm (3 px), no FrameError; "
        "90 deg already fails: the tip runs along an epipolar plane"))),
])
@settings(phases=S.NO_SHRINK, max_examples=EXAMPLES)
@given(data=S.fold_dicts((90.0, 240.0), (0.0, 3.0), seeds=PAPER_SEED))
def test_fold_seen_edge_on_by_one_camera_is_a_frame_error_or_right(method, data):
    """The inner tube bends 90-240 deg in a plane within 3 deg of the side camera's line of sight:
    the side view sees it fold back over itself (up to ~45 mm of overlap). The paper method
    carves it right (the top view alone places it); the fast method must at least not be wrong."""
    if method == "paper":
        assert_accurate(method, data)
    else:
        assert_frame_error_or_accurate(method, data)


@pytest.mark.parametrize("method", [
    pytest.param("paper", marks=pytest.mark.xfail(strict=False, reason=(
        "measured: a 180 deg fold tilted 5-85 deg shows both legs apart in both views; carving keeps the ghost "
        "voxels where one view's leg meets the other view's other leg at the same x, and the backbone runs through "
        "them: mean 0.6-1.8 mm > 0.61 mm voxel, length +26 to +115 mm, no FrameError"))),
    _fast(pytest.mark.xfail(strict=False, reason=(
        "measured: right only with the fold tilted 20-45 deg; at 5-10 and 70-85 deg mean 0.19-3.1 mm > 0.175 mm "
        "(a leg nearly edge on in one view), no FrameError"))),
])
@settings(phases=S.NO_SHRINK, max_examples=EXAMPLES)
@given(data=S.fold_dicts((180.0, 180.0), (5.0, 85.0), seeds=PAPER_SEED))
def test_fold_seen_apart_by_both_cameras_is_a_frame_error_or_right(method, data):
    """A 180 deg fold tilted 5-85 deg out of the side camera's line of sight (both views see two
    legs): a FrameError or the right shape."""
    assert_frame_error_or_accurate(method, data)


# ============================================================================= (d) low contrast
@pytest.mark.parametrize("method", ["paper", _fast()])
@settings(phases=S.NO_SHRINK, max_examples=EXAMPLES)
@given(data=S.contrast_dicts(0.65, 0.86, seeds=PAPER_SEED))
def test_backdrop_40_gray_levels_brighter_than_the_tubes_is_accurate(method, data):
    """A plain backdrop of gray 0.65-0.86 behind the paper's Nitinol tubes (median contrast
    42-88 gray levels, tubes darker) is reconstructed accurately."""
    assert_accurate(method, data)


@pytest.mark.parametrize("method", [
    pytest.param("paper", marks=pytest.mark.xfail(strict=False, reason=(
        "measured: FrameError ('no region as wide as a tube') for backdrops 0.35-0.6 (median robot - backdrop "
        "-24 to +32 gray levels), but at 0.3 (+43) it loses the inner tube and returns the outer tube alone: "
        "length -40 mm, mean 8.4 mm, no FrameError. Re-measured after issue 13 (hysteresis threshold): right at "
        "0.3, 0.35, 0.4 and 0.55, a wrong shape at 0.45 and 0.5, no FrameError; the ci draws miss those and pass"))),
    _fast(pytest.mark.xfail(strict=False, reason=(
        "measured: at backdrops 0.4-0.5 (median robot - backdrop -1 to +20 gray levels) the fast method loses the "
        "distal 12-28 mm of the inner tube (mean 1.0-4.4 mm > 0.175 mm), no FrameError; accurate at 0.6 (-24) "
        "and at 0.3-0.35 (+32 to +43), just outside at 0.55 (-13: mean 0.18 mm). Re-measured after issue 13: "
        "wrong at 0.4, right at 0.45 and 0.5; the ci draws miss 0.4 and pass"))),
])
@settings(phases=S.NO_SHRINK, max_examples=EXAMPLES)
@given(data=S.contrast_dicts(0.3, 0.55, seeds=PAPER_SEED))
def test_backdrop_as_gray_as_the_tubes_is_a_frame_error_or_right(method, data):
    """A plain backdrop of gray 0.3-0.55, around the tubes' own median (~0.5): a FrameError or the right shape."""
    assert_frame_error_or_accurate(method, data)
