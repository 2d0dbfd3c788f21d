"""Hypothesis strategies for twin scenes: robots, joints, rig perturbations and noise.

Everything builds on ``scenes/paper.toml`` (the validated set-up): a strategy
draws changes to its TOML dict, and :func:`scenes` validates the result with
:func:`twin.scene.scene_from_dict`. Scenes drawn here render fast: a handful
of frames and few background frames (>= 6, the eigenbackground model needs
k + 1 = 6 with the default k = 5).

Ranges (the "validated envelope" of docs/envelope.md unless a strategy's
``wide=True`` asks for more):

* outer tube OD 1.2-2.0 mm (wall 0.15-0.3 mm, leaving a bore >= 0.75 mm), inner tube OD 0.6 mm up to the
  outer tube's bore minus 0.1 mm; precurvatures: outer 0-1/100 mm^-1 over
  20-40 mm, inner 1/120-1/45 mm^-1 over 40-70 mm;
* joints: outer extension 30-60 mm, inner 15-50 mm beyond it, any rotations;
  the tip stays inside both fields of view (about x in [-15, 105] mm,
  |y|, |z| < 40 mm around the rig target (45, 0, 0));
* rig: mount rotations up to 1 deg, offsets up to 3 mm, principal point
  offsets up to 6 px, radial distortion |k1| <= 0.1, |k2| <= 0.06, camera
  distance 260-340 mm;
* noise: lighting drift <= 0.08, flicker <= 0.02, offsets <= 3 DN, gradient
  <= 0.05, jitter <= 0.5 px and 0.02 deg, shot noise 2000-8000 e- full
  scale, read noise <= 2.5 DN, blur <= 0.8 px.
"""
from __future__ import annotations

import copy
import sys
from pathlib import Path

import numpy as np
from hypothesis import strategies as st

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = [
    "PAPER_TOML",
    "paper_dict",
    "tubes",
    "joint_values",
    "joints_in_view",
    "rig_perturbations",
    "noise_models",
    "lighting",
    "scene_dicts",
    "scenes",
    "with_sequence",
    "tip_in_view",
]

PAPER_TOML = Path(__file__).resolve().parents[1] / "scenes" / "paper.toml"
_PAPER = None

#: World box both cameras of the paper rig see with some margin (mm): lo, hi.
VIEW_BOX_MM = (np.array([-12.0, -38.0, -38.0]), np.array([100.0, 38.0, 38.0]))


def paper_dict() -> dict:
    """A fresh (deep) copy of ``scenes/paper.toml`` as a dict."""
    global _PAPER
    if _PAPER is None:
        _PAPER = tomllib.loads(PAPER_TOML.read_text())
    return copy.deepcopy(_PAPER)


def _f(lo, hi):
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False)


# ----------------------------------------------------------------------------- robot
@st.composite
def tubes(draw, wide: bool = False) -> list:
    """The ``[[robot.tubes]]`` list of a two-tube robot (outermost first).

    ``wide=True`` lets the inner tube be as thin as 0.15 mm (about 1.3 px at
    the paper rig's 0.116 mm per pixel), outside the envelope.
    """
    outer_od = draw(_f(1.2, 2.0))
    wall = draw(_f(0.15, min(0.3, (outer_od - 0.75) / 2)))
    outer_id = outer_od - 2 * wall
    inner_od = draw(_f(0.15 if wide else 0.6, outer_id - 0.1))
    inner_id = inner_od * draw(_f(0.4, 0.8))
    outer_curved = draw(_f(20.0, 40.0))
    inner_curved = draw(_f(40.0, 70.0))
    return [
        {
            "name": "outer",
            "outer_diameter_mm": round(outer_od, 3),
            "inner_diameter_mm": round(outer_id, 3),
            "length_mm": 200.0,
            "curved_length_mm": round(outer_curved, 2),
            "precurvature_per_mm": round(draw(_f(0.0, 1 / 100)), 6),
            "youngs_modulus_gpa": 60.0,
            "poisson_ratio": 0.33,
        },
        {
            "name": "inner",
            "outer_diameter_mm": round(inner_od, 3),
            "inner_diameter_mm": round(inner_id, 3),
            "length_mm": 260.0,
            "curved_length_mm": round(inner_curved, 2),
            "precurvature_per_mm": round(draw(_f(1 / 120, 1 / 45)), 6),
            "youngs_modulus_gpa": 60.0,
            "poisson_ratio": 0.33,
        },
    ]


@st.composite
def joint_values(draw) -> tuple:
    """``(extension_mm, rotation_deg)`` lists for two tubes (outermost first)."""
    outer = draw(_f(30.0, 60.0))
    inner = outer + draw(_f(15.0, 50.0))
    rot = [draw(_f(-180.0, 180.0)), draw(_f(-180.0, 180.0))]
    return [round(outer, 2), round(inner, 2)], [round(r, 2) for r in rot]


def tip_in_view(backbone_world_mm, box=VIEW_BOX_MM) -> bool:
    """Whether every backbone point lies in ``box`` (both views see the whole robot)."""
    p = np.asarray(backbone_world_mm)
    return bool(np.all(p >= box[0]) and np.all(p <= box[1]))


@st.composite
def joints_in_view(draw, robot, model: str = "bending") -> "object":
    """A :class:`twin.robot.Joints` for ``robot`` whose backbone both cameras see whole."""
    from twin.kinematics import solve
    from twin.robot import Joints

    ext, rot = draw(joint_values())
    j = Joints(extension_mm=tuple(ext), rotation_deg=tuple(rot))
    bb = solve(robot, j, model)
    from hypothesis import assume

    assume(tip_in_view(bb.p_world_mm))
    return j


