"""The calibration twin: a printed checkerboard rendered through the rig in known poses.

A *calibration scene* (``scenes/calibration.toml``; keys in docs/calibration.md) names a
rig scene (the cameras, the set, the lights and the sensor noise, e.g.
``paper.toml``) and adds the board and its poses:

* ``[poses]``: views for each camera's intrinsics (the paper used 20 per camera);
* ``[stereo]``: poses seen by both cameras, for the stereo calibration;
* ``[world]``: the image(s) of the board lying in the world-frame pose, taken by
  the top camera.

``render_calibration`` renders them (robot absent, the rig scene's sensor noise)
and ``write_capture`` lays them out as ``ctr-bench calibrate`` reads them.

Board frame (the calibration's world-frame convention, see
:mod:`recon.calibration`): origin at the first inner corner, x along the
``cols`` inner corners, y along the ``rows``, z = x × y out of the printed face.
The square between the first four inner corners is black.

The true rig is the rig scene's (its cameras' ``T_cam_world`` are the truth that
calibration must recover); the world board lies with its axes along the world
axes and its first inner corner at ``world.origin_mm``.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from recon.calibration import BoardSpec
from recon.camera import Camera
from recon.geometry import rotation_matrix, transform_points

from .noise import expose, frame_rng, jitter_camera
from .scene import Scene, load_scene
from .schema import POSITIVE, REQUIRED, SceneError, Table, read_toml

__all__ = [
    "CalibrationScene",
    "BoardLook",
    "ViewRange",
    "StereoRange",
    "CalibrationCapture",
    "load_calibration_scene",
    "calibration_scene_from_dict",
    "board_meshes",
    "checker_texture",
    "plate_outline",
    "SetClearance",
    "sample_view_poses",
    "sample_stereo_poses",
    "render_calibration",
    "write_capture",
]

FORMAT = "ctr-bench-calibration-scene"


# ----------------------------------------------------------------------------- scene
@dataclass(frozen=True)
class BoardLook:
    """How the printed board looks: white border, plate thickness, ink and paper reflectance."""

    margin_mm: float = 6.0
    thickness_mm: float = 3.0
    black: float = 0.02
    white: float = 0.45
    plate_color: tuple = (0.55, 0.56, 0.58)


@dataclass(frozen=True)
class ViewRange:
    """Random single-camera views of the board.

    Attributes
    ----------
    cameras : tuple of str
        Cameras that take views.
    count : int
        Views per camera.
    distance_mm : (min, max)
        Depth of the board centre along the optical axis.
    tilt_deg : (min, max)
        Angle between the board normal and the line of sight to its centre.
    roll_deg : float
        In-plane rotation drawn uniformly in [-roll, roll] from the board's x along image x.
    flip : bool
        Turn every other view by 180 degrees in its plane (the board upside down).
    spread : float
        The board centre's image position is drawn within this fraction of the image
        half-size around the image centre.
    edge_margin_px : float
        The whole plate must project this far inside the image.
    """

    cameras: tuple = ("side", "top")
    count: int = 20
    distance_mm: tuple = (240.0, 300.0)
    tilt_deg: tuple = (5.0, 50.0)
    roll_deg: float = 15.0
    flip: bool = True
    spread: float = 0.2
    edge_margin_px: float = 10.0


@dataclass(frozen=True)
class StereoRange:
    """Random poses seen by both cameras: the board faces the bisector of their optical axes."""

    count: int = 12
    center_mm: tuple = (45.0, 0.0, 0.0)
    center_spread_mm: tuple = (20.0, 10.0, 10.0)
    normal_spread_deg: float = 12.0
    roll_deg: float = 180.0
    max_oblique_deg: float = 62.0


@dataclass(frozen=True, eq=False)
class CalibrationScene:
    """A validated calibration scene.

    Attributes
    ----------
    name, source : str
    rig_scene : Scene
        The rig (true cameras), set, lights and noise model.
    board : BoardSpec
    look : BoardLook
    seed : int
    jitter : bool
        Apply the rig scene's per-image camera jitter.
    views : ViewRange
    stereo : StereoRange
    world_origin_mm : (3,) array
        World position of the world board's first inner corner (its axes are the world axes).
    world_exposures : int
        Images taken of the world board lying still (sensor noise differs; averaged by calibration).
    """

    name: str
    source: str
    rig_scene: Scene
    board: BoardSpec
    look: BoardLook
    seed: int
    jitter: bool
    views: ViewRange
    stereo: StereoRange
    world_origin_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    world_exposures: int = 1

    @property
    def rig(self):
        """The true rig (world frame of the rig scene)."""
        return self.rig_scene.rig

    @property
    def T_world_board(self) -> np.ndarray:
        """``T_world_board`` (4x4, mm): the world board's frame -> the world frame (axes shared, origin at
        ``world_origin_mm``)."""
        T_world_board = np.eye(4)
        T_world_board[:3, 3] = self.world_origin_mm
        return T_world_board


def _pair(t: Table, key, default, lo=None, hi=None):
    v = t.get(key, list(default), ("vec", 2))
    if v[0] > v[1]:
        t.fail(key, f"must be [min, max] with min <= max, got {v!r}")
    if lo is not None and v[0] < lo:
        t.fail(key, f"must be >= {lo}, got {v!r}")
    if hi is not None and v[1] > hi:
        t.fail(key, f"must be <= {hi}, got {v!r}")
    return tuple(v)


def calibration_scene_from_dict(data: dict, source: str = "<calibration scene>", base_dir: Path | None = None) -> CalibrationScene:
    """Validate a parsed calibration-scene TOML document; errors name the file and key."""
    top = Table(data, "", source)
    top.get("format", REQUIRED, str, lambda v: v == FORMAT, f'must be "{FORMAT}"')
    top.get("version", 1, int, lambda v: v == 1, "must be 1 (the only version this ctr-bench reads)")
    name = top.get("name", Path(source).stem, str)
    rig_name = top.get("rig_scene", REQUIRED, str)
    seed = top.get("seed", 0, int, lambda v: v >= 0, "must be >= 0")
    jitter = top.get("jitter", True, bool)
    rig_path = Path(rig_name)
    if not rig_path.is_absolute():
        rig_path = (base_dir or Path(".")) / rig_path
    if not rig_path.is_file():
        top.fail("rig_scene", f"no such scene file {str(rig_path)!r}")
    rig_scene = load_scene(rig_path)
    missing = {"side", "top"} - set(rig_scene.rig.cameras)
    if missing:
        top.fail("rig_scene", f"the rig must have cameras 'side' and 'top' (missing {', '.join(sorted(missing))})")

    b = top.table("board", required=True)
    cols = b.get("cols", REQUIRED, int, lambda v: v >= 3, "must be >= 3")
    rows = b.get("rows", REQUIRED, int, lambda v: v >= 3, "must be >= 3")
    if cols == rows:
        b.fail("rows", f"must differ from cols={cols} (a square board's orientation is ambiguous)")
    square = b.get("square_mm", REQUIRED, float, *POSITIVE)
    look = BoardLook(
        margin_mm=b.get("margin_mm", 6.0, float, lambda v: v >= 0, "must be >= 0"),
        thickness_mm=b.get("thickness_mm", 3.0, float, *POSITIVE),
        black=b.get("black", 0.02, float, lambda v: 0 <= v <= 1, "must be in [0, 1]"),
        white=b.get("white", 0.45, float, lambda v: 0 <= v <= 1, "must be in [0, 1]"),
        plate_color=tuple(b.get("plate_color", [0.55, 0.56, 0.58], ("vec", 3))),
    )
    if look.white <= look.black:
        b.fail("white", f"must be brighter than black={look.black}, got {look.white}")
    b.done()
    board = BoardSpec(cols, rows, square)

    p = top.table("poses")
    cams = p.get("cameras", ["side", "top"])
    if not isinstance(cams, list) or not all(isinstance(c, str) for c in cams) or not cams:
        p.fail("cameras", f"must be a non-empty list of camera names, got {cams!r}")
    for c in cams:
        if c not in rig_scene.rig.cameras:
            p.fail("cameras", f"the rig has no camera {c!r} (has {', '.join(rig_scene.rig.cameras)})")
    views = ViewRange(
        cameras=tuple(cams),
        count=p.get("count", 20, int, lambda v: v >= 0, "must be >= 0"),
        distance_mm=_pair(p, "distance_mm", (240.0, 300.0), lo=1.0),
        tilt_deg=_pair(p, "tilt_deg", (5.0, 50.0), lo=0.0, hi=80.0),
        roll_deg=p.get("roll_deg", 15.0, float, lambda v: 0 <= v <= 180, "must be in [0, 180]"),
        flip=p.get("flip", True, bool),
        spread=p.get("spread", 0.2, float, lambda v: 0 <= v <= 1, "must be in [0, 1]"),
        edge_margin_px=p.get("edge_margin_px", 10.0, float, lambda v: v >= 0, "must be >= 0"),
    )
    p.done()

    s = top.table("stereo")
    stereo = StereoRange(
        count=s.get("count", 12, int, lambda v: v >= 0, "must be >= 0"),
        center_mm=tuple(s.get("center_mm", [45.0, 0.0, 0.0], ("vec", 3))),
        center_spread_mm=tuple(s.get("center_spread_mm", [20.0, 10.0, 10.0], ("vec", 3), lambda v: min(v) >= 0, "must be >= 0")),
        normal_spread_deg=s.get("normal_spread_deg", 12.0, float, lambda v: 0 <= v <= 40, "must be in [0, 40]"),
        roll_deg=s.get("roll_deg", 180.0, float, lambda v: 0 <= v <= 180, "must be in [0, 180]"),
        max_oblique_deg=s.get("max_oblique_deg", 62.0, float, lambda v: 45 < v < 85, "must be in (45, 85)"),
    )
    s.done()

    w = top.table("world")
    origin = np.asarray(w.get("origin_mm", [0.0, 0.0, 0.0], ("vec", 3)))
    exposures = w.get("exposures", 1, int, lambda v: 1 <= v <= 50, "must be in [1, 50]")
    w.done()
    top.done()
    return CalibrationScene(
        name=name, source=source, rig_scene=rig_scene, board=board, look=look, seed=seed, jitter=jitter,
        views=views, stereo=stereo, world_origin_mm=origin, world_exposures=exposures,
    )


def load_calibration_scene(path) -> CalibrationScene:
    """Load and validate a calibration scene; ``rig_scene`` is relative to the file's folder."""
    path = Path(path)
    data = read_toml(path, "calibration scene file", SceneError)
    return calibration_scene_from_dict(data, source=str(path), base_dir=path.parent)


