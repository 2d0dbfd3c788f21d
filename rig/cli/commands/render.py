"""``ctr-bench render SCENE --out DIR``: render a twin scene into a session directory."""
from __future__ import annotations

from pathlib import Path

from rig.bench.scenes import render_believed_session, render_scene_to
from rig.cli.options import add_scene_options, load_scene_from_args


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
