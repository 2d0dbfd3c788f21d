"""A rig calibration from any source a lab has: ctr-bench's rig.json, OpenCV, stereo_calib, Kalibr, ROS.

Shared by ``ctr-bench calibrate --import-*`` (which writes the rig file and its exports)
and ``ctr-bench import`` (which records it in a session): the options have one meaning
in both. Formats: :mod:`recon.calibration_io`; the world frame comes from
``--world-from`` (a world file, a world-frame image or a calibration folder), or from
an OpenCV stereo file's own ``T_top_world``.
"""
from __future__ import annotations

import json
from pathlib import Path

from recon import calibration_io as io
from recon.calibration import (
    IMAGE_SUFFIXES,
    BoardSpec,
    CalibrationImages,
    CalibrationParams,
    calibrate_extrinsics,
    load_calibration_folder,
    pose_difference,
    read_image,
)
from recon.calibration_io import load_world_file, rig_from_parts

#: The ``--import-*`` options, one per format (argparse dests).
SOURCES = (("--import-opencv", "import_opencv"), ("--import-ros", "import_ros"), ("--import-stereo-calib", "import_stereo_calib"),
           ("--import-kalibr", "import_kalibr"))


def given_sources(args) -> list:
    """The ``--import-*`` options given on the command line."""
    return [opt for opt, dest in SOURCES if getattr(args, dest, None)]


def _vec3(values, option: str):
    if values is None:
        return None
    return [float(v) for v in values]


def board_meta(folder: Path | None) -> dict:
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


def board_spec(args, meta: dict, required: bool = True):
    text = args.board or (f"{meta['cols']}x{meta['rows']}" if "cols" in meta and "rows" in meta else None)
    square = args.square_mm if args.square_mm is not None else meta.get("square_mm")
    if text is None or square is None:
        if not required:
            return None
        raise ValueError("give the board: --board COLSxROWS (inner corners, e.g. 9x6) and --square-mm (or a board.json in the folder)")
    return BoardSpec.parse(text, float(square))


def placement_of(args, meta: dict) -> dict:
    return {
        "world_origin_mm": _vec3(args.world_origin_mm, "--world-origin-mm") or meta.get("world_origin_mm", [0.0, 0.0, 0.0]),
        "base_point_world_mm": _vec3(args.base_point_mm, "--base-point-mm") or meta.get("base_point_world_mm", [0.0, 0.0, 0.0]),
        "insertion_axis_world": _vec3(args.insertion_axis, "--insertion-axis") or meta.get("insertion_axis_world", [1.0, 0.0, 0.0]),
    }


def _world_images(path: Path):
    """World-frame images from --world-from: a calibration folder or one image (None for a world file)."""
    if path.is_dir():
        return load_calibration_folder(path, extrinsics_only=True)
    if path.suffix.lower() in IMAGE_SUFFIXES:
        return CalibrationImages(views={}, stereo=[], world={"top": [(path.name, read_image(path))]}, source=str(path))
    return None


def _same_pose(world_from: Path, source: str, key: str, T_world_file, T_source) -> None:
    """Refuse a world file whose ``key`` differs from ``source``'s by more than 0.01 mm or 0.001 deg.

    A second, different pose would otherwise silently replace the calibrated one (issue 14: 182 mm).
    """
    d_mm, d_deg = pose_difference(T_world_file, T_source)
    if d_mm > 0.01 or d_deg > 0.001:
        raise ValueError(f"{world_from}: {key} differs from the one of {source} by {d_mm:.3f} mm, {d_deg:.4f} deg "
                         f"(--world-from): give {key} in one file only")


def _one_side_pose(world_from: Path, source: str, T_stereo, T_world_file):
    """The side pose from the imported files or the world file; both, only when they agree."""
    if T_world_file is not None and T_stereo is not None:
        _same_pose(world_from, source, "T_side_top", T_world_file, T_stereo)
    return T_stereo if T_stereo is not None else T_world_file


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


