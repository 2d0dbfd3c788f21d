"""``ctr-bench calibrate``: the rig calibration file from checkerboard images (or from existing calibrations).

Modes (exactly one)::

    ctr-bench calibrate --render scenes/calibration.toml --out DIR      twin images in the folder layout
    ctr-bench calibrate DIR --board 9x6 --square-mm 5 --out rig.json   calibrate from a folder
    ctr-bench calibrate --import-opencv STEREO.yaml --world-from W --out rig.json
    ctr-bench calibrate --import-ros SIDE.yaml TOP.yaml --world-from W --out rig.json
    ctr-bench calibrate --import-stereo-calib intrinsics.yml extrinsics.yml --world-from W --out rig.json
    ctr-bench calibrate --import-kalibr camchain.yaml --world-from W --out rig.json

The folder layout, the world-frame convention and the outputs are described in
docs/calibration.md.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import cv2

from recon.calibration import CalibrationParams, calibrate_rig, draw_coverage, load_calibration_folder, save_report
from recon.calibration_check import check_rig
from recon.calibration_io import export_rig_opencv, export_rig_ros
from recon.distortion import MODEL_NAMES, MODEL_SIZES
from recon.rigcal import load_rig_calibration, save_rig_calibration
from rig.hw.calibration_sources import (
    SOURCES,
    add_source_options,
    board_meta,
    board_spec,
    placement_of,
    rig_from_sources,
)
from rig.progress import Progress
from rig.scenefiles import scene_path
from twin.board import load_calibration_scene, render_calibration, write_capture

DEFAULT_CAL_SCENE = scene_path("calibration.toml")


def _params(args):
    return CalibrationParams(distortion_model=args.distortion_model, distortion=args.distortion, joint_refinement=not args.no_joint_refinement,
                             min_views=args.min_views)


# ----------------------------------------------------------------------------- modes
def _render(args) -> int:
    if args.out is None:
        raise ValueError("--render needs --out DIR (the folder to write the images into)")
    cal = load_calibration_scene(args.render)
    out = Path(args.out)
    progress = Progress(enabled=not args.quiet)
    capture = render_calibration(cal, progress=progress)
    progress.close()
    write_capture(capture, out)
    n = sum(len(v) for v in capture.views.values()) + 2 * len(capture.stereo) + sum(len(v) for v in capture.world.values())
    print(f"rendered {n} calibration images of a {cal.board.label} board ({cal.board.square_mm:g} mm squares) into {out}")
    print(f"calibrate them with: ctr-bench calibrate {out} --out {out / 'rig.json'}")
    return 0


def _calibrate_folder(args) -> int:
    folder = Path(args.folder)
    if not folder.is_dir():
        raise ValueError(f"{folder}: no such calibration folder")
    meta = board_meta(folder)
    board = board_spec(args, meta)
    placement = placement_of(args, meta)
    images = load_calibration_folder(folder)
    progress = Progress(enabled=not args.quiet)
    rig, report = calibrate_rig(images, board, _params(args), progress=progress, **placement)
    progress.close()
    out = Path(args.out)
    written = _save_rig(out, rig)
    report_path = out.parent / "calibration_report.json"
    save_report(report_path, report)
    written.append(report_path)
    for cam, cal in report.cameras.items():
        background = images.views[cam][0][1] if images.views.get(cam) else None
        path = out.parent / f"calibration_coverage_{cam}.png"
        if not cv2.imwrite(str(path), draw_coverage(cal, board, background)):
            raise OSError(f"cannot write {path}")
        written.append(path)
    truth = None
    truth_path = folder / "truth" / "rig.json"
    if truth_path.is_file():
        truth = load_rig_calibration(truth_path)
    print(report.summary(truth))
    print("wrote " + ", ".join(str(p) for p in written))
    return 0


def _save_rig(out: Path, rig) -> list:
    """The rig file and its exports: OpenCV (``<stem>_stereo.yaml``, per camera) and a rectified ROS stereo pair
    (``<stem>_ros_<camera>.yaml``, skipped with a note when the distortion has no ROS model); returns the paths.

    The rig is checked first (:func:`recon.calibration_check.check_rig`: K, principal point, orthonormal R, a lens that
    neither folds nor bends the corners implausibly), so a calibration that reconstruct would refuse is never written.
    """
    check_rig(rig, str(out))
    out.parent.mkdir(parents=True, exist_ok=True)
    save_rig_calibration(out, rig)
    written = [out] + export_rig_opencv(rig, out.with_suffix(""))
    try:
        written += export_rig_ros(rig, out.with_suffix(""))
    except ValueError as exc:
        print(f"note: no ROS camera_info written: {exc}")
    return written


def _import(args) -> int:
    written = _save_rig(Path(args.out), rig_from_sources(args, _params(args)))
    print("wrote " + ", ".join(str(p) for p in written))
    return 0


def _run(args) -> int:
    modes = [m for m, on in [("folder", args.folder), ("--render", args.render)] + [(o, getattr(args, d)) for o, d in SOURCES] if on]
    if len(modes) != 1:
        raise ValueError("give exactly one of: a calibration folder, --render SCENE, --import-opencv FILE, --import-ros SIDE TOP, "
                         "--import-stereo-calib INTRINSICS EXTRINSICS, --import-kalibr CAMCHAIN"
                         + (f" (got {', '.join(modes)})" if modes else ""))
    if args.render:
        return _render(args)
    if args.out is None:
        raise ValueError("--out is required (the rig calibration JSON to write)")
    if args.folder:
        return _calibrate_folder(args)
    return _import(args)


def _model(text: str) -> int:
    """``--distortion-model``'s type: an OpenCV coefficient count or its name (recon.distortion.MODEL_NAMES)."""
    n = MODEL_NAMES.get(text, int(text) if text.isdigit() else None)
    if n not in MODEL_SIZES:
        raise argparse.ArgumentTypeError(f"expected {', '.join(map(str, MODEL_SIZES))} or {', '.join(MODEL_NAMES)}, got {text!r}")
    return n


