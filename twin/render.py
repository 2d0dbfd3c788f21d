"""Offscreen rendering of the twin's set through the shared camera model.

pyrender (the maintained ``pyrender2`` distribution) draws an ideal pinhole
image on a canvas larger than the sensor; lens distortion is then applied by
remapping every sensor pixel through :meth:`recon.camera.Camera.undistort_pixels`,
so rendered images obey exactly the Brown-Conrady model that calibration
estimates. One OpenGL context is created per :class:`SetRenderer` and reused
for every frame.

The static set is rendered once per camera; per frame only the robot is drawn,
in the window of the canvas that its box on the sensor resamples (a few per cent
of the canvas), and composited over the set. Mono scenes are resampled and
composited in one channel, the sensor's signal.
"""
from __future__ import annotations

import atexit
from dataclasses import dataclass

import numpy as np

from .gl import select_platform

# PyOpenGL binds its platform at its first import (pyrender's, below): this module alone chooses it.
_PLATFORM = select_platform()

import cv2  # noqa: E402
from numba import njit  # noqa: E402
import pyrender  # noqa: E402
import trimesh  # noqa: E402
from OpenGL import GL  # noqa: E402

from recon.camera import Camera  # noqa: E402

from . import mesh as meshes  # noqa: E402
from .backdrop import auto_texture_px, backdrop_planes, place_clutter  # noqa: E402
from .noise import LUMA  # noqa: E402
from .scene import ACTUATION_UNIT_BOX_BASE_MM, Scene  # noqa: E402
from .textures import backdrop_texture  # noqa: E402

__all__ = ["SetRenderer", "View", "T_cvcam_glcam"]

#: OpenGL camera frame (x right, y up, z backward) -> OpenCV camera frame (x right, y down,
#: z forward): ``T_world_cvcam @ T_cvcam_glcam`` is the pose pyrender wants. (It is its own inverse.)
T_cvcam_glcam = np.diag([1.0, -1.0, -1.0, 1.0])

#: Segmentation colours of the tubes in the label pass (tube index -> RGB).
_SEG_COLORS = [(255, 0, 0), (0, 255, 0), (0, 0, 255)]


@dataclass(frozen=True, eq=False)
class View:
    """One rendered camera image before sensor noise.

    Attributes
    ----------
    radiance : (H, W, 3) float32, or (H, W) for a mono scene
        Linear-ish RGB in [0, 1] as the lens delivers it (distorted); for a mono scene
        (``scene.color == "mono"``) the sensor's signal, RGB weighted by :data:`twin.noise.LUMA`.
    labels : (H, W) uint8 or None
        0 background, 1 + tube index where that tube is the visible robot surface
        (a pixel counts when the tube covers at least half of it).
    depth_mm : (H, W) float32 or None
        Camera-frame z of the visible robot surface (mm), 0 elsewhere.
    """

    radiance: np.ndarray
    labels: np.ndarray | None
    depth_mm: np.ndarray | None


_RENDERERS: dict = {}


class _ProgramCache(pyrender.shader_program.ShaderProgramCache):
    """pyrender's shader program cache, keyed without the OpenGL context handle.

    pyrender keys its cache on the current context as PyOpenGL returns it; under
    OSMesa that is a new ctypes pointer object at every call, which never compares
    equal to the last, so every pass recompiled its shaders (about 10 ms a pass) and
    the cache grew by a program per primitive per pass. Each cache belongs to one
    renderer, hence to one context, so the handle adds nothing to the key.
    """

    def __init__(self):
        super().__init__()
        self._by_source = {}

    def get_program(self, vertex_shader, fragment_shader, geometry_shader=None, defines=None):
        key = (vertex_shader, fragment_shader, geometry_shader, tuple(sorted((defines or {}).items())))
        if key not in self._by_source:
            self._by_source[key] = super().get_program(vertex_shader, fragment_shader, geometry_shader, defines)
        return self._by_source[key]

    def clear(self):
        super().clear()
        self._by_source = {}


@njit(cache=True, nogil=True)
def _linear_depth_nb(raw, z_near, z_far):  # pragma: no cover - compiled
    """pyrender's linear depth (mm, 0 where nothing was drawn) of an OpenGL depth buffer ``raw`` (h, w) float32
    read bottom row first: the rows flipped and the same float32 arithmetic as pyrender's NumPy passes, in one
    pass (those took 1.7 ms of a 300x900 robot window, its boolean masks and fancy indexing). ``z_far`` <= 0:
    an infinite far plane."""
    h, w = raw.shape
    out = np.empty((h, w), np.float32)
    one, two = np.float32(1.0), np.float32(2.0)
    infinite = z_far <= 0.0
    num = np.float32(2.0 * z_near) if infinite else np.float32(2.0 * z_near * z_far)
    span, total = np.float32(z_far - z_near), np.float32(z_far + z_near)
    for i in range(h):
        for j in range(w):
            d = raw[h - 1 - i, j]
            if d == one:
                out[i, j] = 0.0
            else:
                d = two * d - one
                out[i, j] = num / (one - d) if infinite else num / (total - d * span)
    return out


def _read_depth(width: int, height: int, z_near: float, z_far) -> np.ndarray:
    """The bound framebuffer's depth (``width`` x ``height`` from the lower-left corner) as pyrender gives it:
    (h, w) float32 mm, top row first, 0 where nothing was drawn."""
    raw = np.frombuffer(GL.glReadPixels(0, 0, width, height, GL.GL_DEPTH_COMPONENT, GL.GL_FLOAT), np.float32)
    return _linear_depth_nb(raw.reshape(height, width), float(z_near), -1.0 if z_far is None else float(z_far))


