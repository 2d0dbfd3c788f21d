"""``ctr-bench run [SCENE]``: the main job: render a twin scene, reconstruct it, score it.

Outputs go to a fresh ``out/<scene>-<time>/`` unless ``--out`` names a directory;
one that is not empty is refused unless ``--overwrite`` (the earlier run, its
rendered session included, is removed) or ``--resume`` (its session is reused
when it holds the whole scene, and its finished frames are kept).
"""
from __future__ import annotations

import shutil
import time
from pathlib import Path

from .reconstruct import add_existing_options, add_method_options, add_report_options, existing_mode, reconstruct_and_report
from .render import add_scene_options, load_scene_from_args, render_scene_to


def _rendered_session(session: Path, scene) -> bool:
    """Whether ``session`` holds the whole of ``scene`` already (for --resume); a partial or other render is refused."""
    from rig.rundir import RunDirError
    from rig.session import Session

    if not (session / "session.json").exists():
        return False
    s = Session(session)
    name, bg = s.meta.get("scene_name"), s.meta.get("background_frames")
    if name != scene.name or len(s.frames) != len(scene.joints) or bg != scene.background_frames:
        raise RunDirError(f"{session}: holds {len(s.frames)} frames and {bg} background frames of scene {name!r}, not the "
                          f"{len(scene.joints)} and {scene.background_frames} of {scene.name!r} (a render cut short, or "
                          "another scene); --overwrite renders it again")
    return True


def _make_room(out: Path, mode: str) -> None:
    """Before rendering into ``out/session``: refuse a directory in use, or remove the earlier run (``overwrite``)."""
    from rig.rundir import RunDirError, earlier_files, remove_files, writing

    if not out.exists() or not any(out.iterdir()):
        return
    if mode == "refuse":
        raise RunDirError(f"--out {out}: exists and is not empty (nothing is overwritten; --overwrite replaces an "
                          "earlier run, --resume continues it, or choose another)")
    earlier = earlier_files(out)
    if mode == "resume" and earlier:
        raise RunDirError(f"{out}: --resume: holds an earlier run but not its whole session ({out / 'session'}); "
                          "--overwrite starts again")
    if mode == "overwrite":
        remove_files(out, earlier)
        if (out / "session").is_dir():  # run's own render: rendered again below
            with writing(out / "session"):
                shutil.rmtree(out / "session")


def _run(args) -> int:
    scene = load_scene_from_args(args)
    out = Path(args.out) if args.out else Path("out") / f"{scene.name}-{time.strftime('%Y%m%d-%H%M%S')}"
    mode = existing_mode(args)
    session = out / "session"
    t0 = time.perf_counter()
    if mode == "resume" and _rendered_session(session, scene):
        print(f"resuming in {out}: {session} holds the whole scene; reconstructing the frames not yet done")
    else:
        _make_room(out, mode)
        print(f"rendering {scene.name!r} ({len(scene.joints)} frames, {scene.background_frames} background frames) into {session}")
        render_scene_to(scene, session, quiet=args.quiet)
    t1 = time.perf_counter()
    print(f"rendered in {t1 - t0:.1f} s; reconstructing with method {args.method!r}")
    summary = reconstruct_and_report(session, out, args)
    print(f"total {time.perf_counter() - t0:.1f} s (render {t1 - t0:.1f} s)")
    return 0 if summary["failed_frames"] < summary["frames"] else 1


def register(sub) -> None:
    p = sub.add_parser("run", help="render a twin scene, reconstruct and score it (the main job)",
                       description="Render a twin scene (default scenes/paper.toml) into OUT/session, reconstruct every frame "
                       "into OUT, score against the ground truth and print a per-frame table.")
    add_scene_options(p)
    add_method_options(p)
    add_report_options(p)
    p.add_argument("--out", default=None, help="output directory (default out/<scene>-<timestamp>, a new one each time)")
    add_existing_options(p, ("OUT/session", "OUT/session is reused when it holds the whole scene"))
    p.set_defaults(func=_run)
