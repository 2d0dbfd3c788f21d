"""Render a scene into a session directory (the layout of docs/session-format.md)."""
from __future__ import annotations

import numpy as np

from .robot import Joints
# session.json's robot is twin.robotfile's; rig/ and tests still import robot_to_dict from here.
from .robotfile import robot_to_dict
from .scene import Scene
from .simulator import Twin, TwinFrame

__all__ = ["render_session", "truth_arrays", "robot_to_dict"]


def truth_arrays(frame: TwinFrame) -> dict:
    """Ground truth of one twin frame as named arrays (mm, px; see docs/session-format.md)."""
    bb = frame.backbone
    out = {
        "s_mm": bb.s_mm,
        "backbone_world_mm": bb.p_world_mm,
        "R_world_body": bb.R_world_body,
        "outer_radius_mm": bb.outer_radius_mm,
        "outermost_tube": bb.outermost_tube.astype(np.int16),
        "tip_world_mm": bb.tip_world_mm,
        "extension_mm": np.asarray(frame.joints.extension_mm),
        "rotation_deg": np.asarray(frame.joints.rotation_deg),
    }
    for name, cam in frame.cameras.items():
        out[f"T_cam_world_{name}"] = cam.T_cam_world
        out[f"labels_{name}"] = frame.labels[name]
        out[f"depth_mm_{name}"] = frame.depth_mm[name]
        out[f"centerline_px_{name}"] = frame.centerline_px[name]
    return out


def render_session(scene: Scene, writer, progress=None, joint_offsets=None) -> None:
    """Render the scene's background frames, then its robot frames, into ``writer``.

    Parameters
    ----------
    scene : Scene
    writer : rig.session.SessionWriter
        Receives each frame as soon as it is rendered (crash-safe).
    progress : callable(str stage, int done, int total), optional
    joint_offsets : object with ``extension_mm`` and ``rotation_deg`` (one per tube), optional
        An actuator that is off by these: the twin renders (and ``truth/``
        stores) the scene's joints, while ``frames.csv`` records the commanded
        joints, scene joints minus the offsets (true = recorded + offset, as
        ``twin.modelfit.JointOffsets`` and ``ctr-bench fit`` read it).
    """
    with Twin(scene) as tw:
        nb = scene.background_frames
        for i in range(nb):
            writer.add_background(i, tw.background(i).images)
            if progress:
                progress("background", i + 1, nb)
        n = len(scene.joints)
        for i in range(n):
            f = tw.frame(i)
            recorded = f.joints
            if joint_offsets is not None:
                recorded = Joints(
                    extension_mm=tuple(np.subtract(f.joints.extension_mm, joint_offsets.extension_mm)),
                    rotation_deg=tuple(np.subtract(f.joints.rotation_deg, joint_offsets.rotation_deg)),
                )
            writer.add_frame(i, f.images, t_s=i * scene.frame_interval_s, joints=recorded, truth=truth_arrays(f))
            if progress:
                progress("frames", i + 1, n)
