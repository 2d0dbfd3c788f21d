"""Peer reconstruction methods from other projects, behind the interface of :mod:`recon.methods`.

Only used by ``ctr-bench bench`` to compare against; :mod:`recon` never
imports this module (nor the peers' packages).

``icp-epipolar``: :class:`icpReconstructor.epipolar_reconstruction.EpipolarReconstructor`
(Hoffmann et al., "An iterative closest point algorithm for marker-free 3D
shape registration of continuum robots", package ``icpReconstructor``, the
optional extra ``peers``). It binarizes each raw frame at a gray-level
threshold after a 5x5 grayscale opening, skeletonizes, orders the skeleton
from a start point, then casts epipolar lines from every ``interval``-th
skeleton pixel of camera 0 into camera 1 and triangulates with OpenCV.

The adapter feeds it the same frames and calibration as the other methods:

* cameras: ``A`` = K, ``dist`` as calibrated, ``P = K [R | t]`` with each
  camera's world pose, and ``R = I``, ``T = 0``, so its triangulated points
  come out in world coordinates (mm);
* its "tip estimator" file (a MATLAB .mat it reads per point) holds the
  robot base projected into each image as the start point and, as
  ``blank_idc``, the pixels that are dark in the mean background frame (the
  actuation unit, posts), which its ``real_image`` mode whitens before
  thresholding; the threshold is 0.8 x the median gray level of the mean
  background;
* its output rows ``(x, y, z, length)`` become the backbone, base first.

icpReconstructor 0.1.5 predates NumPy 2 and OpenCV 5: its skeleton walk
(``utils.find_longest_path``/``set_edges_branch``) calls ``int()`` on
one-element arrays, which NumPy 2.x rejects, and it passes single points to
``cv2.triangulatePoints`` as 1-D arrays, which OpenCV 5 reads as two 1-D
points; either way it fails on every frame. :func:`_compat_shims` swaps in
the same two functions with those conversions written for NumPy 2 and a
``triangulatePoints`` that reshapes 1-D points to 2x1 (no other change); the
bench says so when it lists the peer.
"""
from __future__ import annotations

import tempfile
import time
import types
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.io import savemat

from recon.errors import FrameError
from recon.paper import camera_order

__all__ = ["PEERS", "peer_status", "prepare_peer", "PeerResult"]

#: Peer method name -> (import name, description).
PEERS = {
    "icp-epipolar": ("icpReconstructor", "icpReconstructor 0.1.5 EpipolarReconstructor (threshold, skeleton, epipolar lines, OpenCV triangulation)"),
}


def peer_status(name: str) -> tuple[bool, str]:
    """``(available, reason)``: whether the peer's package imports here, and why not."""
    if name not in PEERS:
        return False, f"unknown peer {name!r}"
    try:
        import icpReconstructor.epipolar_reconstruction  # noqa: F401
    except ImportError as exc:
        return False, f"package icpReconstructor not importable ({exc}); install the extra: pip install 'ctr-bench[peers]' torch casadi"
    except Exception as exc:  # noqa: BLE001 - a broken install of a third-party package
        return False, f"icpReconstructor fails to import: {exc.__class__.__name__}: {exc}"
    return True, "available"


@dataclass(frozen=True, eq=False)
class PeerResult:
    """A peer's reconstruction of one frame pair (the attributes the bench reads)."""

    points_world_mm: np.ndarray
    tip_world_mm: np.ndarray
    length_mm: float
    transition_s_mm: float
    timings_ms: dict


def _compat_shims() -> None:
    """Make icpReconstructor 0.1.5 run under NumPy 2 and OpenCV 5 (same algorithm; see the module doc)."""
    import icpReconstructor.epipolar_reconstruction as er
    import icpReconstructor.utils as u

    if getattr(u.set_edges_branch, "_ctr_bench_shim", False):
        return

    def set_edges_branch(skeleton_pixels, current_index, has_edge, G, initial_index):
        bifurcation_points = []
        while True:
            current_pixel = skeleton_pixels[current_index, :]
            next_pixels_bool = (np.linalg.norm(skeleton_pixels - current_pixel, axis=1, ord=np.inf) == 1) & (~has_edge)
            next_pixels_idx = np.argwhere(next_pixels_bool)
            if not all(next_pixels_idx.shape):
                break
            for i in range(next_pixels_idx.shape[0]):
                j = int(next_pixels_idx[i, 0])
                if current_index == initial_index:
                    G.add_edge(int(current_index), j, weight=1e8)
                else:
                    G.add_edge(int(current_index), j)
                has_edge[j] = True
            if next_pixels_idx.shape[0] > 1:
                current_vectors = skeleton_pixels[current_index, :] - skeleton_pixels[current_index - 5:current_index, :]
                current_vector = np.mean(current_vectors / np.linalg.norm(current_vectors, axis=1)[:, None], axis=0) / np.linalg.norm(np.mean(current_vectors, axis=0))
                next_vectors = skeleton_pixels[next_pixels_idx[:, 0], :] - skeleton_pixels[current_index, :]
                next_vectors = next_vectors / np.linalg.norm(next_vectors, axis=1)[:, None]
                current_index = int(next_pixels_idx[np.argmax(next_vectors @ current_vector.T), 0])
                bifurcation_points.append(next_pixels_idx[next_pixels_idx[:, 0] != current_index, :])
            else:
                current_index = int(next_pixels_idx[0, 0])
        return bifurcation_points

    def find_longest_path(skeleton_pixels, initial_point):
        import networkx as nx

        G = nx.DiGraph()
        G.add_nodes_from(range(skeleton_pixels.shape[0]))
        has_edge = np.zeros((skeleton_pixels.shape[0],), dtype=bool)
        initial_index = int(np.argmin(np.linalg.norm(skeleton_pixels - initial_point, axis=1)))
        has_edge[initial_index] = True
        bifurcation_points = [[initial_index]]
        for bifurcation in bifurcation_points:
            current_index = int(np.asarray(bifurcation[0]).reshape(-1)[0])
            bifurcation_points.extend(set_edges_branch(skeleton_pixels, current_index, has_edge, G, initial_index))
        return skeleton_pixels[nx.dag_longest_path(G), :]

    def triangulatePoints(P0, P1, x0, x1, *args):
        x0 = np.asarray(x0, np.float64).reshape(2, -1)
        x1 = np.asarray(x1, np.float64).reshape(2, -1)
        return cv2.triangulatePoints(P0, P1, x0, x1, *args)

    proxy = types.SimpleNamespace(**{k: getattr(cv2, k) for k in dir(cv2) if not k.startswith("__")})
    proxy.triangulatePoints = triangulatePoints
    set_edges_branch._ctr_bench_shim = True
    u.set_edges_branch = set_edges_branch
    u.find_longest_path = find_longest_path
    er.find_longest_path = find_longest_path
    er.cv2 = proxy


