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

import json
from pathlib import Path

DEFAULT_CAL_SCENE = Path(__file__).resolve().parents[2] / "scenes" / "calibration.toml"


def _vec3(values, option: str):
    if values is None:
        return None
    return [float(v) for v in values]


def _board_meta(folder: Path | None) -> dict:
    """``board.json`` of a calibration folder (the twin writes one; a lab may), or {}."""
    if folder is None:
        return {}
    path = folder / "board.json"
    if not path.is_file():
        return {}
    try:
        meta = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    if not isinstance(meta, dict):
        raise ValueError(f"{path}: expected a JSON object")
    return meta


def _board(args, meta: dict, required: bool = True):
    from recon.calibration import BoardSpec

    text = args.board or (f"{meta['cols']}x{meta['rows']}" if "cols" in meta and "rows" in meta else None)
    square = args.square_mm if args.square_mm is not None else meta.get("square_mm")
    if text is None or square is None:
        if not required:
            return None
        raise ValueError("give the board: --board COLSxROWS (inner corners, e.g. 9x6) and --square-mm (or a board.json in the folder)")
    return BoardSpec.parse(text, float(square))


def _placement(args, meta: dict) -> dict:
    return {
        "world_origin_mm": _vec3(args.world_origin_mm, "--world-origin-mm") or meta.get("world_origin_mm", [0.0, 0.0, 0.0]),
        "base_point_world_mm": _vec3(args.base_point_mm, "--base-point-mm") or meta.get("base_point_world_mm", [0.0, 0.0, 0.0]),
        "insertion_axis_world": _vec3(args.insertion_axis, "--insertion-axis") or meta.get("insertion_axis_world", [1.0, 0.0, 0.0]),
    }


def _params(args):
    from recon.calibration import CalibrationParams

    return CalibrationParams(model=args.model, distortion=args.distortion, joint_refinement=not args.no_joint_refinement,
                             min_views=args.min_views)


# ----------------------------------------------------------------------------- modes
def _render(args) -> int:
    from rig.progress import Progress
    from twin.board import load_calibration_scene, render_calibration, write_capture

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
    import cv2

    from recon.calibration import calibrate_rig, draw_coverage, load_calibration_folder, save_report
    from recon.rigcal import load_rig_calibration
    from rig.progress import Progress

    folder = Path(args.folder)
    if not folder.is_dir():
        raise ValueError(f"{folder}: no such calibration folder")
    meta = _board_meta(folder)
    board = _board(args, meta)
    placement = _placement(args, meta)
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


def _world_images(path: Path):
    """World-frame images from --world-from: a calibration folder or one image (None for a world file)."""
    from recon.calibration import IMAGE_SUFFIXES, CalibrationImages, load_calibration_folder, read_image

    if path.is_dir():
        return load_calibration_folder(path, extrinsics_only=True)
    if path.suffix.lower() in IMAGE_SUFFIXES:
        return CalibrationImages(views={}, stereo=[], world={"top": [(path.name, read_image(path))]}, source=str(path))
    return None


def _one_side_pose(world_from: Path, source: str, T_stereo, T_world_file):
    """The side pose from the stereo file or the world file; both, only when they agree (0.01 mm, 0.001 deg).

    An OpenCV stereo file's R, T is T_side_top; a world file giving another one
    would silently replace the calibrated stereo pose (issue 14: 182 mm).
    """
    if T_world_file is None or T_stereo is None:
        return T_world_file if T_world_file is not None else T_stereo
    from recon.calibration import pose_difference

    d_mm, d_deg = pose_difference(T_world_file, T_stereo)
    if d_mm > 0.01 or d_deg > 0.001:
        raise ValueError(f"{world_from}: T_side_top differs from the side pose of {source} by {d_mm:.3f} mm, {d_deg:.4f} deg "
                         "(--world-from): give the side camera's pose in one file only")
    return T_stereo


def _save_rig(out: Path, rig) -> list:
    """The rig file and its exports: OpenCV (``<stem>_stereo.yaml``, per camera) and a rectified ROS stereo pair
    (``<stem>_ros_<camera>.yaml``, skipped with a note when the distortion has no ROS model); returns the paths."""
    from recon.calibration_io import export_rig_opencv, export_rig_ros
    from recon.rigcal import save_rig_calibration

    out.parent.mkdir(parents=True, exist_ok=True)
    save_rig_calibration(out, rig)
    written = [out] + export_rig_opencv(rig, out.with_suffix(""))
    try:
        written += export_rig_ros(rig, out.with_suffix(""))
    except ValueError as exc:
        print(f"note: no ROS camera_info written: {exc}")
    return written


