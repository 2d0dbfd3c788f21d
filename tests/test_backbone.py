"""Ordering a voxel cloud into a base-first backbone curve."""
import numpy as np
import pytest
from scipy.spatial import cKDTree

from recon.backbone import BackboneParams, order_backbone
from recon.errors import FrameError
from recon.geometry import arc_length, resample_polyline
from recon.metrics import point_to_polyline_distances


def bent_curve(n=2000):
    """Straight 30 mm along x, then a 3-D arc of radius 40 mm over 70 degrees (mm)."""
    s = np.linspace(0.0, 30.0 + 40.0 * np.radians(70.0), n)
    a = np.clip(s - 30.0, 0.0, None) / 40.0
    x = np.where(s < 30.0, s, 30.0 + 40.0 * np.sin(a))
    bend = 40.0 * (1.0 - np.cos(a))
    return np.stack([x, 0.6 * bend, 0.8 * bend], axis=1) + np.array([5.0, 2.0, -3.0]), s


def voxelize(curve, size, radius_voxels=0.9, origin=(0.0, 0.0, 0.0)):
    """Centres of the grid voxels (edges ``size`` mm) within ``radius_voxels`` x max edge of the curve.

    Returns the centres (n, 3) mm and, per voxel, the index of the nearest curve point.
    """
    size = np.broadcast_to(np.asarray(size, float), (3,))
    radius = radius_voxels * size.max()
    reach = np.ceil(radius / size).astype(int)
    offsets = np.stack(np.meshgrid(*[np.arange(-r, r + 1) for r in reach], indexing="ij"), axis=-1).reshape(-1, 3)
    near = np.round((curve - origin) / size).astype(int)
    cells = np.unique((near[:, None, :] + offsets[None, :, :]).reshape(-1, 3), axis=0)
    centres = cells * size + origin
    d, idx = cKDTree(curve).query(centres, distance_upper_bound=radius)
    keep = np.isfinite(d)
    return centres[keep], idx[keep]


@pytest.mark.parametrize("size", [0.8, (0.9, 0.3, 0.25)], ids=["cubic", "anisotropic"])
def test_recovers_curve_base_first(size):
    curve, s = bent_curve()
    vox, _ = voxelize(curve, size)
    vox = vox[np.random.default_rng(0).permutation(len(vox))]  # order must not matter
    bb = order_backbone(vox, None, curve[0], [1.0, 0.0, 0.0], voxel_size_mm=size)
    voxel = float(np.max(size))
    # Within half a voxel of the true curve, base first, tip last (the end
    # points average voxels past the curve's ends: one voxel there).
    assert point_to_polyline_distances(bb.points_mm[1:-1], curve).max() <= 0.5 * voxel
    assert np.linalg.norm(bb.points_mm[0] - curve[0]) <= voxel
    assert np.linalg.norm(bb.tip_mm - curve[-1]) <= voxel
    np.testing.assert_array_equal(bb.tip_mm, bb.points_mm[-1])
    assert abs(bb.length_mm - s[-1]) <= 2 * voxel
    steps = np.linalg.norm(np.diff(bb.points_mm, axis=0), axis=1)
    np.testing.assert_allclose(steps[:-1], 0.5, rtol=0.01)  # chords of 0.5 mm arcs
    assert bb.n_voxels == len(vox) and bb.n_dropped == 0
    assert np.isnan(bb.transition_s_mm) and np.all(np.isnan(bb.transition_mm))


def test_base_is_the_end_nearest_the_base_point():
    curve, _ = bent_curve()
    vox, _ = voxelize(curve, 0.8)
    bb = order_backbone(vox, None, curve[-1] + 3.0, [1.0, 0.0, 0.0], voxel_size_mm=0.8)
    assert np.linalg.norm(bb.points_mm[0] - curve[-1]) <= 0.8


