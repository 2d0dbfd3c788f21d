"""Geometry of the twin's set: the backdrop planes behind the robot and seeded clutter on them.

Two layouts:

* ``"floor-wall"``: the original set for the nominal orthogonal rig, a floor at
  ``floor_z_mm`` (seen by the top camera) and a wall at ``wall_y_mm`` (seen by the
  side camera), 600 mm square.
* ``"per-camera"``: one plane per camera, perpendicular to its line of sight to the
  target, ``behind_mm`` beyond the target, sized to fill that camera's whole canvas
  (sensor, distortion margin and jitter). Each plane faces its camera; pyrender culls
  back faces, so when the optical axes are more than 90 deg apart a camera looks
  through the back of the other camera's plane and sees its own plane only.

Clutter (boxes and cylinders) stands on the backdrop planes in the slab between the
plane and the robot's nearest approach to it, and is kept out of every camera's line
of sight to the robot, so it appears behind the tubes but never in front of them.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import trimesh

from .groundtruth import extend_to_mesh_start
from .kinematics import solve
from .mesh import box_mesh, cylinder_mesh

__all__ = ["Plane", "backdrop_planes", "robot_points_mm", "place_clutter", "auto_texture_px"]


@dataclass(frozen=True)
class Plane:
    """A rectangular backdrop plane (world mm); ``normal = u x v`` faces the cameras."""

    center_mm: np.ndarray
    u_axis: np.ndarray
    v_axis: np.ndarray
    size_u_mm: float
    size_v_mm: float

    @property
    def normal(self) -> np.ndarray:
        return np.cross(self.u_axis, self.v_axis)


def auto_texture_px(width_px: int, height_px: int) -> int:
    """Texture side (texels) for a backdrop that fills a view of this sensor without looking soft.

    About 1.25 texels per sensor pixel across the larger image side (a plane a bit
    larger than the view), in steps of 256, within [1024, 3072].
    """
    n = int(np.ceil(1.25 * max(width_px, height_px) / 256.0)) * 256
    return int(np.clip(n, 1024, 3072))


def _camera_plane(camera, target_mm: np.ndarray, behind_mm: float, margin_px: float) -> Plane:
    """The plane behind the target that fills ``camera``'s view (``margin_px`` beyond the sensor's border)."""
    C = camera.center_world_mm
    los = target_mm - C
    dist = float(np.linalg.norm(los))
    los /= dist
    normal = -los
    center = C + (dist + behind_mm) * los
    R_world_cam = camera.T_world_cam[:3, :3]
    x_cam = R_world_cam[:, 0]
    u = x_cam - np.dot(x_cam, normal) * normal
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    # Rays through the sensor border, through the lens distortion (barrel or pincushion
    # moves the view's edge), and through the border ``margin_px`` further out (jitter).
    w, h = camera.width, camera.height
    m = margin_px
    u_s = np.linspace(-0.5 - m, w - 0.5 + m, 64)
    v_s = np.linspace(-0.5 - m, h - 0.5 + m, 64)
    border = np.concatenate([np.stack([u_s, np.full(64, v_s[0])], 1), np.stack([u_s, np.full(64, v_s[-1])], 1),
                             np.stack([np.full(64, u_s[0]), v_s], 1), np.stack([np.full(64, u_s[-1]), v_s], 1)])
    _, d_world = camera.rays(border)
    t = ((center - C) @ normal) / (d_world @ normal)
    hits = C + t[:, None] * d_world - center
    half_u = float(np.abs(hits @ u).max())
    half_v = float(np.abs(hits @ v).max())
    # 10 % and 10 mm more: camera jitter and the mount deviations of other frames never show an edge.
    return Plane(center, u, v, 2.2 * half_u + 20.0, 2.2 * half_v + 20.0)


def backdrop_planes(scene, margin_px: float = 8.0) -> list:
    """The backdrop planes of ``scene`` (see the module docstring for the two layouts)."""
    d = scene.dressing
    cams = list(scene.rig.cameras.values())
    if d.planes == "per-camera":
        target = _target_mm(scene)
        return [_camera_plane(cam, target, d.behind_mm, margin_px) for cam in cams]
    cx = float(np.mean([c.T_world_cam[0, 3] for c in cams]))
    ex, ey, ez = np.eye(3)
    return [
        Plane(np.array([cx, 0.0, d.floor_z_mm]), ex, ey, 600.0, 600.0),  # faces +z, the top camera
        Plane(np.array([cx, d.wall_y_mm, 0.0]), ex, ez, 600.0, 600.0),  # faces -y, the side camera
    ]


def _target_mm(scene) -> np.ndarray:
    """Where the optical axes pass closest to each other (world mm): the rig's target."""
    cams = list(scene.rig.cameras.values())
    origins = [c.center_world_mm for c in cams]
    dirs = [c.T_world_cam[:3, 2] for c in cams]
    # Least-squares point nearest to both optical axes.
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for o, dvec in zip(origins, dirs):
        P = np.eye(3) - np.outer(dvec, dvec)
        A += P
        b += P @ o
    return np.linalg.lstsq(A, b, rcond=None)[0]


