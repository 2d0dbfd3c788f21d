"""Backbone curve from a carved voxel cloud: order base to tip, average, resample.

The paper draws the reconstruction straight from the surviving voxels. A
backbone curve, base first, is what the rest of the project measures (tip
position, length, error against a model), so the voxel cloud is ordered here:
voxels are pooled into cubic cells, neighbouring cells are linked, the
geodesic distance from the base end is computed along the links, voxels are
binned by it and each bin averaged into one backbone point; the points are
lightly smoothed and resampled at a fixed arc-length step.

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

__all__ = ["BackboneParams", "ReconstructedBackbone", "order_backbone", "resample_polyline", "arc_length"]


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
    """

    step_mm: float = 0.5
    neighbour_radius_voxels: float = 1.8
    bin_voxels: float = 1.0
    smooth_passes: int = 2

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
        Voxels in the largest connected component, the one used.
    n_dropped : int
        Voxels outside it (ghosts, specks).
    """

    points_mm: np.ndarray
    tip_mm: np.ndarray
    transition_s_mm: float
    transition_mm: np.ndarray
    length_mm: float
    n_voxels: int
    n_dropped: int


def arc_length(points: np.ndarray) -> np.ndarray:
    """Cumulative arc length (m,) of a polyline (m, d), starting at 0."""
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(seg)])


def resample_polyline(points: np.ndarray, step: float) -> np.ndarray:
    """Points every ``step`` along a polyline (m, d), first and last kept.

    Parameters
    ----------
    points : (m, d) array
    step : float
        Arc-length step, in the units of ``points``.

    Returns
    -------
    (k, d) array
    """
    s = arc_length(points)
    if s[-1] <= 0.0:
        return points[:1].copy()
    n = max(1, int(np.ceil(s[-1] / step - 1e-9)))
    t = np.minimum(np.arange(n + 1) * step, s[-1])
    return np.stack([np.interp(t, s, points[:, c]) for c in range(points.shape[1])], axis=1)


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


def order_backbone(
    voxels_mm,
    labels,
    base_point_world_mm,
    insertion_axis_world,
    params: BackboneParams = BackboneParams(),
    *,
    voxel_size_mm=None,
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
    params : BackboneParams
    voxel_size_mm : float or (3,) array, optional
        Voxel edge per axis (mm); estimated from the coordinates if omitted.

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

    # Cells of the largest voxel edge; each holds the sum and count of its voxels.
    cell = float(size.max())
    # +0.5: voxel centres on the coarsest axis sit exactly on cell centres, not on edges.
    keys = np.floor((vox - vox.min(axis=0)) / cell + 0.5).astype(np.int64)
    keys, of_voxel, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    of_voxel = of_voxel.reshape(-1)
    sums = np.zeros((keys.shape[0], 3))
    np.add.at(sums, of_voxel, vox)
    centres = sums / counts[:, None]

    # Cell graph, weighted by the distance between cell means (mm).
    pairs = cKDTree(keys).query_pairs(params.neighbour_radius_voxels, output_type="ndarray")
    m = keys.shape[0]
    w = np.linalg.norm(centres[pairs[:, 0]] - centres[pairs[:, 1]], axis=1)
    graph = coo_matrix((np.maximum(w, 1e-9), (pairs[:, 0], pairs[:, 1])), shape=(m, m)).tocsr()
    _, comp = connected_components(graph, directed=False)
    main = comp == np.argmax(np.bincount(comp, weights=counts))
    graph = graph[main][:, main]
    in_main = main[of_voxel]
    n_dropped = int(np.count_nonzero(~in_main))
    # Re-index voxels to the kept cells.
    of_voxel = (np.cumsum(main) - 1)[of_voxel[in_main]]
    vox, lab = vox[in_main], lab[in_main]
    sums, counts, centres = sums[main], counts[main], centres[main]

    # Ends by a double sweep: the cell farthest from any cell is one end, the
    # cell farthest from that end is the other.
    d0 = dijkstra(graph, directed=False, indices=0)
    end_a = int(np.argmax(d0))
    d_a = dijkstra(graph, directed=False, indices=end_a)
    end_b = int(np.argmax(d_a))
    dist_a, dist_b = (float(np.linalg.norm(centres[e] - base)) for e in (end_a, end_b))
    if abs(dist_a - dist_b) > cell:
        base_is_a = dist_a < dist_b
    else:
        base_is_a = float((centres[end_a] - centres[end_b]) @ axis) <= 0.0
    g_cell = d_a if base_is_a else dijkstra(graph, directed=False, indices=end_b)

    # One point per geodesic bin: the mean of its voxels.
    bins = np.floor(g_cell / (params.bin_voxels * cell)).astype(np.int64)
    _, of_cell, per_bin = np.unique(bins, return_inverse=True, return_counts=True)
    acc = np.zeros((per_bin.size, 5))
    np.add.at(acc, of_cell.reshape(-1), np.column_stack([sums, counts * g_cell, counts]))
    means = acc[:, :4] / acc[:, 4:5]
    pts = _smooth(means[:, :3], int(params.smooth_passes))
    s_bins = arc_length(pts)
    points = resample_polyline(pts, params.step_mm)
    length = float(arc_length(points)[-1])

    g_t = _transition_distance(g_cell[of_voxel], lab)
    if np.isnan(g_t):
        s_t, p_t = float("nan"), np.full(3, np.nan)
    else:
        # Geodesic distance overestimates arc length (grid paths zigzag); map
        # it through the bins' own (mean geodesic, arc length) pairs.
        s_t = float(np.interp(g_t, means[:, 3], s_bins))
        s_pts = arc_length(points)
        p_t = np.array([np.interp(s_t, s_pts, points[:, c]) for c in range(3)])
    return ReconstructedBackbone(
        points_mm=points,
        tip_mm=points[-1].copy(),
        transition_s_mm=s_t,
        transition_mm=p_t,
        length_mm=length,
        n_voxels=int(vox.shape[0]),
        n_dropped=n_dropped,
    )