def _min_views(text: str) -> int:
    """``--min-views``'s type: an integer of at least 3 (OpenCV's intrinsic calibration needs 3 views of a planar board)."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
    if n < 3:
        raise argparse.ArgumentTypeError(f"must be at least 3 (a camera's intrinsics need 3 views of the board), got {n}")
    return n


def register(sub) -> None:
    p = sub.add_parser(
        "calibrate",
        help="calibrate the rig from checkerboard images (or import OpenCV/ROS calibrations)",
        description="Calibrate the two-camera rig as Morimoto & Sketch did: each camera's intrinsics from its checkerboard "
        "views, T_side_top from stereo pairs, T_top_world from the board in the world-frame pose, T_side_world = "
        "T_side_top @ T_top_world; then one joint refinement. Writes the rig calibration JSON that reconstruct reads, an "
        "OpenCV YAML export, calibration_report.json and corner-coverage images. See docs/calibration.md.",
    )
    p.add_argument("folder", nargs="?", default=None, help="calibration folder (side/, top/, stereo/side, stereo/top, world/top.png)")
    p.add_argument("--render", metavar="SCENE", default=None, help=f"render the twin's calibration images of a calibration scene "
                   f"(e.g. the bundled {DEFAULT_CAL_SCENE.name}) into --out DIR")
    add_source_options(p)
    p.add_argument("--out", default=None, help="rig calibration JSON to write (with --render: the folder to create)")
    p.add_argument("--distortion-model", type=_model, default=5, metavar="N",
                   help="OpenCV distortion model: 4, 5 (plumb_bob, default), 8 (rational_polynomial), 12 (thin_prism) or 14 (tilted), "
                   "by count or name")
    p.add_argument("--distortion", default="auto",
                   help="which of the model's terms are estimated: auto (all, insignificant groups held at 0), none, or e.g. "
                   "'k1 k2 p1 p2 k3', 'k1 k2'")
    p.add_argument("--no-joint-refinement", action="store_true", help="stop after the OpenCV stages (as the paper did)")
    p.add_argument("--min-views", type=_min_views, default=5, help="usable views each camera needs (at least 3; default 5)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_run)
