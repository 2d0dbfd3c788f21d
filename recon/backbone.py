"""Backbone curve from a carved voxel cloud: order base to tip, average, resample.

The paper draws the reconstruction straight from the surviving voxels. A
backbone curve, base first, is what the rest of the project measures (tip
position, length, error against a model), so the voxel cloud is ordered here:

1. voxels are pooled into cubic cells (the largest voxel edge) and
   neighbouring cells are linked;
2. the pieces of that graph (the cloud breaks wherever a centerline has a gap
   in either view, e.g. at the step from the outer to the inner tube) are
   joined along a minimum spanning tree of the pieces, a gap being bridged
   when it is no longer than the pieces it joins or the images support it;
   what no bridge reaches (specks) is dropped. Keeping only the largest
   connected piece instead, as a fixed-radius graph does, can drop the base
   (the reconstruction then starts beyond the gap);
3. the geodesic distance from the base end (the end nearer the rig's base
   point, where the robot leaves the actuation unit) orders the cells; they
   are binned by it and each bin averaged into one backbone point;
4. twice, the cells are re-binned by their projection onto that curve (the
   last bins become slabs across the cloud instead of its farthest corner),
   the end points are taken from a line fit over the last few bins (an end
   bin holds few voxels and its mean jitters laterally), and the points are
   lightly smoothed;
5. the curve is resampled at a fixed arc-length step.

World coordinates in mm; arc length ``s`` in mm from the base end.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from .centerline import INNER, OUTER
from .errors import FrameError
from .geometry import arc_length, points_at_arc_length, resample_polyline

__all__ = ["BackboneParams", "ReconstructedBackbone", "order_backbone", "back_to_border", "back_to_base_plane",
           "from_base_plane", "MAX_BORDER_EXTENSION_PX"]

#: Longest straight continuation (px, in the view where it is longest) of a backbone back to the image border.
MAX_BORDER_EXTENSION_PX = 48.0


@dataclass(frozen=True)
class BackboneParams:
    """Parameters of :func:`order_backbone`.

    Attributes
    ----------
    step_mm : float
        Arc-length step of the output backbone (mm).
    neighbour_radius_voxels : float
        Voxels are first pooled into cubic cells with the largest voxel edge
        (the grid may be anisotropic; cells make the graph small and its
        metric isotropic). Cells whose grid positions are closer than this are
        linked: 1.8 links the 26-neighbourhood (sqrt(3) = 1.73) only.
    bin_voxels : float
        Width of the geodesic-distance bins, in units of the largest voxel
        edge.
    smooth_passes : int
        Passes of a [1, 2, 1] / 4 filter over the bin averages (ends fixed).
    refine_passes : int
        Passes re-binning the voxels by their projection onto the curve of the
        previous pass (see the module docstring).
    end_fit_bins : int
        Each end point is the end of a line fitted to this many end bins
        (< 2: the end bins' means as they are).
    bridge_factor : float
        Pieces of the cloud are joined across a gap no longer than this times
        the extent of the smaller side (see :func:`order_backbone`).
    max_gap_mm : float
        Longest gap bridged (mm).
    """

    step_mm: float = 0.5
    neighbour_radius_voxels: float = 1.8
    bin_voxels: float = 1.0
    smooth_passes: int = 2
    refine_passes: int = 2
    end_fit_bins: int = 5
    bridge_factor: float = 1.0
    max_gap_mm: float = 20.0

    def __post_init__(self):
        if not self.step_mm > 0:
            raise ValueError(f"BackboneParams.step_mm must be > 0, got {self.step_mm}")
        if not self.neighbour_radius_voxels >= 1.0:
            raise ValueError(f"BackboneParams.neighbour_radius_voxels must be >= 1, got {self.neighbour_radius_voxels}")
        if not self.bin_voxels > 0:
            raise ValueError(f"BackboneParams.bin_voxels must be > 0, got {self.bin_voxels}")


@dataclass(frozen=True, eq=False)
class ReconstructedBackbone:
    """A backbone curve ordered from base to tip.

    Attributes
    ----------
    points_mm : (m, 3) array
        Backbone points (world, mm), base first, ``step_mm`` apart along the
        curve (the last step may be shorter).
    tip_mm : (3,) array
        Last point (world, mm).
    transition_s_mm : float
        Arc length (mm) where the outer tube ends and the inner one goes on;
        NaN when the voxels do not show both tubes.
    transition_mm : (3,) array
        Backbone point at ``transition_s_mm`` (world, mm); NaN when absent.
    length_mm : float
        Arc length of ``points_mm`` (mm).
    n_voxels : int
        Voxels used: the pieces joined to the one holding the most voxels.
    n_dropped : int
        Voxels in pieces no bridge reached (ghosts, specks).
    """

    points_mm: np.ndarray
    tip_mm: np.ndarray
    transition_s_mm: float
    transition_mm: np.ndarray
    length_mm: float
    n_voxels: int
    n_dropped: int


def back_to_base_plane(x0_mm, t0, base_point_world_mm, insertion_axis_world, max_gap_mm: float, step_mm: float) -> np.ndarray:
    """Points continuing ``x0_mm`` straight back along ``-t0`` to the base plane.

    The base plane passes through the base point, across the insertion axis:
    where the robot leaves its actuation unit. A backbone starts a little in
    front of it (the images are cut behind it, and a centerline ends short of
    a cut); the robot goes on straight to it. Only when ``t0`` points away
    from the plane (cosine with the axis over 0.3) and the way back is at most
    ``max_gap_mm``.

    Parameters
    ----------
    x0_mm : (3,) array
        The backbone's first point (world, mm).
    t0 : (3,) array
        Its tangent, pointing along the backbone (world; any length).
    base_point_world_mm : (3,) array
        A point of the base plane (world, mm).
    insertion_axis_world : (3,) array
        Unit normal of the base plane, along the insertion (world).
    max_gap_mm : float
        Longest way back (mm).
    step_mm : float
        Largest spacing of the points (mm).

    Returns
    -------
    (k, 3) float64 array
        Points (world, mm) every ``step_mm`` or finer, farthest (on the plane) first, ``x0_mm``
        excluded; empty (0, 3) when the conditions above do not hold.
    """
    x0 = np.asarray(x0_mm, np.float64)
    t0 = np.asarray(t0, np.float64) / np.linalg.norm(t0)
    axis = np.asarray(insertion_axis_world, np.float64)
    h = float((x0 - np.asarray(base_point_world_mm, np.float64)) @ axis)
    cosb = float(t0 @ axis)
    if not (cosb > 0.3 and 0.0 < h / cosb <= max_gap_mm):
        return np.zeros((0, 3))
    gap = h / cosb
    k = max(1, int(np.ceil(gap / step_mm)))
    return x0 - np.linspace(gap, 0.0, k, endpoint=False)[:, None] * t0


def from_base_plane(points_mm, base_point_world_mm, insertion_axis_world) -> np.ndarray:
    """The backbone from where it crosses the base plane on: its leading points behind the plane cut off.

    The robot leaves its actuation unit at the base plane (through the base
    point, across the insertion axis); none of it lies behind. A backbone
    that starts behind the plane carries the carving's or the centerline's
    overshoot past the cut behind the base, off the robot by about its
    distance from the base (the paper method on the wide suite: up to 2.4 mm,
    13 px footprints, most of those frames' largest errors).

    Parameters
    ----------
    points_mm : (n, 3) array
        The backbone (world, mm), base first.
    base_point_world_mm : (3,) array
        A point of the base plane (world, mm).
    insertion_axis_world : (3,) array
        Unit normal of the base plane, along the insertion (world).

    Returns
    -------
    (m, 3) float64 array
        ``points_mm`` from the first crossing onto the plane (a new first
        point, on it, interpolated along the segment that crosses) when the
        backbone starts behind the plane; ``points_mm`` itself when it does
        not, or when no point lies in front of the plane.
    """
    pts = np.asarray(points_mm, np.float64)
    h = (pts - np.asarray(base_point_world_mm, np.float64)) @ np.asarray(insertion_axis_world, np.float64)
    ahead = np.flatnonzero(h >= 0.0)
    if h[0] >= 0.0 or not ahead.size:
        return pts
    k = int(ahead[0])
    if h[k] == 0.0:
        return pts[k:]
    a = h[k - 1] / (h[k - 1] - h[k])
    return np.concatenate([(pts[k - 1] + a * (pts[k] - pts[k - 1]))[None], pts[k:]])


#: Arc length (mm) from the backbone's first measured point over which :func:`from_base_point` joins it to
#: the base: about the stretch a curl of the first centres spans (wide-2-0 frame 1, side view: ~20 px).
BASE_JOIN_MM = 5.0


def from_base_point(points_mm, base_point_world_mm, insertion_axis_world, step_mm: float,
                    join_mm: float = BASE_JOIN_MM) -> tuple:
    """The backbone started at the base point, along the insertion axis, joined to the measured curve.

    The robot leaves its actuation unit at the base point along the insertion
    axis: the rig says so. Near the unit the tube often shows faintly (its
    shadow, the unit's edges beside it), the first centres wander by a few px
    and a curve through them curls; continued straight back to the base plane
    along its first tangent, the curl is amplified (wide-2-0 frame 1: 16 px
    footprints at the base; wide-1-69 frame 1: 10 px). The first ``join_mm``
    (at most a third of the curve) are replaced by the cubic Hermite curve
    from the base point, tangent along the axis, to the measured point there,
    tangent along the curve: a tube bent to a circle over that stretch is
    followed within 0.2 um for a radius of 30 mm, 1.5 um for 15 mm.

    Parameters
    ----------
    points_mm : (n, 3) array
        The measured backbone (world, mm, n >= 3), base end first, starting
        in front of the base plane.
    base_point_world_mm : (3,) array
        Where the robot leaves its actuation unit (world, mm).
    insertion_axis_world : (3,) array
        The insertion axis (world; any length), pointing along the robot.
    step_mm : float
        Largest spacing (mm) of the joining points.
    join_mm : float, optional
        Arc length (mm) of the measured curve replaced.

    Returns
    -------
    points : (m, 3) float64 array
        The backbone (world, mm) from the base point on.
    added_mm : float
        Arc length (mm) it gained before the measured point where the join ends
        (the base end's shift in arc length, for curve parameters measured along
        ``points_mm``).
    """
    pts = np.asarray(points_mm, np.float64)
    s = arc_length(pts)
    k = min(max(int(np.searchsorted(s, min(join_mm, s[-1] / 3.0))), 1), len(pts) - 2)  # np.clip's result, ~5 us cheaper
    p0 = np.asarray(base_point_world_mm, np.float64)
    t0 = np.asarray(insertion_axis_world, np.float64)
    t0 = t0 / np.linalg.norm(t0)
    t1 = pts[k + 1] - pts[k - 1]
    t1 = t1 / max(float(np.linalg.norm(t1)), 1e-12)
    chord = float(np.linalg.norm(pts[k] - p0))
    u = np.linspace(0.0, 1.0, max(4, int(np.ceil(2.0 * chord / step_mm))), endpoint=False)[:, None]
    join = ((2 * u ** 3 - 3 * u ** 2 + 1) * p0 + (u ** 3 - 2 * u ** 2 + u) * chord * t0
            + (3 * u ** 2 - 2 * u ** 3) * pts[k] + (u ** 3 - u ** 2) * chord * t1)
    out = np.concatenate([join, pts[k:]])
    return out, float(arc_length(out[: len(join) + 1])[-1] - s[k])


def back_to_border(rig, names, x0_mm, t0, step_mm: float) -> np.ndarray:
    """Points continuing ``x0_mm`` straight back along ``-t0`` until one camera's image ends.

    Where the robot enters across the image border, a method's backbone stops
    short of it by about its image window; the robot goes on straight there:
    while each of ``names`` sees the point in its image, at most
    :data:`MAX_BORDER_EXTENSION_PX` in the view where the continuation is
    longest, never behind the base plane (through ``rig.base_point_world_mm``,
    across ``rig.insertion_axis_world``).

    Parameters
    ----------
    rig : RigCalibration
        The calibrated cameras, base point and insertion axis (world, mm).
    names : iterable of str
        The cameras that must see each point.
    x0_mm : (3,) array
        The backbone's first point (world, mm).
    t0 : (3,) array
        Its tangent, pointing along the backbone (world; any length).
    step_mm : float
        Spacing of the points (mm).

    Returns
    -------
    (k, 3) float64 array
        Points (world, mm) every ``step_mm``, farthest first, ``x0_mm`` excluded; empty (0, 3) when
        the first step already leaves a view.
    """
    x0 = np.asarray(x0_mm, np.float64)
    t0 = np.asarray(t0, np.float64) / np.linalg.norm(t0)
    px_per_mm = max(rig[n].K[0, 0] / max(float(rig[n].world_to_camera(x0[None])[0, 2]), 1e-6) for n in names)
    reach = MAX_BORDER_EXTENSION_PX / px_per_mm
    axis = np.asarray(rig.insertion_axis_world, np.float64)
    cos_base = float(t0 @ axis)
    if cos_base > 1e-6:
        reach = min(reach, float((x0 - np.asarray(rig.base_point_world_mm, np.float64)) @ axis) / cos_base)
    d = np.arange(step_mm, reach + 1e-9, step_mm)
    if d.size == 0:
        return np.zeros((0, 3))
    pts = x0 - d[:, None] * t0
    inside = np.ones(d.size, bool)
    for n in names:
        cam = rig[n]
        uv, z = cam.project(pts)
        inside &= (z > 0) & cam.in_image(np.nan_to_num(uv, nan=-1e9), margin_px=0.5)  # pixel centres 0 .. size - 1
    k = d.size if inside.all() else int(np.argmin(inside))
    return pts[:k][::-1]


def _voxel_size(voxels: np.ndarray) -> np.ndarray:
    """Grid spacing per axis: the smallest gap between distinct coordinates."""
    size = np.full(3, np.nan)
    for a in range(3):
        gaps = np.diff(np.unique(voxels[:, a]))
        gaps = gaps[gaps > 1e-9]
        if gaps.size:
            size[a] = gaps.min()
    if np.all(np.isnan(size)):
        return np.ones(3)
    return np.where(np.isnan(size), np.nanmax(size), size)


def _smooth(points: np.ndarray, passes: int) -> np.ndarray:
    p = points.copy()
    for _ in range(passes if p.shape[0] > 2 else 0):
        p[1:-1] = 0.25 * p[:-2] + 0.5 * p[1:-1] + 0.25 * p[2:]
    return p


def _fit_ends(means: np.ndarray, n_fit: int) -> np.ndarray:
    """Bin means (k, 4: x, y, z, t) with each end point replaced by a line fit over the ``n_fit`` end bins.

    An end bin holds few voxels (the cloud thins out), so its mean jitters
    laterally by a fraction of a voxel; the line through the last few bins,
    evaluated at the end bin's mean ``t``, does not.
    """
    k = means.shape[0]
    if n_fit < 2 or k < n_fit + 1:
        return means
    out = means.copy()
    for sl, i in ((slice(0, n_fit), 0), (slice(k - n_fit, k), k - 1)):
        t = means[sl, 3]
        A = np.column_stack([np.ones_like(t), t - t.mean()])
        coef, *_ = np.linalg.lstsq(A, means[sl, :3], rcond=None)
        out[i, :3] = coef[0] + (means[i, 3] - t.mean()) * coef[1]
    return out


def _bin_means(t, sums, counts, width):
    """Per bin of ``t`` (``width`` wide): the mean voxel position and the mean ``t``, (k, 4), in order."""
    bins = np.floor(t / width).astype(np.int64)
    _, of_cell, per_bin = np.unique(bins, return_inverse=True, return_counts=True)
    acc = np.zeros((per_bin.size, 5))
    np.add.at(acc, of_cell.reshape(-1), np.column_stack([sums, counts * t, counts]))
    return acc[:, :4] / acc[:, 4:5]


def _project_cells(centres, pts, s_prior, tolerance):
    """Arc length along the polyline ``pts`` of each cell's nearest point, extrapolated past the ends.

    Cells past an end are placed along the end's tangent, so that the last
    bins are slabs across the cloud rather than its farthest corner. Where
    the projection disagrees with ``s_prior`` (the geodesic order) by more
    than ``tolerance`` (mm), a curve that passes near itself, the prior
    stays.
    """
    if pts.shape[0] < 2:
        return s_prior
    # A tenth of the tolerance's cell: nearest vertex ~ nearest point.
    dense = resample_polyline(pts, tolerance / 30.0)
    s_dense = arc_length(dense)
    if s_dense[-1] <= 0.0:
        return s_prior
    _, j = cKDTree(dense).query(centres)
    s = s_dense[j]
    t0 = dense[1] - dense[0]
    t1 = dense[-1] - dense[-2]
    first, last = j == 0, j == dense.shape[0] - 1
    s[first] = np.minimum(0.0, (centres[first] - dense[0]) @ (t0 / np.linalg.norm(t0)))
    s[last] = s_dense[-1] + np.maximum(0.0, (centres[last] - dense[-1]) @ (t1 / np.linalg.norm(t1)))
    return np.where(np.abs(s - s_prior) <= tolerance, s, s_prior)


def _transition_distance(g: np.ndarray, labels: np.ndarray) -> float:
    """Geodesic distance best separating outer (before) from inner (after) labels; NaN if one is missing."""
    order = np.argsort(g)
    lab = labels[order]
    known = (lab == OUTER) | (lab == INNER)
    lab, gs = lab[known], g[order][known]
    if not (np.any(lab == OUTER) and np.any(lab == INNER)):
        return float("nan")
    # errors(k) = inner labels before k + outer labels from k on; k = split index.
    inner_before = np.concatenate([[0], np.cumsum(lab == INNER)])
    outer_after = np.concatenate([np.cumsum((lab == OUTER)[::-1])[::-1], [0]])
    k = int(np.argmin(inner_before + outer_after))
    if k == 0 or k == lab.size:
        return float("nan")
    return 0.5 * float(gs[k - 1] + gs[k])


def _bridge_pieces(centres, comp, n_comp, counts, cell, params, bridge_check=None):
    """Bridges (k, 2 cell indices) joining pieces of the cell graph, and the cells kept (m,) bool.

    The carved cloud of a robot comes in pieces wherever a centerline has a
    gap in either view (the step from the outer to the inner tube, a stretch
    the silhouette missed). The pieces are joined along a minimum spanning
    tree: Kruskal over the pieces, the gap between two pieces being the
    distance between their nearest cells. A gap is bridged when it is no
    longer than ``bridge_factor`` times the smaller of the two groups it
    joins (their extent, the diagonal of their bounding box) and at most
    ``max_gap_mm``, or shorter than two cells in any case: a stretch of robot
    continues across a gap of its own size, an isolated speck does not. A
    longer gap (up to ``max_gap_mm``) is bridged when ``bridge_check(p, q)``
    says the images support it (the paper's method: the straight segment
    between the two cells projects into every silhouette). The group holding
    the most voxels is kept; the rest are dropped.
    """
    m = centres.shape[0]
    if n_comp == 1:
        return np.zeros((0, 2), np.int64), np.ones(m, bool)
    members = [np.flatnonzero(comp == c) for c in range(n_comp)]
    trees = [cKDTree(centres[idx]) for idx in members]
    cand = []
    for a in range(n_comp):
        for b in range(a + 1, n_comp):
            # Query the smaller piece against the larger one's tree.
            small, big = (a, b) if members[a].size <= members[b].size else (b, a)
            d, j = trees[big].query(centres[members[small]])
            k = int(np.argmin(d))
            cand.append((float(d[k]), int(members[small][k]), int(members[big][j[k]]), a, b))
    cand.sort()
    parent = list(range(n_comp))
    lo = [centres[idx].min(axis=0) for idx in members]
    hi = [centres[idx].max(axis=0) for idx in members]

    def find(c):
        while parent[c] != c:
            parent[c] = parent[parent[c]]
            c = parent[c]
        return c

    bridges = []
    for gap, i, j, a, b in cand:
        ra, rb = find(a), find(b)
        if ra == rb:
            continue
        extent = min(float(np.linalg.norm(hi[ra] - lo[ra])) + cell, float(np.linalg.norm(hi[rb] - lo[rb])) + cell)
        if gap > params.max_gap_mm:
            continue
        if gap > 2.0 * cell and gap > params.bridge_factor * extent:
            if bridge_check is None or not bridge_check(centres[i], centres[j]):
                continue
        parent[rb] = ra
        lo[ra], hi[ra] = np.minimum(lo[ra], lo[rb]), np.maximum(hi[ra], hi[rb])
        bridges.append((i, j))
    root = np.array([find(c) for c in range(n_comp)])
    weight = np.bincount(root[comp], weights=counts, minlength=n_comp)
    main = root[comp] == int(np.argmax(weight))
    bridges = [(i, j) for i, j in bridges if main[i]]
    return np.array(bridges, np.int64).reshape(-1, 2), main


def _cells(vox: np.ndarray, cell: float) -> tuple:
    """Voxels (n, 3) mm pooled into cubic cells of edge ``cell`` (mm, the largest voxel edge).

    Returns ``(keys, of_voxel, counts, sums, centres)``: cell indices (m, 3),
    each voxel's cell (n,), voxels per cell (m,), their coordinate sums and
    means (m, 3) mm.
    """
    # +0.5: voxel centres on the coarsest axis sit exactly on cell centres, not on edges.
    grid = np.floor((vox - vox.min(axis=0)) / cell + 0.5).astype(np.int64)
    # One integer per cell (a 1-D unique is several times faster than a row-wise one).
    dims = grid.max(axis=0) + 1
    flat, of_voxel, counts = np.unique(np.ravel_multi_index(grid.T, dims), return_inverse=True, return_counts=True)
    keys = np.stack(np.unravel_index(flat, dims), axis=1)
    of_voxel = of_voxel.reshape(-1)
    sums = np.zeros((keys.shape[0], 3))
    np.add.at(sums, of_voxel, vox)
    return keys, of_voxel, counts, sums, sums / counts[:, None]


def _cell_graph(keys, centres, counts, cell: float, params: BackboneParams, bridge_check) -> tuple:
    """The main piece's cell graph, weighted by the distance between cell means (mm), and the (m,) mask of its cells.

    Links between neighbouring cells, plus bridges over the gaps between
    pieces (:func:`_bridge_pieces`).
    """
    pairs = cKDTree(keys).query_pairs(params.neighbour_radius_voxels, output_type="ndarray")
    m = keys.shape[0]
    n_comp, comp = connected_components(
        coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(m, m)), directed=False
    )
    bridges, main = _bridge_pieces(centres, comp, n_comp, counts, cell, params, bridge_check)
    if bridges.size:
        pairs = np.concatenate([pairs, bridges])
    w = np.linalg.norm(centres[pairs[:, 0]] - centres[pairs[:, 1]], axis=1)
    graph = coo_matrix((np.maximum(w, 1e-9), (pairs[:, 0], pairs[:, 1])), shape=(m, m)).tocsr()
    return graph[main][:, main], main


def _distance_from_base(graph, centres, base, axis, cell: float) -> np.ndarray:
    """Each cell's geodesic distance (mm) from the base end of the graph.

    Ends by a double sweep: the cell farthest from any cell is one end, the
    cell farthest from that end is the other. The base end is the one nearer
    ``base`` (mm), or, within a cell of a tie, the one further back along ``axis``.
    """
    d0 = dijkstra(graph, directed=False, indices=0)
    end_a = int(np.argmax(d0))
    d_a = dijkstra(graph, directed=False, indices=end_a)
    end_b = int(np.argmax(d_a))
    dist_a, dist_b = (float(np.linalg.norm(centres[e] - base)) for e in (end_a, end_b))
    if abs(dist_a - dist_b) > cell:
        base_is_a = dist_a < dist_b
    else:
        base_is_a = float((centres[end_a] - centres[end_b]) @ axis) <= 0.0
    return d_a if base_is_a else dijkstra(graph, directed=False, indices=end_b)


def _binned_curve(g_cell, centres, sums, counts, cell: float, params: BackboneParams) -> tuple:
    """The curve (k, 3) mm through the means of geodesic bins, refined by projecting the cells onto it,
    and each cell's arc length (mm) along it."""
    width = params.bin_voxels * cell
    means = _bin_means(g_cell, sums, counts, width)
    pts = _smooth(means[:, :3], int(params.smooth_passes))
    # Geodesic distance overestimates arc length (grid paths zigzag); map it
    # through the bins' own (mean geodesic, arc length) pairs.
    s_cell = np.interp(g_cell, means[:, 3], arc_length(pts))
    for _ in range(int(params.refine_passes)):
        s_cell = _project_cells(centres, pts, s_cell, 3.0 * cell)
        means = _bin_means(s_cell, sums, counts, width)
        means = _fit_ends(means, int(params.end_fit_bins))
        pts = _smooth(means[:, :3], int(params.smooth_passes))
        s_cell = np.interp(s_cell, means[:, 3], arc_length(pts))
    return pts, s_cell


def order_backbone(
    voxels_mm,
    labels,
    base_point_world_mm,
    insertion_axis_world,
    params: BackboneParams = BackboneParams(),
    *,
    voxel_size_mm=None,
    bridge_check=None,
) -> ReconstructedBackbone:
    """Order a carved voxel cloud into a backbone curve, base first.

    Parameters
    ----------
    voxels_mm : (n, 3) array
        Voxel centres (world, mm).
    labels : (n,) int array or None
        Tube label per voxel (1 outer, 2 inner, 0 unknown); ``None``: unknown.
    base_point_world_mm : (3,) array
        Where the robot leaves the actuation unit (world, mm). Of the cloud's
        two ends, the one nearer to it is the base.
    insertion_axis_world : (3,) array
        Insertion direction (world). Breaks the tie when both ends are about
        equally near the base point: the base end is the one further back
        along the axis.
    params : BackboneParams, optional
        Output step, cell linking, binning, refinement and bridging.
    voxel_size_mm : float or (3,) array, optional
        Voxel edge per axis (mm); estimated from the coordinates if omitted.
    bridge_check : callable(p, q) -> bool, optional
        Whether a straight bridge between world points ``p`` and ``q`` (mm)
        over a gap between pieces of the cloud is supported by the images;
        lets gaps longer than the pieces they join be bridged.

    Returns
    -------
    ReconstructedBackbone

    Raises
    ------
    FrameError
        The cloud holds no voxel.
    """
    vox = np.asarray(voxels_mm, dtype=np.float64).reshape(-1, 3)
    if vox.shape[0] == 0:
        raise FrameError("no voxel survives carving")
    lab = np.zeros(vox.shape[0], np.uint8) if labels is None else np.asarray(labels).reshape(-1)
    size = _voxel_size(vox) if voxel_size_mm is None else np.broadcast_to(np.asarray(voxel_size_mm, float), (3,))
    base = np.asarray(base_point_world_mm, dtype=np.float64).reshape(3)
    axis = np.asarray(insertion_axis_world, dtype=np.float64).reshape(3)
    axis = axis / np.linalg.norm(axis)

    cell = float(size.max())
    keys, of_voxel, counts, sums, centres = _cells(vox, cell)
    graph, main = _cell_graph(keys, centres, counts, cell, params, bridge_check)
    in_main = main[of_voxel]
    n_dropped = int(np.count_nonzero(~in_main))
    # Re-index voxels to the kept cells.
    of_voxel = (np.cumsum(main) - 1)[of_voxel[in_main]]
    vox, lab = vox[in_main], lab[in_main]
    sums, counts, centres = sums[main], counts[main], centres[main]
    g_cell = _distance_from_base(graph, centres, base, axis, cell)
    pts, s_cell = _binned_curve(g_cell, centres, sums, counts, cell, params)
    points = resample_polyline(pts, params.step_mm)
    length = float(arc_length(points)[-1])

    s_t = _transition_distance(s_cell[of_voxel], lab)
    if np.isnan(s_t):
        p_t = np.full(3, np.nan)
    else:
        p_t = points_at_arc_length(points, np.array([s_t]))[0]
    return ReconstructedBackbone(
        points_mm=points,
        tip_mm=points[-1].copy(),
        transition_s_mm=s_t,
        transition_mm=p_t,
        length_mm=length,
        n_voxels=int(vox.shape[0]),
        n_dropped=n_dropped,
    )
