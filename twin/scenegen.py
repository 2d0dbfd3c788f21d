"""Seeded generator of wide scene distributions for the twin (issue 13: hold-out images the twin did not make).

``generate_suite("wide", n, seed)`` draws ``n`` scenes, each a TOML-ready dict that
:func:`twin.scene.scene_from_dict` accepts, with class labels (backdrop kind, angle
between the optical axes, resolution, base placement, number of tubes, input kind).
The same ``(suite, n, seed)`` always gives the same scenes.

Every draw is checked before it is kept, with the shared camera model and the twin's
kinematics: the whole robot (or, with its base outside the view, the tip and most of
the robot) projects inside both images, the robot spans 20-95 % of the image, and the
thinnest tube is at least 3 px wide. A draw that fails is redrawn.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from recon.params import dumps_toml

from .backdrop import auto_texture_px, depth_beyond_target_mm
from .groundtruth import extend_to_mesh_start
from .kinematics import solve
from .scene import ACTUATION_UNIT_BOX_BASE_MM, Scene, scene_from_dict
from .textures import KINDS, PHOTOS

__all__ = ["GeneratedScene", "SUITES", "generate_suite", "draw_wide", "camera_angle_deg", "view_problem",
           "shrink_images", "angle_class", "resolution_class", "IMAGE_SIZES", "write_suite"]

SUITES = ("wide",)

#: Sensor sizes of common machine-vision cameras (px), 0.3 to 5 MP.
IMAGE_SIZES = ((640, 480), (752, 480), (800, 600), (1024, 768), (1280, 960), (1280, 1024), (1440, 1080),
               (1600, 1200), (1920, 1200), (2048, 1536), (2448, 2048))
_PIXEL_UM = (2.2, 3.45, 4.65, 5.86)
_BASES = ("in-view-unit", "in-view-bare", "outside")
#: Backdrop kinds drawn (photographs twice as often: sixteen photos behind one kind).
_BACKDROPS = KINDS + ("photo",)
#: Ranges the "wide" suite draws from (and its tests check).
ANGLE_DEG = (45.0, 135.0)
DISTANCE_MM = (150.0, 600.0)
SPAN = (0.20, 0.95)
MIN_TUBE_PX = 3.0
#: Draws per scene before giving up (a bug, never a property of a seed).
_MAX_ATTEMPTS = 2000


@dataclass(frozen=True)
class GeneratedScene:
    """One generated scene: ``data`` is the TOML document, ``classes`` its labels."""

    name: str
    data: dict
    classes: dict


def angle_class(angle_deg: float) -> str:
    """Bin of the angle between the optical axes: ``"45-75"``, ``"75-105"`` or ``"105-135"``."""
    if angle_deg < 75.0:
        return "45-75"
    return "75-105" if angle_deg <= 105.0 else "105-135"


def resolution_class(width_px: int, height_px: int) -> str:
    """Bin of the sensor size: ``"<0.5MP"``, ``"0.5-2MP"`` or ``">2MP"``."""
    mp = width_px * height_px / 1e6
    if mp < 0.5:
        return "<0.5MP"
    return "0.5-2MP" if mp <= 2.0 else ">2MP"


def camera_angle_deg(scene: Scene) -> float:
    """Angle (deg) between the two cameras' optical axes."""
    a, b = (c.T_world_cam[:3, 2] for c in scene.rig.cameras.values())
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


def _r(x: float, nd: int = 4) -> float:
    """Round for the TOML file (short, and exactly what is parsed back)."""
    return float(round(float(x), nd))