def _image_size(args, images) -> tuple | None:
    """The image size (w, h) px from --image-size and/or the world-frame images; an error when they disagree."""
    from_images = None
    if images is not None:
        shapes = {img.shape[1::-1] for group in images.world.values() for _, img in group}
        shapes |= {img.shape[1::-1] for _, pair in images.stereo for img in pair.values()}
        from_images = next(iter(shapes)) if len(shapes) == 1 else None
    given = tuple(args.image_size) if args.image_size else None
    if given and from_images and given != from_images:
        raise ValueError(f"--image-size {given[0]} {given[1]} disagrees with the {from_images[0]}x{from_images[1]} images of "
                         f"{args.world_from} (--world-from)")
    return given or from_images


def _imported(args, images) -> tuple:
    """``(side, top, T_side_top or None, source)`` from whichever --import-* option was given."""
    from recon import calibration_io as io

    if args.import_opencv:
        st, src = io.load_opencv_stereo(args.import_opencv), args.import_opencv
    elif args.import_stereo_calib:
        size = _image_size(args, images)
        if size is None:
            raise ValueError("--import-stereo-calib: the files hold no image size: give --image-size W H (or world-frame images "
                             "with --world-from)")
        st = io.load_stereo_calib(*args.import_stereo_calib, size, args.camera1, args.t_unit_mm)
        src = " + ".join(args.import_stereo_calib)
    elif args.import_kalibr:
        cams = {"top": args.kalibr_cams[0], "side": args.kalibr_cams[1]}
        st, src = io.load_kalibr_camchain(args.import_kalibr, cams), args.import_kalibr
        size = _image_size(args, images)
        if size is not None and size != st["top"].image_size:
            raise ValueError(f"{src}: resolution {st['top'].width}x{st['top'].height} disagrees with --image-size / the "
                             f"--world-from images ({size[0]}x{size[1]})")
    else:
        side = io.load_ros_camera_info(args.import_ros[0], "side")
        top = io.load_ros_camera_info(args.import_ros[1], "top")
        return side, top, None, " + ".join(args.import_ros)
    return st["side"], st["top"], st["T_side_top"], src


def _world_from_file(args, world_from: Path, T_side_top, source: str) -> tuple:
    """``(T_top_world, T_side_top, T_side_world)`` from a world file, refusing a side pose that contradicts ``source``."""
    from recon.calibration_io import load_world_file

    w = load_world_file(world_from)
    T_side_top = _one_side_pose(world_from, source, T_side_top, w.get("T_side_top"))
    T_side_world = w.get("T_side_world")
    if w.get("T_top_world") is None:
        raise ValueError(f"{world_from}: missing T_top_world")
    if T_side_top is None and T_side_world is None:
        raise ValueError(f"{world_from}: the ROS files hold no pose: give T_side_top or T_side_world in the world file")
    return w["T_top_world"], T_side_top, T_side_world


def _import(args) -> int:
    from recon.calibration import calibrate_extrinsics
    from recon.calibration_io import rig_from_parts

    if args.world_from is None:
        raise ValueError("importing needs --world-from: a world file (T_top_world), a world-frame image or a calibration folder")
    world_from = Path(args.world_from)
    if not world_from.exists():
        raise ValueError(f"{world_from}: not found (--world-from)")
    images = _world_images(world_from)
    side, top, T_side_top, source = _imported(args, images)
    placement = _placement(args, _board_meta(world_from if world_from.is_dir() else None))
    T_side_world = None
    if images is None:
        T_top_world, T_side_top, T_side_world = _world_from_file(args, world_from, T_side_top, source)
    else:
        board = _board(args, _board_meta(world_from if world_from.is_dir() else None))
        T_side_top, world, _ = calibrate_extrinsics(side, top, images, board, _params(args), placement["world_origin_mm"], T_side_top)
        T_top_world = world.T_top_world
        print(f"world frame from {world.view.name}: RMS {world.rms_px:.3f} px")
    rig = rig_from_parts(side, top, T_top_world, T_side_top, T_side_world,
                         placement["base_point_world_mm"], placement["insertion_axis_world"])
    written = _save_rig(Path(args.out), rig)
    print("wrote " + ", ".join(str(p) for p in written))
    return 0


