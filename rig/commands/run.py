"""``ctr-bench run [SCENE]``: the main job: render a twin scene, reconstruct it, score it."""
from __future__ import annotations

import time
from pathlib import Path

from .reconstruct import add_method_options, add_report_options, reconstruct_and_report
from .render import add_scene_options, load_scene_from_args, render_scene_to


def _run(args) -> int:
    scene = load_scene_from_args(args)
    out = Path(args.out) if args.out else Path("out") / f"{scene.name}-{time.strftime('%Y%m%d-%H%M%S')}"
    if out.exists() and any(out.iterdir()):
        raise ValueError(f"--out {out}: exists and is not empty (nothing is overwritten; choose another)")
    session = out / "session"
    t0 = time.perf_counter()
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
    p.add_argument("--out", default=None, help="output directory (default out/<scene>-<timestamp>)")
    p.set_defaults(func=_run)