# ----------------------------------------------------------------------------- geometry
def plate_outline(board: BoardSpec, look: BoardLook) -> np.ndarray:
    """The 8 corners (board frame, mm) of the plate: printed face (z = 0) and back."""
    s = board.square_mm
    lo = np.array([-s - look.margin_mm, -s - look.margin_mm])
    hi = np.array([board.cols * s + look.margin_mm, board.rows * s + look.margin_mm])
    xy = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    face = np.concatenate([xy, np.zeros((4, 1))], 1)
    back = np.concatenate([xy, np.full((4, 1), -look.thickness_mm)], 1)
    return np.concatenate([face, back])


def _linear_to_srgb(x: float) -> float:
    return 12.92 * x if x <= 0.0031308 else 1.055 * x ** (1 / 2.4) - 0.055


def checker_texture(board: BoardSpec, look: BoardLook, texels_per_square: int = 16) -> np.ndarray:
    """The printed squares as an RGB texture (rows + 1 by cols + 1 squares), sRGB-encoded.

    Row 0 of the image is the board's y = -square edge (texture v = 0). Values are relative
    to the paper's reflectance (white = 255), the material scales them.
    """
    t = int(texels_per_square)
    nx, ny = board.cols + 1, board.rows + 1
    i = np.arange(nx * t) // t  # square index + 1 along x
    j = np.arange(ny * t) // t
    black = (i[None, :] + j[:, None]) % 2 == 0  # square (i-1, j-1) black when i + j is even
    ink = round(255 * _linear_to_srgb(look.black / look.white))
    img = np.where(black, ink, 255).astype(np.uint8)
    return np.repeat(img[:, :, None], 3, axis=2)