def test_insertion_axis_breaks_a_tie():
    line = np.stack([np.linspace(-20, 20, 400), np.zeros(400), np.zeros(400)], axis=1)
    vox, _ = voxelize(line, 0.5)
    # Base point equidistant from both ends: the end further back along the axis is the base.
    bb = order_backbone(vox, None, [0.0, 10.0, 0.0], [-1.0, 0.0, 0.0], voxel_size_mm=0.5)
    assert bb.points_mm[0, 0] > 19.0 and bb.tip_mm[0] < -19.0


def test_transition_from_labels():
    curve, s = bent_curve()
    vox, idx = voxelize(curve, 0.8)
    labels = np.where(s[idx] < 45.0, 1, 2).astype(np.uint8)
    bb = order_backbone(vox, labels, curve[0], [1.0, 0.0, 0.0], voxel_size_mm=0.8)
    assert abs(bb.transition_s_mm - 45.0) <= 2 * 0.8
    true_point = curve[np.searchsorted(s, 45.0)]
    assert np.linalg.norm(bb.transition_mm - true_point) <= 2 * 0.8


def test_largest_component_kept():
    curve, _ = bent_curve()
    vox, _ = voxelize(curve, 0.8)
    speck = curve[0] + np.array([0.0, 0.0, 30.0]) + np.array([[0, 0, 0], [0.8, 0, 0], [0, 0.8, 0]])
    bb = order_backbone(np.vstack([vox, speck]), None, curve[0], [1.0, 0.0, 0.0], voxel_size_mm=0.8)
    assert bb.n_dropped == 3 and bb.n_voxels == len(vox)
    assert point_to_polyline_distances(bb.points_mm[1:-1], curve).max() <= 0.4


def test_voxel_size_inferred():
    curve, _ = bent_curve()
    vox, _ = voxelize(curve, (0.9, 0.3, 0.25), origin=(0.1, 0.05, 0.02))
    bb = order_backbone(vox, None, curve[0], [1.0, 0.0, 0.0])
    assert point_to_polyline_distances(bb.points_mm[1:-1], curve).max() <= 0.45


def test_empty_cloud():
    with pytest.raises(FrameError, match="no voxel"):
        order_backbone(np.zeros((0, 3)), None, np.zeros(3), [1.0, 0.0, 0.0])


def test_resample_polyline():
    pts = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 2.0, 0.0]])
    out = resample_polyline(pts, 0.5)
    assert len(out) == 7
    np.testing.assert_allclose(out[-1], pts[-1])
    np.testing.assert_allclose(arc_length(out)[-1], 3.0)


def test_params_validated():
    with pytest.raises(ValueError):
        BackboneParams(step_mm=0.0)


def test_gaps_bridged_base_kept():
    # The step from the outer to the inner tube leaves a 1.5 mm gap in the
    # carved cloud: the backbone must still start at the base, not at the
    # larger piece beyond the gap.
    curve, s = bent_curve()
    vox, idx = voxelize(curve, 0.8)
    keep = (s[idx] < 20.0) | (s[idx] > 21.5)
    bb = order_backbone(vox[keep], None, curve[0], [1.0, 0.0, 0.0], voxel_size_mm=0.8)
    assert np.linalg.norm(bb.points_mm[0] - curve[0]) <= 0.8
    assert np.linalg.norm(bb.tip_mm - curve[-1]) <= 0.8
    assert bb.n_dropped == 0


def test_long_gap_bridged_only_with_image_support():
    curve, s = bent_curve()
    vox, idx = voxelize(curve, 0.8)
    # A 6 mm gap before a 4 mm tip piece: longer than the piece it would join.
    keep = (s[idx] < s[-1] - 10.0) | (s[idx] > s[-1] - 4.0)
    calls = []

    def supported(p, q):
        calls.append((p, q))
        return True

    bb = order_backbone(vox[keep], None, curve[0], [1.0, 0.0, 0.0], voxel_size_mm=0.8)
    assert bb.n_dropped > 0 and np.linalg.norm(bb.tip_mm - curve[-1]) > 5.0
    bb = order_backbone(vox[keep], None, curve[0], [1.0, 0.0, 0.0], voxel_size_mm=0.8, bridge_check=supported)
    assert calls and bb.n_dropped == 0
    assert np.linalg.norm(bb.tip_mm - curve[-1]) <= 0.8
    # A bridge's straight chord over 6 mm of a 40 mm radius arc: within ~0.15 mm of it.
    assert point_to_polyline_distances(bb.points_mm[1:-1], curve).max() <= 0.5 * 0.8


