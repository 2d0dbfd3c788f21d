"""The twin's renderer draws the robot in a window of the canvas, and does it the way the whole canvas would.

Only the canvas window that the robot's sensor box resamples is rendered per frame;
these tests check that the window holds every pixel the remap reads and that it
renders the same pixels as the whole canvas, on both offscreen platforms where present,
and that pyrender's shaders are compiled once (under OSMesa it used to recompile them
at every pass).
"""
import json
import os
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from twin.gl import available_platforms

pytestmark = pytest.mark.skipif(not available_platforms(), reason="no offscreen OpenGL library on this machine")

#: Renders two robot frames of the paper scene on the platform in the environment and prints the
#: renderer's shader program count after each, and the platform.
_PROBE = """
import json
from rig.scenefiles import DEFAULT_SCENE
from twin.scene import load_scene
from twin.simulator import Twin
tw = Twin(load_scene(DEFAULT_SCENE))
cache = tw.renderer._renderer._renderer._program_cache
counts = []
for i in (3, 12):
    tw.frame(i)
    counts.append(len(cache._program_cache))
print(json.dumps({"platform": tw.renderer.platform, "programs": counts}))
"""


@pytest.fixture(scope="module")
def robot_view(paper_twin):
    """The top camera of a rotated frame, with its sensor box and canvas window."""
    f = paper_twin.frame(15)
    cam = f.cameras["top"]
    r = paper_twin.renderer
    box = r._robot_box(cam)
    return r, cam, box, r._robot_viewport(cam, box)


def test_window_holds_every_canvas_pixel_the_box_remap_reads(robot_view):
    r, cam, box, (u0, v0, w, h) = robot_view
    m1, _ = r._box_maps(cam, box, (u0, v0))
    # bilinear: each sensor pixel reads its canvas pixel and the next one right and down
    assert m1[..., 0].min() >= 0 and m1[..., 1].min() >= 0
    assert m1[..., 0].max() + 1 < w and m1[..., 1].max() + 1 < h
    assert 0 <= u0 and u0 + w <= r.canvas[0] and 0 <= v0 and v0 + h <= r.canvas[1]


@pytest.mark.parametrize("truth", [False, True], ids=["look", "labels"])
def test_window_renders_what_the_whole_canvas_does(robot_view, truth):
    import pyrender

    r, cam, _, (u0, v0, w, h) = robot_view
    meshes = [t.mesh if truth else n.mesh for n, t, _ in r._robot_nodes]
    flags = pyrender.RenderFlags.FLAT if truth else pyrender.RenderFlags.NONE
    r._place_camera(cam)
    whole, z_whole = r._render_only(meshes, flags)
    r._place_camera(cam, (u0, v0))
    window, z_window = r._render_only(meshes, flags, (w, h))
    ref, z_ref = whole[v0:v0 + h, u0:u0 + w], z_whole[v0:v0 + h, u0:u0 + w]
    assert window.shape == ref.shape and (ref > 0).any()
    # The window's projection differs from the canvas's in rounding only: a few anti-aliased edge pixels.
    d = np.abs(window.astype(int) - ref).max(axis=-1)
    assert (d > 2).mean() < 1e-3
    assert ((z_window > 0) != (z_ref > 0)).mean() < 1e-3


def test_mono_scenes_render_one_channel(paper_twin, paper_scene):
    cam = paper_scene.rig["side"]
    view = paper_twin.renderer.render(cam, with_truth=False)
    assert paper_scene.color == "mono"
    assert view.radiance.shape == (cam.height, cam.width) and view.radiance.dtype == np.float32


@pytest.mark.parametrize("platform", available_platforms())
def test_shaders_are_compiled_once(platform):
    env = dict(os.environ, CTR_BENCH_GL=platform, PYOPENGL_PLATFORM=platform)
    out = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, check=True)
    seen = json.loads(out.stdout.strip().splitlines()[-1])
    assert seen["platform"] == platform
    assert seen["programs"][0] == seen["programs"][1], seen


def _filled_reference(rgb, z, coverage):
    """The edge fill as box filters over the whole window (how :meth:`SetRenderer._look` first did it), or None if pixels stay unfilled."""
    import cv2

    sampled = (z > 0).astype(np.float32)
    colour = rgb.astype(np.float32) * sampled[..., None]
    filled = colour
    missing = (coverage > 0) & (sampled == 0)
    for k in (3, 7):
        n = cv2.boxFilter(sampled, -1, (k, k), normalize=False)
        mean = cv2.boxFilter(colour, -1, (k, k), normalize=False) / np.maximum(n, 1.0)[..., None]
        found = missing & (n > 0)
        filled = np.where(found[..., None], mean, filled)
        missing &= ~found
    return None if missing.any() else filled * coverage[..., None]


