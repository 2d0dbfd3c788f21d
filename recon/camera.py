"""Pinhole camera with OpenCV's lens distortion (4 to 14 coefficients, :mod:`recon.distortion`).

One model shared by the twin (which renders through it) and the pipeline (which
reconstructs through it), so rendered images obey exactly the model that
calibration estimates.

Conventions
-----------
* Lengths in mm, image coordinates in pixels with (0, 0) at the *centre* of the
  top-left pixel (OpenCV convention), u to the right, v down.
* Camera frame: OpenCV (x right, y down, z forward).
* ``T_cam_world`` is the 4x4 homogeneous transform that maps world points (mm)
  into the camera frame (mm): ``X_cam = T_cam_world @ X_world``.
* Distortion coefficients ``dist`` as in OpenCV: ``k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4
  [tau_x tau_y]]]]`` (5, 8, 12 or 14 values; 4 gain ``k3 = 0``).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .distortion import as_coefficients, distort_normalized, padded, tilt_matrix, undistort_normalized

__all__ = [
    "Camera",
    "distort_normalized",
    "undistort_normalized",
    "look_at",
    "rotation_matrix",
    "invert_transform",
]


def _as_points(points, dim: int, name: str) -> np.ndarray:
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim == 1 and arr.shape[0] == dim:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise ValueError(f"{name} must have shape (n, {dim}), got {np.shape(points)}")
    return arr


def invert_transform(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform: ``T_a_b -> T_b_a`` (mm)."""
    T = np.asarray(T, dtype=np.float64)
    R = T[:3, :3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    return out


def rotation_matrix(axis, angle_rad: float) -> np.ndarray:
    """Rotation matrix (3x3) about ``axis`` by ``angle_rad`` (Rodrigues)."""
    axis = np.asarray(axis, dtype=np.float64)
    n = np.linalg.norm(axis)
    if n == 0.0:
        return np.eye(3)
    k = axis / n
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle_rad) * K + (1.0 - np.cos(angle_rad)) * (K @ K)