def _read_rgb(width: int, height: int) -> np.ndarray:
    """The bound framebuffer's colour (``width`` x ``height`` from the lower-left corner): (h, w, 3) uint8, top row first."""
    rgb = np.frombuffer(GL.glReadPixels(0, 0, width, height, GL.GL_RGB, GL.GL_UNSIGNED_BYTE), np.uint8)
    return rgb.reshape(height, width, 3)[::-1]


class _SampledRenderer(pyrender.renderer.Renderer):
    """pyrender's renderer with a settable multisample count for its offscreen framebuffer.

    pyrender always makes a 4-sample framebuffer. llvmpipe shades a multisampled
    fragment about twice as slowly, and the lit robot's shading is most of a frame's
    drawing; its colour needs one sample a pixel (the coverage comes from the
    multisampled flat pass), so the look pass asks for ``samples = 0``. A change of
    count re-makes the framebuffer, as a change of size already does.
    """

    samples = 4
    _fb_samples = 4

    def _sorted_mesh_nodes(self, scene):
        """pyrender's draw order (solid before transparent, each far to near by node origin), of the visible nodes only.

        pyrender sorts every node of the set, hidden or not, for each robot pass
        (~0.4 ms) and then skips the hidden ones. The sorts are stable, so the
        visible nodes come in the order pyrender's would give them.
        """
        eye = scene.get_pose(scene.main_camera_node)[:3, 3]
        shown = [n for n in scene.mesh_nodes if n.mesh.is_visible]

        def far_first(node):
            return -np.linalg.norm(scene.get_pose(node)[:3, 3] - eye)

        solid = sorted((n for n in shown if not n.mesh.is_transparent), key=far_first)
        return solid + sorted((n for n in shown if n.mesh.is_transparent), key=far_first)

    def _read_main_framebuffer(self, scene, flags):
        """pyrender's colour and depth of the offscreen framebuffer (same values), its depth linearized in one
        compiled pass (:func:`_linear_depth_nb`). Only the flags the twin draws with: no RGBA, no depth only."""
        width, height = self._main_fb_dims[0], self._main_fb_dims[1]
        if flags & (pyrender.RenderFlags.RGBA | pyrender.RenderFlags.DEPTH_ONLY):  # pragma: no cover - not drawn so
            return super()._read_main_framebuffer(scene, flags)
        GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, self._main_fb_ms)
        GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, self._main_fb)
        GL.glBlitFramebuffer(0, 0, width, height, 0, 0, width, height, GL.GL_COLOR_BUFFER_BIT, GL.GL_LINEAR)
        GL.glBlitFramebuffer(0, 0, width, height, 0, 0, width, height, GL.GL_DEPTH_BUFFER_BIT, GL.GL_NEAREST)
        GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, self._main_fb)
        cam = scene.main_camera_node.camera
        return _read_rgb(width, height), _read_depth(width, height, cam.znear, cam.zfar)

    def _configure_main_framebuffer(self):
        if self._fb_samples != self.samples:
            self._delete_main_framebuffer()
            self._fb_samples = self.samples
        storage = pyrender.renderer.glRenderbufferStorageMultisample
        # pyrender names the sample count in its call; swap the call for the one set here.
        pyrender.renderer.glRenderbufferStorageMultisample = lambda target, _n, *rest: storage(target, self.samples, *rest)
        try:
            super()._configure_main_framebuffer()
        finally:
            pyrender.renderer.glRenderbufferStorageMultisample = storage


def _shared_renderer(width: int, height: int) -> "pyrender.OffscreenRenderer":
    """One offscreen context per canvas size for the whole process.

    pyrender's EGL platform terminates the process-wide EGL display when any
    renderer is deleted, which breaks every other live renderer; sharing one
    context per size (released at exit) avoids that and saves the set-up cost.
    """
    key = (int(width), int(height))
    if key not in _RENDERERS:
        if not _RENDERERS:
            atexit.register(_release_renderers)
        r = pyrender.OffscreenRenderer(*key)
        r._renderer.__class__ = _SampledRenderer
        r._renderer._program_cache = _ProgramCache()
        _RENDERERS[key] = r
    return _RENDERERS[key]


def _release_renderers() -> None:
    for r in _RENDERERS.values():
        try:
            r.delete()
        except Exception:  # noqa: BLE001 - the process is exiting; nothing left to protect
            pass
    _RENDERERS.clear()


def _textured_plane(verts, faces, uv, normal, image: np.ndarray) -> pyrender.Mesh:
    tex = pyrender.Texture(source=image, source_channels="RGB")
    mat = pyrender.MetallicRoughnessMaterial(baseColorTexture=tex, metallicFactor=0.0, roughnessFactor=0.9)
    prim = pyrender.Primitive(
        positions=verts.astype(np.float32),
        normals=np.tile(normal, (len(verts), 1)).astype(np.float32),
        texcoord_0=uv.astype(np.float32),
        indices=faces.astype(np.uint32),
        material=mat,
    )
    return pyrender.Mesh([prim])


def _solid(m: trimesh.Trimesh, color, metallic=0.0, roughness=0.6, smooth=False) -> pyrender.Mesh:
    mat = pyrender.MetallicRoughnessMaterial(
        baseColorFactor=list(color) + [1.0], metallicFactor=metallic, roughnessFactor=roughness
    )
    return pyrender.Mesh.from_trimesh(m, material=mat, smooth=smooth)