# ----------------------------------------------------------------------------- robot
def _draw_robot(rng, n_tubes: int) -> tuple:
    """Tube tables (outermost first) and three frames of joints, or None to redraw."""
    od = rng.uniform(0.5, 1.4 if n_tubes == 3 else 2.0)  # innermost tube
    inner = od * rng.uniform(0.55, 0.85)
    tubes = []
    for _ in range(n_tubes):
        tubes.append([od, inner])
        inner = od + rng.uniform(0.02, 0.15)  # next tube out: its bore just clears this one
        od = inner * rng.uniform(1.12, 1.4)
    tubes = tubes[::-1]  # outermost first
    if tubes[0][0] > 3.0:
        return None
    exposed_mm = rng.uniform(30.0, 200.0)
    frames = []
    for _ in range(3):
        tip = exposed_mm * rng.uniform(0.6, 1.0)
        fr = np.sort(rng.uniform(0.15, 0.85, n_tubes - 1)) * tip
        ext = np.concatenate([fr, [tip]])
        if np.any(np.diff(ext) < 4.0) or ext[0] < 4.0:
            return None  # each tube shows at least 4 mm
        rot = rng.uniform(-180.0, 180.0, n_tubes)
        frames.append((ext, rot))
    max_ext = np.max([f[0] for f in frames], axis=0)
    names = ["outer", "middle", "inner"] if n_tubes == 3 else ["outer", "inner"]
    tables = []
    for i, (o, inner) in enumerate(tubes):
        length = max_ext[i] + rng.uniform(20.0, 60.0)
        curved = min(length, max_ext[i] * rng.uniform(0.3, 1.0))
        straight = i == 0 and rng.random() < 0.4
        bend_rad = 0.0 if straight else rng.uniform(0.2, 1.5)
        tables.append({
            "name": names[i],
            "outer_diameter_mm": _r(o),
            "inner_diameter_mm": _r(inner),
            "length_mm": _r(length, 2),
            "curved_length_mm": _r(curved, 2),
            "precurvature_per_mm": _r(bend_rad / curved, 6),
        })
    steps = [{"frames": 1, "extension_mm_from": [_r(e, 2) for e in ext], "rotation_deg_from": [_r(a, 2) for a in rot]}
             for ext, rot in frames]
    return tables, steps


def _robot_points(scene: Scene) -> list:
    """Per frame: backbone points (n, 3) mm from the mesh start (8 mm inside the base) to the tip."""
    return [extend_to_mesh_start(solve(scene.robot, j, scene.model)) for j in scene.joints]


# ----------------------------------------------------------------------------- cameras
def _distortion(rng) -> list:
    """OpenCV k1, k2, p1, p2, k3 with |k1| <= 0.25."""
    k1 = rng.uniform(-0.25, 0.25)
    return [_r(k1), _r(rng.uniform(-0.12, 0.12)), _r(rng.uniform(-0.002, 0.002), 5), _r(rng.uniform(-0.002, 0.002), 5),
            _r(rng.uniform(-0.04, 0.04))]


def _monotonic(dist, r_max: float) -> bool:
    """Whether the radial distortion keeps growing with the radius up to ``r_max`` (no fold-over)."""
    k1, k2, _, _, k3 = dist[:5]
    r = np.linspace(0.0, r_max, 200)
    r2 = r * r
    slope = 1.0 + 3 * k1 * r2 + 5 * k2 * r2 * r2 + 7 * k3 * r2**3
    return bool(np.all(slope > 0.4))


