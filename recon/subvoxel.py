"""Sub-voxel refinement of a carved backbone against the views' centerlines.

A carved backbone is quantized to the voxel grid: 100 voxels per axis over a
box as long as the robot make a voxel edge of 3-13 pixel footprints on the
wide suite (docs/paper-method.md). Its lateral position is averaged over many
voxels, but a bias of a voxel remains where the carved cloud is lopsided,
and the tip is where the last voxel column ends: up to a voxel short or long.
The views' centerlines are pixel-accurate, so the curve is moved onto them:

* **Across the curve.** Each backbone point ``P`` projects to ``u_v`` in view
  ``v``, whose nearest centerline pixel is ``f_v``; with ``n_v`` the image
  normal of the projected curve and ``J_v`` the projection's Jacobian, the
  step ``dP`` solves ``n_v . (J_v dP) = n_v . (f_v - u_v)`` for every view,
  with no motion along the 3-D tangent (damped least squares: where the curve
  runs within an epipolar plane the views constrain one direction only, and
  the point stays put in the other). Steps are capped at a voxel and smoothed
  along the curve, which averages the pixel grid of the feet.
* **At the tip.** Each view's silhouette (where the caller gives them; else
  its centerline) is followed along the projected tangent from the
  reprojected tip until it ends (forward, or backward when the tip
  overshoots it), less the tube's end face beyond the tip; the tip moves
  along the 3-D tangent to the views' ends, weighted by how many px per mm
  each sees along it, capped at six voxels. The silhouette, not the
  centerline: a two-disk erosion ends a thin tube's centerline up to 16 px
  before its tip (wide-4-15 frame 2, a plain backdrop: the tip 8.5
  footprints short).

World coordinates in mm, image coordinates in px (OpenCV convention).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from .geometry import arc_length, resample_polyline
from .morphology import near_mask

__all__ = ["SubvoxelParams", "refine_backbone"]


@dataclass(frozen=True)
class SubvoxelParams:
    """Parameters of :func:`refine_backbone`.

    Attributes
    ----------
    iterations : int
        Passes of the across-curve step (0: only the tip).
    max_step_voxels : float
        Cap of one point's step per pass, in largest voxel edges.
    max_foot_px : float
        A centerline pixel farther than this from a reprojected point (px) is
        not its foot: that view does not move the point (a gap in its
        centerline, a bridged stretch).
    smooth_passes : int
        Passes of a [1, 2, 1] / 4 filter over the steps along the curve.
    max_tip_voxels : float
        Cap of the tip's move along the tangent, in largest voxel edges. The
        carved tip of a thin tube ends up to 3-4 mm (5 voxels) short where
        its silhouettes run on (wide-4-15 frame 2).
    tip_from_silhouette : bool
        Place the tip at the silhouettes' ends (where :func:`refine_backbone`
        is given them), not the centerlines'.
    on_centerline_px : float
        A sample is on a view's centerline when one lies within this (px).
    tip_end_px, tip_end_per_disk : float
        Without silhouettes: how far the tube's end lies beyond its centerline's end (px):
        ``tip_end_px + tip_end_per_disk * r``, with ``r`` the radius (px) of
        the disk whose erosion gave the tip's centerline (an erosion shortens
        a tube's end by up to its radius). Fitted to the medians per disk
        radius over the good frames of wide seeds 2 and 3 (1 px disks: 0.8-1.0
        px, 4 px: 1.7-2.1, 9-10 px: 3-8; 10-90 % about +-2 px).
    """

    iterations: int = 2
    max_step_voxels: float = 1.0
    max_foot_px: float = 6.0
    smooth_passes: int = 3
    max_tip_voxels: float = 6.0
    on_centerline_px: float = 1.5
    tip_end_px: float = 0.5
    tip_end_per_disk: float = 0.5
    tip_from_silhouette: bool = True


class _View:
    """One camera's centerline pixels, for nearest-pixel queries, and its silhouette where given (None: not given)."""

    def __init__(self, camera, centerline: np.ndarray, silhouette: np.ndarray | None = None):
        nz = cv2.findNonZero((np.asarray(centerline) > 0).astype(np.uint8))
        self.camera = camera
        self.silhouette = silhouette
        self.ok = nz is not None
        if self.ok:
            self.pixels = nz.reshape(-1, 2).astype(np.float64)
            self.tree = cKDTree(self.pixels)

    def lookup(self, uv: np.ndarray) -> tuple:
        """Distance to the centerline (px) and the nearest centerline pixel (px) at each ``uv``; inf / NaN where not finite."""
        ok = np.all(np.isfinite(uv), axis=1)
        d = np.full(len(uv), np.inf)
        f = np.full((len(uv), 2), np.nan)
        if ok.any():
            dd, i = self.tree.query(uv[ok])
            d[ok] = dd
            f[ok] = self.pixels[i]
        return d, f


