"""``ctr-bench run [SCENE]``: the main job: render a twin scene, reconstruct it, score it.

Outputs go to a fresh ``out/<scene>-<time>/`` unless ``--out`` names a directory;
one that is not empty is refused unless ``--overwrite`` (the earlier run, its
rendered session included, is removed) or ``--resume`` (its session is reused
when it holds the whole scene, and its finished frames are kept).

The scene is rendered once: the render cache (:mod:`rig.bench.render_cache`, shared
with ``bench``, ``tune`` and ``dataset``; ``--cache-dir``, default
``out/bench-cache``) keeps it under a hash of the scene file's content, the frame
counts, the model and the twin's code, and ``OUT/session`` is made of hard links
to the cached files. A second run of the same scene renders nothing;
``--no-cache`` renders into ``OUT/session`` afresh without reading or writing the cache.
"""
from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

from rig.bench.render_cache import DEFAULT_CACHE_DIR, cached_session, link_session
from rig.bench.scenes import render_scene_to
from rig.cli.options import (
    add_existing_options,
    add_method_options,
    add_report_options,
    add_scene_options,
    existing_mode,
    load_scene_from_args,
)
from rig.cli.shared import reconstruct_and_report
from rig.rundir import RunDirError, earlier_files, remove_files, write_json_atomic, writing
from rig.session import Session


def _rendered_session(session: Path, scene) -> bool:
    """Whether ``session`` holds the whole of ``scene`` already (for --resume); a partial or other render is refused."""
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


def _fill_session(scene, session: Path, args) -> str:
    """Put the whole scene into ``session``: linked from the render cache (rendered there first if need be),
    or rendered in place with ``--no-cache``; returns ``"cached"`` when nothing was rendered, else ``"rendered"``."""
    if args.no_cache:
        print(f"rendering {scene.name!r} ({len(scene.joints)} frames, {scene.background_frames} background frames) into {session}")
        render_scene_to(scene, session, quiet=args.quiet)
        return "rendered"
    rendered = []

    def log(line: str) -> None:
        rendered.append(line)
        print(line)

    cached = cached_session(scene, 1.0, Path(args.cache_dir), quiet=args.quiet, log=log)
    if not rendered:
        print(f"reusing the render of {scene.name!r} ({len(scene.joints)} frames, {scene.background_frames} background "
              f"frames) cached in {cached} (--no-cache renders it again)")
    link_session(cached, session)
    meta = json.loads((session / "session.json").read_text())
    if meta.get("scene") != scene.source:  # cached from another copy of the same file: name this run's
        write_json_atomic(session / "session.json", dict(meta, scene=scene.source))  # a file of its own, the cache's unchanged
    return "rendered" if rendered else "cached"


def _run(args) -> int:
    scene = load_scene_from_args(args)
    out = Path(args.out) if args.out else Path("out") / f"{scene.name}-{time.strftime('%Y%m%d-%H%M%S')}"
    mode = existing_mode(args)
    session = out / "session"
    t0 = time.perf_counter()
    how = "rendered"
    if mode == "resume" and _rendered_session(session, scene):
        print(f"resuming in {out}: {session} holds the whole scene; reconstructing the frames not yet done")
    else:
        _make_room(out, mode)
        how = _fill_session(scene, session, args)
    t1 = time.perf_counter()
    print(f"{'session from the cache' if how == 'cached' else 'rendered'} in {t1 - t0:.1f} s; reconstructing with method {args.method!r}")
    summary = reconstruct_and_report(session, out, args)
    print(f"total {time.perf_counter() - t0:.1f} s (render {t1 - t0:.1f} s{', from the cache' if how == 'cached' else ''})")
    return 0 if summary["failed_frames"] < summary["frames"] else 1


def register(sub) -> None:
    p = sub.add_parser("run", help="render a twin scene, reconstruct and score it (the main job)",
                       description="Render a twin scene (default scenes/paper.toml) into OUT/session, reconstruct every frame "
                       "into OUT, score against the ground truth and print a per-frame table. The render is cached "
                       "(keyed by the scene file's content): running the same scene again renders nothing.")
    add_scene_options(p)
    add_method_options(p)
    add_report_options(p)
    p.add_argument("--out", default=None, help="output directory (default out/<scene>-<timestamp>, a new one each time)")
    add_existing_options(p, ("OUT/session", "OUT/session is reused when it holds the whole scene"))
    p.add_argument("--cache-dir", default=str(DEFAULT_CACHE_DIR),
                   help="where rendered scenes are cached, shared with bench (default %(default)s)")
    p.add_argument("--no-cache", action="store_true",
                   help="render the scene afresh into OUT/session, neither reading nor writing the cache")
    p.set_defaults(func=_run)