def board_meshes(board: BoardSpec, look: BoardLook | None = None, texels_per_square: int = 16) -> list:
    """pyrender meshes of the board in its own frame (mm): printed face at z = 0, plate behind.

    The squares are a texture on one quad whose edges fall on texel boundaries (a
    power-of-two number of texels per square, so every mipmap level keeps them there).
    At the paper rig's scale a texel spans 2-3 pixels, and bilinear texture filtering
    draws each edge as a smooth ramp of that width, as a lens would blur it: corners
    then lie exactly where the board frame says at any sub-pixel position. Sharper
    edges (geometry squares, or many texels per pixel) are quantized by the rasterizer
    and pull detected corners toward pixel boundaries by up to 0.1 px. The white
    border is plain geometry.
    """
    import pyrender  # noqa: PLC0415 - twin.render chose the OpenGL platform
    import trimesh  # noqa: PLC0415

    look = look or BoardLook()
    s = board.square_mm
    x0, y0, x1, y1 = -s, -s, board.cols * s, board.rows * s
    z = np.float32(0.0)
    verts = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], np.float32)
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
    normals = np.tile(np.array([0.0, 0.0, 1.0], np.float32), (4, 1))
    tris = np.array([[0, 1, 2], [0, 2, 3]], np.uint32)
    clamp = 33071  # GL_CLAMP_TO_EDGE
    tex = pyrender.Texture(
        source=checker_texture(board, look, texels_per_square), source_channels="RGB",
        sampler=pyrender.Sampler(magFilter=9729, minFilter=9987, wrapS=clamp, wrapT=clamp),  # LINEAR, LINEAR_MIPMAP_LINEAR
    )
    ink = pyrender.MetallicRoughnessMaterial(
        baseColorTexture=tex, baseColorFactor=[look.white] * 3 + [1.0], metallicFactor=0.0, roughnessFactor=0.95
    )
    prims = [pyrender.Primitive(positions=verts, normals=normals, texcoord_0=uv, indices=tris, material=ink)]
    m = look.margin_mm
    if m > 0:
        X0, Y0, X1, Y1 = x0 - m, y0 - m, x1 + m, y1 + m
        rects = np.array([(X0, Y0, X1, y0), (X0, y1, X1, Y1), (X0, y0, x0, y1), (x1, y0, X1, y1)], float)
        v = np.stack(
            [rects[:, [0, 1]], rects[:, [2, 1]], rects[:, [2, 3]], rects[:, [0, 3]]], 1
        ).reshape(-1, 2)
        mv = np.concatenate([v, np.zeros((len(v), 1))], 1).astype(np.float32)
        base = 4 * np.arange(len(rects))[:, None]
        mf = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]]).astype(np.uint32)
        paper = pyrender.MetallicRoughnessMaterial(baseColorFactor=[look.white] * 3 + [1.0], metallicFactor=0.0, roughnessFactor=0.95)
        prims.append(
            pyrender.Primitive(positions=mv, normals=np.tile(normals[:1], (len(mv), 1)), indices=mf, material=paper)
        )
    face = pyrender.Mesh(prims)
    corners = plate_outline(board, look)
    lo = corners.min(0)
    hi = corners.max(0)
    hi[2] = -0.05  # just behind the print, clear of depth-buffer fighting
    box = trimesh.creation.box(extents=hi - lo)
    box.apply_translation((lo + hi) / 2)
    plate_mat = pyrender.MetallicRoughnessMaterial(
        baseColorFactor=list(look.plate_color) + [1.0], metallicFactor=0.2, roughnessFactor=0.6
    )
    plate = pyrender.Mesh.from_trimesh(box, material=plate_mat, smooth=False)
    return [face, plate]


