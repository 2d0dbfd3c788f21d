"""Option syntaxes shared by the sub-commands: one parser per syntax, so that one option name means one thing.

* ``--frames LIST`` (verify, fit) and ``--background-frames LIST`` (import) select
  frames by number: ``3,7,10-12``; :func:`parse_frames` reads both.
* ``--n-frames N`` and ``--n-background-frames N`` (render, run, bench,
  render-bench) are counts; :func:`count` checks them when the options are read.
* ``--params FILE`` is a TOML parameter file of a reconstruction method (run,
  reconstruct, experiment, tune); ``fit --fit-params LIST`` names the robot
  parameters to estimate.

Not a sub-command: rig/cli/__init__.py registers only the modules it lists.
"""
from __future__ import annotations

import argparse
from dataclasses import replace

import cv2

from recon.methods import get_method
from recon.params import params_from_dict, read_params_file
from rig.scenefiles import DEFAULT_SCENE
from rig.session import Session
from twin.scene import load_scene
from twin.scenegen import IMAGE_SIZES

__all__ = ["parse_frames", "count"]


def parse_frames(text: str | None, option: str = "--frames") -> set | None:
    """``"3,7,10-12"`` -> ``{3, 7, 10, 11, 12}`` (frame numbers, from 0); None -> None (all frames).

    Raises
    ------
    ValueError
        Not numbers and ``a-b`` ranges, or no frame at all; the message names ``option``.
    """
    if text is None:
        return None
    out = set()
    try:
        for part in text.split(","):
            part = part.strip()
            if not part:
                continue
            a, sep, b = part.partition("-")
            out.update(range(int(a), int(b) + 1) if sep else [int(a)])
    except ValueError:
        raise ValueError(f"{option} {text!r}: expected frame numbers and ranges like 3,7,10-12") from None
    if not out:
        raise ValueError(f"{option} {text!r}: no frames")
    return out


def count(minimum: int):
    """An argparse ``type`` for a whole number >= ``minimum`` (refused when the options are read, before any work)."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {value}")
        return value

    return parse


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
    scene = load_scene(args.scene or DEFAULT_SCENE)
    if args.n_frames is not None:
        scene = scene.with_frames(scene.joints[: args.n_frames])
    if args.n_background_frames is not None:
        scene = replace(scene, background_frames=args.n_background_frames)
    if getattr(args, "model", None):
        scene = replace(scene, model=args.model)
    return scene


def method_name(name: str) -> str:
    """``--method``'s type: a known method's name, checked when the options are read (before any render)."""
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
    m = get_method(args.method)
    data = read_params_file(args.params, args.method) if args.params else {}
    params = params_from_dict(m.params_type, data, source=str(args.params or "defaults"))
    if session_dir is not None and not {"outer_tube_radius_mm", "inner_tube_radius_mm"} & set(data):
        radii = Session(session_dir).robot_tube_radii_mm
        if radii is not None and hasattr(params, "outer_tube_radius_mm"):
            params = replace(params, outer_tube_radius_mm=radii[0], inner_tube_radius_mm=radii[1])
    return params


def one_core() -> None:
    """Keep reconstruction on one core, so ms per pair are one-core figures."""
    cv2.setNumThreads(1)


def add_data_options(p) -> None:
    """Options shared by verify and fit."""
    p.add_argument("recon", metavar="RECON_DIR", help="reconstruction output directory (or a twin session: its ground truth is the measurement)")
    p.add_argument("--model", choices=("bending", "compliant"), default=None, help="kinematic model (default: the robot's)")
    p.add_argument("--robot", default=None, metavar="ROBOT.toml",
                   help="robot file ([robot] table as in a scene, optional [actuator] offsets) instead of the session's nominal robot")
    p.add_argument("--session", default=None, metavar="DIR", help="session directory (default: the one summary.json names)")
    p.add_argument("--frames", default=None, metavar="LIST", help="use only these frames, e.g. 3,7,10-12 (default: all)")
    p.add_argument("--ds", type=float, default=0.25, metavar="MM", help="model sample spacing (mm, default 0.25)")


def megapixels_limit(megapixels) -> int | None:
    """``--max-megapixels`` as a pixel count (None: every sensor size), checked against the smallest sensor drawn."""
    if megapixels is None:
        return None
    smallest = IMAGE_SIZES[0][0] * IMAGE_SIZES[0][1]
    if not megapixels * 1e6 >= smallest:
        raise ValueError(f"--max-megapixels must be >= {smallest / 1e6:g} (the smallest sensor drawn, "
                         f"{IMAGE_SIZES[0][0]}x{IMAGE_SIZES[0][1]}), got {megapixels:g}")
    return int(megapixels * 1e6)


def add_sweep_options(p, prefix: str = "") -> None:
    """``--scheduler`` and ``--workers``: where a sweep's tasks run (:mod:`rig.bench.sweep`, docs/scale.md)."""
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help=f"{prefix}run the sweep on this Dask scheduler (tcp://host:port; its workers need ctr-bench and "
                   "the cache and output folders); default: an in-process cluster on this machine")
    p.add_argument("--workers", type=count(0), default=None, metavar="N",
                   help=f"{prefix}workers of the in-process cluster (default: one a core; 0: no cluster, "
                   "the tasks run one after another in this process)")
