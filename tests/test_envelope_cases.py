"""Property tests on the four cases outside the drawn envelope (docs/envelope.md, "Outside the drawn envelope").

A tube pointing at a camera, a tube in an epipolar plane (x = const in the paper rig), a
robot folding back over itself, a backdrop as gray as the tubes. The borders asserted here
were measured by ``scripts/measure_envelope.py`` (numbers in docs/envelope.md): inside a
border the method is accurate; beyond it a FrameError is acceptable, a wrong shape is not.
Beyond a border the tests pin measured cases (:func:`pinned`) instead of drawing them: where
a method returns a wrong shape there, the case is a strict xfail with the measured cause,
rather than a widened bound, and it fails as XPASS the day the method gets it right.

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


def pinned(method: str, value, wrong: str = "", raises=AssertionError):
    """One pinned case of a test beyond a border: ``(method, value)``, with the measured outcome.

    ``wrong`` is the measurement of a case that fails today; it becomes a strict xfail, so the
    day a change makes the case right the test XPASSes and fails until the mark is removed
    (and docs/envelope.md updated). Beyond a border a drawn example can land on either side of
    a method's failures, so these tests pin their values instead of drawing them.
    """
    marks = []
    if wrong:
        marks.append(pytest.mark.xfail(strict=True, raises=raises, reason=f"measured 2026-12-02: {wrong}"))
    return pytest.param(method, value, marks=marks, id=f"{method}-{value}")


EXAMPLES = S.examples(1, 12)


# ============================================================================= (a) pointing at a camera
@pytest.mark.parametrize("method", ["paper", "fast"])
@settings(phases=S.NO_SHRINK, max_examples=EXAMPLES)
@given(data=S.pointing_dicts(5.0, 90.0, seeds=PAPER_SEED))
def test_tube_at_5_deg_or_more_to_a_camera_axis_is_accurate(method, data):
    """A straight robot at 5-90 deg to either camera's optical axis (at 5 deg the camera sees
    5 mm of it, ~45 px) is reconstructed accurately by both methods."""
    assert_accurate(method, data, clip_to_base=True)


@pytest.mark.parametrize("method, angle_deg", [
    pinned("paper", 1.0),
    # Measured wrong on 2026-12-02 (7.7 mm short, no FrameError), right since the twin's noise draws changed
    # (2026-12-04): at this border the outcome follows the noise.
    pinned("paper", 4.0),
    pinned("fast", 1.0),
    pinned("fast", 3.5, wrong="at 3.5 deg the backbone is 4.7 mm short at the base end (mean 0.19 > 0.18 mm), no "
                             "FrameError; right at 2.5, 3.0 and 4.0 deg, FrameError ('robot too short in the "
                             "image', 'no tube edges found') at 0-2 deg"),
    pinned("fast", 4.0),
])
def test_tube_end_on_to_a_camera_is_a_frame_error_or_right(method, angle_deg):
    """0-4 deg from the side camera's axis (end on: a blob ~14 px across): a FrameError or the right shape."""
    assert_frame_error_or_accurate(method, S.pointing_dict(angle_deg, "side"), clip_to_base=True)


# ============================================================================= (b) along an epipolar plane
@pytest.mark.parametrize("method", ["paper", "fast"])
@settings(phases=S.NO_SHRINK, max_examples=EXAMPLES)
@given(data=S.epipolar_dicts(20.0, 90.0, seeds=PAPER_SEED))
def test_tube_at_20_deg_or_more_to_the_epipolar_planes_is_accurate(method, data):
    """A straight robot at 20-90 deg to the epipolar planes x = const (90: along x, the paper's
    insertion axis) is reconstructed accurately, arc length included."""
    assert_accurate(method, data, clip_to_base=True)


@pytest.mark.parametrize("method, angle_deg", [
    pinned("paper", 1.5, wrong="carving cannot place a tube near an epipolar plane along it: the backbone wanders "
                              "through the carved slab, mean 1.4 mm > 0.53 mm voxel, length +61 mm, no FrameError"),
    pinned("paper", 10.0, wrong="at 10 deg the mean is within a voxel but the backbone is 7.0 mm too long (bound "
                               "1.5 mm); still 2.3 mm at 15 deg; no FrameError"),
    pinned("fast", 1.5, wrong="at 0.5-3 deg the epipolar match is degenerate: mean 0.18-0.96 mm > 0.175 mm (1.5 "
                             "px), no FrameError; right from 5 deg"),
    pinned("fast", 10.0),
])
def test_tube_near_an_epipolar_plane_is_a_frame_error_or_right(method, angle_deg):
    """0-15 deg from the epipolar planes: a FrameError or the right shape (arc length included)."""
    assert_frame_error_or_accurate(method, S.epipolar_dict(angle_deg), clip_to_base=True)