def depth_beyond_target_mm(scene, points_world_mm: np.ndarray, target_mm=None) -> float:
    """How far (mm) the points reach beyond a target along any camera's line of sight to it: a per-camera
    backdrop ``behind_mm`` beyond the target must exceed it, or that plane cuts through them.

    ``target_mm`` None: :func:`_target_mm`, where the planes are placed. With mounts a few degrees off, the
    optical axes pass 30 mm or more from the target the rig was aimed at (wide-3-6: clear by 15 mm from the
    aimed target, the robot lay 20 mm behind the side camera's plane, hidden in both views in every frame).
    """
    target = _target_mm(scene) if target_mm is None else np.asarray(target_mm, float)
    depth = -np.inf
    for cam in scene.rig.cameras.values():
        los = target - cam.center_world_mm
        los /= np.linalg.norm(los)
        depth = max(depth, float(((np.asarray(points_world_mm, float) - target) @ los).max()))
    return depth


def robot_points_mm(scene, step: int = 10) -> tuple:
    """Backbone points (n, 3) mm of every frame of the scene (with the hidden start) and the largest tube radius (mm)."""
    pts = []
    for joints in scene.joints:
        bb = extend_to_mesh_start(solve(scene.robot, joints, scene.model))
        pts.append(bb.p_world_mm[::step])
        pts.append(bb.p_world_mm[-1:])
    return np.concatenate(pts), max(t.outer_radius_mm for t in scene.robot.tubes)


def _occludes(mesh: trimesh.Trimesh, cameras, robot_mm: np.ndarray, radius_mm: float) -> bool:
    """Whether ``mesh`` could hide any robot point from any camera (conservative: convex hull, padded)."""
    for cam in cameras:
        uv_r, z_r = cam.project(robot_mm)
        uv_m, z_m = cam.project(mesh.vertices)
        if np.any(z_m <= 1.0):
            return True  # reaches behind the camera: never place it
        near = z_r > z_m.min()
        if not np.any(near):
            continue
        hull = cv2.convexHull(uv_m.astype(np.float32))
        pad_px = radius_mm * cam.K[0, 0] / max(float(z_r.min()), 1.0) + 4.0
        for p in uv_r[near]:
            if cv2.pointPolygonTest(hull, (float(p[0]), float(p[1])), True) > -pad_px:
                return True
    return False


def place_clutter(scene, planes: list, rng: np.random.Generator) -> list:
    """Up to ``scene.dressing.clutter`` boxes and cylinders standing on the backdrop planes.

    Each object stands in the slab between its plane and the robot's nearest
    approach to that plane (5 mm clear of it) and is rejected if it could hide the
    robot from a camera; an object that fails 40 draws is left out.

    Returns
    -------
    list of (trimesh.Trimesh, (r, g, b), metallic, roughness)
    """
    n = scene.dressing.clutter
    if n == 0:
        return []
    robot_mm, radius_mm = robot_points_mm(scene)
    cams = list(scene.rig.cameras.values())
    clear = [float(((robot_mm - p.center_mm) @ p.normal).min()) - radius_mm - 5.0 for p in planes]
    out = []
    for _ in range(n):
        for _attempt in range(40):
            k = int(rng.integers(len(planes)))
            p = planes[k]
            if clear[k] < 3.0:
                continue
            foot = min(p.size_u_mm, p.size_v_mm) * rng.uniform(0.03, 0.14)
            height = min(clear[k], foot * rng.uniform(0.3, 1.5))
            a, b = rng.uniform(-0.42, 0.42, 2)
            base = p.center_mm + a * p.size_u_mm * p.u_axis + b * p.size_v_mm * p.v_axis
            nrm = p.normal
            if rng.random() < 0.5:
                m = box_mesh([-foot / 2, -foot * rng.uniform(0.3, 0.6), 0.0], [foot / 2, foot * rng.uniform(0.3, 0.6), height])
                spin = rng.uniform(0.0, 2 * np.pi)
                R = np.stack([p.u_axis, p.v_axis, nrm], axis=1) @ np.array(
                    [[np.cos(spin), -np.sin(spin), 0.0], [np.sin(spin), np.cos(spin), 0.0], [0.0, 0.0, 1.0]]
                )
                T = np.eye(4)
                T[:3, :3] = R
                T[:3, 3] = base - 0.5 * nrm  # sunk 0.5 mm: no seam of light under it
                m.apply_transform(T)
            else:
                m = cylinder_mesh(base - 0.5 * nrm, base + height * nrm, foot / 2)
            if _occludes(m, cams, robot_mm, radius_mm):
                continue
            grey = rng.uniform(0.1, 0.9)
            tint = np.clip(grey + rng.normal(0.0, 0.12, 3), 0.02, 0.98)
            metallic = float(rng.choice([0.0, 0.0, 0.5, 0.9]))
            out.append((m, tuple(float(c) for c in tint), metallic, float(rng.uniform(0.25, 0.9))))
            break
    return out