def _mount_rotation(rng) -> list:
    """Mount deviation: a random axis, up to 5 deg."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    return [_r(a) for a in axis * rng.uniform(0.0, 5.0)]


# ----------------------------------------------------------------------------- set
def _colors(rng, contrast: str, rgb: bool) -> tuple:
    """Backdrop colours (``color``, ``color2``): their difference sets the contrast."""
    delta = rng.uniform(0.06, 0.16) if contrast == "low" else rng.uniform(0.2, 0.7)
    level = rng.uniform(0.1 + delta / 2, 0.95 - delta / 2)
    tint = rng.normal(0.0, 0.05, 3) if rgb else np.zeros(3)
    hi = np.clip(level + delta / 2 + tint, 0.0, 1.0)
    lo = np.clip(level - delta / 2 + tint, 0.0, 1.0)
    if rng.random() < 0.5:
        hi, lo = lo, hi  # which end of the pattern is bright
    return [_r(c, 3) for c in hi], [_r(c, 3) for c in lo]


def _lights(rng, target: np.ndarray) -> list:
    lights = []
    for _ in range(int(rng.integers(1, 3))):
        d = rng.normal(size=3)
        d[2] = -abs(d[2]) - 0.3  # light comes from above
        lights.append({"kind": "directional", "direction": [_r(v, 3) for v in d / np.linalg.norm(d)],
                       "intensity": _r(rng.uniform(1.5, 5.0), 2)})
    if rng.random() < 0.6:
        v = rng.normal(size=3)
        v[2] = abs(v[2])
        dist = rng.uniform(150.0, 400.0)
        pos = target + dist * v / np.linalg.norm(v)
        # A point light falls off with the square of the distance: scale to the paper's 4e4 at 190 mm.
        lights.append({"kind": "point", "position_mm": [_r(p, 1) for p in pos],
                       "intensity": _r(rng.uniform(2e4, 6e4) * (dist / 190.0) ** 2, 0)})
    return lights


def _noise(rng, f_max_px: float) -> dict:
    """Light and sensor disturbances; camera jitter (shift and rotation together) stays under 1 px sigma.

    The rotation's sigma is drawn as image motion (px) at the longer focal length
    ``f_max_px`` and converted to degrees: a fixed angle would move a long lens's
    image by several pixels.
    """
    return {
        "gain": _r(rng.uniform(0.8, 1.2), 3),
        "lighting_drift": _r(rng.uniform(0.0, 0.05)),
        "lighting_period_frames": _r(rng.uniform(10.0, 60.0), 1),
        "flicker": _r(rng.uniform(0.0, 0.03)),
        "offset_dn": _r(rng.uniform(0.0, 4.0), 2),
        "gradient": _r(rng.uniform(0.0, 0.12)),
        "jitter_px": _r(rng.uniform(0.0, 0.6), 3),
        "jitter_rotation_deg": _r(float(np.degrees(rng.uniform(0.0, 0.3) / f_max_px)), 6),
        "photons_full_scale": _r(rng.uniform(1000.0, 20000.0), 0),
        "read_noise_dn": _r(rng.uniform(0.5, 3.0), 2),
        "blur_px": _r(rng.uniform(0.0, 1.0), 3),
        "vignetting": _r(rng.uniform(0.0, 0.35), 3),
        "jpeg_quality": float(int(rng.uniform(60, 96))) if rng.random() < 0.3 else 0.0,
    }


# ----------------------------------------------------------------------------- checks
def view_problem(scene: Scene, base: str, backbones: list | None = None) -> str | None:
    """Why ``scene`` breaks the suite's view rules (one line), or None when it keeps them.

    Rules, per nominal camera and frame: every backbone point (from 8 mm inside the
    base) lies inside the image by the tube's radius plus 3 px, unless ``base`` is
    ``"outside"``: then the tip is inside, at least half the points are, the start is
    outside and the robot crosses the border once (it enters at the border). The
    robot spans 20-95 % of the image (its visible part, for base outside), and the
    thinnest exposed tube is at least 3 px wide.
    """
    backbones = backbones or _robot_points(scene)
    for name, cam in scene.rig.cameras.items():
        span = 0.0
        for bb in backbones:
            uv, z = cam.project(bb.p_world_mm)
            if np.any(z < 30.0) or np.any(~np.isfinite(uv)):
                return f"{name}: robot behind or too close to the camera"
            f = float(np.sqrt(cam.K[0, 0] * cam.K[1, 1]))
            r_px = bb.outer_radius_mm * f / z
            inner = bb.outermost_tube == scene.robot.n_tubes - 1
            if np.any(2.0 * r_px[inner] < MIN_TUBE_PX - 1e-6):
                return f"{name}: thinnest tube {2 * r_px[inner].min():.2f} px wide"
            margin = float(r_px.max()) + 3.0
            inside = cam.in_image(uv, margin_px=margin)
            if base == "outside":
                if not inside[-1] or inside.mean() < 0.5 or inside[0] or np.any(np.diff(inside.astype(int)) < 0):
                    return f"{name}: base-outside robot does not enter at the border with its tip inside"
                vis = uv[inside]
            else:
                if not np.all(inside):
                    return f"{name}: robot leaves the image"
                vis = uv
            ext = vis.max(axis=0) - vis.min(axis=0)
            span = max(span, ext[0] / cam.width, ext[1] / cam.height)
        if not SPAN[0] <= span <= SPAN[1]:
            return f"{name}: robot spans {span:.2f} of the image"
    return None


# ----------------------------------------------------------------------------- one draw
def _draw_rig(rng, target: np.ndarray, width: int, height: int, pixel_um: float) -> dict:
    """The ``[rig]`` table before focal lengths: orbits giving the angle between the axes, mounts, distortion."""
    # Angle between the optical axes: the top camera orbits about the insertion axis by
    # (90 - angle) * w and the side one by -(90 - angle) * (1 - w); then both get a yaw or
    # pitch of their own (changing the angle a little, checked below) and a common roll.
    angle = rng.uniform(*ANGLE_DEG)
    w = rng.uniform(0.0, 1.0)
    roll = rng.uniform(-30.0, 30.0)
    orbits = {
        "side": [(angle - 90.0) * (1 - w) + roll, 0.0, rng.uniform(-25.0, 25.0)],
        "top": [(90.0 - angle) * w + roll, rng.uniform(-25.0, 25.0), 0.0],
    }
    rig = {"focal_length_mm": 10.0, "pixel_size_um": pixel_um, "target_mm": [_r(t, 3) for t in target], "distance_mm": 300.0}
    for cam in ("side", "top"):
        pp = rng.uniform(-0.03, 0.03, 2) * np.array([width, height])
        dist = _distortion(rng)
        rig[cam] = {
            "distance_mm": _r(rng.uniform(*DISTANCE_MM), 2),
            "orbit_deg": [_r(o, 3) for o in orbits[cam]],
            "rotation_deg": _mount_rotation(rng),
            "offset_mm": [_r(o, 3) for o in rng.uniform(-3.0, 3.0, 3)],
            "principal_offset_px": [_r(p, 2) for p in pp],
            "distortion": dist,
        }
    return rig


def _fit_focal_lengths(rng, data: dict, name: str, tube_tables: list, aim_pts: np.ndarray, width: int, height: int,
                       pixel_um: float) -> dict | None:
    """Set each camera's ``focal_length_mm`` in ``data["rig"]``; returns focal lengths (px) by camera, or None to redraw."""
    rig = data["rig"]
    # Focal lengths: first at 10 mm, then scaled so the robot spans the drawn fraction of the
    # image, raised where the thinnest tube would be under 3 px wide.
    probe = scene_from_dict(data, source=name)
    thinnest = min(t["outer_diameter_mm"] for t in tube_tables)
    f_px_by_cam = {}
    for cam_name, cam in probe.rig.cameras.items():
        uv, z = cam.project(aim_pts)
        ext = np.nanmax(uv, axis=0) - np.nanmin(uv, axis=0)
        span0 = max(ext[0] / width, ext[1] / height)
        f0_px = float(cam.K[0, 0])
        f_px = f0_px * rng.uniform(*SPAN) / max(span0, 1e-9)
        f_px = max(f_px, 1.05 * MIN_TUBE_PX * float(np.max(z)) / thinnest)
        if f_px > 1.3 * max(width, height) / 0.35 or f_px < 0.3 * max(width, height):
            return None  # field of view narrower than 15 deg or wider than ~115 deg: no machine-vision lens
        r_corner = 0.5 * np.hypot(width, height) / f_px
        if not _monotonic(cam.dist, 1.2 * r_corner):
            return None
        rig[cam_name]["focal_length_mm"] = _r(f_px * pixel_um * 1e-3, 4)
        f_px_by_cam[cam_name] = f_px
    return f_px_by_cam