def _cameras(args, images) -> tuple:
    """``(side, top, T_side_top or None, source, T_top_world or None)`` from whichever --import-* option was given."""
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
        return side, top, None, " + ".join(args.import_ros), None
    return st["side"], st["top"], st["T_side_top"], src, st["T_top_world"]


def _world_from_file(world_from: Path, T_side_top, source: str, T_top_world=None) -> tuple:
    """``(T_top_world, T_side_top, T_side_world)`` from a world file, refusing poses that contradict ``source``'s
    (``T_side_top``, and ``T_top_world`` when the source holds one)."""
    w = load_world_file(world_from)
    T_side_top = _one_side_pose(world_from, source, T_side_top, w.get("T_side_top"))
    if T_top_world is not None and w.get("T_top_world") is not None:
        _same_pose(world_from, source, "T_top_world", w["T_top_world"], T_top_world)
    T_side_world = w.get("T_side_world")
    if w.get("T_top_world") is None:
        raise ValueError(f"{world_from}: missing T_top_world")
    if T_side_top is None and T_side_world is None:
        raise ValueError(f"{world_from}: the ROS files hold no pose: give T_side_top or T_side_world in the world file")
    return w["T_top_world"], T_side_top, T_side_world


def rig_from_sources(args, params=None):
    """The rig calibration of an ``--import-*`` option and ``--world-from`` (or the stereo file's ``T_top_world``).

    ``params`` (:class:`recon.calibration.CalibrationParams`) govern the board detection of
    world-frame images. Messages name the options and files at fault.
    """
    world_from = Path(args.world_from) if args.world_from else None
    if world_from is not None and not world_from.exists():
        raise ValueError(f"{world_from}: not found (--world-from)")
    images = _world_images(world_from) if world_from else None
    side, top, T_side_top, source, T_top_world = _cameras(args, images)
    meta = board_meta(world_from if world_from and world_from.is_dir() else None)
    placement = placement_of(args, meta)
    T_side_world = None
    if world_from is None:
        if T_top_world is None:
            raise ValueError(f"{source} holds no world frame: give --world-from (a world file with T_top_world, a world-frame "
                             "image or a calibration folder)")
    elif images is None:
        T_top_world, T_side_top, T_side_world = _world_from_file(world_from, T_side_top, source, T_top_world)
    else:
        board = board_spec(args, meta)
        T_side_top, world, _ = calibrate_extrinsics(side, top, images, board, params or CalibrationParams(),
                                                    placement["world_origin_mm"], T_side_top)
        T_top_world = world.T_top_world
        print(f"world frame from {world.view.name}: RMS {world.rms_px:.3f} px")
    return rig_from_parts(side, top, T_top_world, T_side_top, T_side_world,
                          placement["base_point_world_mm"], placement["insertion_axis_world"])


def add_source_options(p, board: bool = True) -> None:
    """The ``--import-*`` options, ``--world-from`` and (with ``board``) the board and placement options."""
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
                   "a world-frame image of the top camera, or a calibration folder (world/ and stereo/); not needed when "
                   "an --import-opencv file holds T_top_world")
    if board:
        add_board_options(p)


def add_board_options(p) -> None:
    """The checkerboard and robot placement options."""
    p.add_argument("--board", default=None, help="inner corners COLSxROWS, e.g. 9x6 (default: the folder's board.json)")
    p.add_argument("--square-mm", type=float, default=None, help="square size in mm (default: the folder's board.json)")
    p.add_argument("--world-origin-mm", nargs=3, type=float, metavar=("X", "Y", "Z"), default=None,
                   help="world position of the world board's first inner corner (default 0 0 0: the board is the world frame)")
    p.add_argument("--base-point-mm", nargs=3, type=float, metavar=("X", "Y", "Z"), default=None,
                   help="where the robot leaves the actuation unit, world mm (default 0 0 0)")
    p.add_argument("--insertion-axis", nargs=3, type=float, metavar=("X", "Y", "Z"), default=None,
                   help="world direction of insertion (default 1 0 0)")