# ----------------------------------------------------------------------------- rig
@st.composite
def rig_perturbations(draw, scale: float = 1.0) -> dict:
    """The ``[rig]`` table: camera distance, distortion and per-camera mount deviations."""
    rig = {
        "distance_mm": round(draw(_f(300.0 - 40 * scale, 300.0 + 40 * scale)), 2),
        "focal_length_mm": 12.0,
        "pixel_size_um": 4.65,
        "target_mm": [45.0, 0.0, 0.0],
        "distortion": [round(draw(_f(-0.1 * scale, 0.1 * scale)), 4), round(draw(_f(-0.06 * scale, 0.06 * scale)), 4), 0.0, 0.0, 0.0],
    }
    for cam in ("side", "top"):
        rig[cam] = {
            "rotation_deg": [round(draw(_f(-scale, scale)), 3) for _ in range(3)],
            "offset_mm": [round(draw(_f(-3 * scale, 3 * scale)), 3) for _ in range(3)],
            "principal_offset_px": [round(draw(_f(-6 * scale, 6 * scale)), 2) for _ in range(2)],
        }
    return rig


# ----------------------------------------------------------------------------- noise and light
@st.composite
def noise_models(draw, scale: float = 1.0) -> dict:
    """The ``[noise]`` table; ``scale`` multiplies every amplitude's upper bound."""
    return {
        "lighting_drift": round(draw(_f(0.0, 0.08 * scale)), 4),
        "lighting_period_frames": round(draw(_f(10.0, 80.0)), 1),
        "flicker": round(draw(_f(0.0, 0.02 * scale)), 4),
        "offset_dn": round(draw(_f(0.0, 3.0 * scale)), 3),
        "gradient": round(draw(_f(0.0, 0.05 * scale)), 4),
        "jitter_px": round(draw(_f(0.0, 0.5 * scale)), 3),
        "jitter_rotation_deg": round(draw(_f(0.0, 0.02 * scale)), 4),
        "photons_full_scale": round(draw(_f(2000.0, 8000.0)), 0),
        "read_noise_dn": round(draw(_f(0.0, 2.5 * scale)), 3),
        "blur_px": round(draw(_f(0.0, 0.8 * scale)), 3),
    }


@st.composite
def lighting(draw) -> dict:
    """The ``[lighting]`` table: ambient and a directional and a point light of varied strength."""
    return {
        "ambient": round(draw(_f(0.25, 0.45)), 3),
        "lights": [
            {"kind": "directional", "direction": [round(draw(_f(-0.5, 0.5)), 3), round(draw(_f(0.3, 0.8)), 3), -1.0],
             "intensity": round(draw(_f(2.0, 4.0)), 3)},
            {"kind": "point", "position_mm": [40.0, -150.0, 120.0], "intensity": round(draw(_f(2.5e4, 5.5e4)), 0)},
        ],
    }


# ----------------------------------------------------------------------------- scenes
def with_sequence(data: dict, joints: list, background_frames: int = 6) -> dict:
    """``data`` with its sequence replaced by one step per ``(extension_mm, rotation_deg)`` pair."""
    data = copy.deepcopy(data)
    data["sequence"] = {
        "background_frames": int(background_frames),
        "frame_interval_s": 1.0,
        "steps": [
            {"frames": 1, "extension_mm_from": list(map(float, e)), "rotation_deg_from": list(map(float, r))}
            for e, r in joints
        ],
    }
    return data


@st.composite
def scene_dicts(
    draw,
    robot: bool = True,
    rig: bool = True,
    noise: bool = True,
    light: bool = True,
    frames: int = 1,
    background_frames: int = 6,
    wide: bool = False,
) -> dict:
    """A scene dict: paper.toml with drawn parts (each switchable) and ``frames`` drawn joint values.

    Joint values are drawn so that the robot stays inside both views (rejection on
    the backbone); ``wide=True`` widens the tube and noise ranges past the envelope.
    """
    from hypothesis import assume

    from twin.kinematics import solve
    from twin.robot import Joints
    from twin.scene import scene_from_dict

    data = paper_dict()
    data["seed"] = draw(st.integers(0, 2**16))
    if robot:
        data["robot"]["tubes"] = draw(tubes(wide=wide))
    if rig:
        data["rig"] = draw(rig_perturbations())
    if noise:
        data["noise"] = draw(noise_models(scale=2.0 if wide else 1.0))
    if light:
        data["lighting"] = draw(lighting())
    probe = scene_from_dict(with_sequence(data, [([30.0, 45.0], [0.0, 0.0])], background_frames))
    seq = []
    for _ in range(frames):
        ext, rot = draw(joint_values())
        bb = solve(probe.robot, Joints(extension_mm=tuple(ext), rotation_deg=tuple(rot)), probe.model)
        assume(tip_in_view(bb.p_world_mm))
        seq.append((ext, rot))
    return with_sequence(data, seq, background_frames)


def scenes(**kwargs):
    """Validated :class:`twin.scene.Scene` objects from :func:`scene_dicts` (same keywords)."""
    from twin.scene import scene_from_dict

    return scene_dicts(**kwargs).map(lambda d: scene_from_dict(d, source="<hypothesis>"))