def unit_corners_world_mm(scene: Scene) -> np.ndarray:
    """The 8 corners (world mm) of the actuation unit's block (:data:`twin.scene.ACTUATION_UNIT_BOX_BASE_MM`)."""
    lo, hi = ACTUATION_UNIT_BOX_BASE_MM
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    T = scene.robot.T_world_base
    return corners @ T[:3, :3].T + T[:3, 3]


def _behind_mm(scene: Scene, solid: np.ndarray, aimed_mm: np.ndarray, drawn_mm: float) -> float:
    """How far beyond the target (mm) the per-camera backdrop planes stand: ``drawn_mm`` (5-120 mm, drawn) plus
    10 mm beyond the robot (``solid``, world mm) along each camera's line of sight to the target it was aimed
    at (``aimed_mm``), and at least 15 mm beyond it along the lines of sight the planes are placed on
    (:func:`twin.backdrop.depth_beyond_target_mm`).

    The planes are placed from where the optical axes pass closest, 30 mm or more from the aimed target with
    the mounts a few degrees off; measured from the aimed target alone, a plane could cut through the robot
    and hide it while its truth said it was there (wide-3-6: 20 mm of the robot behind the side camera's
    plane in every frame; wide-5-0 frame 2: its last 6 mm). The draw is kept where it is clear, so that
    scenes drawn before stay as they were.
    """
    drawn = max(0.0, depth_beyond_target_mm(scene, solid, aimed_mm)) + 10.0 + drawn_mm
    return max(drawn, depth_beyond_target_mm(scene, solid) + 15.0)