class _InsertionOrdered(dict):
    """A set of pyrender nodes that iterates in the order they were added.

    pyrender keeps a scene's mesh and light nodes in sets, which iterate in the order
    of the nodes' hashes, their memory addresses: a new order in every process. It
    draws nodes at the same distance in that order (the set's planes all sit at the
    origin), so where two surfaces of the set are coplanar the depth test's winner,
    and a few pixels of the image, changed from run to run; the lights' order changes
    the shader's sums as well. With these, a scene renders the same pixels every time.
    """

    def add(self, node) -> None:
        self[node] = None

    def remove(self, node) -> None:
        del self[node]

    def discard(self, node) -> None:
        self.pop(node, None)

    def copy(self) -> "_InsertionOrdered":
        return _InsertionOrdered(self)

    def __or__(self, other) -> "_InsertionOrdered":
        out = self.copy()
        out.update(dict.fromkeys(other))
        return out


def _ordered_scene(**kwargs) -> pyrender.Scene:
    """An empty pyrender scene whose mesh and light nodes iterate in the order they are added (:class:`_InsertionOrdered`)."""
    scene = pyrender.Scene(**kwargs)
    for name in ("_mesh_nodes", "_point_light_nodes", "_spot_light_nodes", "_directional_light_nodes"):
        setattr(scene, name, _InsertionOrdered())
    return scene


def _coverage(seg: np.ndarray) -> np.ndarray:
    """The robot's coverage (h, w) float32 in [0, 1] of each pixel of a flat label pass ``seg`` (h, w, 3) uint8.

    Each tube's label colour is one full channel, so the channels' sum over 255 is
    the covered fraction. The channels are added one by one: ``sum(axis=2)`` over a
    3-wide axis is ~9x slower, and the integer sums are the same.
    """
    total = seg[..., 0].astype(np.float32)
    total += seg[..., 1]
    total += seg[..., 2]
    return np.minimum(total * np.float32(1.0 / 255.0), np.float32(1.0))


@njit(cache=True, nogil=True)
def _reflect101(i, n):  # pragma: no cover - compiled
    """Index ``i`` reflected into ``[0, n)`` without repeating the edge (OpenCV's BORDER_REFLECT_101)."""
    if n == 1:
        return 0
    while i < 0 or i >= n:
        i = -i if i < 0 else 2 * (n - 1) - i
    return i


@njit(cache=True, nogil=True)
def _premultiply_filled_nb(rgb, z, coverage, out):  # pragma: no cover - compiled
    """The one-sample lit pass ``rgb`` (h, w, 3) uint8, edges filled, premultiplied by ``coverage`` into ``out`` (float32).

    A pixel whose centre was drawn (``z > 0``) keeps its colour. A covered pixel that
    no centre sample hit takes the mean colour of the drawn pixels in its 3x3, else
    its 7x7 neighbourhood (reflected at the borders, as OpenCV's box filter is). The
    sums are of whole gray levels in float32, hence exact in any order. Returns how
    many covered pixels found no drawn neighbour (their ``out`` is not set).
    """
    h, w, c = rgb.shape
    left = 0
    acc = np.zeros(c, np.float32)
    for y in range(h):
        for x in range(w):
            cov = coverage[y, x]
            if z[y, x] > 0:
                for k in range(c):
                    out[y, x, k] = np.float32(rgb[y, x, k]) * cov
                continue
            for k in range(c):
                out[y, x, k] = 0.0
            if cov <= 0:
                continue
            found = False
            for r in (1, 3):
                n = np.float32(0.0)
                acc[:] = 0.0
                for dy in range(-r, r + 1):
                    yy = _reflect101(y + dy, h)
                    for dx in range(-r, r + 1):
                        xx = _reflect101(x + dx, w)
                        if z[yy, xx] > 0:
                            n += np.float32(1.0)
                            for k in range(c):
                                acc[k] += np.float32(rgb[yy, xx, k])
                if n > 0:
                    for k in range(c):
                        out[y, x, k] = (acc[k] / n) * cov
                    found = True
                    break
            if not found:
                left += 1
    return left