def _tangents(points: np.ndarray) -> np.ndarray:
    t = np.gradient(points, axis=0)
    return t / np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-12)


def _smooth(x: np.ndarray, passes: int) -> np.ndarray:
    for _ in range(passes):
        if len(x) < 3:
            break
        y = x.copy()
        y[1:-1] = 0.25 * x[:-2] + 0.5 * x[1:-1] + 0.25 * x[2:]
        x = y
    return x


def _across_step(views: list, points: np.ndarray, voxel_mm: float, params: SubvoxelParams) -> np.ndarray:
    """One pass of the across-curve step (mm, (n, 3))."""
    n = len(points)
    T = _tangents(points)
    A = np.zeros((n, 3, 3))
    b = np.zeros((n, 3))
    for v in views:
        uv, J = v.camera.project_jacobian(points)
        d, foot = v.lookup(uv)
        t2 = np.einsum("nij,nj->ni", J, T)
        t2 /= np.maximum(np.linalg.norm(t2, axis=1, keepdims=True), 1e-12)
        nrm = np.stack([-t2[:, 1], t2[:, 0]], axis=1)
        rel = np.nan_to_num(foot - uv)
        off = np.einsum("ni,ni->n", nrm, rel)
        # A foot that lies along the curve, not across it, is a centerline's end or the edge of
        # a gap in it: it does not say where the curve is across.
        use = np.isfinite(d) & (d <= params.max_foot_px) & (np.abs(np.einsum("ni,ni->n", t2, rel)) <= np.maximum(1.0, np.abs(off)))
        off = np.where(use, off, 0.0)
        a = np.einsum("ni,nij->nj", nrm, J) * use[:, None]
        A += a[:, :, None] * a[:, None, :]
        b += a * off[:, None]
    scale = np.trace(A, axis1=1, axis2=2)[:, None, None] / 3.0 + 1e-9
    # No motion along the tangent; a small isotropic damping for the direction no view constrains.
    A += scale * (T[:, :, None] * T[:, None, :] + 1e-2 * np.eye(3)[None])
    step = np.linalg.solve(A, b[:, :, None])[:, :, 0]
    cap = params.max_step_voxels * voxel_mm
    norm = np.linalg.norm(step, axis=1, keepdims=True)
    step *= np.minimum(1.0, cap / np.maximum(norm, 1e-12))
    return _smooth(step, params.smooth_passes)


def _tip_reach_mm(view: _View, tip: np.ndarray, tangent: np.ndarray, max_mm: float, on_px: float) -> tuple:
    """Signed distance (mm along the 3-D tangent) from the tip to where this view's centerline ends (NaN: no say),
    and the view's px per mm along the tangent.

    A tip beyond the centerline's end has that end as its nearest centerline
    pixel. Otherwise the centerline is walked from the tip in 1 px steps
    along the projected tangent, each step re-centred on the nearest
    centerline pixel (a straight walk leaves a curving centerline), while one
    lies within ``on_px``; the end is the last pixel's position along the
    tangent.
    """
    uv, J = view.camera.project_jacobian(tip[None])
    dir_px = J[0] @ tangent
    speed = float(np.linalg.norm(dir_px))  # px per mm along the tangent
    if not np.all(np.isfinite(uv)) or speed < 0.2:
        return np.nan, speed  # the tangent runs nearly along this camera's ray: the view cannot place the tip
    unit = dir_px / speed
    d, foot = view.lookup(uv)
    if not d[0] <= on_px + 1.0:
        return (np.nan if not np.isfinite(d[0]) else float(np.clip((foot[0] - uv[0]) @ unit / speed, -max_mm, max_mm))), speed
    last = foot[0]
    for _ in range(int(np.ceil(max_mm * speed)) + 1):
        d, f = view.lookup(np.stack([last + unit, last + 2.0 * unit]))  # 1 px on; 2 px where 1 px rounds back
        ahead = (d <= on_px) & ((f - last) @ unit > 0.25)
        if not ahead.any():
            break
        last = f[int(np.argmax(ahead))]
    return float(np.clip((last - uv[0]) @ unit / speed, -max_mm, max_mm)), speed