def _draw_backdrop(rng, scene: Scene, classes: dict, base: str, pts: np.ndarray, target: np.ndarray, width: int,
                   height: int, rgb: bool) -> tuple:
    """The ``[backdrop]`` table (planes behind the robot and unit, kind, colours, clutter, tube look) and the contrast class."""
    # Backdrop planes beyond the robot (and the actuation unit) along each camera's line of sight.
    unit = base == "in-view-unit" or (base == "outside" and rng.random() < 0.5)
    solid = pts
    if unit:
        solid = np.concatenate([pts, unit_corners_world_mm(scene)])
    contrast = "low" if rng.random() < 0.3 else "normal"
    kind = classes["backdrop"]
    c1, c2 = _colors(rng, contrast, rgb)
    backdrop = {
        "kind": kind,
        "color": c1,
        "color2": c2,
        "planes": "per-camera",
        "behind_mm": _r(_behind_mm(scene, solid, target, rng.uniform(5.0, 120.0)), 2),
        "texture_px": auto_texture_px(width, height),
        "pattern_scale": _r(rng.uniform(0.6, 2.0), 3),
        "clutter": int(rng.integers(0, 7)),
        "actuation_unit": bool(unit),
        "mount_posts": False,
        "robot_color": [_r(rng.uniform(0.3, 0.8), 3)] * 3,
        "robot_metallic": _r(rng.uniform(0.3, 0.9), 3),
        "robot_roughness": _r(rng.uniform(0.2, 0.6), 3),
    }
    if kind == "photo":
        backdrop["photo"] = PHOTOS[int(rng.integers(len(PHOTOS)))]
    return backdrop, contrast