def _facing_frame(normal_toward_viewer: np.ndarray, up_hint: np.ndarray) -> np.ndarray:
    """Rotation (columns x, y, z) with z along ``normal_toward_viewer`` and x as near ``up_hint`` x as possible."""
    z = normal_toward_viewer / np.linalg.norm(normal_toward_viewer)
    x = up_hint - np.dot(up_hint, z) * z
    if np.linalg.norm(x) < 1e-6:
        x = np.cross(z, [0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], 1)


def _board_centre(board: BoardSpec) -> np.ndarray:
    return np.array([(board.cols - 1) * board.square_mm / 2, (board.rows - 1) * board.square_mm / 2, 0.0])


def _fits(camera: Camera, T_world_board: np.ndarray, outline: np.ndarray, margin_px: float) -> bool:
    pts = transform_points(T_world_board, outline)
    uv, z = camera.project(pts)
    if np.any(z <= 1.0) or not np.all(np.isfinite(uv)):
        return False
    return bool(np.all(camera.in_image(uv, margin_px)))


def _plate_samples(board: BoardSpec, look: BoardLook, step_mm: float = 2.5) -> np.ndarray:
    """Points (board frame, mm) covering the plate's faces, for the clearance test."""
    c = plate_outline(board, look)
    lo, hi = c.min(0), c.max(0)
    xs = np.linspace(lo[0], hi[0], max(2, int(np.ceil((hi[0] - lo[0]) / step_mm)) + 1))
    ys = np.linspace(lo[1], hi[1], max(2, int(np.ceil((hi[1] - lo[1]) / step_mm)) + 1))
    X, Y = np.meshgrid(xs, ys)
    face = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1)
    back = face + [0.0, 0.0, lo[2]]
    return np.concatenate([face, back])


