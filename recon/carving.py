"""Two-stage voxel carving of the backbone from centerline images.

Section III-C of the paper: a 100 x 100 x 100 voxel volume is placed around
the robot "based on the dimensions of the silhouettes"; the voxels are
projected into the side camera and those off the centerline are carved away,
then the survivors are projected into the top camera and carved likewise.

Two points the paper leaves open are settled here:

* The box. :func:`bounding_box` intersects the cameras' viewing frusta of the
  silhouettes' bounding rectangles, then carves a coarse visual hull of the
  silhouettes in it and takes the hull's bounds plus a margin.
* "Off the centerline". A voxel (~1 mm) is far larger than a pixel (~0.12 mm)
  and a centerline is 1-3 px wide, so a voxel centre almost never projects
  exactly onto a centerline pixel. A voxel is kept when a centerline pixel
  lies within its projected footprint: the voxel's half-diagonal (mm) seen at
  its depth (px), tested against a distance transform of the centerline
  computed once per view.

World coordinates in mm; pixel coordinates with (0, 0) at the centre of the
top-left pixel (OpenCV). Projection applies the cameras' lens distortion
exactly as :meth:`recon.camera.Camera.project` does, in float32.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from .camera import Camera
from .distortion import distort_xy
from .errors import FrameError
from .geometry import transform_directions, transform_points

__all__ = ["CarvingParams", "CarveResult", "bounding_box", "carve", "rig_center"]


@dataclass(frozen=True)
class CarvingParams:
    """Parameters of :func:`bounding_box` and :func:`carve`.

    Attributes
    ----------
    resolution : int
        Voxels per axis of the carving volume (paper: 100).
    margin_mm : float
        Added on every side of the visual hull's bounds (mm).
    max_anisotropy : float
        The box's shorter sides are grown until no voxel edge is more than this
        many times shorter than the longest: a nearly straight robot would
        otherwise get 100 voxels across a few mm, i.e. thousands of survivors
        per mm of backbone.
    coarse_resolution : int
        Cells per axis of the coarse visual hull of :func:`bounding_box`.
    coarse_passes : int
        Coarse hulls computed, each in the previous one's box: the first box,
        from the frusta alone, can be several times larger than the robot.
    coarse_downsample : int
        The silhouettes are max-pooled by this factor for the coarse hull
        (cells are 10-50 px across; full resolution would only cost time).
    depth_range_mm : (float, float) or None
        Depth range (mm, along each camera's optical axis) searched for the
        robot. ``None``: 0.5 to 1.5 times the depth of the rig centre, the
        point nearest all optical axes.
    footprint_scale : float
        Footprint radius as a multiple of the voxel's half-diagonal.
    footprint_slack_px : float
        Added to the footprint radius (px): voxel centres are looked up at the
        nearest pixel, up to 0.71 px away.
    """

    resolution: int = 100
    margin_mm: float = 1.0
    max_anisotropy: float = 4.0
    coarse_resolution: int = 48
    coarse_passes: int = 2
    coarse_downsample: int = 4
    depth_range_mm: tuple | None = None
    footprint_scale: float = 1.0
    footprint_slack_px: float = 0.5

    def __post_init__(self):
        if int(self.resolution) < 2 or int(self.coarse_resolution) < 2:
            raise ValueError("CarvingParams: resolution and coarse_resolution must be >= 2")
        if self.max_anisotropy < 1.0:
            raise ValueError(f"CarvingParams.max_anisotropy must be >= 1, got {self.max_anisotropy}")
        if int(self.coarse_downsample) < 1:
            raise ValueError(f"CarvingParams.coarse_downsample must be >= 1, got {self.coarse_downsample}")


@dataclass(frozen=True, eq=False)
class CarveResult:
    """Voxels that survive carving.

    Attributes
    ----------
    points_mm : (n, 3) float64 array
        Surviving voxel centres (world, mm).
    labels : (n,) uint8 array
        Tube of each voxel: the label (1 outer, 2 inner, see
        :mod:`recon.centerline`) of the centerline pixel nearest to its
        projection, taken in the view where that pixel is nearest; 0 when no
        label images were given.
    voxel_size_mm : (3,) float64 array
        Voxel edge along world x, y, z (mm).
    box : tuple of (3,) arrays
        ``(lo_mm, hi_mm)``, the carved volume (world, mm).
    n_after_view : tuple of int
        Survivors after each view, in carving order.
    """

    points_mm: np.ndarray
    labels: np.ndarray
    voxel_size_mm: np.ndarray
    box: tuple
    n_after_view: tuple


# --------------------------------------------------------------- geometry


def rig_center(cameras) -> np.ndarray:
    """World point (mm) nearest, in least squares, to all cameras' optical axes.

    Parameters
    ----------
    cameras : sequence of recon.camera.Camera
        At least two cameras with non-parallel optical axes.

    Returns
    -------
    (3,) array
    """
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for cam in cameras:
        d = cam.T_cam_world[2, :3]  # optical axis in world = third row of R_cam_world
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ cam.center_world_mm
    if np.linalg.cond(A) > 1e8:
        raise ValueError("rig_center: the cameras' optical axes are parallel")
    return np.linalg.solve(A, b)


def _camera_depth(camera, point_world_mm) -> float:
    return float(camera.T_cam_world[2, :3] @ point_world_mm + camera.T_cam_world[2, 3])


def _frustum_box(camera, mask: np.ndarray, near: float, far: float) -> tuple[np.ndarray, np.ndarray]:
    """World AABB (mm) of the frustum of ``mask``'s bounding rectangle between two depths."""
    x, y, w, h = cv2.boundingRect(mask.view(np.uint8))
    # A few px of slack: lens distortion bends the rectangle's sides.
    s = 0.02 * max(camera.width, camera.height)
    uv = np.array([[x - 0.5 - s, y - 0.5 - s], [x + w - 0.5 + s, y - 0.5 - s],
                   [x - 0.5 - s, y + h - 0.5 + s], [x + w - 0.5 + s, y + h - 0.5 + s]])
    xy = camera.pixels_to_normalized(uv)
    rays = np.concatenate([xy, np.ones((4, 1))], axis=1)
    pts_cam = np.concatenate([rays * near, rays * far])
    pts = transform_points(camera.T_world_cam, pts_cam)
    return pts.min(axis=0), pts.max(axis=0)


def _voxel_axes(lo: np.ndarray, hi: np.ndarray, n: int) -> tuple[list, np.ndarray]:
    size = (hi - lo) / n
    return [lo[a] + (np.arange(n) + 0.5) * size[a] for a in range(3)], size


# ------------------------------------------------------ footprint testing


@dataclass(frozen=True, eq=False)
class _View:
    """One camera prepared for footprint tests against one binary image.

    ``dist`` is the distance (px) to the nearest set pixel over the image
    crop ``[x0, x0 + w) x [y0, y0 + h)``, framed by a 1-px border of +inf so
    that anything projecting outside the crop fails every test. ``tube``,
    when label images are given, is the label of that nearest pixel.
    """

    camera: object
    dist: np.ndarray
    x0: int
    y0: int
    focal_px: float
    r2_max: float
    tube: np.ndarray | None = None


def _prepare_view(camera, mask: np.ndarray, pad_px: float, labels: np.ndarray | None = None) -> _View:
    """Distance map (and nearest-pixel labels) of ``mask`` over its bounding box grown by ``pad_px``."""
    H, W = mask.shape
    x, y, w, h = cv2.boundingRect(mask.view(np.uint8))
    pad = int(np.ceil(pad_px)) + 2
    x0, y0 = max(x - pad, 0), max(y - pad, 0)
    x1, y1 = min(x + w + pad, W), min(y + h + pad, H)
    # distanceTransform measures the distance to the nearest zero pixel.
    src = np.where(mask[y0:y1, x0:x1], np.uint8(0), np.uint8(1))
    dist = np.full((y1 - y0 + 2, x1 - x0 + 2), np.inf, np.float32)
    tube = None
    if labels is None:
        dist[1:-1, 1:-1] = cv2.distanceTransform(src, cv2.DIST_L2, cv2.DIST_MASK_5)
    else:
        dist[1:-1, 1:-1], nearest = cv2.distanceTransformWithLabels(
            src, cv2.DIST_L2, cv2.DIST_MASK_5, labelType=cv2.DIST_LABEL_PIXEL
        )
        # OpenCV numbers the zero pixels 1, 2, ... in raster order, the order
        # of boolean indexing: entry i of ``of_pixel`` is zero pixel i's label.
        zero = src == 0
        if not np.array_equal(nearest[zero], np.arange(1, np.count_nonzero(zero) + 1)):
            raise RuntimeError("cv2.distanceTransformWithLabels numbered pixels in an unexpected order")
        of_pixel = np.concatenate([[0], labels[y0:y1, x0:x1][zero]]).astype(np.uint8)
        tube = np.zeros(dist.shape, np.uint8)
        tube[1:-1, 1:-1] = of_pixel[nearest]
    r2_max = _seen_r2_max(tuple(camera.K.ravel()), tuple(camera.dist), W, H)
    return _View(camera, dist, x0, y0, float(np.sqrt(camera.K[0, 0] * camera.K[1, 1])), r2_max, tube)


@functools.lru_cache(maxsize=64)
def _seen_r2_max(K: tuple, dist: tuple, width: int, height: int) -> float:
    """Largest ideal normalized r^2 a camera is taken to see.

    Guards against the distortion polynomial folding points far outside the
    field of view back into the image: beyond 1.2x the image corners' radius
    (normalized, undistorted) a point counts as unseen. Cached: undistorting
    iterates, and every frame asks again for the same cameras.
    """
    cam = Camera("guard", width, height, np.reshape(K, (3, 3)), dist=np.asarray(dist))
    corners = np.array([[-0.5, -0.5], [width - 0.5, -0.5], [-0.5, height - 0.5], [width - 0.5, height - 0.5]])
    return float((cam.pixels_to_normalized(corners) ** 2).sum(axis=1).max()) * 1.44


def _pixel_index(view: _View, X, Y, Z) -> tuple[np.ndarray, np.ndarray]:
    """Flat index into ``view.dist`` of each point's projection, and whether the camera sees it.

    ``X, Y, Z`` are float32 camera-frame coordinates (mm) of any common shape;
    ``X`` and ``Y`` are consumed (overwritten) to save allocations. Points
    the camera does not see index the +inf border.
    """
    cam = view.camera
    d = cam.dist14.astype(np.float32)
    K = cam.K.astype(np.float32)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        seen = Z > np.float32(1e-6)
        inv_z = np.reciprocal(Z)
        xn = np.multiply(X, inv_z, out=X)
        yn = np.multiply(Y, inv_z, out=Y)
        r2 = xn * xn
        r2 += yn * yn
        seen &= r2 <= np.float32(view.r2_max)
        if np.any(d):
            # float32 coefficients keep the arithmetic in float32 (half the memory traffic).
            xn, yn = distort_xy(xn, yn, d, cam.tilt[0].astype(np.float32))
        # Pixel coordinates, then column/row in the bordered crop: floor(u + 0.5) - x0 + 1.
        u = xn * K[0, 0]
        if K[0, 1]:
            u += yn * K[0, 1]
        u += np.float32(K[0, 2] + 1.5 - view.x0)
        v = np.multiply(yn, K[1, 1], out=yn)
        v += np.float32(K[1, 2] + 1.5 - view.y0)
        h, w = view.dist.shape
        # Points not seen go to the border; fmax/fmin also send NaN there.
        u[~seen] = -1.0
        iu = np.fmin(np.fmax(u, np.float32(0.0), out=u), np.float32(w - 1), out=u).astype(np.int32)
        iv = np.fmin(np.fmax(v, np.float32(0.0), out=v), np.float32(h - 1), out=v).astype(np.int32)
        iv *= w
        iv += iu
    return iv, seen


def _footprint_hits(view: _View, X, Y, Z, radius_mm: float, slack_px: float) -> np.ndarray:
    """Whether a set pixel lies within ``radius_mm`` (seen at depth) + slack of each point's projection.

    ``X, Y, Z`` are float32 camera-frame coordinates (mm) of any common shape;
    ``X`` and ``Y`` are consumed.
    """
    idx, seen = _pixel_index(view, X, Y, Z)
    d = view.dist.ravel().take(idx)
    # d <= f r / Z + slack  <=>  (d - slack) Z <= f r  for Z > 0; points
    # behind the camera (inf * -Z = -inf) are removed by ``seen``.
    d -= np.float32(slack_px)
    d *= Z
    hits = d <= np.float32(view.focal_px * radius_mm)
    hits &= seen
    return hits


def _grid_in_camera(camera, axes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera-frame coordinates (float32, (nx, ny, nz) each) of a world grid, separably."""
    R = camera.T_cam_world[:3, :3]
    t = camera.T_cam_world[:3, 3]
    xs, ys, zs = axes
    out = []
    for c in range(3):
        # R[c] . (x, y, z) + t[c] = (R[c,0] x + t[c]) + R[c,1] y + R[c,2] z, one 3-D add.
        xy = (R[c, 0] * xs + t[c])[:, None] + (R[c, 1] * ys)[None, :]
        out.append(np.add(xy.astype(np.float32)[:, :, None], (R[c, 2] * zs).astype(np.float32)[None, None, :]))
    return out[0], out[1], out[2]


def _points_in_camera(camera, points_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    pc = camera.world_to_camera(points_mm).astype(np.float32)
    return pc[:, 0].copy(), pc[:, 1].copy(), pc[:, 2].copy()


def _min_depth(camera, lo, hi) -> float:
    corners = np.array([[a, b, c] for a in (lo[0], hi[0]) for b in (lo[1], hi[1]) for c in (lo[2], hi[2])])
    z = camera.world_to_camera(corners)[:, 2]
    return float(z.min())


# Voxels per block: the ~30 float32 temporaries of a block stay in cache and
# come from numpy's small-allocation pool. Whole-grid arrays (4 MB each) cost
# more in page faults than in arithmetic.
_BLOCK = 32768


def _dense_grid_hits(view: _View, axes, radius_mm: float, slack_px: float) -> np.ndarray:
    """Footprint test of every voxel of a grid, in blocks of x-slabs; (nx, ny, nz) bool."""
    nx, ny, nz = (len(a) for a in axes)
    per = max(1, _BLOCK // (ny * nz))
    out = np.empty((nx, ny, nz), bool)
    for i in range(0, nx, per):
        X, Y, Z = _grid_in_camera(view.camera, (axes[0][i : i + per], axes[1], axes[2]))
        out[i : i + per] = _footprint_hits(view, X, Y, Z, radius_mm, slack_px)
    return out


# Coarse-to-fine: cells of _CELL^3 voxels are tested first with a radius
# grown by the cell's half-diagonal, and only voxels of passing cells are
# tested. The distance map is (nearly) 1-Lipschitz, so a voxel that passes
# lies in a passing cell: the result is the dense test's, at a fraction of
# the cost (the centerline of one view is a thin sheet through the grid).
_CELL = 4
# Covers the magnification of perspective within a cell and of the lens
# distortion, and the chamfer distance's ~2% error.
_CELL_SAFETY = 1.25


def _cell_radius_mm(radius_mm: float, step) -> float:
    """Radius (mm) of the cell test of :func:`_grid_hits` for voxels of edges ``step`` (mm)."""
    return _CELL_SAFETY * (radius_mm + 0.5 * (_CELL - 1) * float(np.linalg.norm(step)))


def _grid_hits(view: _View, axes, radius_mm: float, slack_px: float) -> np.ndarray:
    """Flat (C-order) indices of the grid voxels whose footprint hits ``view``, sorted."""
    shape = tuple(len(a) for a in axes)
    if min(shape) < 2 * _CELL:
        return np.flatnonzero(_dense_grid_hits(view, axes, radius_mm, slack_px))
    step = np.array([a[1] - a[0] for a in axes])
    ncell = [-(-m // _CELL) for m in shape]
    # Cell origins (first voxel) and cell centres, per axis (a partial last
    # cell is tested as if full: conservative).
    origins = [a[0] + np.arange(nc) * _CELL * d for a, nc, d in zip(axes, ncell, step)]
    centres = [o + 0.5 * (_CELL - 1) * d for o, d in zip(origins, step)]
    cell_radius = _cell_radius_mm(radius_mm, step)
    # +1.5 px: both the cell centre and the voxel are looked up at the nearest pixel.
    cells = np.argwhere(_dense_grid_hits(view, centres, cell_radius, slack_px + 1.5))
    # Voxels of the passing cells, separably again: camera coordinates of each
    # cell's origin (m, 3) plus those of the in-cell offsets (C^3, 3).
    org = np.stack([origins[a][cells[:, a]] for a in range(3)], axis=1)
    org_cam = transform_points(view.camera.T_cam_world, org).astype(np.float32)
    offs = np.stack(np.meshgrid(*(np.arange(_CELL),) * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    offs_cam = transform_directions(view.camera.T_cam_world, offs * step).astype(np.float32)
    strides = np.array([shape[1] * shape[2], shape[2], 1])
    base = (cells * _CELL) @ strides
    off_flat = offs @ strides
    partial = any(m % _CELL for m in shape)
    rows = max(1, _BLOCK // offs.shape[0])
    found = []
    for r in range(0, cells.shape[0], rows):
        sl = slice(r, r + rows)
        X, Y, Z = (np.add(org_cam[sl, c : c + 1], offs_cam[None, :, c]) for c in range(3))
        hit = _footprint_hits(view, X, Y, Z, radius_mm, slack_px)
        if partial:
            hit &= ((cells[sl, None, :] * _CELL + offs[None, :, :]) < np.array(shape)).all(axis=2)
        found.append((base[sl, None] + off_flat[None, :])[hit])
    return np.sort(np.concatenate(found)) if found else np.zeros(0, np.int64)


def _point_hits(view: _View, pts: np.ndarray, radius_mm: float, slack_px: float) -> np.ndarray:
    """Footprint test of world points (n, 3) mm, in blocks; (n,) bool."""
    out = np.empty(pts.shape[0], bool)
    for i in range(0, pts.shape[0], _BLOCK):
        out[i : i + _BLOCK] = _footprint_hits(view, *_points_in_camera(view.camera, pts[i : i + _BLOCK]), radius_mm, slack_px)
    return out


def _hull(cameras, masks, lo, hi, n, radius_scale, slack_px, label_images=None):
    """Voxels of an n^3 grid over [lo, hi] whose footprint hits every mask, carved view by view.

    Returns the survivors' centres (m, 3) mm, the voxel size (3,) mm, the
    number of survivors after each view (stops early at zero) and the views.
    """
    axes, size = _voxel_axes(lo, hi, n)
    radius_mm = radius_scale * 0.5 * float(np.linalg.norm(size))
    # Distance maps cover what the widest test (a cell's) can reach: beyond
    # their crop everything counts as a miss, which would break the cell
    # test's guarantee.
    reach_mm = max(radius_mm, _cell_radius_mm(radius_mm, size))
    views = []
    for i, (cam, m) in enumerate(zip(cameras, masks)):
        z_min = _min_depth(cam, lo, hi)
        if z_min <= 0:
            raise ValueError(f"carving: the box reaches behind camera {cam.name!r}")
        lab = None if label_images is None else np.asarray(label_images[i])
        views.append(_prepare_view(cam, m, cam.K[0, 0] * reach_mm / z_min + slack_px + 2.0, lab))
    idx = _grid_hits(views[0], axes, radius_mm, slack_px)
    counts = [idx.size]
    i, j, k = np.unravel_index(idx, (n, n, n))
    pts = np.stack([axes[0][i], axes[1][j], axes[2][k]], axis=1)
    for view in views[1:]:
        if pts.shape[0] == 0:
            break
        pts = pts[_point_hits(view, pts, radius_mm, slack_px)]
        counts.append(pts.shape[0])
    return pts, size, counts, views


# ------------------------------------------------------------- public API


def _check_inputs(cameras, masks, what: str):
    if len(cameras) < 2 or len(cameras) != len(masks):
        raise ValueError(f"need two or more cameras and one {what} per camera, got {len(cameras)} and {len(masks)}")
    out = []
    for cam, m in zip(cameras, masks):
        m = np.asarray(m)
        if m.shape != (cam.height, cam.width):
            raise FrameError(f"{what} is {m.shape[1]}x{m.shape[0]} but the camera is {cam.width}x{cam.height}", cam.name)
        m = np.ascontiguousarray(m, dtype=bool)
        if not m.any():
            raise FrameError(f"empty {what}", cam.name)
        out.append(m)
    return out


def _max_pool(mask: np.ndarray, s: int) -> np.ndarray:
    """``mask`` (H, W) bool max-pooled by ``s`` (padded up to a multiple of ``s``)."""
    H, W = mask.shape
    Hp, Wp = -(-H // s) * s, -(-W // s) * s
    m8 = np.zeros((Hp, Wp), np.uint8)
    m8[:H, :W] = mask.view(np.uint8) * np.uint8(255)
    # INTER_AREA with an integer factor averages s x s blocks: > 0 is a max-pool.
    return cv2.resize(m8, (Wp // s, Hp // s), interpolation=cv2.INTER_AREA) > 0


def bounding_box(cameras, silhouettes, params: CarvingParams = CarvingParams()) -> tuple[np.ndarray, np.ndarray]:
    """Box (world, mm) around the robot, from its silhouettes.

    The search starts from the intersection of the cameras' viewing frusta of
    the silhouettes' bounding rectangles over the depth range; a coarse visual
    hull of the (max-pooled) silhouettes is carved in it, ``coarse_passes``
    times, each in the previous hull's bounds. The box is the last hull's
    bounds plus ``margin_mm``, its short sides grown to ``max_anisotropy``.

    Parameters
    ----------
    cameras : sequence of recon.camera.Camera
    silhouettes : sequence of (H, W) bool arrays
        One per camera, same order.
    params : CarvingParams

    Returns
    -------
    lo_mm, hi_mm : (3,) arrays
        Opposite corners of the box (world, mm).

    Raises
    ------
    FrameError
        An empty silhouette, or silhouettes that no common volume explains.
    """
    masks = _check_inputs(cameras, silhouettes, "silhouette")
    centre = rig_center(cameras)
    boxes = []
    for cam, m in zip(cameras, masks):
        if params.depth_range_mm is not None:
            near, far = params.depth_range_mm
        else:
            d = _camera_depth(cam, centre)
            near, far = 0.5 * d, 1.5 * d
        boxes.append(_frustum_box(cam, m, near, far))
    lo = np.max([b[0] for b in boxes], axis=0)
    hi = np.min([b[1] for b in boxes], axis=0)
    disjoint = "the views' silhouettes do not overlap in space (check the calibration)"
    if np.any(hi <= lo):
        raise FrameError(disjoint)
    s = int(params.coarse_downsample)
    pooled_cams = [cam.scaled(1.0 / s) if s > 1 else cam for cam in cameras]
    pooled = [_max_pool(m, s) if s > 1 else m for m in masks]
    # Slack (pooled px): lookup at the nearest pooled pixel (0.71) plus the
    # pooling itself (a set pooled pixel stands for any pixel of its block).
    slack = 0.71 + 1.0
    for _ in range(max(1, int(params.coarse_passes))):
        pts, size, _, _ = _hull(pooled_cams, pooled, lo, hi, int(params.coarse_resolution), 1.0, slack)
        if pts.shape[0] == 0:
            raise FrameError(disjoint)
        lo = pts.min(axis=0) - 0.5 * size
        hi = pts.max(axis=0) + 0.5 * size
    lo = lo - params.margin_mm
    hi = hi + params.margin_mm
    # Grow short sides so that voxels are at most max_anisotropy times thinner than long.
    grow = np.maximum((hi - lo).max() / params.max_anisotropy - (hi - lo), 0.0)
    return lo - 0.5 * grow, hi + 0.5 * grow


def carve(
    cameras,
    centerline_masks,
    box,
    params: CarvingParams = CarvingParams(),
    centerline_labels=None,
) -> CarveResult:
    """Carve a voxel grid over ``box`` against the centerlines, one view after the other.

    The whole ``resolution^3`` grid is projected into the first camera (the
    paper: side) and voxels whose footprint misses its centerline are carved;
    the survivors are projected into the next camera and carved likewise.
    (The first view is evaluated coarse-to-fine, with the same result as
    projecting every voxel.)

    Parameters
    ----------
    cameras : sequence of recon.camera.Camera
        Carving order (paper: side, then top).
    centerline_masks : sequence of (H, W) bool arrays
        Centerline image of each camera.
    box : (lo_mm, hi_mm)
        The carving volume (world, mm), e.g. from :func:`bounding_box`.
    params : CarvingParams
    centerline_labels : sequence of (H, W) uint8 arrays, optional
        Tube label images (1 outer, 2 inner) for per-voxel labels.

    Returns
    -------
    CarveResult

    Raises
    ------
    FrameError
        An empty centerline, or no voxel left after a view.
    ValueError
        An empty box, or one reaching behind a camera.
    """
    masks = _check_inputs(cameras, centerline_masks, "centerline")
    lo = np.asarray(box[0], dtype=np.float64).reshape(3)
    hi = np.asarray(box[1], dtype=np.float64).reshape(3)
    if np.any(hi <= lo):
        raise ValueError(f"carve: empty box lo={lo.tolist()} hi={hi.tolist()}")
    pts, size, counts, views = _hull(
        cameras,
        masks,
        lo,
        hi,
        int(params.resolution),
        params.footprint_scale,
        float(params.footprint_slack_px),
        centerline_labels,
    )
    if pts.shape[0] == 0:
        bad = cameras[len(counts) - 1]
        before = [c.name for c in cameras[: len(counts) - 1]]
        why = "no voxel projects onto the centerline" + (f" (of those left by {', '.join(before)})" if before else "")
        raise FrameError(why, bad.name)
    labels = _nearest_labels(views, pts) if centerline_labels is not None else np.zeros(pts.shape[0], np.uint8)
    return CarveResult(
        points_mm=pts,
        labels=labels,
        voxel_size_mm=size,
        box=(lo, hi),
        n_after_view=tuple(counts),
    )


def _nearest_labels(views, pts: np.ndarray) -> np.ndarray:
    """Label of the centerline pixel nearest to each point's projection, from the view where it is nearest."""
    best_d = np.full(pts.shape[0], np.inf, np.float32)
    best = np.zeros(pts.shape[0], np.uint8)
    for view in views:
        idx, _ = _pixel_index(view, *_points_in_camera(view.camera, pts))
        d = view.dist.ravel().take(idx)
        better = d < best_d
        best_d[better] = d[better]
        best[better] = view.tube.ravel().take(idx[better])
    return best
