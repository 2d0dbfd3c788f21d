"""Voxel carving against synthetic orthogonal views of known 3-D curves."""
import cv2
import numpy as np
import pytest
from scipy.ndimage import distance_transform_edt
from scipy.spatial import cKDTree

from recon.camera import Camera
from recon.carving import CarvingParams, bounding_box, carve, rig_center
from recon.errors import FrameError
from recon.geometry import look_at

K = np.array([[2580.0, 0.0, 511.5], [0.0, 2580.0, 383.5], [0.0, 0.0, 1.0]])


def cameras(dist=(0, 0, 0, 0, 0)):
    side = Camera("side", 1024, 768, K, dist=dist, T_cam_world=look_at([50, -300, 0], [50, 0, 0], [0, 0, -1]))
    top = Camera("top", 1024, 768, K, dist=dist, T_cam_world=look_at([50, 0, 300], [50, 0, 0], [0, -1, 0]))
    return [side, top]


def line(n=800):
    t = np.linspace(0.0, 1.0, n)[:, None]
    return np.array([5.0, -3.0, 2.0]) + t * np.array([85.0, 12.0, -9.0])


def arc(n=1200):
    # 3-D arc of radius 60 mm over 50 degrees, tilted out of every world plane.
    # (Not further: where a curve runs square to the x axis that both views
    # share, two views cannot tell where along y and z it is, and carving
    # leaves a slab of ghost voxels; the paper's method has that limit.)
    a = np.linspace(0.0, np.radians(50.0), n)
    pts = np.stack([60 * np.sin(a), 60 * (1 - np.cos(a)) * 0.6, 60 * (1 - np.cos(a)) * 0.8], axis=1)
    return pts + np.array([10.0, -8.0, -12.0])


def raster(cam, curve, thickness=1):
    uv, _ = cam.project(curve)
    m = np.zeros((cam.height, cam.width), np.uint8)
    cv2.polylines(m, [np.round(uv * 16).astype(np.int32)], False, 1, thickness, cv2.LINE_8, 4)
    return m > 0


CURVES = {"line": line, "arc": arc}


@pytest.mark.parametrize("dist", [(0, 0, 0, 0, 0), (-0.1, 0.08, 0.001, -0.0015, 0.0)], ids=["pinhole", "distorted"])
@pytest.mark.parametrize("name", list(CURVES))
def test_carving_keeps_the_curve_and_only_the_curve(name, dist):
    cams = cameras(dist)
    curve = CURVES[name]()
    centerlines = [raster(c, curve) for c in cams]
    silhouettes = [raster(c, curve, thickness=13) for c in cams]
    box = bounding_box(cams, silhouettes)
    lo, hi = box
    assert np.all(curve.min(axis=0) >= lo) and np.all(curve.max(axis=0) <= hi)
    res = carve(cams, centerlines, box, CarvingParams(resolution=100))
    voxel = res.voxel_size_mm.max()
    np.testing.assert_allclose(res.voxel_size_mm, (hi - lo) / 100)
    assert res.points_mm.shape[0] == res.n_after_view[-1] > 0
    assert res.n_after_view[0] >= res.n_after_view[1]
    # Every curve point has a surviving voxel within one voxel...
    d_curve, _ = cKDTree(res.points_mm).query(curve)
    assert d_curve.max() <= voxel
    # ...and survivors lie within about one voxel of the curve. A survivor
    # projects within the footprint radius of the centerline in both views;
    # where the two footprint bands cross, their corners are up to ~sqrt(2)
    # times that radius off the curve.
    d_vox, _ = cKDTree(curve).query(res.points_mm)
    assert np.percentile(d_vox, 95) <= voxel
    assert d_vox.max() <= 1.5 * voxel


@pytest.mark.parametrize("name", list(CURVES))
def test_carving_matches_brute_force_projection(name):
    """Coarse-to-fine float32 carving = projecting every voxel with Camera.project."""
    cams = cameras((-0.1, 0.08, 0.001, -0.0015, 0.0))
    curve = CURVES[name]()
    centerlines = [raster(c, curve) for c in cams]
    box = bounding_box(cams, [raster(c, curve, thickness=13) for c in cams])
    params = CarvingParams(resolution=100)
    res = carve(cams, centerlines, box, params)

    lo, hi = box
    size = (hi - lo) / params.resolution
    axes = [lo[a] + (np.arange(params.resolution) + 0.5) * size[a] for a in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    radius_mm = 0.5 * np.linalg.norm(size)
    within = []  # per view: distance to the centerline (px) and footprint radius (px)
    for cam, m in zip(cams, centerlines):
        uv, z = cam.project(grid)
        iu, iv = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int)
        inside = (iu >= 0) & (iu < cam.width) & (iv >= 0) & (iv < cam.height)
        d = np.full(len(grid), np.inf)
        d[inside] = distance_transform_edt(~m)[iv[inside], iu[inside]]
        within.append((d, K[0, 0] * radius_mm / z + params.footprint_slack_px))

    def brute_force(views, scale, extra_px):
        keep = np.ones(len(grid), bool)
        for d, r in within[:views]:
            keep &= d <= scale * r + extra_px
        return keep

    # Equal up to the chamfer distance transform's ~2% error, after the first
    # view (where the coarse-to-fine search works) and after both.
    tight, loose = brute_force(1, 0.97, -0.1), brute_force(1, 1.03, 0.1)
    assert tight.sum() <= res.n_after_view[0] <= loose.sum()
    tight, loose = brute_force(2, 0.97, -0.1), brute_force(2, 1.03, 0.1)
    got = {tuple(p) for p in np.round(res.points_mm, 6)}
    assert {tuple(p) for p in np.round(grid[tight], 6)} <= got <= {tuple(p) for p in np.round(grid[loose], 6)}


def test_labels_from_label_images():
    cams = cameras()
    curve = line()
    half = len(curve) // 2
    labels = []
    for c in cams:
        lab = np.zeros((c.height, c.width), np.uint8)
        lab[raster(c, curve[:half])] = 1
        lab[raster(c, curve[half + 40 :])] = 2  # a gap at the step, as erosion leaves
        labels.append(lab)
    box = (curve.min(axis=0) - 2, curve.max(axis=0) + 2)
    res = carve(cams, [lab > 0 for lab in labels], box, centerline_labels=labels)
    _, idx = cKDTree(curve).query(res.points_mm)
    first, second = idx < half - 20, idx > half + 60
    assert np.all(res.labels[first] == 1) and np.all(res.labels[second] == 2)


def test_views_that_disagree():
    cams = cameras()
    curve = line()
    box = (curve.min(axis=0) - 2, curve.max(axis=0) + 2)
    # The views show different ends of the robot: no x is seen by both.
    with pytest.raises(FrameError, match=r"^top: no voxel projects onto the centerline \(of those left by side\)$"):
        carve(cams, [raster(cams[0], curve[:200]), raster(cams[1], curve[-200:])], box)


def test_empty_centerline():
    cams = cameras()
    m = raster(cams[0], line())
    with pytest.raises(FrameError, match=r"^top: empty centerline$"):
        carve(cams, [m, np.zeros_like(m)], (np.zeros(3), np.ones(3)))


def test_rig_center_of_orthogonal_cameras():
    np.testing.assert_allclose(rig_center(cameras()), [50.0, 0.0, 0.0], atol=1e-9)
