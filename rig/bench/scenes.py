"""Twin scenes rendered into session directories: as the scene is, or as a researcher with a wrong model records it.

The one place a scene becomes a session on disk (docs/session-format.md): ``render``,
``run``, the render cache (bench, tune, dataset) and ``fit``'s believed sessions all
come through here.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from rig.progress import Progress
from rig.session import SessionWriter
from twin.modelfit import JointOffsets, load_robot_file
from twin.record import render_session
from twin.robotfile import robot_to_dict
from twin.scene import load_scene

__all__ = ["render_scene_to", "render_believed_session"]


def _write_session(scene, out, meta: dict, quiet: bool, joint_offsets=None) -> Path:
    """Render every frame of ``scene`` into the session directory ``out`` with session.json's ``meta``."""
    progress = Progress(enabled=not quiet)
    with SessionWriter(out, scene.rig, source="twin", n_tubes=scene.robot.n_tubes, meta=meta) as writer:
        render_session(scene, writer, progress=progress, joint_offsets=joint_offsets)
    progress.close()
    return Path(out)


def render_scene_to(scene, out: Path, quiet: bool = False) -> Path:
    """Render ``scene`` (a :class:`twin.scene.Scene`) into the session directory ``out``; returns ``out``.

    session.json records the scene's robot, its scene classes (wide suites) and, for
    masks-only scenes, the image kind and mask polarity.
    """
    meta = {"scene": scene.source, "scene_name": scene.name, "robot": robot_to_dict(scene.robot, scene.model)}
    if scene.classes:
        meta["classes"] = dict(scene.classes)
    if scene.image_kind != "camera":
        meta["image_kind"] = scene.image_kind
        meta["mask_polarity"] = scene.mask_polarity
    return _write_session(scene, out, meta, quiet)


def render_believed_session(scene_path, out, nominal_robot=None, joint_offsets=None, frames=None, quiet=True,
                            background_frames=None) -> Path:
    """Render a twin session as a researcher with a wrong model would record it.

    The twin renders the scene's (true) robot at the scene's (true) joints; the
    session records ``nominal_robot`` (a robot file: what the researcher
    believes) in session.json and the commanded joints, true minus
    ``joint_offsets`` (dict ``{"rotation_deg": [...], "extension_mm": [...]}``),
    in frames.csv. The true robot and offsets are kept in session.json under
    ``true_robot`` and ``true_joint_offsets`` for the record. ``frames`` and
    ``background_frames`` shorten the scene (as ``ctr-bench render``'s options).
    ``scene_path`` may also be an already loaded (and adjusted) Scene.
    """
    scene = load_scene(scene_path) if isinstance(scene_path, (str, Path)) else scene_path
    if frames is not None:
        scene = scene.with_frames(scene.joints[:frames])
    if background_frames is not None:
        scene = replace(scene, background_frames=background_frames)
    n = scene.robot.n_tubes
    jo = joint_offsets or {}
    offsets = JointOffsets(np.asarray(jo.get("extension_mm", [0.0] * n), float), np.asarray(jo.get("rotation_deg", [0.0] * n), float))
    believed = load_robot_file(nominal_robot) if nominal_robot else None
    meta = {
        "scene": scene.source, "scene_name": scene.name,
        "robot": robot_to_dict(believed.robot, believed.model) if believed else robot_to_dict(scene.robot, scene.model),
        "true_robot": robot_to_dict(scene.robot, scene.model),
        "true_joint_offsets": {"extension_mm": offsets.extension_mm.tolist(), "rotation_deg": offsets.rotation_deg.tolist()},
    }
    return _write_session(scene, out, meta, quiet, joint_offsets=offsets)