@given(
    shape=st.tuples(st.integers(1, 23), st.integers(1, 23)),
    drawn=st.floats(0.0, 1.0),
    seed=st.integers(0, 2**31 - 1),
)
def test_edge_fill_is_the_box_filters_value_for_value(shape, drawn, seed):
    """The one-sample lit pass's edge fill equals box filters over the window (OpenCV's reflected borders), bit for bit.

    Fails if the kernel reads its neighbourhoods past the borders in another way, takes
    the 7x7 mean where a 3x3 one exists, or forgets that only covered pixels are filled.
    """
    from twin.render import _premultiply_filled_nb

    rng = np.random.default_rng(seed)
    h, w = shape
    rgb = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    z = np.where(rng.random((h, w)) < drawn, rng.uniform(100, 400, (h, w)), 0.0).astype(np.float32)
    coverage = np.where(rng.random((h, w)) < 0.7, rng.random((h, w)), 0.0).astype(np.float32)
    out = np.full((h, w, 3), np.nan, np.float32)
    # pyrender hands back its buffers flipped upside down: views with negative row strides.
    flipped_rgb, flipped_z = np.ascontiguousarray(rgb[::-1])[::-1], np.ascontiguousarray(z[::-1])[::-1]
    left = _premultiply_filled_nb(flipped_rgb, flipped_z, coverage, out)
    expected = _filled_reference(rgb, z, coverage)
    assert (left == 0) == (expected is not None)
    if expected is not None:
        assert np.array_equal(out, expected)


def test_the_set_draws_in_the_order_it_was_built():
    """Nodes at the same distance are drawn, and lights summed, in the order they were added, in every process.

    pyrender's node sets iterate in address order, so coplanar surfaces of the set
    won the depth test in a different order from run to run (a few pixels of a wide
    scene's images changed between identical runs). Fails with pyrender's plain sets:
    40 nodes almost never iterate in the order they were made.
    """
    from twin.render import _ordered_scene  # first: it chooses the OpenGL platform that pyrender binds

    import pyrender
    import trimesh

    scene = _ordered_scene()
    meshes = [scene.add(pyrender.Mesh.from_trimesh(trimesh.creation.box())) for _ in range(40)]
    lights = [scene.add(pyrender.PointLight(intensity=float(i + 1))) for i in range(20)]
    lights += [scene.add(pyrender.DirectionalLight()) for _ in range(5)]
    scene.add(pyrender.PerspectiveCamera(yfov=1.0), pose=np.eye(4))
    scene.remove_node(meshes.pop(7))
    assert pyrender.renderer.Renderer._sorted_mesh_nodes(None, scene) == meshes
    assert list(scene.light_nodes) == lights


def _pyrender_linear_depth(raw: np.ndarray, z_near: float, z_far) -> np.ndarray:
    """pyrender 0.1.x's depth read-back after glReadPixels (Renderer._read_main_framebuffer), as NumPy passes."""
    depth_im = np.flip(raw, axis=0)
    inf_inds = depth_im == 1.0
    depth_im = 2.0 * depth_im - 1.0
    noninf = np.logical_not(inf_inds)
    if z_far is None:
        depth_im[noninf] = 2 * z_near / (1.0 - depth_im[noninf])
    else:
        depth_im[noninf] = (2.0 * z_near * z_far) / (z_far + z_near - depth_im[noninf] * (z_far - z_near))
    depth_im[inf_inds] = 0.0
    return depth_im


@pytest.mark.parametrize("z_far", [2000.0, None])
def test_depth_read_back_is_pyrenders_bit_for_bit(z_far):
    """The compiled read-back gives pyrender's depth (mm) to the bit, rows flipped, 0 where nothing was drawn.

    Fails if the float32 operations differ in order or precision from pyrender's (the labels' and the
    truth depth's pixels would move), or the rows are not flipped."""
    from twin.render import _linear_depth_nb

    rng = np.random.default_rng(3)
    raw = rng.uniform(0.9, 1.0, (37, 53)).astype(np.float32)
    raw[rng.random(raw.shape) < 0.3] = 1.0
    got = _linear_depth_nb(raw, 10.0, -1.0 if z_far is None else z_far)
    want = _pyrender_linear_depth(raw.copy(), 10.0, z_far)
    assert got.dtype == np.float32 and np.array_equal(got, want)