def _silhouette_reach_mm(camera, silhouette: np.ndarray, tip: np.ndarray, tangent: np.ndarray, max_mm: float,
                         tip_radius_mm: float = 0.0) -> tuple:
    """Signed distance (mm along the 3-D tangent) from the tip to where the view's silhouette ends (NaN: no
    say), and the view's px per mm along the tangent.

    The silhouette is read every 0.5 px along the projected tangent's line through the tip, each point with
    its 3x3 neighbourhood (a curving tube leaves the line by a pixel): from the tip on, where the tip is on
    it, to its last point before a gap of a pixel; else back to the nearest point on it. Less the pixel the
    neighbourhood reaches and the end face beyond the tip (``tip_radius_mm`` times
    :meth:`recon.camera.Camera.ray_cosine`, at the tip's px per mm).
    """
    uv, J = camera.project_jacobian(tip[None])
    dir_px = J[0] @ tangent
    speed = float(np.linalg.norm(dir_px))
    if not np.all(np.isfinite(uv)) or speed < 0.2:
        return np.nan, speed  # the tangent runs nearly along this camera's ray: the view cannot place the tip
    n = float(np.ceil(max_mm * speed)) + 3.0
    k = np.arange(-n, n + 0.25, 0.5)
    on = near_mask(silhouette, uv[0][None] + k[:, None] * (dir_px / speed)[None], 1.5)
    i0 = int(np.searchsorted(k, 0.0))
    if on[i0]:
        gap = ~on[i0 + 1:-1] & ~on[i0 + 2:]
        stop = i0 + 1 + int(np.argmax(gap)) if gap.any() else len(k)
        j = int(np.flatnonzero(on[:stop])[-1])
    elif on[:i0].any():
        j = int(np.flatnonzero(on[:i0])[-1])
    else:
        return np.nan, speed
    # The walk reads each point's 3x3 neighbourhood: it ends a pixel beyond the silhouette.
    face_px = tip_radius_mm * camera.ray_cosine(tip, tangent) / camera.mm_per_pixel_at(tip)
    end_px = k[j] - 1.0 - face_px
    return float(np.clip(end_px / speed, -max_mm, max_mm)), speed


def _tip_move_mm(views: list, end_px: list, tip: np.ndarray, tangent: np.ndarray, max_mm: float, params: SubvoxelParams,
                 tip_radius_mm: float = 0.0) -> float:
    """How far (mm) to move the tip along ``tangent``: the views' ends, weighted by their px per mm; NaN: none has a say.

    Each view's end is its silhouette's end (:func:`_silhouette_reach_mm`, where the view has one and
    ``tip_from_silhouette``), else its centerline's end plus ``end_px`` (px), weighted by
    the square of its px per mm along the tangent: a view that sees the tip
    foreshortened places it poorly (1 px is 1 mm at 1 px/mm). Not the
    nearest end: a view that lost the tube early is the tip check's
    (:func:`recon.paper.centerline_beyond_tip_px`), and the nearest end made
    the tip worse on the wide suite.
    """
    ends, weights = [], []
    for v, e in zip(views, end_px):
        if params.tip_from_silhouette and v.silhouette is not None:
            (reach, speed), e = _silhouette_reach_mm(v.camera, v.silhouette, tip, tangent, max_mm, tip_radius_mm), 0.0
        else:
            reach, speed = _tip_reach_mm(v, tip, tangent, max_mm, params.on_centerline_px)
        if np.isfinite(reach):
            ends.append(reach + e / speed)
            weights.append(speed * speed)
    if not ends:
        return np.nan
    return float(np.clip(np.average(ends, weights=weights), -max_mm, max_mm))


