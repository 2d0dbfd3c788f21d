"""The robot description, read and written here only: the ``[robot]`` table, robot files and session.json's ``robot``.

Forms
-----
* **TOML** ``[robot]`` table with its ``[[robot.tubes]]``, as in a scene (docs/scenes.md):
  ``model``, ``base_position_mm`` (world mm), ``insertion_axis`` and ``bend_axis`` (world,
  the base frame's z and x), and per tube ``name``, ``outer_diameter_mm``,
  ``inner_diameter_mm``, ``length_mm``, ``curved_length_mm``, ``precurvature_per_mm``
  (1/mm), ``youngs_modulus_gpa`` and ``poisson_ratio`` (:func:`parse_robot_table`,
  :func:`robot_table`).
* **Robot file** (``ctr-bench fit`` writes one, ``--robot``/``--nominal-robot`` read it): the
  ``[robot]`` table, an optional ``[actuator]`` table of joint offsets
  (``rotation_offset_deg``, ``insertion_offset_mm``: one per tube, outermost first, true
  joint = recorded joint + offset) and an optional ``[fit]`` table, written for the record
  and never read (:func:`read_robot_file`, :func:`robot_file_toml`).
* **JSON** ``robot`` of session.json: ``model``, ``T_world_base`` (4x4, mm) and ``tubes``
  (the :class:`twin.robot.Tube` fields) (:func:`robot_to_dict`, :func:`robot_from_dict`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from recon.params import dumps_toml

from .robot import Robot, Tube
from .schema import NONNEGATIVE, POSITIVE, REQUIRED, Table, read_toml

__all__ = ["RobotFile", "parse_robot_table", "robot_from_toml", "read_robot_file", "robot_table", "robot_file_toml",
           "robot_to_dict", "robot_from_dict"]


@dataclass(frozen=True, eq=False)
class RobotFile:
    """What a robot file holds.

    Attributes
    ----------
    robot : Robot
    model : str
        Kinematic model, ``"bending"`` or ``"compliant"``.
    insertion_offset_mm, rotation_offset_deg : (n_tubes,) float arrays
        Actuator offsets (mm, deg), outermost tube first: true joint = recorded joint + offset.
    """

    robot: Robot
    model: str
    insertion_offset_mm: np.ndarray
    rotation_offset_deg: np.ndarray


# ----------------------------------------------------------------------------- reading TOML
def _parse_tube(t: Table) -> Tube:
    kw = dict(
        name=t.get("name", REQUIRED, str),
        outer_diameter_mm=t.get("outer_diameter_mm", REQUIRED, float, *POSITIVE),
        inner_diameter_mm=t.get("inner_diameter_mm", REQUIRED, float, *NONNEGATIVE),
        length_mm=t.get("length_mm", REQUIRED, float, *POSITIVE),
        curved_length_mm=t.get("curved_length_mm", REQUIRED, float, *NONNEGATIVE),
        precurvature_per_mm=t.get("precurvature_per_mm", REQUIRED, float, *NONNEGATIVE),
        youngs_modulus_gpa=t.get("youngs_modulus_gpa", 60.0, float, *POSITIVE),
        poisson_ratio=t.get("poisson_ratio", 0.33, float, lambda v: -1 < v < 0.5, "must be in (-1, 0.5)"),
    )
    if kw["inner_diameter_mm"] >= kw["outer_diameter_mm"]:
        t.fail("inner_diameter_mm", f"must be smaller than outer_diameter_mm={kw['outer_diameter_mm']}, got {kw['inner_diameter_mm']}")
    if kw["curved_length_mm"] > kw["length_mm"]:
        t.fail("curved_length_mm", f"must be <= length_mm={kw['length_mm']}, got {kw['curved_length_mm']}")
    t.done()
    return Tube(**kw)


def _base_transform(position, insertion_axis, bend_axis) -> np.ndarray:
    """``T_world_base`` (4x4, mm): origin at ``position``, z along the insertion axis, x towards the bend axis."""
    z = np.asarray(insertion_axis, float)
    z /= np.linalg.norm(z)
    x = np.asarray(bend_axis, float)
    x = x - np.dot(x, z) * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = position
    return T


def parse_robot_table(r: Table, source: str) -> tuple:
    """The robot of a checked ``[robot]`` table.

    Parameters
    ----------
    r : Table
        The ``[robot]`` table (:mod:`twin.schema`); every key is checked, unknown keys are errors.
    source : str
        The file, for messages.

    Returns
    -------
    robot : Robot
    model : str
    base_position_mm : (3,) array
        ``base_position_mm`` as written (world mm).
    insertion_axis : (3,) array
        ``insertion_axis`` as written (world, not normalised).

    Raises
    ------
    SceneError
        One line naming the file and the key.
    """
    model = r.get("model", "bending", str, lambda v: v in ("bending", "compliant"), 'must be "bending" or "compliant"')
    position = r.get("base_position_mm", [0.0, 0.0, 0.0], ("vec", 3))
    ins = r.get("insertion_axis", [1.0, 0.0, 0.0], ("vec", 3), lambda v: np.linalg.norm(v) > 0, "must be non-zero")
    bend = r.get("bend_axis", [0.0, 1.0, 0.0], ("vec", 3), lambda v: np.linalg.norm(v) > 0, "must be non-zero")
    if np.linalg.norm(np.cross(ins, bend)) < 1e-6:
        r.fail("bend_axis", "must not be parallel to insertion_axis")
    tube_tables = r.tables("tubes")
    if not tube_tables:
        r.fail("tubes", "at least one [[robot.tubes]] is required")
    tubes = [_parse_tube(t) for t in tube_tables]
    for i in range(1, len(tubes)):
        if tubes[i].outer_diameter_mm > tubes[i - 1].inner_diameter_mm:
            tube_tables[i].fail(
                "outer_diameter_mm",
                f"tube {tubes[i].name!r} ({tubes[i].outer_diameter_mm} mm) is wider than the bore of "
                f"tube {tubes[i - 1].name!r} ({tubes[i - 1].inner_diameter_mm} mm) it sits in",
            )
    r.done()
    return Robot(tubes=tuple(tubes), T_world_base=_base_transform(position, ins, bend)), model, np.asarray(position), np.asarray(ins)


def robot_from_toml(data: dict, source: str) -> tuple:
    """``(Robot, model)`` from the ``[robot]`` table of a parsed scene or robot file; its other tables are not read.

    Raises
    ------
    SceneError
        One line naming ``source`` and the key.
    """
    robot, model, _, _ = parse_robot_table(Table(data, "", source).table("robot", required=True), source)
    return robot, model


def read_robot_file(path) -> RobotFile:
    """Read and check a robot file (``[robot]``, optional ``[actuator]``; ``[fit]`` is not read).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    RobotFile

    Raises
    ------
    SceneError
        One line naming the file (missing, unreadable, not TOML) and the key (unknown, wrong).
    """
    source = str(path)
    top = Table(read_toml(path, "robot file"), "", source)
    robot, model, _, _ = parse_robot_table(top.table("robot", required=True), source)
    act = top.table("actuator")
    n = robot.n_tubes
    rot = act.get("rotation_offset_deg", [0.0] * n, ("vec", n))
    ins = act.get("insertion_offset_mm", [0.0] * n, ("vec", n))
    act.done()
    top.used.add("fit")  # the record of a fit, never read back
    top.done()
    return RobotFile(robot, model, np.asarray(ins), np.asarray(rot))


# ----------------------------------------------------------------------------- writing TOML
def robot_table(robot: Robot, model: str) -> dict:
    """The ``[robot]`` table (with ``tubes``, written as ``[[robot.tubes]]``) of ``robot``: TOML-ready.

    The base frame is written as its origin (world mm) and its z and x axes, which
    :func:`parse_robot_table` turns back into ``T_world_base``.
    """
    T_world_base = robot.T_world_base
    return {
        "model": model,
        "base_position_mm": T_world_base[:3, 3],
        "insertion_axis": T_world_base[:3, 2],
        "bend_axis": T_world_base[:3, 0],
        "tubes": [dict(t.__dict__) for t in robot.tubes],
    }


def _tidy(value):
    """``value`` with every number a float to 12 decimals, and a non-finite one as text.

    Rounding strips the float noise of the base frame's columns (6e-17 for 0) and of
    fitted values, so a written file reads as if typed; a non-finite number (a fit's
    interval) is written as the string ``"nan"``/``"inf"``, so reading the file back
    never yields it as a value.
    """
    if isinstance(value, dict):
        return {k: _tidy(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_tidy(v) for v in value]
    if isinstance(value, (str, bool, np.bool_)) or value is None:
        return value
    v = float(value)
    if not math.isfinite(v):
        return str(v)
    return round(v, 12) if v != 0 else 0.0  # 0.0, not -0.0


def robot_file_toml(robot: Robot, model: str, insertion_offset_mm, rotation_offset_deg, header: str = "",
                    fit_table: dict | None = None) -> str:
    """A robot file (TOML) that :func:`read_robot_file` reads back.

    Parameters
    ----------
    robot : Robot
    model : str
    insertion_offset_mm, rotation_offset_deg : sequence of float
        Actuator offsets (mm, deg), one per tube, outermost first (true = recorded + offset).
    header : str, optional
        Comment lines at the top of the file.
    fit_table : dict, optional
        What a fit found, written as ``[fit]`` for the record (keys may hold dots).

    Returns
    -------
    str
    """
    data = {
        "robot": robot_table(robot, model),
        "actuator": {"rotation_offset_deg": rotation_offset_deg, "insertion_offset_mm": insertion_offset_mm},
    }
    # tomli_w writes no comments: what the inline comments of the tables said goes in the header.
    notes = ["[actuator]: true joint = recorded joint + offset (per tube, outermost first)."]
    if fit_table:
        data["fit"] = fit_table
        notes.append("[fit]: what the fit found (for the record; not read back).")
    return dumps_toml(_tidy(data), "\n".join(([header, ""] if header else []) + notes))


# ----------------------------------------------------------------------------- JSON (session.json)
def robot_to_dict(robot: Robot, model: str) -> dict:
    """session.json's ``robot``: JSON-ready (``verify``/``fit`` read it back with :func:`robot_from_dict`)."""
    return {
        "model": model,
        "T_world_base": robot.T_world_base.tolist(),
        "tubes": [dict(t.__dict__) for t in robot.tubes],
    }


def robot_from_dict(d: dict, source: str = "session.json", error=ValueError) -> tuple:
    """``(Robot, model)`` from :func:`robot_to_dict`'s form.

    Raises
    ------
    error
        One line, ``"<source>: robot: not a valid robot description (...)"``.
    """
    try:
        tubes = tuple(Tube(**t) for t in d["tubes"])
        robot = Robot(tubes=tubes, T_world_base=np.asarray(d.get("T_world_base", np.eye(4)), float))
        model = d.get("model", "bending")
    except (KeyError, TypeError, ValueError) as exc:
        raise error(f"{source}: robot: not a valid robot description ({exc})") from None
    return robot, model
