"""A synthetic run directory (a small session written with the session writer, a hand-made summary).

The report and export tests read it, so they depend on no reconstruction method.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np

from recon.camera import Camera
from recon.geometry import look_at
from recon.metrics import point_to_polyline_distances
from recon.rigcal import RigCalibration
from rig.session import SessionWriter

__all__ = ["make_run_dir", "W", "H"]

W, H = 320, 240


def _rig() -> RigCalibration:
    K = np.array([[700.0, 0, (W - 1) / 2], [0, 700.0, (H - 1) / 2], [0, 0, 1]])
    target = [35.0, 0.0, 0.0]
    side = Camera("side", W, H, K, dist=[-0.05, 0.02, 0, 0, 0], T_cam_world=look_at([35, -300, 0], target, [0, 0, -1]))
    top = Camera("top", W, H, K, dist=[-0.05, 0.02, 0, 0, 0], T_cam_world=look_at([35, 0, 300], target, [0, -1, 0]))
    return RigCalibration({"side": side, "top": top}, base_point_world_mm=[0, 0, 0], insertion_axis_world=[1, 0, 0])


def _true_backbone(ext_mm: float) -> np.ndarray:
    s = np.arange(0.0, ext_mm + 1e-9, 0.1)
    return np.stack([s, 0.004 * s**2, 0.0005 * s**2], axis=1)


def _image(rig_cam: Camera, backbone: np.ndarray, rng) -> np.ndarray:
    img = rng.normal(200, 3, (H, W)).clip(0, 255).astype(np.uint8)
    uv, _ = rig_cam.project(backbone)
    cv2.polylines(img, [np.round(uv * 16).astype(np.int32).reshape(-1, 1, 2)], False, 70, 4, cv2.LINE_AA, 4)
    return img


def make_run_dir(root: Path, with_session: bool = True) -> Path:
    """A run directory: session (images, rig, truth), backbones.npz, frames/*.csv, summary.json; frame 2 failed."""
    rng = np.random.default_rng(7)
    rig = _rig()
    out = root / "run"
    (out / "frames").mkdir(parents=True)
    session = out / "session"
    records, backbones = [], {}
    with SessionWriter(session, rig, "twin", 2, meta={"scene_name": "synthetic",
                                                      "robot": {"tubes": [{"outer_diameter_mm": 1.6}, {"outer_diameter_mm": 1.0}]}}) as w:
        for b in range(2):
            w.add_background(b, {c: rng.normal(200, 3, (H, W)).clip(0, 255).astype(np.uint8) for c in rig.names})
        for f in range(3):
            tb = _true_backbone(40.0 + 8 * f)
            s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(tb, axis=0), axis=1))])
            radius = np.where(s < 30.0, 0.8, 0.5)
            truth = {"s_mm": s, "backbone_world_mm": tb, "outer_radius_mm": radius, "tip_world_mm": tb[-1]}
            for c in rig.names:
                truth[f"T_cam_world_{c}"] = rig[c].T_cam_world
                truth[f"centerline_px_{c}"] = rig[c].project(tb)[0]
            w.add_frame(f, {c: _image(rig[c], tb, rng) for c in rig.names}, t_s=2.0 * f, truth=truth)
            rec = {"frame": f, "t_s": 2.0 * f, "status": "ok", "reason": None}
            if f == 2:
                rec.update(status="failed", reason="side: no robot silhouette found (synthetic)")
            else:
                pts = tb[100::5] + rng.normal(0, 0.05, tb[100::5].shape)  # starts 10 mm from the base
                backbones[f] = pts
                np.savetxt(out / "frames" / f"{f:06d}.csv", pts, delimiter=",", fmt="%.4f", header="x_mm,y_mm,z_mm", comments="")
                d = point_to_polyline_distances(pts, tb)
                rec.update(ms=80.0 + 10 * f, n_points=len(pts), length_mm=float(np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1))),
                           tip_world_mm=pts[-1].tolist(), transition_s_mm=20.0,
                           timings_ms={"background": 20.0, "silhouette": 10.0 + f, "carve": 40.0, "backbone": 10.0, "total": 80.0 + f},
                           mean_error_mm=float(d.mean()) + 1.0, max_error_mm=10.0, tip_error_mm=float(np.linalg.norm(pts[-1] - tb[-1])),
                           length_error_mm=-10.0)
            records.append(rec)
    np.savez_compressed(out / "backbones.npz", frames=np.array(sorted(backbones)), **{f"frame_{i:06d}": p for i, p in backbones.items()})
    summary = {"format": "ctr-bench-summary", "version": 1, "method": "paper", "params": {"outer_tube_radius_mm": 0.8, "inner_tube_radius_mm": 0.5},
               "session": str(session), "frames": 3, "failed_frames": 1, "scored_frames": 2, "mm_per_px": 0.43,
               "mean_error_mm": 1.1, "max_error_mm": 10.0, "tip_error_mm_median": 0.1, "tip_error_mm_max": 0.2,
               "length_error_mm_median": -10.0, "ms_per_pair_median": 85.0, "ms_per_pair_p95": 89.5, "per_frame": records}
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    if not with_session:
        shutil.rmtree(session)
    return out
