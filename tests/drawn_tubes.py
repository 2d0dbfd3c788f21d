"""Robots drawn without the twin, for the methods' tests: a known backbone, a two-camera rig, tubes anti-aliased by supersampling."""
from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial import cKDTree

from recon.camera import Camera
from recon.geometry import look_at
from recon.rigcal import RigCalibration

__all__ = ["draw_tube", "robot_backbone", "paper_robot", "paper_rig", "PAPER_K", "PAPER_DIST"]

PAPER_K = np.array([[2580.0, 0.0, 511.5], [0.0, 2580.0, 383.5], [0.0, 0.0, 1.0]])
PAPER_DIST = (-0.08, 0.1, 0.0005, -0.0007, 0.0)


def draw_tube(img, cam, pts_mm, radii_mm, level=60.0, ss=6):
    """Draw a tube of given radius along a 3D backbone, anti-aliased by ``ss`` x ``ss`` supersampling."""
    uv, z = cam.project(pts_mm)
    r_px = radii_mm * cam.K[0, 0] / z
    # Dense centerline (0.05 px) and the pixels near it.
    seg = np.linalg.norm(np.diff(uv, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    t = np.arange(0.0, s[-1], 0.05)
    c = np.stack([np.interp(t, s, uv[:, 0]), np.interp(t, s, uv[:, 1])], axis=1)
    rc = np.interp(t, s, r_px)
    band = np.zeros(img.shape, np.uint8)
    cv2.polylines(band, [np.rint(uv).astype(np.int32)], False, 1, int(2 * r_px.max() + 5))
    vy, vx = np.nonzero(band)
    sub = (np.arange(ss) + 0.5) / ss - 0.5
    su, sv = np.meshgrid(sub, sub)
    P = np.stack([(vx[:, None] + su.ravel()).ravel(), (vy[:, None] + sv.ravel()).ravel()], axis=1)
    dist, k = cKDTree(c).query(P)
    cov = (dist <= rc[k]).reshape(len(vx), ss * ss).mean(axis=1)
    img[vy, vx] = img[vy, vx] * (1.0 - cov) + level * cov
    return img


def robot_backbone(n=400, straight=35.0, length=80.0, bend_axis=(0.0, 0.6, 0.8)):
    """``(s, points, radii)`` (mm): ``straight`` mm along x, then bent about ``bend_axis`` at 1/60 mm^-1; radii 0.8 mm
    to s = 50 mm, 0.5 mm beyond."""
    s = np.linspace(0.0, length, n)
    ds = s[1] - s[0]
    pts = np.zeros((n, 3))
    d = np.array([1.0, 0.0, 0.0])
    ax = np.asarray(bend_axis) / np.linalg.norm(bend_axis)
    for i in range(1, n):
        if s[i] > straight:
            d = d + ds / 60.0 * np.cross(ax, d)
            d /= np.linalg.norm(d)
        pts[i] = pts[i - 1] + d * ds
    radii = np.where(s <= 50.0, 0.8, 0.5)
    return s, pts, radii


def paper_robot(n: int = 1900) -> tuple:
    """``(s, points)`` (mm): the base at the origin along +x for 35 mm, then bending at 1/60 mm^-1 about
    (0, 0.6, 0.8) to 95 mm."""
    s, pts, _ = robot_backbone(n, straight=35.0, length=95.0)
    return s, pts


def paper_rig() -> RigCalibration:
    """Two 1024x768 cameras 300 mm from (50, 0, 0) mm, side along -y and top along +z, "top" listed first
    (a method must still take the side view first)."""
    top = Camera("top", 1024, 768, PAPER_K, dist=PAPER_DIST, T_cam_world=look_at([50, 0, 300], [50, 0, 0], [0, -1, 0]))
    side = Camera("side", 1024, 768, PAPER_K, dist=PAPER_DIST, T_cam_world=look_at([50, -300, 0], [50, 0, 0], [0, 0, -1]))
    return RigCalibration({"top": top, "side": side}, base_point_world_mm=[0, 0, 0], insertion_axis_world=[1, 0, 0])
