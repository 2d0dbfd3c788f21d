"""``ctr-bench reconstruct SESSION_DIR --out DIR``: reconstruct (and score) every frame of a session."""
from __future__ import annotations

from pathlib import Path


def method_name(name: str) -> str:
    """``--method``'s type: a known method's name, checked when the options are read (before any render)."""
    import argparse

    from recon.methods import get_method

    try:
        get_method(name)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return name


def add_method_options(p) -> None:
    """--method and --params, shared by run, reconstruct and experiment."""
    p.add_argument("--method", default="paper", type=method_name, help="reconstruction method: paper (default) or fast")
    p.add_argument("--params", default=None, metavar="FILE", help="TOML parameter file (e.g. written by ctr-bench tune)")


def add_report_options(p) -> None:
    """--no-report and --live, shared by run, reconstruct and experiment."""
    p.add_argument("--no-report", action="store_true",
                   help="do not build OUT/report/index.html and OUT/meshes (ctr-bench report OUT builds them later)")
    p.add_argument("--live", action="store_true",
                   help="show images, backbones and errors live in a rerun viewer (needs the 'live' extra: rerun-sdk)")


def add_existing_options(p, session: tuple = ()) -> None:
    """--overwrite and --resume, shared by run and reconstruct: what to do with an output directory holding an earlier run.

    ``session``: (what --overwrite also removes, what --resume reuses) of ``run``'s rendered session; () for reconstruct.
    """
    g = p.add_mutually_exclusive_group()
    g.add_argument("--overwrite", action="store_true",
                   help="OUT holds an earlier run: remove what it wrote (summary, journal, frame files, backbones, report, "
                   f"meshes{session and ', ' + session[0]}; nothing else) and start again")
    g.add_argument("--resume", action="store_true",
                   help="OUT holds an earlier run cut short: keep its finished frames and do the others (same method, "
                   f"parameters and session, else refused naming the difference){session and '; ' + session[1]}")


def existing_mode(args) -> str:
    """``reconstruct_session``'s ``existing`` for the parsed --overwrite / --resume (refuse when neither)."""
    if getattr(args, "overwrite", False):
        return "overwrite"
    return "resume" if getattr(args, "resume", False) else "refuse"


def method_params(args, session_dir=None):
    """The parameter dataclass for ``args.method``, from ``--params`` when given.

    The tube radii describe the robot, not the method: unless the parameter
    file sets them, they are taken from the session's robot description
    (session.json) when ``session_dir`` has one.
    """
    from dataclasses import replace

    from recon.methods import get_method
    from recon.params import params_from_dict, read_params_file

    m = get_method(args.method)
    data = read_params_file(args.params, args.method) if args.params else {}
    params = params_from_dict(m.params_type, data, source=str(args.params or "defaults"))
    if session_dir is not None and not {"outer_tube_radius_mm", "inner_tube_radius_mm"} & set(data):
        from rig.session import Session

        radii = Session(session_dir).robot_tube_radii_mm
        if radii is not None and hasattr(params, "outer_tube_radius_mm"):
            params = replace(params, outer_tube_radius_mm=radii[0], inner_tube_radius_mm=radii[1])
    return params


def one_core() -> None:
    """Keep reconstruction on one core, so ms per pair are one-core figures."""
    import cv2

    cv2.setNumThreads(1)


def reconstruct_and_report(session_dir: Path, out: Path, args) -> dict:
    from rig.progress import Progress
    from rig.reconstruct import format_table, reconstruct_session

    params = method_params(args, session_dir)
    one_core()
    progress = Progress(enabled=not getattr(args, "quiet", False))
    live = None
    if getattr(args, "live", False):
        from rig.live import LiveLogger

        live = LiveLogger()
    try:
        summary = reconstruct_session(session_dir, out, method=args.method, params=params, existing=existing_mode(args),
                                      progress=live.watch(session_dir, out, progress) if live else progress)
    finally:
        progress.close()
    print(format_table(summary))
    for note in summary.get("session_notes") or ():
        print(f"note: {note}")
    print(f"\noutputs in {out}: frames/*.csv, frames.jsonl, frames.csv, backbones.npz, summary.json")
    if not getattr(args, "no_report", False):
        from rig.report import report_or_warn

        report_or_warn(out)
    return summary


def _run(args) -> int:
    summary = reconstruct_and_report(Path(args.session), Path(args.out), args)
    if args.json:
        from rig.rundir import json_text

        print(json_text({k: v for k, v in summary.items() if k != "per_frame"}))
    return 0 if summary["failed_frames"] < summary["frames"] else 1


def register(sub) -> None:
    p = sub.add_parser("reconstruct", help="reconstruct every frame of a session directory",
                       description="Build the background model from the session's background frames, reconstruct every frame, "
                       "write a CSV per frame, one NPZ and summary.json, and score against ground truth when the session has it.")
    p.add_argument("session", help="session directory (docs/session-format.md)")
    add_method_options(p)
    p.add_argument("--out", required=True, help="output directory (one holding an earlier run is refused unless "
                   "--overwrite or --resume)")
    add_existing_options(p)
    p.add_argument("--json", action="store_true", help="also print the summary (without per-frame list) as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    add_report_options(p)
    p.set_defaults(func=_run)