def look_at(eye_world_mm, target_world_mm, down_world) -> np.ndarray:
    """``T_cam_world`` of a camera at ``eye`` looking at ``target``.

    The camera z axis points from eye to target and its y axis (image down) is
    as close as possible to ``down_world``.
    """
    eye = np.asarray(eye_world_mm, dtype=np.float64)
    z = np.asarray(target_world_mm, dtype=np.float64) - eye
    z /= np.linalg.norm(z)
    down = np.asarray(down_world, dtype=np.float64)
    y = down - np.dot(down, z) * z
    if np.linalg.norm(y) < 1e-9:
        raise ValueError("look_at: 'down' is parallel to the viewing direction")
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    R_world_cam = np.stack([x, y, z], axis=1)
    T_world_cam = np.eye(4)
    T_world_cam[:3, :3] = R_world_cam
    T_world_cam[:3, 3] = eye
    return invert_transform(T_world_cam)


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated camera: intrinsics, distortion and pose.

    Attributes
    ----------
    name : str
        Camera name (``"side"``, ``"top"``).
    width, height : int
        Image size in pixels.
    K : (3, 3) array
        Intrinsic matrix (pixels).
    dist : (5,), (8,), (12,) or (14,) array
        OpenCV distortion coefficients (:mod:`recon.distortion`); 4 are padded with ``k3 = 0``.
    T_cam_world : (4, 4) array
        World (mm) -> camera (mm).
    """

    name: str
    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    T_cam_world: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self):
        K = np.asarray(self.K, dtype=np.float64)
        dist = as_coefficients(self.dist, f"camera {self.name!r}")
        T = np.asarray(self.T_cam_world, dtype=np.float64)
        if K.shape != (3, 3):
            raise ValueError(f"camera {self.name!r}: K must be 3x3, got {K.shape}")
        if T.shape != (4, 4):
            raise ValueError(f"camera {self.name!r}: T_cam_world must be 4x4, got {T.shape}")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise ValueError(f"camera {self.name!r}: image size must be positive, got {self.width}x{self.height}")
        for arr in (K, dist, T):
            arr.setflags(write=False)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", dist)
        object.__setattr__(self, "T_cam_world", T)
        d14 = padded(dist)
        d14.setflags(write=False)
        object.__setattr__(self, "_d14", d14)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    # ------------------------------------------------------------ distortion
    @property
    def dist14(self) -> np.ndarray:
        """The distortion as all 14 OpenCV coefficients (zeros appended), read-only."""
        return self._d14

    @property
    def tilt(self) -> tuple:
        """The tilted-sensor matrix and its inverse (:func:`recon.distortion.tilt_matrix`)."""
        return tilt_matrix(float(self._d14[12]), float(self._d14[13]))

    # ------------------------------------------------------------------ pose
    @property
    def T_world_cam(self) -> np.ndarray:
        """Camera (mm) -> world (mm)."""
        return invert_transform(self.T_cam_world)

    @property
    def center_world_mm(self) -> np.ndarray:
        """Optical centre in world coordinates (mm)."""
        return self.T_world_cam[:3, 3]

    @property
    def image_size(self) -> tuple[int, int]:
        """``(width, height)`` in pixels."""
        return (self.width, self.height)

    def with_pose(self, T_cam_world: np.ndarray) -> "Camera":
        """The same camera at another pose."""
        return replace(self, T_cam_world=np.asarray(T_cam_world, dtype=np.float64))

    def scaled(self, factor: float) -> "Camera":
        """The same camera with an image ``factor`` times larger (resolution studies)."""
        K = self.K.copy()
        K[:2, :] *= factor
        # pixel centres stay at integer coordinates: (c + 0.5) * f - 0.5
        K[0, 2] = (self.K[0, 2] + 0.5) * factor - 0.5
        K[1, 2] = (self.K[1, 2] + 0.5) * factor - 0.5
        return replace(self, K=K, width=int(round(self.width * factor)), height=int(round(self.height * factor)))

    def mm_per_pixel_at(self, point_world_mm) -> float:
        """Footprint of one pixel (mm) at the depth of a world point."""
        p = _as_points(point_world_mm, 3, "point_world_mm")
        z = (self.T_cam_world[:3, :3] @ p.T + self.T_cam_world[:3, 3:4])[2, 0]
        return float(z / np.sqrt(self.K[0, 0] * self.K[1, 1]))

    # ------------------------------------------------------------ projection
    def world_to_camera(self, points_world_mm) -> np.ndarray:
        """World points (n, 3) mm -> camera frame (n, 3) mm."""
        p = _as_points(points_world_mm, 3, "points_world_mm")
        return p @ self.T_cam_world[:3, :3].T + self.T_cam_world[:3, 3]

    def project(self, points_world_mm) -> tuple[np.ndarray, np.ndarray]:
        """Project world points into the image, with distortion.

        Parameters
        ----------
        points_world_mm : (n, 3) array
            World points (mm).

        Returns
        -------
        uv : (n, 2) array
            Pixel coordinates; NaN for points at or behind the camera.
        depth_mm : (n,) array
            z in the camera frame (mm).
        """
        pc = self.world_to_camera(points_world_mm)
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = pc[:, :2] / z[:, None]
        xy[z <= 1e-9] = np.nan
        return self.normalized_to_pixels(distort_normalized(xy, self.dist)), z

    def normalized_to_pixels(self, xy: np.ndarray) -> np.ndarray:
        """Distorted normalized coordinates -> pixels."""
        K = self.K
        u = K[0, 0] * xy[:, 0] + K[0, 1] * xy[:, 1] + K[0, 2]
        v = K[1, 1] * xy[:, 1] + K[1, 2]
        return np.stack([u, v], axis=1)

    def pixels_to_normalized(self, uv) -> np.ndarray:
        """Pixels -> ideal (undistorted) normalized coordinates x/z, y/z."""
        uv = _as_points(uv, 2, "uv")
        K = self.K
        y = (uv[:, 1] - K[1, 2]) / K[1, 1]
        x = (uv[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
        return undistort_normalized(np.stack([x, y], axis=1), self.dist)

    def undistort_pixels(self, uv) -> np.ndarray:
        """Distorted pixels -> pixels of the ideal pinhole camera with the same K."""
        xy = self.pixels_to_normalized(uv)
        return self.normalized_to_pixels(xy)

    def rays(self, uv) -> tuple[np.ndarray, np.ndarray]:
        """Back-project pixels to world rays.

        Returns
        -------
        origin_world_mm : (3,) array
            Optical centre (mm).
        directions_world : (n, 3) array
            Unit ray directions in the world frame.
        """
        xy = self.pixels_to_normalized(uv)
        d_cam = np.concatenate([xy, np.ones((xy.shape[0], 1))], axis=1)
        d_cam /= np.linalg.norm(d_cam, axis=1, keepdims=True)
        d_world = d_cam @ self.T_world_cam[:3, :3].T
        return self.center_world_mm, d_world

    def in_image(self, uv: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
        """Boolean mask of pixel coordinates inside the image (with a margin)."""
        u = uv[:, 0]
        v = uv[:, 1]
        return (
            (u >= -0.5 + margin_px)
            & (u <= self.width - 0.5 - margin_px)
            & (v >= -0.5 + margin_px)
            & (v <= self.height - 0.5 - margin_px)
        )

    # ---------------------------------------------------------- (de)serialize
    def to_dict(self) -> dict:
        """JSON-ready description (lists, mm, pixels)."""
        return {
            "name": self.name,
            "width": self.width,
            "height": self.height,
            "K": self.K.tolist(),
            "dist": self.dist.tolist(),
            "T_cam_world": self.T_cam_world.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict, name: str | None = None) -> "Camera":
        """Inverse of :meth:`to_dict`; raises ``ValueError`` naming a missing key."""
        for key in ("width", "height", "K", "T_cam_world"):
            if key not in d:
                raise ValueError(f"camera {name or d.get('name', '?')!r}: missing key {key!r}")
        return cls(
            name=name or d.get("name", "camera"),
            width=d["width"],
            height=d["height"],
            K=np.asarray(d["K"], dtype=np.float64),
            dist=np.asarray(d.get("dist", np.zeros(5)), dtype=np.float64),
            T_cam_world=np.asarray(d["T_cam_world"], dtype=np.float64),
        )