def _inside(cam, p):
    uv, z = cam.project(np.atleast_2d(p))
    return bool(z[0] > 0 and 0 <= uv[0, 0] <= cam.width - 1 and 0 <= uv[0, 1] <= cam.height - 1)


def test_back_to_border_stops_where_the_first_camera_loses_the_robot(paper_scene):
    from recon.backbone import MAX_BORDER_EXTENSION_PX, back_to_border

    rig = paper_scene.rig
    names = rig.names
    side = rig["side"]
    t0 = side.T_world_cam[:3, 1]  # image-down in the world: the continuation runs up, out of the top border
    # A point ~25 px below the side image's top border (and in the top image).
    x0 = np.array([60.0, 0.0, 0.0])
    while side.project(x0[None])[0][0, 1] > 25.0:
        x0 = x0 - 0.5 * t0
    assert all(_inside(rig[n], x0) for n in names)
    step = 0.25
    back = back_to_border(rig, names, x0, t0, step)
    assert len(back) > 0
    assert all(_inside(rig[n], p) for n in names for p in back)
    beyond = back[0] - step * t0 / np.linalg.norm(t0)
    px_per_mm = max(rig[n].K[0, 0] / rig[n].world_to_camera(x0[None])[0, 2] for n in names)
    assert not all(_inside(rig[n], beyond) for n in names)  # 25 px: the border, not the cap, ends it
    assert np.linalg.norm(back[0] - x0) <= MAX_BORDER_EXTENSION_PX / px_per_mm + 1e-9
    # Ordered farthest first, evenly spaced, on the line, never past the base plane.
    assert np.allclose(np.linalg.norm(np.diff(back, axis=0), axis=1), step)
    assert np.allclose(back[-1], x0 - step * t0 / np.linalg.norm(t0))
    along_axis = back_to_border(rig, names, np.array([2.0, 0.0, 0.0]), np.array(rig.insertion_axis_world, float), 0.25)
    assert all((p - rig.base_point_world_mm) @ rig.insertion_axis_world >= -1e-9 for p in along_axis)


def test_from_base_plane_cuts_a_start_behind_the_plane():
    """A backbone starting behind the base plane starts on it, where it crosses; one in front is left alone."""
    from recon.backbone import from_base_plane

    base, axis = np.zeros(3), np.array([1.0, 0.0, 0.0])
    x = np.linspace(-1.5, 10.0, 24)
    pts = np.column_stack([x, 0.1 * x + 0.3, np.zeros_like(x)])
    cut = from_base_plane(pts, base, axis)
    np.testing.assert_allclose(cut[0], [0.0, 0.3, 0.0], atol=1e-12)  # on the plane, on the polyline
    assert np.all(cut[1:, 0] > 0) and np.array_equal(cut[1:], pts[pts[:, 0] > 0])
    assert np.array_equal(from_base_plane(pts[3:], base, axis), pts[3:])  # starts on the plane: as it is
    assert np.array_equal(from_base_plane(pts - [20.0, 0, 0], base, axis), pts - [20.0, 0, 0])  # all behind: nothing to keep


