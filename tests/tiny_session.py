"""A tiny valid session written without rendering (32x24 px, 2 cameras, 2 tubes, 6 background pairs): the
template the input-validation tests spoil."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from recon.camera import Camera
from recon.geometry import look_at
from recon.rigcal import RigCalibration
from rig.session import SessionWriter

W, H = 32, 24
N_POINTS = 20


def tiny_rig() -> RigCalibration:
    """Two 32x24 px cameras 300 mm from the robot, side (-y) and top (+z)."""
    K = np.array([[40.0, 0, (W - 1) / 2], [0, 40.0, (H - 1) / 2], [0, 0, 1]])
    side = Camera("side", W, H, K, dist=np.zeros(5), T_cam_world=look_at([35, -300, 0], [35, 0, 0], [0, 0, -1]))
    top = Camera("top", W, H, K, dist=np.zeros(5), T_cam_world=look_at([35, 0, 300], [35, 0, 0], [0, -1, 0]))
    return RigCalibration({"side": side, "top": top})


def tiny_backbone(f: int) -> np.ndarray:
    """Frame ``f``'s backbone (world, mm): ``N_POINTS`` points along a gentle parabola, 40 + f mm long."""
    s = np.linspace(0.0, 40.0 + f, N_POINTS)
    return np.stack([s, 0.004 * s**2, np.zeros_like(s)], axis=1)


class TinyJoints:
    """Frame ``f``'s joints: outer tube 30 mm out, inner 40 + f mm, rotated 10 f deg."""

    def __init__(self, f: int):
        self.extension_mm, self.rotation_deg = (30.0, 40.0 + f), (0.0, 10.0 * f)


def write_tiny_session(d: Path, n_frames: int, truth) -> Path:
    """Write the session to ``d``: uniform gray frames, ``truth(rig, f)`` the ground-truth dict of frame ``f``."""
    rig = tiny_rig()
    img = np.full((H, W), 200, np.uint8)
    meta = {"robot": {"tubes": [{"outer_diameter_mm": 1.6}, {"outer_diameter_mm": 1.0}]}}
    with SessionWriter(d, rig, source="twin", n_tubes=2, meta=meta) as w:
        for b in range(6):
            w.add_background(b, {c: img for c in rig.names})
        for f in range(n_frames):
            w.add_frame(f, {c: img for c in rig.names}, t_s=0.1 * f, joints=TinyJoints(f), truth=truth(rig, f))
    return d