def _run(args) -> int:
    modes = [m for m, on in (("folder", args.folder), ("--render", args.render), ("--import-opencv", args.import_opencv),
                             ("--import-ros", args.import_ros), ("--import-stereo-calib", args.import_stereo_calib),
                             ("--import-kalibr", args.import_kalibr)) if on]
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
    """``--model``'s type: an OpenCV coefficient count or its name (recon.distortion.MODEL_NAMES)."""
    import argparse

    from recon.distortion import MODEL_NAMES, MODEL_SIZES

    n = MODEL_NAMES.get(text, int(text) if text.isdigit() else None)
    if n not in MODEL_SIZES:
        raise argparse.ArgumentTypeError(f"expected {', '.join(map(str, MODEL_SIZES))} or {', '.join(MODEL_NAMES)}, got {text!r}")
    return n


def _min_views(text: str) -> int:
    """``--min-views``'s type: an integer of at least 3 (OpenCV's intrinsic calibration needs 3 views of a planar board)."""
    import argparse

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
                   f"(e.g. {DEFAULT_CAL_SCENE.relative_to(DEFAULT_CAL_SCENE.parents[1])}) into --out DIR")
    p.add_argument("--import-opencv", metavar="STEREO_YAML", default=None, help="build the rig from an OpenCV stereo file (M1 D1 = top, M2 D2 = side, R T)")
    p.add_argument("--import-ros", metavar=("SIDE_YAML", "TOP_YAML"), nargs=2, default=None, help="build the rig from two ROS camera_info files")
    p.add_argument("--import-stereo-calib", metavar=("INTRINSICS", "EXTRINSICS"), nargs=2, default=None,
                   help="build the rig from OpenCV stereo_calib's intrinsics.yml (M1 D1 M2 D2) and extrinsics.yml (R T ...)")
    p.add_argument("--camera1", choices=("top", "side"), default="top",
                   help="with --import-stereo-calib: which camera was stereo_calib's camera 1 (default top)")
    p.add_argument("--t-unit-mm", type=float, default=1.0,
                   help="with --import-stereo-calib: mm per unit of T (stereo_calib writes T in its -s square-size units; default 1)")
    p.add_argument("--import-kalibr", metavar="CAMCHAIN", default=None, help="build the rig from a Kalibr camchain YAML (pinhole-radtan)")
    p.add_argument("--kalibr-cams", nargs=2, metavar=("TOP", "SIDE"), default=("cam0", "cam1"),
                   help="with --import-kalibr: the camchain keys of the top and side cameras (default cam0 cam1)")
    p.add_argument("--image-size", nargs=2, type=int, metavar=("W", "H"), default=None,
                   help="image size in px, for imports whose files hold none (stereo_calib); checked against the images")
    p.add_argument("--world-from", metavar="PATH", default=None,
                   help="for imports: a world file (YAML/JSON with T_top_world, and T_side_top or T_side_world for ROS), "
                   "a world-frame image of the top camera, or a calibration folder (world/ and stereo/)")
    p.add_argument("--out", default=None, help="rig calibration JSON to write (with --render: the folder to create)")
    p.add_argument("--board", default=None, help="inner corners COLSxROWS, e.g. 9x6 (default: the folder's board.json)")
    p.add_argument("--square-mm", type=float, default=None, help="square size in mm (default: the folder's board.json)")
    p.add_argument("--world-origin-mm", nargs=3, type=float, metavar=("X", "Y", "Z"), default=None,
                   help="world position of the world board's first inner corner (default 0 0 0: the board is the world frame)")
    p.add_argument("--base-point-mm", nargs=3, type=float, metavar=("X", "Y", "Z"), default=None,
                   help="where the robot leaves the actuation unit, world mm (default 0 0 0)")
    p.add_argument("--insertion-axis", nargs=3, type=float, metavar=("X", "Y", "Z"), default=None,
                   help="world direction of insertion (default 1 0 0)")
    p.add_argument("--model", type=_model, default=5, metavar="N",
                   help="OpenCV distortion model: 4, 5 (plumb_bob, default), 8 (rational_polynomial), 12 (thin_prism) or 14 (tilted), "
                   "by count or name")
    p.add_argument("--distortion", default="auto",
                   help="which of the model's terms are estimated: auto (all, insignificant groups held at 0), none, or e.g. "
                   "'k1 k2 p1 p2 k3', 'k1 k2'")
    p.add_argument("--no-joint-refinement", action="store_true", help="stop after the OpenCV stages (as the paper did)")
    p.add_argument("--min-views", type=_min_views, default=5, help="usable views each camera needs (at least 3; default 5)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_run)