def draw_wide(rng: np.random.Generator, name: str, classes: dict, max_pixels: int | None = None) -> dict | None:
    """One draw of the "wide" suite with the given class labels: the TOML dict, or None to redraw.

    ``max_pixels`` limits the sensor sizes drawn (width x height, px); None draws them all.
    """
    n_tubes = int(classes["tubes"])
    base = classes["base"]
    masks = classes["input"] == "masks"
    drawn = _draw_robot(rng, n_tubes)
    if drawn is None:
        return None
    tube_tables, steps = drawn
    sizes = [wh for wh in IMAGE_SIZES if max_pixels is None or wh[0] * wh[1] <= max_pixels]
    width, height = sizes[int(rng.integers(len(sizes)))]
    rgb = (not masks) and rng.random() < 0.5
    pixel_um = float(_PIXEL_UM[int(rng.integers(len(_PIXEL_UM)))])
    data = {
        "format": "ctr-bench-scene",
        "version": 1,
        "name": name,
        "seed": int(rng.integers(0, 2**31 - 1)),
        "image": {"width": width, "height": height, "color": "rgb" if rgb else "mono"},
        "robot": {"model": "bending", "base_position_mm": [0.0, 0.0, 0.0], "insertion_axis": [1.0, 0.0, 0.0],
                  "bend_axis": [0.0, 1.0, 0.0], "tubes": tube_tables},
        "sequence": {"background_frames": 8, "frame_interval_s": 1.0, "steps": steps},
    }
    if masks:
        data["image"]["kind"] = "masks"
        data["image"]["mask_polarity"] = "robot-white" if rng.random() < 0.6 else "robot-black"
    backbones = _robot_points(scene_from_dict(data, source=name))
    pts = np.concatenate([bb.p_world_mm for bb in backbones])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    if base == "outside":
        # Aim at the distal part of the robot, so its base falls outside the views.
        distal = np.concatenate([bb.p_world_mm[bb.s_mm > 0.45 * bb.s_mm[-1]] for bb in backbones])
        target = 0.5 * (distal.min(axis=0) + distal.max(axis=0))
        aim_pts = distal
    else:
        target = 0.5 * (lo + hi) + rng.uniform(-0.08, 0.08, 3) * (hi - lo)
        aim_pts = pts
    rig = _draw_rig(rng, target, width, height, pixel_um)
    data["rig"] = rig
    f_px_by_cam = _fit_focal_lengths(rng, data, name, tube_tables, aim_pts, width, height, pixel_um)
    if f_px_by_cam is None:
        return None
    scene = scene_from_dict(data, source=name)
    if not ANGLE_DEG[0] <= camera_angle_deg(scene) <= ANGLE_DEG[1]:
        return None
    if view_problem(scene, base, backbones):
        return None
    data["backdrop"], contrast = _draw_backdrop(rng, scene, classes, base, pts, target, width, height, rgb)
    data["lighting"] = {"ambient": _r(rng.uniform(0.15, 0.6), 3), "lights": _lights(rng, target)}
    data["noise"] = _noise(rng, max(f_px_by_cam.values()))
    final = scene_from_dict(data, source=name)
    classes = dict(classes, camera_angle=angle_class(camera_angle_deg(final)), resolution=resolution_class(width, height),
                   contrast=contrast)
    data["classes"] = classes
    return data


def _draw_classes(rng) -> dict:
    """Class labels of one scene (drawn first, so every class shows up in a suite)."""
    return {
        "backdrop": _BACKDROPS[int(rng.integers(len(_BACKDROPS)))],
        "base": _BASES[int(rng.integers(len(_BASES)))],
        "tubes": "3" if rng.random() < 0.35 else "2",
        "input": "masks" if rng.random() < 0.15 else "camera",
    }