def _projection(cam) -> np.ndarray:
    return cam.K @ cam.T_cam_world[:3, :]


def prepare_peer(name: str, rig, background_frames: dict, interval: int = 20):
    """The per-frame callable of peer ``name`` (raises ValueError when it is not available)."""
    ok, why = peer_status(name)
    if not ok:
        raise ValueError(why)

    from icpReconstructor.epipolar_reconstruction import EpipolarReconstructor

    _compat_shims()

    names = camera_order(rig.names)[:2]
    cams = [rig[n] for n in names]
    workdir = Path(tempfile.mkdtemp(prefix="ctr-bench-peer-"))
    params_files, thresholds = [], []
    for n, cam in zip(names, cams):
        mean = np.asarray(background_frames[n], np.float32).mean(axis=0)
        thr = float(0.8 * np.median(mean))
        dark = (mean < thr + 10.0).astype(np.uint8)
        dark = cv2.dilate(dark, np.ones((7, 7), np.uint8))
        base_uv, _ = cam.project(rig.base_point_world_mm[None])
        tip_uv, _ = cam.project(rig.base_point_world_mm[None] + 5.0 * rig.insertion_axis_world[None])
        # Keep the start point itself clear of the blanked region.
        bu, bv = np.rint(base_uv[0]).astype(int)
        ys, xs = np.nonzero(dark)
        keep = (xs - bu) ** 2 + (ys - bv) ** 2 > 6 ** 2
        blank = np.stack([xs[keep], ys[keep]], axis=1).astype(np.int64)
        path = workdir / f"tip_{n}.mat"
        d = tip_uv[0] - base_uv[0]
        savemat(path, {"p_start": base_uv[0][None, :], "exit_dir": (d / np.linalg.norm(d))[None, :], "blank_idc": blank})
        params_files.append(str(path))
        thresholds.append(thr)
    P0, P1 = _projection(cams[0]), _projection(cams[1])
    thr = float(np.mean(thresholds))

    def reconstruct(frames: dict) -> PeerResult:
        t0 = time.perf_counter()
        for n in names:
            if n not in frames or frames[n] is None:
                raise FrameError("no frame", n)
        imgs = [np.array(frames[n], dtype=np.uint8, copy=True) for n in names]
        rec = EpipolarReconstructor(
            imgs[0], imgs[1], cams[0].K, cams[1].K, cams[0].dist, cams[1].dist, P0, P1,
            np.eye(3), np.zeros(3), thr, params_files[0], params_files[1],
        )
        try:
            d0, d1, _, _ = rec.get_2D(plot=False, real_image=True)
            t1 = time.perf_counter()
            out = rec.get_3D(d0, d1, interval=interval, plot=False)
        except FrameError:
            raise
        except Exception as exc:  # noqa: BLE001 - the peer fails in its own ways; report them as frame failures
            raise FrameError(f"icp-epipolar failed: {exc.__class__.__name__}: {' '.join(str(exc).split())[:120]}") from None
        t2 = time.perf_counter()
        pts = np.asarray(out, float)[:, :3]
        if len(pts) < 2:
            raise FrameError("icp-epipolar returned fewer than 2 points")
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        return PeerResult(
            points_world_mm=pts,
            tip_world_mm=pts[-1].copy(),
            length_mm=float(seg.sum()),
            transition_s_mm=float("nan"),
            timings_ms={"get_2D": 1e3 * (t1 - t0), "get_3D": 1e3 * (t2 - t1), "total": 1e3 * (t2 - t0)},
        )

    return reconstruct