# ============================================================================= (c) folding back over itself
@pytest.mark.parametrize("method, bend_tilt_deg", [
    # A FrameError ('the carved robot is in pieces the backbone cannot join') on 2026-12-02, where the top view
    # alone places the fold; right since the twin's noise draws changed (2026-12-04).
    pinned("paper", (150.0, 1.5)),
    pinned("paper", (240.0, 3.0)),
    pinned("fast", (150.0, 1.5)),
    pinned("fast", (240.0, 3.0)),
])
def test_fold_seen_edge_on_by_one_camera_is_a_frame_error_or_right(method, bend_tilt_deg):
    """The inner tube bends 90-240 deg in a plane within 3 deg of the side camera's line of sight:
    the side view sees it fold back over itself (up to ~45 mm of overlap). The paper method
    carves it right (the top view alone places it); the fast method must at least not be wrong
    (it says 'the views disagree on the tip')."""
    data = S.fold_dict(*bend_tilt_deg)
    if method == "paper":
        assert_accurate(method, data)
    else:
        assert_frame_error_or_accurate(method, data)


@pytest.mark.parametrize("method, tilt_deg", [
    pinned("paper", 30.0, wrong="a 180 deg fold tilted 5-85 deg: carving keeps the ghost voxels where one view's "
                               "leg meets the other view's other leg at the same x, and the backbone runs through "
                               "them: mean 1.6 mm > 0.62 mm voxel, length +103 mm, no FrameError"),
    pinned("paper", 85.0, wrong="tilted 85 deg: mean 0.79 mm > 0.61 mm voxel, length +26 mm, no FrameError"),
    pinned("fast", 30.0),
    pinned("fast", 85.0, wrong="right with the fold tilted 20-45 deg; at 5-10 and 70-85 deg a leg is nearly edge "
                              "on in one view: mean 0.19-8.9 mm > 0.175 mm (1.1 mm at 85 deg), no FrameError"),
])
def test_fold_seen_apart_by_both_cameras_is_a_frame_error_or_right(method, tilt_deg):
    """A 180 deg fold tilted 5-85 deg out of the side camera's line of sight (both views see two
    legs): a FrameError or the right shape."""
    assert_frame_error_or_accurate(method, S.fold_dict(180.0, tilt_deg))


# ============================================================================= (d) low contrast
@pytest.mark.parametrize("method", ["paper", "fast"])
@settings(phases=S.NO_SHRINK, max_examples=EXAMPLES)
@given(data=S.contrast_dicts(0.65, 0.86, seeds=PAPER_SEED))
def test_backdrop_40_gray_levels_brighter_than_the_tubes_is_accurate(method, data):
    """A plain backdrop of gray 0.65-0.86 behind the paper's Nitinol tubes (median contrast
    42-88 gray levels, tubes darker) is reconstructed accurately."""
    assert_accurate(method, data)


@pytest.mark.parametrize("method, gray", [
    pinned("paper", 0.4),
    pinned("paper", 0.5, wrong="at backdrops 0.45-0.5 the silhouette loses the inner tube and the backbone is the "
                              "outer tube's: length -40 mm, mean 8.2 mm > 0.54 mm voxel, no FrameError; right at "
                              "0.3-0.4 and 0.55"),
    pinned("fast", 0.4, wrong="at backdrops 0.4-0.45 (median robot - backdrop about -1 to +20 gray levels) the "
                             "distal inner tube is lost: mean 0.29-0.30 mm > 0.175 mm, tip 0.47-0.59 mm, no "
                             "FrameError; right at 0.3-0.35 and 0.5-0.55"),
    pinned("fast", 0.5),
])
def test_backdrop_as_gray_as_the_tubes_is_a_frame_error_or_right(method, gray):
    """A plain backdrop of gray 0.3-0.55, around the tubes' own median (~0.5): a FrameError or the right shape."""
    assert_frame_error_or_accurate(method, S.contrast_dict(gray))