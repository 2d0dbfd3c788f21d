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
  into the camera frame (mm): ``X_cam = T_cam_world @ X_world``; :mod:`recon.geometry` builds,
  inverts, chains and applies such transforms.
* Distortion coefficients ``dist`` as in OpenCV: ``k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4
  [tau_x tau_y]]]]`` (5, 8, 12 or 14 values; 4 gain ``k3 = 0``).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .distortion import as_coefficients, distort_normalized, padded, tilt_matrix, undistort_normalized
from .geometry import invert_transform, transform_directions, transform_points

__all__ = ["Camera", "distort_normalized", "undistort_normalized"]


def _as_points(points, dim: int, name: str) -> np.ndarray:
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim == 1 and arr.shape[0] == dim:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise ValueError(f"{name} must have shape (n, {dim}), got {np.shape(points)}")
    return arr


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
        """The distortion as all 14 OpenCV coefficients.

        Returns
        -------
        (14,) float64 array
            ``dist`` with zeros appended, read-only.
        """
        return self._d14

    @property
    def tilt(self) -> tuple:
        """The tilted-sensor matrices (:func:`recon.distortion.tilt_matrix`).

        Returns
        -------
        tuple of two (3, 3) arrays
            The tilt matrix of ``tau_x, tau_y`` and its inverse.
        """
        return tilt_matrix(float(self._d14[12]), float(self._d14[13]))

    # ------------------------------------------------------------------ pose
    @property
    def T_world_cam(self) -> np.ndarray:
        """The camera's pose in the world.

        Returns
        -------
        (4, 4) float64 array
            ``T_world_cam`` (mm): camera frame -> world.
        """
        return invert_transform(self.T_cam_world)

    @property
    def center_world_mm(self) -> np.ndarray:
        """The optical centre.

        Returns
        -------
        (3,) float64 array
            Optical centre (world, mm).
        """
        return self.T_world_cam[:3, 3]

    @property
    def image_size(self) -> tuple[int, int]:
        """The image size.

        Returns
        -------
        tuple of (int, int)
            ``(width, height)`` (px).
        """
        return (self.width, self.height)

    def with_pose(self, T_cam_world: np.ndarray) -> "Camera":
        """The same camera at another pose.

        Parameters
        ----------
        T_cam_world : (4, 4) array
            The new pose: world -> camera (mm).

        Returns
        -------
        Camera
            Same intrinsics and distortion, posed at ``T_cam_world``.
        """
        return replace(self, T_cam_world=np.asarray(T_cam_world, dtype=np.float64))

    def scaled(self, factor: float) -> "Camera":
        """The same camera with an image ``factor`` times larger (resolution studies).

        Parameters
        ----------
        factor : float
            Scale of the image size and of the focal lengths (> 0).

        Returns
        -------
        Camera
            Same pose and distortion; ``K`` scaled so that pixel centres stay on integer coordinates,
            image size rounded to whole px.
        """
        K = self.K.copy()
        K[:2, :] *= factor
        # pixel centres stay at integer coordinates: (c + 0.5) * f - 0.5
        K[0, 2] = (self.K[0, 2] + 0.5) * factor - 0.5
        K[1, 2] = (self.K[1, 2] + 0.5) * factor - 0.5
        return replace(self, K=K, width=int(round(self.width * factor)), height=int(round(self.height * factor)))

    def mm_per_pixel_at(self, point_world_mm) -> float:
        """Footprint of one pixel at the depth of a world point.

        Parameters
        ----------
        point_world_mm : (3,) or (1, 3) array
            The point (world, mm); of several, the first.

        Returns
        -------
        float
            mm per px at the point's depth (camera z over the geometric mean focal length).
        """
        z = self.world_to_camera(point_world_mm)[0, 2]
        return float(z / np.sqrt(self.K[0, 0] * self.K[1, 1]))

    def ray_cosine(self, point_world_mm, direction_world) -> float:
        """|cos| of the angle between a direction and the viewing ray to a point (0: across the view, 1: along it).

        A tube's flat end face, a disk of radius ``r`` across its tangent, reaches
        ``r * ray_cosine(tip, tangent)`` beyond the tip's projection along the projected tangent.

        Parameters
        ----------
        point_world_mm : (3,) array
            The point (world frame, mm).
        direction_world : (3,) array
            The direction (world frame; any length but 0).

        Returns
        -------
        float
            In [0, 1]; 0 where the direction or the point's distance from the camera is 0.
        """
        p = self.world_to_camera(np.stack([np.asarray(point_world_mm, float), np.asarray(point_world_mm, float) + direction_world]))
        t, ray = p[1] - p[0], p[0]
        nt, nr = float(np.linalg.norm(t)), float(np.linalg.norm(ray))
        return abs(float(t @ ray)) / (nt * nr) if nt > 1e-12 and nr > 1e-12 else 0.0

    # ------------------------------------------------------------ projection
    def world_to_camera(self, points_world_mm) -> np.ndarray:
        """World points in the camera frame.

        Parameters
        ----------
        points_world_mm : (n, 3) or (3,) array
            Points (world, mm).

        Returns
        -------
        (n, 3) float64 array
            The points in the camera frame (mm, OpenCV axes).
        """
        return transform_points(self.T_cam_world, _as_points(points_world_mm, 3, "points_world_mm"))

    def project(self, points_world_mm) -> tuple[np.ndarray, np.ndarray]:
        """Project world points into the image, with distortion.

        Parameters
        ----------
        points_world_mm : (n, 3) or (3,) array
            World points (mm).

        Returns
        -------
        uv : (n, 2) array
            Pixel coordinates (image frame, px); NaN for points at or behind the camera.
        depth_mm : (n,) array
            z in the camera frame (mm).
        """
        pc = self.world_to_camera(points_world_mm)
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = pc[:, :2] / z[:, None]
        xy[z <= 1e-9] = np.nan
        return self.normalized_to_pixels(distort_normalized(xy, self.dist)), z

    def project_jacobian(self, points_world_mm, h_mm: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
        """Projections of world points and their Jacobians, by central differences of :meth:`project`.

        Parameters
        ----------
        points_world_mm : (n, 3) array
            World points (mm).
        h_mm : float, optional
            Half the difference step (mm).

        Returns
        -------
        uv : (n, 2) array
            Pixel coordinates (px), as :meth:`project`.
        J : (n, 2, 3) array
            d(uv) / d(point), px per mm of world displacement; NaN where a point is at or behind the camera.
        """
        p = _as_points(points_world_mm, 3, "points_world_mm")
        uv = self.project(p)[0]
        J = np.empty((len(p), 2, 3))
        for k in range(3):
            e = np.zeros(3)
            e[k] = h_mm
            J[:, :, k] = (self.project(p + e)[0] - self.project(p - e)[0]) / (2.0 * h_mm)
        return uv, J

    def normalized_to_pixels(self, xy: np.ndarray) -> np.ndarray:
        """Distorted normalized coordinates -> pixels.

        Parameters
        ----------
        xy : (n, 2) array
            Distorted normalized image coordinates (camera frame, x/z and y/z after distortion).

        Returns
        -------
        (n, 2) float64 array
            Pixel coordinates (image frame, px).
        """
        K = self.K
        u = K[0, 0] * xy[:, 0] + K[0, 1] * xy[:, 1] + K[0, 2]
        v = K[1, 1] * xy[:, 1] + K[1, 2]
        return np.stack([u, v], axis=1)

    def pixels_to_normalized(self, uv) -> np.ndarray:
        """Pixels -> ideal (undistorted) normalized coordinates.

        Parameters
        ----------
        uv : (n, 2) or (2,) array
            Distorted pixel coordinates (image frame, px).

        Returns
        -------
        (n, 2) float64 array
            Undistorted normalized coordinates x/z, y/z (camera frame).
        """
        uv = _as_points(uv, 2, "uv")
        K = self.K
        y = (uv[:, 1] - K[1, 2]) / K[1, 1]
        x = (uv[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
        return undistort_normalized(np.stack([x, y], axis=1), self.dist)

    def undistort_pixels(self, uv) -> np.ndarray:
        """Distorted pixels -> pixels of the ideal pinhole camera with the same K.

        Parameters
        ----------
        uv : (n, 2) or (2,) array
            Distorted pixel coordinates (image frame, px).

        Returns
        -------
        (n, 2) float64 array
            Undistorted pixel coordinates (px).
        """
        xy = self.pixels_to_normalized(uv)
        return self.normalized_to_pixels(xy)

    def rays(self, uv) -> tuple[np.ndarray, np.ndarray]:
        """Back-project pixels to world rays.

        Parameters
        ----------
        uv : (n, 2) or (2,) array
            Distorted pixel coordinates (image frame, px).

        Returns
        -------
        origin_world_mm : (3,) array
            Optical centre (world, mm).
        directions_world : (n, 3) array
            Unit ray directions in the world frame.
        """
        xy = self.pixels_to_normalized(uv)
        d_cam = np.concatenate([xy, np.ones((xy.shape[0], 1))], axis=1)
        d_cam /= np.linalg.norm(d_cam, axis=1, keepdims=True)
        return self.center_world_mm, transform_directions(self.T_world_cam, d_cam)

    def in_image(self, uv: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
        """Which pixel coordinates lie inside the image, a margin in from its border.

        Parameters
        ----------
        uv : (n, 2) array
            Pixel coordinates (image frame, px).
        margin_px : float, optional
            Distance (px) inside the image's outer edge (which lies 0.5 px outside the border pixels' centres).

        Returns
        -------
        (n,) bool array
            True where inside.
        """
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
        """JSON-ready description of the camera.

        Returns
        -------
        dict
            ``name``, ``width``, ``height`` (px), ``K`` (px), ``dist`` and ``T_cam_world`` (mm) as lists.
        """
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
        """Inverse of :meth:`to_dict`.

        Parameters
        ----------
        d : dict
            ``width``, ``height``, ``K``, ``T_cam_world`` (mm) and optionally ``dist`` and ``name``.
        name : str, optional
            Camera name, overriding ``d["name"]``.

        Returns
        -------
        Camera

        Raises
        ------
        ValueError
            A required key is missing (named in the message).
        """
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
