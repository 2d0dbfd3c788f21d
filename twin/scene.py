"""Scene files: the robot, the rig, the set, the noise and the joint sequence of a twin run.

A scene is a TOML file (see ``scenes/paper.toml``, documented key by key). It is
validated completely on load: an error names the file, the key and what is
wrong, e.g. ``scenes/x.toml: robot.tubes[1].outer_diameter_mm: must be > 0,
got -1``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from recon.calibration_check import distortion_problem, field_of_view_problem, principal_point_problem
from recon.camera import Camera
from recon.distortion import MODEL_SIZES
from recon.geometry import look_at, rotation_matrix
from recon.memory import check_memory, render_bytes
from recon.rigcal import RigCalibration

from .robot import Joints, Robot
from .robotfile import parse_robot_table
# SceneError and read_toml are this module's names too (its users read scenes); the table helpers are imported from twin.schema.
from .schema import NONNEGATIVE, POSITIVE, REQUIRED, SceneError, Table, read_toml


__all__ = ["Scene", "SceneError", "load_scene", "check_scene_cameras", "read_toml", "scene_from_dict", "NoiseModel",
           "SetDressing", "Light", "ACTUATION_UNIT_BOX_BASE_MM"]


# A camera at ~0 mm from its target has no line of sight (look_at would divide by ~0).
_AWAY = (lambda v: v >= 1.0, "must be > 0 (at least 1 mm from the target)")


# ----------------------------------------------------------------------------- scene parts
@dataclass(frozen=True)
class NoiseModel:
    """Per-frame image and pose disturbances (seeded, reproducible).

    Attributes
    ----------
    lighting_drift : float
        Amplitude of a slow gain drift over the sequence (relative).
    lighting_period_frames : float
        Period of the drift (frames).
    flicker : float
        Standard deviation of a per-frame gain change (relative).
    offset_dn : float
        Standard deviation of a per-frame offset (8-bit digital numbers).
    gradient : float
        Amplitude of a per-frame linear illumination ramp across the image (relative).
    jitter_px : float
        Standard deviation of the camera shift per frame, expressed as image motion (px).
    jitter_rotation_deg : float
        Standard deviation of the camera rotation about each of its axes per frame (deg).
    photons_full_scale : float
        Photo-electrons at 255 DN (sets Poisson shot noise); 0 disables it.
    read_noise_dn : float
        Gaussian read noise (DN).
    blur_px : float
        Gaussian blur sigma (px); 0 disables it.
    gain : float
        Static exposure gain of the whole session (relative, 1 = as rendered).
    vignetting : float
        Relative darkening at the image corners (cos^4-like radial falloff); 0 disables it.
    jpeg_quality : float
        Store each image through JPEG at this quality (1-100), as compressed camera
        streams do; 0 keeps lossless images.
    """

    lighting_drift: float = 0.0
    lighting_period_frames: float = 40.0
    flicker: float = 0.0
    offset_dn: float = 0.0
    gradient: float = 0.0
    jitter_px: float = 0.0
    jitter_rotation_deg: float = 0.0
    photons_full_scale: float = 0.0
    read_noise_dn: float = 0.0
    blur_px: float = 0.0
    gain: float = 1.0
    vignetting: float = 0.0
    jpeg_quality: float = 0.0


@dataclass(frozen=True)
class Light:
    """A directional light (world direction of travel) or a point light (world position, mm)."""

    kind: str
    intensity: float
    direction: tuple = (0.0, 0.0, -1.0)
    position_mm: tuple = (0.0, 0.0, 300.0)
    color: tuple = (1.0, 1.0, 1.0)


#: The actuation unit's block in the robot's base frame (mm): the corners (lo, hi) of a box behind the base,
#: against the insertion axis (base z). The renderer draws it; the scene generator keeps the backdrop beyond it.
ACTUATION_UNIT_BOX_BASE_MM = ((-14.0, -14.0, -95.0), (14.0, 14.0, -18.0))


@dataclass(frozen=True)
class SetDressing:
    """What surrounds the robot: backdrop, clutter and lights.

    ``planes`` is ``"floor-wall"`` (a floor at ``floor_z_mm`` and a wall at
    ``wall_y_mm``, 600 mm square, for the nominal orthogonal rig) or ``"per-camera"``
    (one plane per camera, perpendicular to its line of sight ``behind_mm`` beyond the
    target, sized to fill its whole view). ``texture_px`` 0 picks the texture size
    from the image size; ``clutter`` is the number of seeded boxes and cylinders
    placed on the backdrop planes, clear of the robot.
    """

    backdrop: str = "gradient"
    backdrop_color: tuple = (0.80, 0.80, 0.78)
    backdrop_color2: tuple = (0.55, 0.56, 0.60)
    floor_z_mm: float = -60.0
    wall_y_mm: float = 70.0
    actuation_unit: bool = True
    mount_posts: bool = True
    ambient: float = 0.35
    lights: tuple = ()
    robot_color: tuple = (0.78, 0.78, 0.80)
    robot_metallic: float = 0.6
    robot_roughness: float = 0.35
    photo: str = "camera"
    pattern_scale: float = 1.0
    texture_px: int = 256
    planes: str = "floor-wall"
    behind_mm: float = 80.0
    clutter: int = 0


@dataclass(frozen=True, eq=False)
class Scene:
    """A fully validated scene.

    Attributes
    ----------
    name : str
    source : str
        File it came from (for messages).
    seed : int
        Seed of every random draw of the twin (noise, jitter, texture).
    robot : Robot
    model : str
        Kinematic model, ``"bending"`` or ``"compliant"``.
    rig : RigCalibration
        The nominal (true, undisturbed) cameras.
    color : str
        ``"mono"`` (8-bit gray) or ``"rgb"``.
    dressing : SetDressing
    noise : NoiseModel
    joints : list of Joints
        One per robot frame.
    background_frames : int
        Background-only frames per camera (for the eigenbackground model).
    frame_interval_s : float
        Time between frames (s).
    image_kind : str
        ``"camera"`` (rendered camera images) or ``"masks"`` (binary silhouettes, as a
        segmentation tool delivers them).
    mask_polarity : str
        ``"robot-white"`` (robot 255 on 0) or ``"robot-black"`` (robot 0 on 255).
    classes : dict
        Free-form class labels (str -> str) of the scene, e.g. from the scene generator.
    """

    name: str
    source: str
    seed: int
    robot: Robot
    model: str
    rig: RigCalibration
    color: str
    dressing: SetDressing
    noise: NoiseModel
    joints: list
    background_frames: int
    frame_interval_s: float
    image_kind: str = "camera"
    mask_polarity: str = "robot-white"
    classes: dict = field(default_factory=dict)

    def with_frames(self, joints: list) -> "Scene":
        """The same scene with another joint sequence (e.g. a prefix for quick tests)."""
        from dataclasses import replace

        return replace(self, joints=list(joints))


# ----------------------------------------------------------------------------- parsing
#: Nominal line of sight (target -> camera, unit) and image-down direction of each camera (world).
_NOMINAL_MOUNTS = {"side": ((0.0, -1.0, 0.0), (0.0, 0.0, -1.0)), "top": ((0.0, 0.0, 1.0), (0.0, -1.0, 0.0))}


def orbit_rotation(orbit_deg) -> np.ndarray:
    """Rotation (3x3) of an orbit about the world x, then y, then z axis (deg), through the target."""
    R = np.eye(3)
    for ax, ang in zip(np.eye(3), orbit_deg):
        R = rotation_matrix(ax, np.deg2rad(ang)) @ R
    return R


_OPENCV_COUNTS = "must hold 4, 5, 8, 12 or 14 OpenCV coefficients (k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4 tau_x tau_y)"


def _opencv_count(v) -> bool:
    return len(v) in MODEL_SIZES


def _orbited_mount(name: str, target: np.ndarray, distance_mm: float, orbit_deg) -> tuple:
    """Eye (world mm) and image-down direction of camera ``name`` orbited about the target."""
    back, down = (np.asarray(v) for v in _NOMINAL_MOUNTS[name])
    R = orbit_rotation(orbit_deg)
    return target + distance_mm * (R @ back), R @ down


def _parse_rig(g: Table, width: int, height: int, base, axis) -> RigCalibration:
    distance = g.get("distance_mm", 300.0, float, *_AWAY)
    focal = g.get("focal_length_mm", 12.0, float, *POSITIVE)
    pixel = g.get("pixel_size_um", 4.65, float, *POSITIVE)
    target = np.asarray(g.get("target_mm", [45.0, 0.0, 0.0], ("vec", 3)))
    dist_default = g.get("distortion", [0.0] * 5, ("vec", None), _opencv_count, _OPENCV_COUNTS)
    # Nominal orthogonal mounts: the top camera looks down (-z) with image-down = world -y;
    # the side camera looks along +y with image-down = world -z (so world up is image up).
    nominal = {
        "side": (target + np.array([0.0, -distance, 0.0]), np.array([0.0, 0.0, -1.0])),
        "top": (target + np.array([0.0, 0.0, distance]), np.array([0.0, -1.0, 0.0])),
    }
    cams = {}
    for name, (eye, down) in nominal.items():
        c = g.table(name)
        cam_distance = c.get("distance_mm", distance, float, *_AWAY)
        orbit = c.get("orbit_deg", [0.0, 0.0, 0.0], ("vec", 3), lambda v: all(abs(a) <= 180 for a in v), "must be within [-180, 180] deg")
        cam_focal = c.get("focal_length_mm", focal, float, *POSITIVE)
        if cam_distance != distance or any(orbit):
            eye, down = _orbited_mount(name, target, cam_distance, orbit)
        rot = c.get("rotation_deg", [0.0, 0.0, 0.0], ("vec", 3))
        off = c.get("offset_mm", [0.0, 0.0, 0.0], ("vec", 3))
        pp = c.get("principal_offset_px", [0.0, 0.0], ("vec", 2))
        dist = c.get("distortion", dist_default, ("vec", None), _opencv_count, _OPENCV_COUNTS)
        f_scale = c.get("focal_scale", 1.0, float, *POSITIVE)
        c.done()
        f_px = cam_focal / (pixel * 1e-3)
        T = look_at(eye, target, down)
        # Mount deviations are small rotations about the camera's own axes, then a shift (mm) in
        # the camera frame: T_cam'_world = D @ T_cam_world.
        D = np.eye(4)
        R = np.eye(3)
        for ax, ang in zip(np.eye(3), rot):
            R = rotation_matrix(ax, np.deg2rad(ang)) @ R
        D[:3, :3] = R
        D[:3, 3] = -np.asarray(off)
        K = np.array(
            [[f_px * f_scale, 0.0, (width - 1) / 2 + pp[0]], [0.0, f_px * f_scale, (height - 1) / 2 + pp[1]], [0, 0, 1.0]]
        )
        cams[name] = Camera(name=name, width=width, height=height, K=K, dist=np.asarray(dist), T_cam_world=D @ T)
    g.done()
    return RigCalibration(cameras=cams, base_point_world_mm=base, insertion_axis_world=axis)


def _parse_dressing(d: Table, lights: list, ambient: float) -> SetDressing:
    from .textures import KINDS, LEGACY_KINDS, PHOTOS

    kind = d.get("kind", "gradient", str, lambda v: v in KINDS, f"must be one of {', '.join(KINDS)}")
    dressing = SetDressing(
        backdrop=kind,
        backdrop_color=tuple(d.get("color", [0.80, 0.80, 0.78], ("vec", 3))),
        backdrop_color2=tuple(d.get("color2", [0.55, 0.56, 0.60], ("vec", 3))),
        floor_z_mm=d.get("floor_z_mm", -60.0, float),
        wall_y_mm=d.get("wall_y_mm", 70.0, float),
        actuation_unit=d.get("actuation_unit", True, bool),
        mount_posts=d.get("mount_posts", True, bool),
        ambient=ambient,
        lights=tuple(lights),
        robot_color=tuple(d.get("robot_color", [0.78, 0.78, 0.80], ("vec", 3))),
        robot_metallic=d.get("robot_metallic", 0.6, float, lambda v: 0 <= v <= 1, "must be in [0, 1]"),
        robot_roughness=d.get("robot_roughness", 0.35, float, lambda v: 0 <= v <= 1, "must be in [0, 1]"),
        photo=d.get("photo", "camera", str, lambda v: v in PHOTOS, f"must be one of {', '.join(PHOTOS)}"),
        pattern_scale=d.get("pattern_scale", 1.0, float, lambda v: 0.1 <= v <= 10, "must be in [0.1, 10]"),
        # The original kinds keep their 256-texel texture (existing scenes render as before);
        # the new ones default to 0: sized from the image so they stay sharp.
        texture_px=d.get("texture_px", 256 if kind in LEGACY_KINDS else 0, int, lambda v: v == 0 or 16 <= v <= 4096,
                         "must be 0 (from the image size) or in [16, 4096]"),
        planes=d.get("planes", "floor-wall", str, lambda v: v in ("floor-wall", "per-camera"), 'must be "floor-wall" or "per-camera"'),
        behind_mm=d.get("behind_mm", 80.0, float, *POSITIVE),
        clutter=d.get("clutter", 0, int, lambda v: 0 <= v <= 50, "must be in [0, 50]"),
    )
    d.done()
    return dressing


def _parse_lights(tables: list) -> list:
    lights = []
    for t in tables:
        kind = t.get("kind", "directional", str, lambda v: v in ("directional", "point"), 'must be "directional" or "point"')
        lights.append(
            Light(
                kind=kind,
                intensity=t.get("intensity", 3.0, float, *POSITIVE),
                direction=tuple(t.get("direction", [0.0, 0.3, -1.0], ("vec", 3))),
                position_mm=tuple(t.get("position_mm", [0.0, 0.0, 300.0], ("vec", 3))),
                color=tuple(t.get("color", [1.0, 1.0, 1.0], ("vec", 3))),
            )
        )
        t.done()
    return lights


def _parse_noise(n: Table) -> NoiseModel:
    kw = {}
    for key, default in NoiseModel().__dict__.items():
        kw[key] = n.get(key, default, float, *NONNEGATIVE)
    if kw["lighting_period_frames"] <= 0:
        n.fail("lighting_period_frames", f"must be > 0, got {kw['lighting_period_frames']}")
    if kw["gain"] <= 0:
        n.fail("gain", f"must be > 0, got {kw['gain']}")
    if kw["vignetting"] >= 1:
        n.fail("vignetting", f"must be < 1, got {kw['vignetting']}")
    if kw["jpeg_quality"] > 100:
        n.fail("jpeg_quality", f"must be in [0, 100] (0: no JPEG), got {kw['jpeg_quality']}")
    n.done()
    return NoiseModel(**kw)


#: Most frames of one step, and background frames, of a scene: the joint list is built in memory.
_MAX_FRAMES = 1_000_000


def _parse_sequence(s: Table, robot: Robot) -> tuple:
    n_tubes = robot.n_tubes
    bg = s.get("background_frames", 30, int, lambda v: 0 <= v <= _MAX_FRAMES, f"must be in [0, {_MAX_FRAMES}]")
    dt = s.get("frame_interval_s", 1.0, float, *POSITIVE)
    joints = []
    for st in s.tables("steps"):
        frames = st.get("frames", REQUIRED, int, lambda v: 1 <= v <= _MAX_FRAMES, f"must be in [1, {_MAX_FRAMES}]")
        ends = {}
        for key in ("extension_mm", "rotation_deg"):
            a = st.get(f"{key}_from", REQUIRED, ("vec", n_tubes))
            b = st.get(f"{key}_to", a, ("vec", n_tubes))
            ends[key] = (np.asarray(a), np.asarray(b))
        st.done()
        for f in range(frames):
            w = 0.0 if frames == 1 else f / (frames - 1)
            ext = (1 - w) * ends["extension_mm"][0] + w * ends["extension_mm"][1]
            rot = (1 - w) * ends["rotation_deg"][0] + w * ends["rotation_deg"][1]
            j = Joints(extension_mm=tuple(ext), rotation_deg=tuple(rot))
            try:
                j.check(robot)
            except ValueError as exc:
                st.fail("extension_mm_from", str(exc))
            joints.append(j)
    s.done()
    return joints, bg, dt


def _parse_classes(c: Table) -> dict:
    """Free-form class labels: every value must be a string."""
    classes = {}
    for key in sorted(c.data):
        classes[key] = c.get(key, None, str)
    c.done()
    return classes


def scene_from_dict(data: dict, source: str = "<scene>") -> Scene:
    """Validate a parsed TOML document and build a :class:`Scene`."""
    top = Table(data, "", source)
    top.get("format", "ctr-bench-scene", str, lambda v: v == "ctr-bench-scene", 'must be "ctr-bench-scene"')
    top.get("version", 1, int, lambda v: v == 1, "must be 1 (the only version this ctr-bench reads)")
    name = top.get("name", Path(source).stem, str)
    seed = top.get("seed", 0, int, lambda v: v >= 0, "must be >= 0")
    image = top.table("image")
    width = image.get("width", 1024, int, lambda v: 16 <= v <= 8192, "must be in [16, 8192]")
    height = image.get("height", 768, int, lambda v: 16 <= v <= 8192, "must be in [16, 8192]")
    color = image.get("color", "mono", str, lambda v: v in ("mono", "rgb"), 'must be "mono" or "rgb"')
    image_kind = image.get("kind", "camera", str, lambda v: v in ("camera", "masks"), 'must be "camera" or "masks"')
    polarity = image.get("mask_polarity", "robot-white", str, lambda v: v in ("robot-white", "robot-black"),
                         'must be "robot-white" or "robot-black"')
    if image_kind == "masks" and color != "mono":
        image.fail("color", 'must be "mono" when image.kind is "masks" (masks are single-channel)')
    image.done()
    check_memory(render_bytes(width, height), f"{source}: image", f"rendering two {width}x{height} px views", SceneError)
    robot, model, base, axis = parse_robot_table(top.table("robot", required=True), source)
    rig = _parse_rig(top.table("rig"), width, height, base, axis)
    lighting = top.table("lighting")
    ambient = lighting.get("ambient", 0.35, float, *NONNEGATIVE)
    lights = _parse_lights(lighting.tables("lights")) or [Light("directional", 3.0, (0.2, 0.5, -1.0))]
    lighting.done()
    dressing = _parse_dressing(top.table("backdrop"), lights, ambient)
    noise = _parse_noise(top.table("noise"))
    joints, bg, dt = _parse_sequence(top.table("sequence", required=True), robot)
    classes = _parse_classes(top.table("classes"))
    if not joints:
        raise SceneError(f"{source}: sequence.steps: at least one step with frames is required")
    top.done()
    return Scene(
        name=name,
        source=source,
        seed=seed,
        robot=robot,
        model=model,
        rig=rig,
        color=color,
        dressing=dressing,
        noise=noise,
        joints=joints,
        background_frames=bg,
        frame_interval_s=dt,
        image_kind=image_kind,
        mask_polarity=polarity,
        classes=classes,
    )


#: The lens checks of a scene camera and the key each one's problem is blamed on (the focal
#: lengths are > 0 and the rotations rigid by construction).
_CAMERA_CHECKS = (
    (lambda cam: principal_point_problem(cam.K, cam.width, cam.height), "principal_offset_px"),
    (field_of_view_problem, "focal_length_mm"),
    (distortion_problem, "distortion"),
)


def check_scene_cameras(scene: Scene) -> None:
    """Refuse a scene whose cameras :mod:`recon.calibration_check` refuses.

    A principal point outside the image, focal lengths that do not fit it, or a lens model
    that folds the image over or is stronger than any lens
    (:func:`recon.calibration_check.distortion_problem`) is a :class:`SceneError` naming
    ``rig.<camera>.<key>``. Not part of :func:`scene_from_dict`: the scene generator builds
    scenes with provisional focal lengths, and folds, before it fits them.
    """
    for name, cam in scene.rig.cameras.items():
        for check, key in _CAMERA_CHECKS:
            why = check(cam)
            if why:
                raise SceneError(f"{scene.source}: rig.{name}.{key}: {why}")


def load_scene(path) -> Scene:
    """Load and validate a scene TOML file (:func:`scene_from_dict`, :func:`check_scene_cameras`);
    every error names the file and the key."""
    path = Path(path)
    data = read_toml(path, "scene file", SceneError)
    scene = scene_from_dict(data, source=str(path))
    check_scene_cameras(scene)
    return scene