@dataclass(frozen=True)
class SetClearance:
    """What a board must keep clear of: the floor, the wall and the boxes around the set's objects (mm)."""

    floor_z_mm: float
    wall_y_mm: float
    boxes: tuple = ()  # ((lo (3,), hi (3,)), ...) world axis-aligned

    @classmethod
    def from_renderer(cls, renderer, margin_mm: float = 2.0) -> "SetClearance":
        """From the meshes a :class:`twin.render.SetRenderer` placed (before any robot or props).

        The two backdrop planes become the floor and wall limits; every other mesh (the
        actuation unit, the mount posts) its world bounding box grown by ``margin_mm``.
        """
        d = renderer.scene.dressing
        boxes = []
        for node in renderer.pr_scene.mesh_nodes:
            b = np.asarray(node.mesh.bounds, float)
            pose = renderer.pr_scene.get_pose(node)
            corners = np.array([[x, y, z] for x in b[:, 0] for y in b[:, 1] for z in b[:, 2]])
            w = transform_points(pose, corners)
            lo, hi = w.min(0), w.max(0)
            if np.sort(hi - lo)[1] > 300.0:  # a backdrop plane
                continue
            boxes.append((lo - margin_mm, hi + margin_mm))
        return cls(float(d.floor_z_mm) + margin_mm, float(d.wall_y_mm) - margin_mm, tuple(boxes))

    def clear(self, pts_world: np.ndarray) -> bool:
        """Whether all points lie above the floor, in front of the wall and outside every box."""
        if np.any(pts_world[:, 2] < self.floor_z_mm) or np.any(pts_world[:, 1] > self.wall_y_mm):
            return False
        for lo, hi in self.boxes:
            if np.any(np.all((pts_world > lo) & (pts_world < hi), axis=1)):
                return False
        return True


def _oblique_deg(camera: Camera, T_world_board: np.ndarray, board: BoardSpec) -> float:
    """Angle between the board normal (out of the print) and the line of sight to its centre (deg); > 90 = seen from behind."""
    centre = T_world_board[:3, :3] @ _board_centre(board) + T_world_board[:3, 3]
    to_cam = camera.center_world_mm - centre
    n = T_world_board[:3, 2]
    return float(np.degrees(np.arccos(np.clip(np.dot(n, to_cam) / np.linalg.norm(to_cam), -1, 1))))