def _end_tangent(points: np.ndarray, baseline_mm: float) -> np.ndarray:
    """Unit direction of the curve's last ``baseline_mm`` (at most a third of it): a chord, not a noisy last step."""
    s = arc_length(points)
    k = int(np.searchsorted(s, s[-1] - min(baseline_mm, s[-1] / 3.0), side="right")) - 1
    d = points[-1] - points[max(0, min(k, len(points) - 2))]
    return d / max(float(np.linalg.norm(d)), 1e-12)


def _move_tip(points: np.ndarray, tangent: np.ndarray, reach_mm: float) -> np.ndarray:
    """The curve extended along its end tangent by ``reach_mm`` (> 0) or cut back by it (< 0)."""
    if reach_mm > 0:
        return np.vstack([points, points[-1] + reach_mm * tangent])
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    s = arc_length(points)
    cut = s[-1] + reach_mm
    if cut <= 0.5 * s[-1]:
        return points  # more than half the robot: not a tip correction
    k = int(np.searchsorted(s, cut))
    f = (cut - s[k - 1]) / max(seg[k - 1], 1e-12)
    return np.vstack([points[:k], points[k - 1] + f * (points[k] - points[k - 1])])


def refine_backbone(cameras, centerlines, points_world_mm, voxel_size_mm, params: SubvoxelParams = SubvoxelParams(),
                    erosion_radii_px=None, silhouettes=None, tip_radius_mm: float = 0.0) -> np.ndarray:
    """Move a carved backbone onto the views' centerlines (across the curve) and its tip to where they end.

    Parameters
    ----------
    cameras : sequence of recon.camera.Camera
    centerlines : sequence of (H, W) arrays
        Each camera's centerline (nonzero on it), in the same order.
    points_world_mm : (n, 3) array
        The backbone, base first (world, mm), points about evenly spaced.
    voxel_size_mm : float or (3,) array
        The carving grid's voxel edges (mm); the largest caps the steps.
    params : SubvoxelParams
    erosion_radii_px : sequence of float, optional
        Per camera, the radius (px) of the disk whose erosion gave the
        centerline at the tip (0 for a centerline that is not eroded); sets
        how far beyond its end the tube ends (``tip_end_per_disk``).
    silhouettes : sequence of (H, W) arrays, optional
        Each camera's silhouette (nonzero on the robot), in the same order:
        where given, the tip moves to their ends (``tip_from_silhouette``).
    tip_radius_mm : float
        The tube's radius at the tip (mm): its flat end face reaches
        ``r |t . ray|`` beyond the tip in a view, which the silhouette's end
        includes (wide-2-14 frame 1: 7.5 px for a tube 17 px in radius).

    Returns
    -------
    (m, 3) array
        The refined backbone (world, mm), base first; ``m`` is ``n`` or
        differs by the tip's extension or cut.
    """
    pts = np.asarray(points_world_mm, np.float64).copy()
    if len(pts) < 3:
        return pts
    voxel = float(np.max(voxel_size_mm))
    radii = [0.0] * len(cameras) if erosion_radii_px is None else [float(r or 0.0) for r in erosion_radii_px]
    views, end_px = [], []
    sils = [None] * len(cameras) if silhouettes is None else list(silhouettes)
    for c, cl, r, sil in zip(cameras, centerlines, radii, sils):
        v = _View(c, cl, sil)
        if v.ok:
            views.append(v)
            end_px.append(params.tip_end_px + params.tip_end_per_disk * r)
    if not views:
        return pts
    for _ in range(params.iterations):
        pts = pts + _across_step(views, pts, voxel, params)
    tangent = _end_tangent(pts, max(1.0, voxel))
    r = _tip_move_mm(views, end_px, pts[-1], tangent, params.max_tip_voxels * voxel, params, tip_radius_mm)
    if np.isfinite(r):
        if r > 1e-6:
            step = float(np.median(np.linalg.norm(np.diff(pts, axis=0), axis=1)))
            pts = resample_polyline(_move_tip(pts, tangent, r), max(step, 1e-3))
            pts = pts + _across_step(views, pts, voxel, params)  # the straight extension onto the centerlines
        elif r < -1e-6:
            pts = _move_tip(pts, tangent, r)
    return pts
