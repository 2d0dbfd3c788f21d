"""``ctr-bench import --side SRC --top SRC --calibration rig.json --out SESSION``: a session from a lab's recordings.

Per camera a folder of images, a glob (``'rec/side/*.png'``), a printf pattern
(``'rec/top/img_%04d.png'``) or a video file; background frames from a range of
the inputs or from their own folders; times from the file names, the video or
``--fps``; joint values from an optional CSV (otherwise they stay empty). The
work is done by :mod:`rig.hw.importer`; the format is docs/session-format.md, the
command docs/import.md. The module is not called ``import`` because that is a
Python keyword; the command is.
"""
from __future__ import annotations

from pathlib import Path

from recon.background import EigenBackgroundParams
from recon.rigcal import load_rig_calibration
from rig.cli.options import parse_frames
from rig.hw.calibration_sources import add_source_options, given_sources, rig_from_sources
from rig.hw.importer import check_out_dir, open_recording, plan_import, robot_meta, write_import
from rig.progress import Progress

CAMERAS = ("side", "top")


def _load_calibration(args) -> tuple:
    """``(RigCalibration, source)`` from ``--calibration rig.json`` or any ``--import-*`` calibration
    (:mod:`rig.hw.calibration_sources`, the same options as ``ctr-bench calibrate``)."""
    given = given_sources(args)
    if bool(args.calibration) + len(given) != 1:
        raise ValueError("give one calibration: --calibration rig.json (ctr-bench calibrate writes it) or one of "
                         "--import-opencv, --import-ros, --import-stereo-calib, --import-kalibr (with --world-from)"
                         + (f"; got {', '.join((['--calibration'] if args.calibration else []) + given)}" if given else ""))
    if args.calibration:
        if args.world_from:
            raise ValueError("--world-from goes with the --import-* calibrations (a rig.json holds the world frame already)")
        rig, source = load_rig_calibration(args.calibration), str(args.calibration)
    else:
        rig = rig_from_sources(args)
        source = " + ".join(str(v) for v in (given[0], args.world_from) if v)
    if sorted(rig.names) != sorted(CAMERAS):
        raise ValueError(f"{source}: cameras are {', '.join(rig.names)}; ctr-bench import reads --side and --top, "
                         "so the calibration must name its cameras side and top")
    return rig, source


def _recordings(args, suffix: str) -> dict:
    """Camera -> Recording of the options ``--side<suffix>`` / ``--top<suffix>`` that were given."""
    out = {}
    for cam in CAMERAS:
        spec = getattr(args, f"{cam}{suffix.replace('-', '_')}")
        if spec is not None:
            out[cam] = open_recording(f"--{cam}{suffix}", spec)
    return out


def _plan(args):
    rig, cal_source = _load_calibration(args)
    robot = robot_meta(args.robot, args.tube_diameters_mm)
    return plan_import(
        rig, _recordings(args, ""),
        background_frames=parse_frames(args.background_frames, "--background-frames"),
        background_inputs=_recordings(args, "-background"),
        fps=args.fps, time_regex=args.time_from_name, time_unit=args.time_unit, joints_file=args.joints,
        robot=robot, masks=args.masks, mask_polarity=args.mask_polarity, calibration_source=cal_source)


def _run(args) -> int:
    out = Path(args.out)
    check_out_dir(out)                   # before reading anything: a wrong --out is the cheapest mistake
    plan = _plan(args)
    progress = Progress(enabled=not args.quiet)
    write_import(plan, out, progress)
    progress.close()
    with_joints = plan.meta["import"]["frames_with_joints"]
    joints = (f"joints for {with_joints} of {plan.frame_count} frames from {args.joints}" if args.joints else
              "no joint values (no --joints: verify and fit need them)")
    print(f"imported {plan.frame_count} frame pairs and {plan.background_count} background pairs into {out}; {joints}")
    need = EigenBackgroundParams().k + 1
    if plan.background_count < need:
        print(f"note: the default eigenbackgrounds need {need} background frames per camera, this session has "
              f"{plan.background_count}")
    print(f"next: ctr-bench reconstruct {out} --out {out}-rec")
    return 0


def register(sub) -> None:
    p = sub.add_parser(
        "import", help="build a session directory from a lab's own image folders or videos",
        description="Build a session directory (docs/session-format.md) from per-camera image folders, glob or printf "
                    "patterns, or video files; background frames from a frame range or their own inputs; times from "
                    "file names, the video or --fps; joints from an optional CSV. Reconstruct it with ctr-bench "
                    "reconstruct. docs/import.md has examples.")
    for cam in CAMERAS:
        p.add_argument(f"--{cam}", metavar="SRC", default=None,
                       help=f"{cam} camera: a folder, a glob ('rec/{cam}/*.png'), a printf pattern "
                            f"('rec/{cam}/img_%%04d.png') or a video file")
    for cam in CAMERAS:
        p.add_argument(f"--{cam}-background", metavar="SRC", default=None,
                       help=f"robot-free frames of the {cam} camera (same kinds of input)")
    p.add_argument("--background-frames", metavar="LIST", default=None,
                   help="input frames (from 0) that are robot-free, e.g. 0-9; the others are robot frames")
    p.add_argument("--calibration", metavar="RIG_JSON", default=None, help="rig calibration (rig.json, ctr-bench calibrate)")
    add_source_options(p)
    p.add_argument("--fps", type=float, default=None, help="frame rate: t = input frame index / FPS (overrides other times)")
    p.add_argument("--time-from-name", metavar="REGEX", default=None,
                   help=r"image inputs: the time is the number REGEX finds in each file name (its first group), e.g. 'img_(\d+)_us'")
    p.add_argument("--time-unit", choices=("s", "ms", "us", "ns"), default="s", help="unit of --time-from-name's number (default s)")
    p.add_argument("--joints", metavar="CSV", default=None,
                   help="joint values: columns frame (or t_s), extension_<i>_mm, rotation_<i>_deg; without it they stay empty")
    p.add_argument("--robot", metavar="TOML", default=None, help="robot or scene file: its [robot] table goes into session.json")
    p.add_argument("--tube-diameters-mm", metavar="LIST", default=None,
                   help="outer tube diameters (mm), outermost first, e.g. 1.6,1.0 (instead of --robot)")
    p.add_argument("--masks", action="store_true", help="the inputs are binary silhouettes (robot white on black)")
    p.add_argument("--mask-polarity", choices=("robot-white", "robot-black"), default="robot-white",
                   help="masks: robot-white (default) or robot-black")
    p.add_argument("--out", required=True, help="session directory to create (must not exist, or be empty)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_run)