def sample_view_poses(
    camera: Camera, board: BoardSpec, look: BoardLook, rng: np.random.Generator, vr: ViewRange, clearance: SetClearance | None = None
) -> list:
    """``vr.count`` random board poses ``T_world_board`` fully inside ``camera``'s image (and clear of the set).

    Raises ``SceneError`` when the ranges do not let the board fit.
    """
    outline = plate_outline(board, look)
    samples = _plate_samples(board, look)
    centre_b = _board_centre(board)
    K = camera.K
    out = []
    tries = 0
    while len(out) < vr.count:
        tries += 1
        if tries > 2000 * max(vr.count, 1):
            raise SceneError(
                f"poses: could place only {len(out)} of {vr.count} boards fully inside the {camera.name} image; "
                "widen poses.distance_mm or poses.spread, or use a smaller board"
            )
        d = rng.uniform(*vr.distance_mm)
        u = K[0, 2] + rng.uniform(-1, 1) * vr.spread * camera.width / 2
        v = K[1, 2] + rng.uniform(-1, 1) * vr.spread * camera.height / 2
        xy = camera.pixels_to_normalized(np.array([[u, v]]))[0]
        c_cam = np.array([xy[0] * d, xy[1] * d, d])
        sight = -c_cam / np.linalg.norm(c_cam)  # from the board toward the camera
        # facing the camera, board x along image x (then y along image up), then tilt and roll
        R = _facing_frame(sight, np.array([1.0, 0.0, 0.0]))
        tilt = np.radians(rng.uniform(*vr.tilt_deg))
        phi = rng.uniform(0, 2 * np.pi)
        axis = np.cos(phi) * R[:, 0] + np.sin(phi) * R[:, 1]
        roll = np.radians(rng.uniform(-vr.roll_deg, vr.roll_deg) + (180.0 if vr.flip and len(out) % 2 else 0.0))
        R = rotation_matrix(axis, tilt) @ rotation_matrix(R[:, 2], roll) @ R
        T_cam_board = np.eye(4)
        T_cam_board[:3, :3] = R
        T_cam_board[:3, 3] = c_cam - R @ centre_b
        T_world_board = camera.T_world_cam @ T_cam_board
        if not _fits(camera, T_world_board, outline, vr.edge_margin_px):
            continue
        if clearance is not None and not clearance.clear(transform_points(T_world_board, samples)):
            continue
        out.append(T_world_board)
    return out


def sample_stereo_poses(
    cameras: dict, board: BoardSpec, look: BoardLook, rng: np.random.Generator, sr: StereoRange, clearance: SetClearance | None = None
) -> list:
    """``sr.count`` board poses seen whole by every camera in ``cameras`` (world frame), clear of the set."""
    outline = plate_outline(board, look)
    samples = _plate_samples(board, look)
    centre_b = _board_centre(board)
    cams = list(cameras.values())
    # the board faces the mean of the directions toward the cameras
    toward = [c.center_world_mm - np.asarray(sr.center_mm) for c in cams]
    bis = np.sum([t / np.linalg.norm(t) for t in toward], axis=0)
    bis /= np.linalg.norm(bis)
    out = []
    tries = 0
    while len(out) < sr.count:
        tries += 1
        if tries > 5000 * max(sr.count, 1):
            raise SceneError(
                f"stereo: could place only {len(out)} of {sr.count} boards inside both images; "
                "reduce stereo.center_spread_mm or use a smaller board"
            )
        tilt = np.radians(sr.normal_spread_deg) * np.sqrt(rng.uniform())
        phi = rng.uniform(0, 2 * np.pi)
        R0 = _facing_frame(bis, np.array([1.0, 0.0, 0.0]))
        axis = np.cos(phi) * R0[:, 0] + np.sin(phi) * R0[:, 1]
        roll = np.radians(rng.uniform(-sr.roll_deg, sr.roll_deg))
        R = rotation_matrix(axis, tilt) @ rotation_matrix(R0[:, 2], roll) @ R0
        centre = np.asarray(sr.center_mm) + rng.uniform(-1, 1, 3) * np.asarray(sr.center_spread_mm)
        T_world_board = np.eye(4)
        T_world_board[:3, :3] = R
        T_world_board[:3, 3] = centre - R @ centre_b
        if not all(_fits(c, T_world_board, outline, 10.0) and _oblique_deg(c, T_world_board, board) < sr.max_oblique_deg for c in cams):
            continue
        if clearance is not None and not clearance.clear(transform_points(T_world_board, samples)):
            continue
        out.append(T_world_board)
    return out