def test_back_to_base_plane():
    """Straight back along -t0 to the plane through the base across the axis; only when it points away from
    the plane and the gap is short."""
    from recon.backbone import back_to_base_plane

    base, axis = np.zeros(3), np.array([1.0, 0.0, 0.0])
    t0 = np.array([1.0, 0.5, 0.0])
    x0 = np.array([4.0, 2.0, 1.0])
    back = back_to_base_plane(x0, t0, base, axis, 6.0, 0.5)
    np.testing.assert_allclose(back[0, 0], 0.0, atol=1e-12)  # on the base plane, farthest first
    np.testing.assert_allclose(np.cross(back - x0, t0), 0.0, atol=1e-12)  # on the line through x0 along t0
    assert np.all(np.diff(back[:, 0]) > 0) and back[-1, 0] < x0[0]
    assert np.linalg.norm(np.diff(back, axis=0), axis=1).max() <= 0.5 + 1e-9
    assert len(back_to_base_plane(x0, t0, base, axis, 4.0, 0.5)) == 0  # 4.5 mm back: beyond the limit
    assert len(back_to_base_plane(x0, -t0, base, axis, 6.0, 0.5)) == 0  # pointing back towards the base
    assert len(back_to_base_plane(x0, np.array([0.2, 1.0, 0.0]), base, axis, 60.0, 0.5)) == 0  # nearly across the axis


@pytest.mark.parametrize("radius_mm", [15.0, 30.0, 60.0])
def test_from_base_point_keeps_a_tube_bent_from_its_base(radius_mm):
    """A tube that leaves the base along the axis and bends to a circle: the join from the base point follows
    that circle within 2 um, is C1 where it meets the measured curve, and the arc length it reports added is
    what the join changed (~0 here)."""
    from recon.backbone import from_base_point

    th = np.linspace(0.0, 60.0 / radius_mm, 2400)
    pts = np.column_stack([radius_mm * np.sin(th), radius_mm * (1.0 - np.cos(th)), np.zeros_like(th)])
    out, added_mm = from_base_point(pts, pts[0], [2.0, 0.0, 0.0], 0.25)
    assert np.abs(np.linalg.norm(out - [0.0, radius_mm, 0.0], axis=1) - radius_mm).max() < 2e-3
    assert abs(added_mm) < 1e-3 and abs(arc_length(out)[-1] - arc_length(pts)[-1]) < 1e-3
    assert np.linalg.norm(np.diff(out, axis=0), axis=1).max() < 0.25


def test_from_base_point_replaces_a_curled_start():
    """The first measured millimetres curl 1 mm off a straight tube (the first centres of a view wandered
    where the tube shows faintly near its unit), and the curve starts 2 mm in front of the base plane:
    continued straight back along its first tangent it would reach the plane 2 mm off the base point; the
    join starts at the base point along the axis and meets the measured curve 5 mm on, where it is right."""
    from recon.backbone import back_to_base_plane, from_base_point

    base, axis = np.array([1.0, 2.0, 3.0]), np.array([0.0, 0.0, 1.0])
    s = np.linspace(2.0, 60.0, 581)
    curl = np.clip(1.0 - (s - 2.0) / 2.0, 0.0, None)  # 1 mm at the first point, gone 2 mm on
    pts = base + np.column_stack([curl, np.zeros_like(s), s])
    straight = back_to_base_plane(pts[0], pts[1] - pts[0], base, axis, 6.0, 0.25)
    assert np.linalg.norm(straight[0] - base) > 1.9  # the old way back lands 2 mm off
    out, added_mm = from_base_point(pts, base, axis, 0.25)
    np.testing.assert_allclose(out[0], base, atol=1e-12)
    t_start = (out[1] - out[0]) / np.linalg.norm(out[1] - out[0])
    assert t_start @ axis > 0.9999
    assert np.hypot(out[:, 0] - base[0], out[:, 1] - base[1]).max() < 1e-9  # on the tube's axis all along
    assert abs(added_mm - (arc_length(out)[-1] - arc_length(pts)[-1])) < 1e-9
    np.testing.assert_array_equal(out[-500:], pts[-500:])  # beyond the join: the measured curve