class SetRenderer:
    """Renders the scene's set (backdrop, clutter, lights) plus a robot, through a :class:`Camera`.

    Parameters
    ----------
    scene : Scene
        Supplies the set dressing, image size and the cameras (their K and
        distortion fix the canvas margin and the distortion maps).
    supersample : int, optional
        Render at this many times the resolution and average down (anti-aliasing).
        Default: 1 on EGL, whose multisampling anti-aliases edges, and 2 on OSMesa,
        which ignores multisampling and would leave edges and ground truth
        quantized to whole pixels.
    """

    def __init__(self, scene: Scene, supersample: int | None = None):
        self.scene = scene
        self.platform = _PLATFORM
        self.supersample = int(supersample or (2 if self.platform == "osmesa" else 1))
        # A mono sensor sees one weighted sum of R, G, B: resampling and compositing that
        # one channel is a third of the work of RGB (and the same, as both are linear).
        self.mono = scene.color == "mono"
        cams = list(scene.rig.cameras.values())
        self.width, self.height = cams[0].width, cams[0].height
        self._maps = {}
        self._ideal = {}
        self._set_cache = {}
        self._set_depth_median = {}
        self._map_buffers = {}
        margin = 4
        for cam in cams:
            margin = max(margin, self._margin_needed(cam))
        self.margin = margin
        for cam in cams:
            self._maps[cam.name] = self._distortion_maps(cam)
        d = scene.dressing
        # Transparent clear colour: passes of a subset of meshes come back with their coverage in alpha.
        self.pr_scene = _ordered_scene(bg_color=[0.0, 0.0, 0.0, 0.0], ambient_light=[d.ambient] * 3)
        self._add_set(scene)
        self._set_meshes = list(self.pr_scene.meshes)
        self._cam_node = None
        self._robot_nodes = []
        self.canvas = (self.width + 2 * margin, self.height + 2 * margin)
        ss = self.supersample
        self._renderer = _shared_renderer(self.canvas[0] * ss, self.canvas[1] * ss)

    # ------------------------------------------------------------------ set-up
    def _margin_needed(self, cam: Camera) -> int:
        """Canvas margin (px) so that every sensor pixel's ideal position lies on the canvas."""
        w, h = cam.width, cam.height
        u = np.arange(w, dtype=float)
        v = np.arange(h, dtype=float)
        border = np.concatenate(
            [
                np.stack([u, np.zeros(w)], 1),
                np.stack([u, np.full(w, h - 1.0)], 1),
                np.stack([np.zeros(h), v], 1),
                np.stack([np.full(h, w - 1.0), v], 1),
            ]
        )
        ideal = cam.undistort_pixels(border)
        over = max(-ideal[:, 0].min(), ideal[:, 0].max() - (w - 1), -ideal[:, 1].min(), ideal[:, 1].max() - (h - 1), 0)
        return int(np.ceil(over)) + 3

    def _distortion_maps(self, cam: Camera) -> tuple:
        """Sensor pixel -> ideal canvas position: OpenCV's fixed-point map pair.

        Also keeps the float map ``_ideal[name]`` ((H, W, 2) float32, canvas px), the one
        the jittered set view transforms.
        """
        uu, vv = np.meshgrid(np.arange(cam.width, dtype=float), np.arange(cam.height, dtype=float))
        ideal = cam.undistort_pixels(np.stack([uu.ravel(), vv.ravel()], 1)) + self.margin
        self._ideal[cam.name] = ideal.reshape(cam.height, cam.width, 2).astype(np.float32)
        return cv2.convertMaps(self._ideal[cam.name], None, cv2.CV_16SC2)

    def _add_set(self, scene: Scene) -> None:
        d = scene.dressing
        rng_seed = scene.seed
        cx = float(np.mean([c.T_world_cam[0, 3] for c in scene.rig.cameras.values()]))
        tex_px = d.texture_px or auto_texture_px(self.width, self.height)
        planes = backdrop_planes(scene)
        for i, plane in enumerate(planes):
            # Plane i's texture is seeded with seed + i (the floor and the wall of the original set: seed, seed + 1).
            tex = backdrop_texture(d.backdrop, d.backdrop_color, d.backdrop_color2, rng_seed + i, tex_px, d.pattern_scale, d.photo)
            geom = meshes.plane_mesh(plane.center_mm, plane.u_axis, plane.v_axis, plane.size_u_mm, plane.size_v_mm)
            self.pr_scene.add(_textured_plane(*geom, tex))
        T_world_base = scene.robot.T_world_base
        if d.actuation_unit:
            # The actuation unit sits behind the base along -insertion: a block carrying the
            # distal pin vise (outer tube) with the proximal one (inner tube) further back.
            def to_world(p_base):
                return (T_world_base[:3, :3] @ np.asarray(p_base, float).T).T + T_world_base[:3, 3]

            block = meshes.box_mesh(*ACTUATION_UNIT_BOX_BASE_MM)
            block.apply_transform(T_world_base)
            self.pr_scene.add(_solid(block, (0.22, 0.23, 0.25), metallic=0.3, roughness=0.5))
            chuck = meshes.cylinder_mesh(to_world([0, 0, -18.0]), to_world([0, 0, -6.0]), 5.0)
            nose = trimesh.creation.cone(radius=5.0, height=7.0, sections=32)
            nose.apply_translation([0, 0, -6.0])
            nose.apply_transform(T_world_base)
            collar = meshes.cylinder_mesh(to_world([0, 0, -6.0]), to_world([0, 0, -0.6]), 1.6)
            brass = (0.72, 0.58, 0.30)
            self.pr_scene.add(_solid(chuck, brass, metallic=0.8, roughness=0.35, smooth=True))
            self.pr_scene.add(_solid(collar, brass, metallic=0.8, roughness=0.35, smooth=True))
        if d.mount_posts:
            # Two posts of the camera mount beside the actuation unit, clear of the robot's workspace.
            for x, y in ((cx - 50.0, 40.0), (cx - 50.0, -40.0)):
                post = meshes.cylinder_mesh([x, y, d.floor_z_mm], [x, y, d.floor_z_mm + 22.0], 4.0)
                self.pr_scene.add(_solid(post, (0.35, 0.36, 0.38), metallic=0.5, roughness=0.4, smooth=True))
        # Clutter draws from its own stream, so adding it changes nothing else of the set.
        clutter_rng = np.random.default_rng(np.random.SeedSequence([rng_seed, 0xC1077E5]))
        for m, color, metallic, roughness in place_clutter(scene, planes, clutter_rng):
            self.pr_scene.add(_solid(m, color, metallic=metallic, roughness=roughness))
        for light in d.lights:
            if light.kind == "directional":
                z = -np.asarray(light.direction, float)
                z /= np.linalg.norm(z)
                x = np.cross([0.0, 1.0, 0.0] if abs(z[1]) < 0.9 else [1.0, 0.0, 0.0], z)
                x /= np.linalg.norm(x)
                pose = np.eye(4)
                pose[:3, :3] = np.stack([x, np.cross(z, x), z], 1)
                self.pr_scene.add(pyrender.DirectionalLight(color=light.color, intensity=light.intensity), pose=pose)
            else:
                pose = np.eye(4)
                pose[:3, 3] = light.position_mm
                self.pr_scene.add(pyrender.PointLight(color=light.color, intensity=light.intensity), pose=pose)

    # ------------------------------------------------------------------ robot
    def set_robot(self, tube_meshes: list | None) -> None:
        """Replace the robot by ``tube_meshes`` (``[(tube index, trimesh), ...]``) or remove it (None).

        Each tube gets two nodes: its Nitinol look for the camera image and a flat
        label colour for the ground-truth pass (only one of them visible at a time).
        """
        for node, truth_node, _ in self._robot_nodes:
            self.pr_scene.remove_node(node)
            self.pr_scene.remove_node(truth_node)
        self._robot_nodes = []
        if not tube_meshes:
            return
        if len(tube_meshes) > len(_SEG_COLORS):
            raise ValueError(f"the label pass separates at most {len(_SEG_COLORS)} visible tubes, got {len(tube_meshes)}")
        d = self.scene.dressing
        look = pyrender.MetallicRoughnessMaterial(
            baseColorFactor=list(d.robot_color) + [1.0], metallicFactor=d.robot_metallic, roughnessFactor=d.robot_roughness
        )
        for k, (idx, m) in enumerate(tube_meshes):
            flat = pyrender.MetallicRoughnessMaterial(baseColorFactor=[c / 255 for c in _SEG_COLORS[k]] + [1.0])
            # Smooth shading, as pyrender.Mesh.from_trimesh(smooth=True) gives it, without trimesh's
            # normals and a deep copy of the material per tube (~2.5 ms a tube a frame).
            lit = pyrender.Primitive(positions=m.vertices, normals=meshes.vertex_normals(m.vertices, m.faces), indices=m.faces, material=look)
            node = self.pr_scene.add(pyrender.Mesh([lit]))
            # The same triangles, unlit: the flat pass needs neither normals nor unshared vertices.
            truth = pyrender.Mesh([pyrender.Primitive(positions=m.vertices, indices=m.faces, material=flat)])
            truth.is_visible = False
            truth_node = self.pr_scene.add(truth)
            self._robot_nodes.append((node, truth_node, idx))

    def set_props(self, props: list | None) -> None:
        """Replace the extra props of the set (e.g. a calibration board) or remove them (None).

        Props are part of the set: they are drawn in the set pass (the set view cache
        is dropped, so the next frame of each camera renders them), hide the robot
        where they are in front of it, and move with camera jitter like the set.

        Parameters
        ----------
        props : list or None
            Items are a ``pyrender.Mesh`` (vertices in world mm) or a
            ``(pyrender.Mesh, T_world_mesh)`` pair (4x4, mesh frame -> world, mm); the
            same mesh may be placed again at another pose without re-uploading it.
        """
        for node in getattr(self, "_prop_nodes", []):
            self.pr_scene.remove_node(node)
        self._prop_nodes = []
        for item in props or []:
            mesh, pose = item if isinstance(item, tuple) else (item, np.eye(4))
            self._prop_nodes.append(self.pr_scene.add(mesh, pose=np.asarray(pose, dtype=np.float64)))
        if hasattr(self, "_set_meshes"):
            if not hasattr(self, "_bare_set_meshes"):
                self._bare_set_meshes = list(self._set_meshes)
            self._set_meshes = self._bare_set_meshes + [node.mesh for node in self._prop_nodes]
            self._set_cache.clear()

    # ------------------------------------------------------------------ render
    def _place_camera(self, camera: Camera, origin: tuple = (0, 0), ss: int | None = None) -> None:
        """Make ``camera`` pyrender's camera, for a viewport whose top-left pixel is canvas pixel ``origin`` (u, v).

        ``ss``: render pixels per canvas pixel, each way (default: the renderer's supersampling).
        """
        K = camera.K
        m = self.margin
        ss = self.supersample if ss is None else ss
        u0, v0 = origin
        # pyrender's window coordinates put pixel centres at +0.5, OpenCV's at integers; a
        # supersampled canvas scales window coordinates by ss. Moving the principal point by
        # the origin makes the viewport a window of the full canvas (pyrender counts rows from the top).
        intrinsics = dict(fx=K[0, 0] * ss, fy=K[1, 1] * ss, cx=(K[0, 2] + m + 0.5 - u0) * ss, cy=(K[1, 2] + m + 0.5 - v0) * ss)
        T_world_glcam = camera.T_world_cam @ T_cvcam_glcam
        if self._cam_node is None:
            self._cam_node = self.pr_scene.add(pyrender.IntrinsicsCamera(**intrinsics, znear=20.0, zfar=2000.0), pose=T_world_glcam)
            return
        # One camera node, moved and re-aimed: adding and removing a node costs ~0.4 ms a pass.
        for name, value in intrinsics.items():
            setattr(self._cam_node.camera, name, value)
        self.pr_scene.set_pose(self._cam_node, T_world_glcam)

    def render(self, camera: Camera, with_truth: bool = True) -> View:
        """Render the set (and robot, if set) through ``camera`` (its pose may be jittered).

        The static set is rendered once per camera at its nominal pose and cached;
        a jittered view of it is obtained by re-projecting every pixel through its
        depth (exact up to the depth change within one pixel of motion). Only the
        robot is rendered per frame, at the jittered pose, and composited over the
        set with its anti-aliased coverage, hidden where the set is in front of it.

        Parameters
        ----------
        camera : Camera
            Must have the name of one of the scene's cameras (selects the distortion maps).
        with_truth : bool
            Also render the robot label and depth pass.
        """
        if camera.name not in self._maps:
            raise KeyError(f"renderer has no camera {camera.name!r}")
        radiance, set_map = self._set_radiance(camera)
        labels = depth = None
        if not self._robot_nodes:
            return View(radiance=radiance, labels=None, depth_mm=None)
        box = self._robot_box(camera)
        if box is None:  # the robot is entirely outside this view
            empty = (np.zeros(radiance.shape[:2], np.uint8), np.zeros(radiance.shape[:2], np.float32))
            return View(radiance=radiance, labels=empty[0] if with_truth else None, depth_mm=empty[1] if with_truth else None)
        (v0, v1), (u0, u1) = box
        # Only the canvas window that the sensor box resamples is rendered (the robot covers
        # a few per cent of the image; clearing, resolving and reading the whole canvas cost more than drawing it).
        port = self._robot_viewport(camera, box)
        m1, m2 = self._box_maps(camera, box, port[:2])
        self._place_camera(camera, port[:2])
        seg, lab, dep, hidden, coverage = self._truth_pass(m1, m2, self._set_depth(camera, set_map[v0:v1, u0:u1]), port[2:])
        # Robot alone on black, premultiplied by the flat pass's coverage (OSMesa contexts
        # have no alpha channel to carry it). Only the robot's box on the sensor is
        # resampled and composited.
        robot = self._signal(cv2.remap(self._look(camera, port, coverage), m1, m2, cv2.INTER_LINEAR))
        visible = (~hidden).astype(np.float32)
        keep = 1.0 - _coverage(seg) * visible
        if robot.ndim == 3:
            visible, keep = visible[..., None], keep[..., None]
        radiance[v0:v1, u0:u1] = robot * visible + radiance[v0:v1, u0:u1] * keep
        if with_truth:
            labels = np.zeros(radiance.shape[:2], np.uint8)
            depth = np.zeros(radiance.shape[:2], np.float32)
            labels[v0:v1, u0:u1] = lab
            depth[v0:v1, u0:u1] = dep
        return View(radiance=radiance, labels=labels, depth_mm=depth)

    def _look(self, camera: Camera, port: tuple, coverage: np.ndarray) -> np.ndarray:
        """The lit robot in viewport ``port`` (canvas px), premultiplied by ``coverage``: (h, w, 3) float32 in [0, 255].

        The lit pass is drawn with one sample a canvas pixel, which halves llvmpipe's
        shading; its colour is exact where it covers a pixel centre. Edge pixels that
        the flat pass covers but no centre sample did take the mean colour of their
        covered neighbours (3x3, then 7x7). Where a thin tube leaves covered pixels with
        no sampled neighbour, the lit pass is drawn again, multisampled, as it was.
        """
        look = [node.mesh for node, _, _ in self._robot_nodes]
        self._place_camera(camera, port[:2], ss=1)
        rgb, z = self._render_only(look, pyrender.RenderFlags.NONE, port[2:], ss=1, samples=0)
        out = np.empty(rgb.shape, np.float32)
        if _premultiply_filled_nb(rgb, z, coverage, out):
            self._place_camera(camera, port[:2])
            rgb, _ = self._render_only(look, pyrender.RenderFlags.NONE, port[2:])
            return rgb.astype(np.float32)
        return out

    def _robot_box(self, camera: Camera, pad_px: int = 4):
        """Sensor rows and columns ``((v0, v1), (u0, u1))`` that can hold the robot, or None."""
        verts = np.concatenate([node.mesh.primitives[0].positions for node, _, _ in self._robot_nodes])
        uv, z = camera.project(verts[::3].astype(np.float64))
        uv = uv[z > 0]
        if uv.size == 0:
            return None
        u0 = int(np.floor(np.nanmin(uv[:, 0]))) - pad_px
        u1 = int(np.ceil(np.nanmax(uv[:, 0]))) + pad_px + 1
        v0 = int(np.floor(np.nanmin(uv[:, 1]))) - pad_px
        v1 = int(np.ceil(np.nanmax(uv[:, 1]))) + pad_px + 1
        u0, v0 = max(u0, 0), max(v0, 0)
        u1, v1 = min(u1, camera.width), min(v1, camera.height)
        if u1 <= u0 or v1 <= v0:
            return None
        return (v0, v1), (u0, u1)

    def _robot_viewport(self, camera: Camera, box: tuple) -> tuple:
        """The canvas window ``(u0, v0, width, height)`` (canvas px) that remapping the sensor ``box`` reads.

        It holds every canvas pixel the bilinear remap of the box touches (the fixed-point
        maps may round up to the next pixel, hence one pixel more each side), kept inside
        the canvas, where rendering it gives the same pixels as rendering the whole canvas.
        Its size differs between cameras, so on EGL pyrender re-makes its framebuffer at
        most renders: that costs under a millisecond (rounding sizes up saved nothing).
        """
        (v0, v1), (u0, u1) = box
        box_ideal = self._ideal[camera.name][v0:v1, u0:u1]
        origin, size = [], []
        for ideal, full in ((box_ideal[..., 0], self.canvas[0]), (box_ideal[..., 1], self.canvas[1])):
            lo = int(np.floor(ideal.min())) - 1
            hi = int(np.floor(ideal.max())) + 3
            n = min(hi - lo, full)
            origin.append(int(np.clip(lo, 0, full - n)))
            size.append(n)
        return origin[0], origin[1], size[0], size[1]

    def _box_maps(self, camera: Camera, box: tuple, origin: tuple) -> tuple:
        """OpenCV's fixed-point distortion maps of the sensor ``box``, into a viewport whose top-left is canvas pixel ``origin``.

        The integer part of the fixed-point maps is the canvas pixel; shifting it by the
        origin leaves the sub-pixel weights, and so every resampled value, unchanged.
        """
        (v0, v1), (u0, u1) = box
        m1, m2 = self._maps[camera.name]
        # cv2.subtract: numpy broadcasting a 2-vector over a strided window takes ~7x as long.
        return cv2.subtract(m1[v0:v1, u0:u1], (float(origin[0]), float(origin[1]), 0.0, 0.0)), m2[v0:v1, u0:u1]

    @staticmethod
    def _hidden(z_robot: np.ndarray, z_set: np.ndarray) -> np.ndarray:
        """Where the robot is drawn behind the set (0.5 mm: beyond depth-buffer noise).

        Coverage, not depth, says where the robot is drawn: at anti-aliased edges the
        resolved depth may come from a background sample, so a pixel is only called
        hidden when both depths are known.
        """
        return (z_robot > 0) & (z_set > 0) & (z_set < z_robot - 0.5)

    def _render_only(self, meshes: list, flags, size: tuple | None = None, ss: int | None = None, samples: int = 4) -> tuple:
        """Render ``meshes`` alone (everything else hidden) on a transparent canvas.

        ``size``: (width, height) of the viewport in canvas px (default: the whole canvas),
        at the camera last placed (:meth:`_place_camera` gives its origin and must be given
        the same ``ss``, render pixels per canvas pixel; default the renderer's
        supersampling). ``samples``: multisamples of a framebuffer platform (0: none).
        Returns its colour (h, w, 3) uint8 and depth (h, w) float32 mm (0: nothing drawn),
        supersampling averaged out.
        """
        w, h = size or self.canvas
        ss = self.supersample if ss is None else ss
        shown = [m for m in self.pr_scene.meshes if m.is_visible]
        for m in shown:
            m.is_visible = False
        for m in meshes:
            m.is_visible = True
        try:
            color, z = self._draw(flags, w * ss, h * ss, samples)
        finally:
            for m in meshes:
                m.is_visible = False
            for m in shown:
                m.is_visible = True
        if ss == 1:
            return color, z
        return self._downsample(color, (w, h)), self._downsample_depth(z, (w, h))

    def _draw(self, flags, width: int, height: int, samples: int = 4) -> tuple:
        """pyrender's colour and depth of the scene in a ``width`` x ``height`` viewport (render px), ``samples`` multisamples."""
        r = self._renderer
        if self.platform != "osmesa":
            # Framebuffer platforms: pyrender re-makes its framebuffer when the size (or here the samples) change.
            r._renderer.samples = samples
            r.viewport_width, r.viewport_height = width, height
            return r.render(self.pr_scene, flags=flags)
        # OSMesa has no framebuffer objects: pyrender would destroy the context to change the
        # size (and with it every mesh and texture uploaded). Draw into the lower-left corner
        # of the canvas-sized buffer instead, the way pyrender's OffscreenRenderer reads it back.
        r._platform.make_current()
        inner = r._renderer
        inner.viewport_width, inner.viewport_height = width, height
        # The scissor keeps the clear to the viewport (pyrender clears the whole buffer).
        GL.glEnable(GL.GL_SCISSOR_TEST)
        GL.glScissor(0, 0, width, height)
        try:
            inner.render(self.pr_scene, flags)
        finally:
            GL.glDisable(GL.GL_SCISSOR_TEST)
        # pyrender's read_color_buf / read_depth_buf, their depth linearized in one compiled pass.
        GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, 0)
        GL.glReadBuffer(GL.GL_FRONT)
        return _read_rgb(width, height), _read_depth(width, height, inner._latest_znear, inner._latest_zfar)

    def _signal(self, color: np.ndarray) -> np.ndarray:
        """Rendered colour (h, w, 3) uint8 as radiance in [0, 1]: float32 RGB, or its :data:`LUMA` sum (h, w) for a mono scene."""
        radiance = color.astype(np.float32) * np.float32(1.0 / 255.0)
        return radiance @ LUMA if self.mono else radiance

    def _nominal_set(self, name: str) -> tuple:
        """The set through camera ``name`` at its nominal pose, on the canvas: radiance (:meth:`_signal`) and depth (mm), cached."""
        if name not in self._set_cache:
            self._place_camera(self.scene.rig[name])
            color, z = self._render_only(self._set_meshes, pyrender.RenderFlags.NONE)
            self._set_cache[name] = (self._signal(color), z.astype(np.float32))
        return self._set_cache[name]

    def _set_radiance(self, camera: Camera) -> tuple:
        """The set's radiance through ``camera`` at the sensor pixels (H, W[, 3]) float32, and its map (:meth:`_set_maps`)."""
        image, z = self._nominal_set(camera.name)
        set_map = self._set_maps(camera, z)
        return cv2.remap(image, set_map, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE), set_map

    def _set_view(self, camera: Camera) -> tuple:
        """The set through ``camera``: radiance (H, W[, 3]) float32 and depth (H, W) mm at the sensor pixels."""
        radiance, set_map = self._set_radiance(camera)
        return radiance, self._set_depth(camera, set_map)

    def _set_depth(self, camera: Camera, set_map: np.ndarray) -> np.ndarray:
        """The set's depth (mm, float32) at the sensor pixels whose :meth:`_set_maps` positions are ``set_map``."""
        _, z = self._nominal_set(camera.name)
        return cv2.remap(z, set_map, None, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)

    def _set_maps(self, camera: Camera, z_nominal: np.ndarray) -> np.ndarray:
        """Sensor pixel -> position on the nominal canvas, through lens distortion and jitter: (H, W, 2) float32 canvas px.

        The map is the renderer's own (the camera's buffer, reused next frame): read it, do not keep it.

        The jitter (a camera motion of about a pixel) is applied as the homography of
        a fronto-parallel plane at the set's median depth: the parallax it neglects,
        between the robot's depth and the backdrop's, is below 0.1 px for the jitter
        of a rigid camera mount (0.035 mm at 300 vs 370 mm: 0.06 px).
        """
        ideal = self._ideal[camera.name]
        nominal = self.scene.rig[camera.name]
        D = camera.T_cam_world @ nominal.T_world_cam  # nominal camera frame -> jittered camera frame
        if np.allclose(D, np.eye(4), atol=1e-12):
            return ideal
        if camera.name not in self._set_depth_median:
            self._set_depth_median[camera.name] = float(np.median(z_nominal[z_nominal > 0]))
        d = self._set_depth_median[camera.name]
        # X_nominal = R^T (X_jittered - t), with X_jittered = d K^-1 p on the plane z = d.
        Kc = camera.K.copy()
        Kc[:2, 2] += self.margin  # canvas coordinates
        R, t = D[:3, :3], D[:3, 3]
        H = Kc @ R.T @ (np.eye(3) - np.outer(t, [0.0, 0.0, 1.0]) / d) @ np.linalg.inv(Kc)
        # Into the camera's own buffer: a fresh 6 MB map each frame costs more in page faults than the transform.
        if camera.name not in self._map_buffers:
            self._map_buffers[camera.name] = np.empty_like(ideal)
        out = self._map_buffers[camera.name]
        cv2.perspectiveTransform(ideal.reshape(-1, 1, 2), H, dst=out.reshape(-1, 1, 2))
        return out

    def _downsample(self, image: np.ndarray, size: tuple) -> np.ndarray:
        """Average a supersampled viewport down to ``size`` (width, height) canvas px (area filter)."""
        return cv2.resize(image, size, interpolation=cv2.INTER_AREA)

    def _downsample_depth(self, z: np.ndarray, size: tuple) -> np.ndarray:
        """Depth of a supersampled viewport at ``size`` canvas px: the first sample of each pixel (no mixing of depths)."""
        return cv2.resize(z, size, interpolation=cv2.INTER_NEAREST)

    def _truth_pass(self, m1, m2, set_depth: np.ndarray, size: tuple) -> tuple:
        """Robot coverage, labels and depth: the tubes alone, in flat label colours.

        A flat (unlit) colour pass keeps the renderer's anti-aliasing, so a label's
        coverage is resolved below a pixel; pyrender's SEG pass is not multisampled
        and would quantize the ground truth to whole pixels. Parts hidden by the
        set (inside the pin vise collar) are removed with the set's depth.

        Parameters
        ----------
        m1, m2 : OpenCV fixed-point maps
            Sensor box pixel -> viewport position (:meth:`_box_maps`).
        set_depth : (h, w) float32
            The set's depth (mm) at the box's sensor pixels.
        size : (int, int)
            Viewport (width, height) in canvas px, at the camera last placed.

        Returns
        -------
        seg : (H, W, 3) uint8
            Flat colour pass (coverage per tube colour).
        labels : (H, W) uint8
            0, or 1 + tube index where that tube covers at least half the pixel and is visible.
        depth : (H, W) float32
            Depth (mm) of the visible robot surface, 0 elsewhere.
        hidden : (H, W) bool
            Where the robot is drawn but the set is in front of it.
        coverage : (h, w) float32
            The robot's coverage of each viewport pixel (0-1), before resampling.
        """
        canvas_seg, z = self._render_only([t.mesh for _, t, _ in self._robot_nodes], pyrender.RenderFlags.FLAT, size)
        coverage = _coverage(canvas_seg)
        seg = cv2.remap(canvas_seg, m1, m2, cv2.INTER_LINEAR)
        depth = cv2.remap(z, m1, m2, cv2.INTER_NEAREST)
        hidden = self._hidden(depth, set_depth)
        labels = np.zeros(seg.shape[:2], np.uint8)
        for k, (_, _, idx) in enumerate(self._robot_nodes):
            ch = int(np.argmax(_SEG_COLORS[k]))
            # A pixel belongs to a tube when the tube covers at least half of it.
            labels[seg[..., ch] >= 128] = idx + 1
        labels[hidden] = 0
        depth[labels == 0] = 0.0
        return seg, labels, depth, hidden, coverage

    def close(self) -> None:
        """Forget the renderer (the shared OpenGL context lives until the process exits)."""
        self._renderer = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