def generate_suite(suite: str, n: int, seed: int, max_pixels: int | None = None) -> list:
    """``n`` generated scenes of ``suite`` (``"wide"``), reproducible from ``seed``.

    Parameters
    ----------
    suite : str
        One of :data:`SUITES`.
    n : int
        Number of scenes (>= 1).
    seed : int
        Seed (>= 0); scene k draws from ``SeedSequence([seed, k])``, so a suite's first
        scenes do not depend on ``n``.
    max_pixels : int, optional
        Draw only sensors of at most this many pixels (quick test profiles); everything
        else is drawn from the same ranges. None (default) draws 0.3-5 MP.

    Returns
    -------
    list of GeneratedScene
        Named ``"<suite>-<seed>-<k>"``; ``data["classes"]`` holds the labels too.
    """
    if suite not in SUITES:
        raise ValueError(f"unknown suite {suite!r}; one of {', '.join(SUITES)}")
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"n must be an integer >= 1, got {n!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    if max_pixels is not None and max_pixels < IMAGE_SIZES[0][0] * IMAGE_SIZES[0][1]:
        raise ValueError(f"max_pixels must be >= {IMAGE_SIZES[0][0] * IMAGE_SIZES[0][1]} (the smallest sensor), got {max_pixels!r}")
    out = []
    for k in range(n):
        rng = np.random.default_rng(np.random.SeedSequence([seed, k]))
        name = f"{suite}-{seed}-{k}"
        classes = _draw_classes(rng)
        for _ in range(_MAX_ATTEMPTS):
            data = draw_wide(rng, name, classes, max_pixels)
            if data is not None:
                break
        else:  # pragma: no cover - would mean the ranges cannot be met
            raise RuntimeError(f"{name}: no valid draw in {_MAX_ATTEMPTS} attempts for classes {classes}")
        out.append(GeneratedScene(name=name, data=data, classes=dict(data["classes"])))
    return out


def shrink_images(data: dict, factor: float) -> dict:
    """A copy of a scene dict with images ``factor`` times smaller and the same geometry.

    Focal lengths, principal-point offsets, jitter and blur scale with the image, so
    the robot lands where it did in the full-size images (for quick tests).
    """
    import copy

    d = copy.deepcopy(data)
    img = d["image"]
    w, h = img.get("width", 1024), img.get("height", 768)
    img["width"] = max(16, int(round(w * factor)))
    img["height"] = max(16, int(round(h * factor)))
    rig = d.setdefault("rig", {})
    base_focal = rig.get("focal_length_mm", 12.0)
    rig["focal_length_mm"] = base_focal * factor
    for cam in ("side", "top"):
        c = rig.setdefault(cam, {})
        c["focal_length_mm"] = c.get("focal_length_mm", base_focal) * factor
        if "principal_offset_px" in c:
            c["principal_offset_px"] = [p * factor for p in c["principal_offset_px"]]
    noise = d.get("noise", {})
    for key in ("blur_px", "jitter_px"):
        if key in noise:
            noise[key] = noise[key] * factor
    if "backdrop" in d and d["backdrop"].get("texture_px"):
        d["backdrop"]["texture_px"] = max(256, int(d["backdrop"]["texture_px"] * factor))
    return d


def write_suite(scenes: list, directory) -> list:
    """Write generated scenes as ``directory/<name>.toml`` plus ``directory/index.json``; returns the TOML paths.

    The one writer of suite files (``ctr-bench scenes generate`` and the wide
    benchmark). A file is replaced (atomically) only when its content changed, so
    render caches keyed by a scene file's bytes stay valid when a suite is written
    again. ``index.json`` lists ``{"name", "file", "classes"}`` in draw order.
    """
    import json
    from pathlib import Path

    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    paths, index = [], []
    for s in scenes:
        path = out / f"{s.name}.toml"
        text = dumps_toml(s.data)
        if not path.exists() or path.read_text() != text:
            tmp = path.with_name(f".{path.name}.tmp")
            tmp.write_text(text)
            tmp.replace(path)
        paths.append(path)
        index.append({"name": s.name, "file": path.name, "classes": s.classes})
    (out / "index.json").write_text(json.dumps(index, indent=2) + "\n")
    return paths
