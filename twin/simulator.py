"""The twin: a scene rendered frame by frame into camera images with ground truth.

``Twin(scene).background(i)`` gives robot-free frames (for the eigenbackground
model); ``Twin(scene).frame(i)`` gives the robot at the scene's i-th joint values
(or at any joints passed in), with everything the pipeline should recover.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .kinematics import solve
from .mesh import tube_meshes
from .noise import expose, frame_rng, jitter_camera
from .robot import Backbone, Joints
from .scene import Scene

__all__ = ["Twin", "TwinFrame"]


@dataclass(frozen=True, eq=False)
class TwinFrame:
    """One rendered camera pair with its ground truth.

    Attributes
    ----------
    images : dict name -> (H, W) uint8 (or (H, W, 3) for rgb scenes)
    cameras : dict name -> Camera
        The cameras as actually used (after this frame's jitter).
    joints : Joints or None
        None for background frames.
    backbone : Backbone or None
        True backbone (world mm).
    labels : dict name -> (H, W) uint8
        0 background, 1 + tube index of the visible tube.
    depth_mm : dict name -> (H, W) float32
        Camera-frame depth of the robot surface (mm), 0 elsewhere.
    centerline_px : dict name -> (n, 2) float
        The true backbone projected through the used camera (with distortion).
    t_frames : float
        Exposure time in frames since the session started.
    """

    images: dict
    cameras: dict
    joints: Joints | None = None
    backbone: Backbone | None = None
    labels: dict | None = None
    depth_mm: dict | None = None
    centerline_px: dict | None = None
    t_frames: float = 0.0


class Twin:
    """Renders a :class:`Scene`; one OpenGL context for all frames.

    Parameters
    ----------
    scene : Scene
    """

    def __init__(self, scene: Scene):
        self.scene = scene
        # PyOpenGL binds its platform at first import: only a twin that renders imports the renderer.
        from .render import SetRenderer

        self.renderer = SetRenderer(scene)

    def close(self) -> None:
        self.renderer.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def backbone(self, joints: Joints) -> Backbone:
        """True backbone for ``joints`` with the scene's kinematic model (world mm)."""
        return solve(self.scene.robot, joints, self.scene.model)

    def _shoot(self, stream: str, index: int, t_frames: float, with_truth: bool) -> tuple:
        sc = self.scene
        images, used, views = {}, {}, {}
        for name, cam in sc.rig.cameras.items():
            cam_used = jitter_camera(cam, sc.noise, frame_rng(sc.seed, f"jitter-{stream}", index, name))
            if sc.image_kind == "masks":
                images[name], views[name] = self._mask(cam_used, with_truth)
            else:
                view = self.renderer.render(cam_used, with_truth=with_truth)
                images[name] = expose(view.radiance, sc.noise, t_frames, frame_rng(sc.seed, f"expose-{stream}", index, name), sc.color)
                views[name] = view
            used[name] = cam_used
        return images, used, views

    def _mask(self, camera, with_truth: bool) -> tuple:
        """A masks-only image: the label pass (a pixel is robot where a tube covers half of it), binarised.

        Background frames of a masks session are uniform, as a segmentation tool's
        output is where there is no robot; they need no rendering.
        """
        robot_value = 255 if self.scene.mask_polarity == "robot-white" else 0
        shape = (camera.height, camera.width)
        if not with_truth:
            return np.full(shape, 255 - robot_value, np.uint8), None
        view = self.renderer.render(camera, with_truth=True)
        image = np.where(view.labels > 0, np.uint8(robot_value), np.uint8(255 - robot_value))
        return image, view

    def background(self, index: int) -> TwinFrame:
        """Robot-free frame ``index`` of the background sequence."""
        self.renderer.set_robot(None)
        images, used, _ = self._shoot("background", index, float(index), with_truth=False)
        return TwinFrame(images=images, cameras=used, t_frames=float(index))

    def frame(self, index: int, joints: Joints | None = None) -> TwinFrame:
        """Robot frame ``index`` (at the scene's joints unless ``joints`` is given)."""
        sc = self.scene
        if joints is None:
            joints = sc.joints[index]
        bb = self.backbone(joints)
        self.renderer.set_robot(tube_meshes(bb, sc.robot, joints))
        t = float(sc.background_frames + index)
        images, used, views = self._shoot("frame", index, t, with_truth=True)
        centerline = {name: cam.project(bb.p_world_mm)[0] for name, cam in used.items()}
        return TwinFrame(
            images=images,
            cameras=used,
            joints=joints,
            backbone=bb,
            labels={n: v.labels for n, v in views.items()},
            depth_mm={n: v.depth_mm for n, v in views.items()},
            centerline_px=centerline,
            t_frames=t,
        )
