"""``ctr-bench render SCENE --out DIR``: render a twin scene into a session directory."""
from __future__ import annotations

from pathlib import Path

from rig.scenefiles import scene_path

from .options import count

#: The scene run, render and bench use without a SCENE: the bundled paper scene (a checkout's
#: scenes/paper.toml, a wheel's rig/scenes/paper.toml; rig/scenefiles.py).
DEFAULT_SCENE = scene_path("paper.toml")


def add_scene_options(p) -> None:
    """Options shared by every command that renders a scene (counts: --n-*; --frames LIST selects frames elsewhere)."""
    p.add_argument("scene", nargs="?", default=None, help="scene TOML file (default: scenes/paper.toml, shipped with ctr-bench)")
    p.add_argument("--n-frames", type=count(1), default=None, metavar="N", help="render only the first N robot frames")
    p.add_argument("--n-background-frames", type=count(0), default=None, metavar="N",
                   help="override the number of background frames")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--model", choices=["bending", "compliant"], default=None,
                   help="render with this kinematic model instead of the scene's robot.model")


def load_scene_from_args(args):
    """The scene named by ``args`` (default :data:`DEFAULT_SCENE`) with --n-frames/--n-background-frames applied."""
    from dataclasses import replace

    from twin.scene import load_scene

    scene = load_scene(args.scene or DEFAULT_SCENE)
    if args.n_frames is not None:
        scene = scene.with_frames(scene.joints[: args.n_frames])
    if args.n_background_frames is not None:
        scene = replace(scene, background_frames=args.n_background_frames)
    if getattr(args, "model", None):
        scene = replace(scene, model=args.model)
    return scene


def render_scene_to(scene, out: Path, quiet: bool = False) -> Path:
    """Render ``scene`` into the session directory ``out``; returns it."""
    from rig.progress import Progress
    from rig.session import SessionWriter
    from twin.record import render_session, robot_to_dict

    meta = {"scene": scene.source, "scene_name": scene.name, "robot": robot_to_dict(scene.robot, scene.model)}
    if scene.classes:
        meta["classes"] = dict(scene.classes)
    if scene.image_kind != "camera":
        meta["image_kind"] = scene.image_kind
        meta["mask_polarity"] = scene.mask_polarity
    progress = Progress(enabled=not quiet)
    with SessionWriter(out, scene.rig, source="twin", n_tubes=scene.robot.n_tubes, meta=meta) as writer:
        render_session(scene, writer, progress=progress)
    progress.close()
    return out


def _offsets(text: str | None, option: str) -> list | None:
    if text is None:
        return None
    try:
        return [float(v) for v in text.split(",")]
    except ValueError:
        raise ValueError(f"{option}: expected comma-separated numbers, one per tube (outermost first), got {text!r}") from None


def _run(args) -> int:
    scene = load_scene_from_args(args)
    out = Path(args.out)
    rot = _offsets(args.rotation_offset_deg, "--rotation-offset-deg")
    ext = _offsets(args.extension_offset_mm, "--extension-offset-mm")
    if args.nominal_robot or rot or ext:
        from rig.commands.fit import render_believed_session

        for vals, option in ((rot, "--rotation-offset-deg"), (ext, "--extension-offset-mm")):
            if vals is not None and len(vals) != scene.robot.n_tubes:
                raise ValueError(f"{option}: {len(vals)} values for a robot of {scene.robot.n_tubes} tubes")
        offsets = {k: v for k, v in (("rotation_deg", rot), ("extension_mm", ext)) if v is not None}
        render_believed_session(scene, out, args.nominal_robot, offsets, quiet=args.quiet)
    else:
        render_scene_to(scene, out, quiet=args.quiet)
    print(f"rendered {len(scene.joints)} frame pairs and {scene.background_frames} background pairs of {scene.name!r} into {out}")
    return 0


def register(sub) -> None:
    p = sub.add_parser("render", help="render a twin scene into a session directory",
                       description="Render a twin scene (robot frames, background frames, ground truth) into a session directory "
                       "laid out as docs/session-format.md describes.")
    add_scene_options(p)
    p.add_argument("--out", required=True, help="session directory to create")
    p.add_argument("--nominal-robot", metavar="FILE", default=None,
                   help="record this robot file (what the researcher believes) in session.json instead of the scene's true robot")
    p.add_argument("--rotation-offset-deg", metavar="LIST", default=None,
                   help="actuator rotation offsets per tube: frames.csv records the scene's (true) rotations minus these")
    p.add_argument("--extension-offset-mm", metavar="LIST", default=None,
                   help="actuator insertion offsets per tube: frames.csv records the true extensions minus these")
    p.set_defaults(func=_run)