# ----------------------------------------------------------------------------- rendering
@dataclass(frozen=True, eq=False)
class CalibrationCapture:
    """Rendered calibration images with their truth.

    Attributes
    ----------
    board : BoardSpec
    views : dict camera -> list of (name, image)
        Single-camera views (intrinsics).
    stereo : list of (name, {camera: image})
        Pairs seen by both cameras.
    world : dict camera -> list of (name, image)
        The world-frame board image(s) (``"top"``: ``world/top.png``, ``world/top_2.png``, ...).
    world_origin_mm : (3,) array
    truth : RigCalibration
        The true rig (nominal cameras; images were taken with per-image jitter when enabled).
    poses : dict
        ``T_world_board`` of every image by its file path in the folder layout.
    """

    board: BoardSpec
    views: dict
    stereo: list
    world: dict
    world_origin_mm: np.ndarray
    truth: object
    poses: dict

    def images(self):
        """The images as :class:`recon.calibration.CalibrationImages` (names as in the folder layout)."""
        from recon.calibration import CalibrationImages  # noqa: PLC0415

        return CalibrationImages(
            views={c: [(f"{c}/{n}", im) for n, im in items] for c, items in self.views.items()},
            stereo=list(self.stereo), world={c: list(v) for c, v in self.world.items()}, source="<twin capture>",
        )


def render_calibration(cal: CalibrationScene, progress=None, renderer=None) -> CalibrationCapture:
    """Render every image of a calibration scene (robot absent), with the rig scene's sensor model.

    Parameters
    ----------
    cal : CalibrationScene
    progress : callable, optional
        ``progress(stage, done, total)``.
    renderer : SetRenderer, optional
        Reused if given (it must render ``cal.rig_scene``); its robot and props are replaced.
    """
    from .render import SetRenderer  # noqa: PLC0415 - OpenGL only when rendering

    sc = cal.rig_scene
    rig = sc.rig
    own = renderer is None
    r = renderer or SetRenderer(sc)
    r.set_robot(None)
    r.set_props(None)
    clearance = SetClearance.from_renderer(r)
    board_mesh = board_meshes(cal.board, cal.look)
    rng = np.random.default_rng(np.random.SeedSequence([cal.seed, 5]))
    jobs = []  # (key, camera name, T_world_board, stream, index)
    for cam_name in cal.views.cameras:
        for i, T_world_board in enumerate(sample_view_poses(rig[cam_name], cal.board, cal.look, rng, cal.views, clearance)):
            jobs.append((f"{cam_name}/{i:03d}.png", cam_name, T_world_board, f"calib-{cam_name}", i))
    stereo_poses = sample_stereo_poses({n: rig[n] for n in ("side", "top")}, cal.board, cal.look, rng, cal.stereo, clearance)
    for i, T_world_board in enumerate(stereo_poses):
        for cam_name in ("side", "top"):
            jobs.append((f"stereo/{cam_name}/{i:03d}.png", cam_name, T_world_board, "calib-stereo", i))
    T_world_board = cal.T_world_board
    if not _fits(rig["top"], T_world_board, plate_outline(cal.board, cal.look), 0.0):
        raise SceneError(f"{cal.source}: world.origin_mm: the world board does not fit in the top image")
    if not clearance.clear(_plate_samples(cal.board, cal.look) + cal.world_origin_mm):
        raise SceneError(f"{cal.source}: world.origin_mm: the world board would cut through the set (floor, wall, actuation unit or posts)")
    world_keys = [f"world/top{'' if e == 0 else f'_{e + 1}'}.png" for e in range(cal.world_exposures)]
    for e, key in enumerate(world_keys):
        jobs.append((key, "top", T_world_board, "calib-world", e))

    images = {}
    poses = {}
    view = None
    try:
        for k, (key, cam_name, T_world_board, stream, i) in enumerate(jobs):
            cam = rig[cam_name]
            # exposures of the world board share one render unless the camera jitters between them
            if cal.jitter or view is None or not (stream == "calib-world" and i > 0):
                if cal.jitter:
                    cam = jitter_camera(cam, sc.noise, frame_rng(cal.seed, f"jitter-{stream}", i, cam_name))
                r.set_props([(m, T_world_board) for m in board_mesh])
                view = r.render(cam, with_truth=False)
            images[key] = expose(view.radiance, sc.noise, float(k), frame_rng(cal.seed, f"expose-{stream}", i, cam_name), sc.color)
            poses[key] = T_world_board
            if progress is not None:
                progress("render", k + 1, len(jobs))
    finally:
        r.set_props(None)
        if own:
            r.close()
    views = {c: [(k.split("/")[-1], images[k]) for k, _, _, _, _ in jobs if k.startswith(f"{c}/")] for c in cal.views.cameras}
    stereo = [(f"{i:03d}.png", {c: images[f"stereo/{c}/{i:03d}.png"] for c in ("side", "top")}) for i in range(len(stereo_poses))]
    return CalibrationCapture(
        board=cal.board, views=views, stereo=stereo, world={"top": [(k, images[k]) for k in world_keys]},
        world_origin_mm=np.asarray(cal.world_origin_mm, float), truth=rig, poses=poses,
    )


def write_capture(capture: CalibrationCapture, out: Path) -> Path:
    """Write a capture in the calibration folder layout (see docs/calibration.md).

    ::

        out/board.json              board size, square, world origin (what calibrate needs)
        out/side/NNN.png            views for the side camera's intrinsics
        out/top/NNN.png             views for the top camera's intrinsics
        out/stereo/side/NNN.png     stereo pairs, matched by file name
        out/stereo/top/NNN.png
        out/world/top.png           the board in the world-frame pose, top camera
        out/world/top_N.png         more exposures of it (the board not moved)
        out/truth/rig.json          twin only: the true rig, for checking
        out/truth/poses.json        twin only: T_world_board of every image
    """
    import cv2  # noqa: PLC0415

    from recon.rigcal import save_rig_calibration  # noqa: PLC0415

    out = Path(out)
    for sub in ("side", "top", "stereo/side", "stereo/top", "world", "truth"):
        (out / sub).mkdir(parents=True, exist_ok=True)

    def write(rel, img):
        if not cv2.imwrite(str(out / rel), img):
            raise OSError(f"cannot write {out / rel}")

    for cam, items in capture.views.items():
        for name, img in items:
            write(f"{cam}/{name}", img)
    for name, imgs in capture.stereo:
        for cam, img in imgs.items():
            write(f"stereo/{cam}/{name}", img)
    for cam, items in capture.world.items():
        for name, img in items:
            write(name, img)
    b = capture.board
    meta = {
        "format": "ctr-bench-calibration-board",
        "cols": b.cols,
        "rows": b.rows,
        "square_mm": b.square_mm,
        "world_origin_mm": [float(v) for v in capture.world_origin_mm],
        "base_point_world_mm": capture.truth.base_point_world_mm.tolist(),
        "insertion_axis_world": capture.truth.insertion_axis_world.tolist(),
    }
    (out / "board.json").write_text(json.dumps(meta, indent=2) + "\n")
    save_rig_calibration(out / "truth" / "rig.json", capture.truth)
    (out / "truth" / "poses.json").write_text(json.dumps({k: T_world_board.tolist() for k, T_world_board in capture.poses.items()}, indent=1) + "\n")
    return out
