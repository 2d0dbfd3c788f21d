"""Datasets for learned methods: the twin's rendered sessions as sharded files anyone can read (docs/dataset.md).

``ctr-bench dataset --suite wide --n N --seed S --out DIR`` draws the suite's
scenes (:func:`rig.bench.widebench.write_suite`, the draw ``bench --suite`` makes),
renders each once through the render cache (:mod:`rig.bench.render_cache`, shared
with ``bench --suite``: a scene already benchmarked is not rendered again) and
writes one *sample* per frame pair: the images, per-pixel tube labels, the
projected centerlines, the 3D backbone and the calibration, all from the twin's
ground truth (``truth/NNNNNN.npz`` of the session, docs/session-format.md).

Samples are numbered in draw order (scene by scene, frame by frame) and stored
in shards ``shard-NNNNN/`` of at most ``shard_size`` samples; a shard is
finished when its ``index.jsonl`` is written, after all its files. A re-run
with the same parameters skips the finished shards; another dataset in ``DIR``
is refused unless ``overwrite`` (which removes only what a dataset writes).

One scene is one call of :func:`write_scene` on a :class:`SceneTask` (plain
data, picklable): scene in, sample files out, index rows back. The driver
(:func:`build_dataset`) takes the ``map`` to run them with, so that a
distributed map can run the scenes anywhere that sees ``DIR`` and the cache.
"""
from __future__ import annotations

import io
import json
import os
import re
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from rig.bench.render_cache import cached_session, code_digest
from rig.bench.widebench import frame_footprint_mm, thinnest_tube_px, tube_px_class, write_suite
from rig.progress import Progress
from rig.rundir import RunDirError, json_text, write_json_atomic, writing
from rig.session import Session
from twin.scene import load_scene

__all__ = ["FORMAT", "VERSION", "META", "INDEX", "SCENES", "LABEL_BACKGROUND", "TRUTH_ARRAYS", "SceneTask", "write_scene",
           "plan", "build_dataset", "shard_name", "sample_id"]

FORMAT = "ctr-bench-dataset"
VERSION = 1
#: The dataset's description (parameters, label values, shards) and its index, one JSON line per sample.
META = "dataset.json"
INDEX = "index.jsonl"
#: The suite's scene files (and their index.json), so the dataset says what it was rendered from.
SCENES = "scenes"
#: Label value of a pixel where no tube is seen; a tube's pixels are 1 + its index (outermost tube 0 -> 1).
LABEL_BACKGROUND = 0
#: Arrays of the twin's truth copied into a sample's NPZ (labels go to PNG; depth only when asked for).
TRUTH_ARRAYS = ("s_mm", "backbone_world_mm", "R_world_body", "outer_radius_mm", "outermost_tube", "tip_world_mm",
                "extension_mm", "rotation_deg")
_SHARD = re.compile(r"shard-\d{5}")
_SAMPLE_FILE = re.compile(r"\d{8}\.(npz|json|[A-Za-z0-9_-]+\.(png|labels\.png))")


def shard_name(shard: int) -> str:
    return f"shard-{shard:05d}"


def sample_id(sample: int) -> str:
    return f"{sample:08d}"


@dataclass(frozen=True)
class SceneTask:
    """One scene's share of a dataset: everything :func:`write_scene` needs, as plain data.

    Attributes
    ----------
    scene_file : str
        The scene TOML.
    classes : dict
        The suite's class labels of the scene (str -> str).
    first_sample : int
        Number of the scene's first frame pair in the dataset (draw order).
    out_dir, cache_dir : str
        The dataset directory; the render cache (sessions go to its ``sessions/``).
    shard_size : int
    scale : float
        Image scale of the render (:func:`rig.bench.render_cache.scaled_scene`).
    depth : bool
        Also store the depth maps.
    skip_shards : tuple of int
        Finished shards: the scene's samples in them are not written again.
    suite, seed : str, int
        Recorded in each index row.
    """

    scene_file: str
    classes: dict
    first_sample: int
    out_dir: str
    cache_dir: str
    shard_size: int
    scale: float = 1.0
    depth: bool = False
    skip_shards: tuple = ()
    suite: str = "wide"
    seed: int = 0


def _write_bytes(path: Path, data: bytes) -> None:
    """Write under a temporary name and rename (a reader never sees half a file); errors name ``path``."""
    tmp = path.with_name(f".{path.name}.tmp")
    with writing(path):
        tmp.write_bytes(data)
        os.replace(tmp, path)


def _link_or_copy(src: Path, dst: Path) -> None:
    """``dst`` as a hard link to ``src`` (a copy across file systems), replacing any earlier ``dst``."""
    tmp = dst.with_name(f".{dst.name}.tmp")
    with writing(dst):
        tmp.unlink(missing_ok=True)
        try:
            os.link(src, tmp)
        except OSError:
            shutil.copyfile(src, tmp)
        os.replace(tmp, dst)


def _png(image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise ValueError("could not encode a PNG image")
    return buf.tobytes()


def _npz(arrays: dict) -> bytes:
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return buf.getvalue()


def write_scene(task: SceneTask) -> list:
    """Write the samples of one scene (those outside ``task.skip_shards``); returns their index rows in frame order.

    The scene is rendered through the render cache (nothing is rendered when it
    is cached). Every file of a sample is written under a temporary name and
    renamed; rows come back only once all of the scene's files are on disk.
    """
    scene = load_scene(task.scene_file)
    session_dir = cached_session(scene, task.scale, Path(task.cache_dir) / "sessions",
                                 log=lambda line: print(line, file=sys.stderr))
    session = Session(session_dir)
    rig = session.rig
    classes = dict(task.classes, tube_px=tube_px_class(thinnest_tube_px(session)))
    robot = session.meta.get("robot")
    out = Path(task.out_dir)
    rows = []
    for k, fr in enumerate(session.frames):
        sample = task.first_sample + k
        shard = sample // task.shard_size
        if shard in task.skip_shards:
            continue
        sdir = out / shard_name(shard)
        with writing(sdir):
            sdir.mkdir(parents=True, exist_ok=True)
        sid = sample_id(sample)
        truth = session.truth(fr.index)
        if truth is None:
            raise ValueError(f"{session_dir}: frame {fr.index} has no ground truth (a dataset needs twin sessions)")
        rel = f"{shard_name(shard)}/{sid}"
        images, labels = {}, {}
        arrays = {key: np.asarray(truth[key]) for key in TRUTH_ARRAYS if key in truth}
        true_pose = {}
        for cam in session.cameras:
            images[cam] = f"{rel}.{cam}.png"
            labels[cam] = f"{rel}.{cam}.labels.png"
            _link_or_copy(session.frame_path(fr.index, cam), out / images[cam])
            _write_bytes(out / labels[cam], _png(np.asarray(truth[f"labels_{cam}"], np.uint8)))
            true_pose[cam] = np.asarray(truth[f"T_cam_world_{cam}"], float)
            arrays[f"centerline_px_{cam}"] = np.asarray(truth[f"centerline_px_{cam}"], float)
            arrays[f"K_{cam}"] = np.asarray(rig[cam].K, float)
            arrays[f"dist_{cam}"] = np.asarray(rig[cam].dist, float)
            arrays[f"T_cam_world_{cam}"] = np.asarray(rig[cam].T_cam_world, float)
            arrays[f"T_cam_world_true_{cam}"] = true_pose[cam]
            if task.depth:
                arrays[f"depth_mm_{cam}"] = np.asarray(truth[f"depth_mm_{cam}"], np.float32)
        _write_bytes(out / f"{rel}.npz", _npz(arrays))
        meta = {"format": f"{FORMAT}-sample", "version": VERSION, "units": "mm", "calibration": rig.to_dict(),
                "T_cam_world_true": true_pose, "robot": robot}
        _write_bytes(out / f"{rel}.json", (json_text(meta) + "\n").encode())
        rows.append({
            "sample": sample, "id": sid, "shard": shard_name(shard), "suite": task.suite, "seed": task.seed,
            "scene": scene.name, "frame": fr.index, "t_s": fr.t_s, "classes": classes,
            "cameras": list(session.cameras),
            "image_size": {cam: [rig[cam].width, rig[cam].height] for cam in session.cameras},
            "color": scene.color, "image_kind": scene.image_kind,
            "mask_polarity": scene.mask_polarity if scene.image_kind == "masks" else None, "n_tubes": session.n_tubes,
            "images": images, "labels": labels, "arrays": f"{rel}.npz", "meta": f"{rel}.json",
            "extension_mm": arrays.get("extension_mm"), "rotation_deg": arrays.get("rotation_deg"),
            "footprint_mm": frame_footprint_mm(rig, truth["backbone_world_mm"]),
        })
    return rows


# ----------------------------------------------------------------------------- the directory
def _params(suite, n, seed, shard_size, scale, max_pixels, depth) -> dict:
    """What a re-run must match to continue a dataset; ``twin_code`` keeps one dataset from mixing renders of two twins."""
    return {"suite": suite, "n": n, "seed": seed, "shard_size": shard_size, "scale": scale, "max_pixels": max_pixels,
            "depth": bool(depth), "twin_code": code_digest("twin")[:12]}


def _ours(out: Path) -> list:
    """What a dataset writes in ``out`` (removed by ``overwrite``; nothing a user put there)."""
    found = [out / n for n in (META, INDEX, f".{META}.tmp", f".{INDEX}.tmp") if (out / n).is_file()]
    if (out / SCENES).is_dir():
        found.append(out / SCENES)
    found += sorted(p for p in out.iterdir() if p.is_dir() and _SHARD.fullmatch(p.name)) if out.is_dir() else []
    return found


def _remove(out: Path, files: list) -> None:
    for p in files:
        with writing(p):
            if p.is_file():
                p.unlink()
            elif p.name == SCENES:
                for f in p.iterdir():
                    if f.is_file() and (f.suffix == ".toml" or f.name in ("index.json",) or f.name.endswith(".tmp")):
                        f.unlink()
                if not any(p.iterdir()):
                    p.rmdir()
            else:  # a shard
                for f in p.iterdir():
                    name = f.name[1:-4] if f.name.startswith(".") and f.name.endswith(".tmp") else f.name
                    if f.is_file() and (name == INDEX or _SAMPLE_FILE.fullmatch(name)):
                        f.unlink()
                if not any(p.iterdir()):
                    p.rmdir()


def _claim(out: Path, params: dict, overwrite: bool) -> str:
    """May this dataset be written into ``out``: ``"new"``, ``"resume"`` (the same dataset), or RunDirError."""
    if not out.exists() or (out.is_dir() and not any(out.iterdir())):
        return "new"
    if not out.is_dir():
        raise RunDirError(f"--out {out}: exists and is not a directory")
    meta_path = out / META
    earlier = None
    if meta_path.is_file():
        try:
            earlier = json.loads(meta_path.read_text())
        except (OSError, ValueError):
            earlier = None
    if isinstance(earlier, dict) and earlier.get("format") == FORMAT and not overwrite:
        old = earlier.get("params") or {}
        diff = sorted(k for k in params.keys() | old.keys() if old.get(k, "missing") != params.get(k, "missing"))
        if diff:
            k = diff[0]
            more = f" (and {len(diff) - 1} more)" if len(diff) > 1 else ""
            raise RunDirError(f"{out}: holds a dataset with {k} = {old.get(k, 'missing')!r}, not {params.get(k, 'missing')!r}"
                              f"{more}; --overwrite replaces it, or choose another --out")
        return "resume"
    if not overwrite:
        what = f"{meta_path} is not a {FORMAT!r} file" if meta_path.exists() else "no dataset.json"
        raise RunDirError(f"--out {out}: exists and is not empty ({what}; nothing is overwritten: --overwrite replaces "
                          "a dataset written there, or choose another)")
    _remove(out, _ours(out))
    return "new"


def _shard_finished(out: Path, shard: int, expected: int) -> bool:
    """A shard is finished when its index.jsonl lists all its samples (written last, after every file)."""
    path = out / shard_name(shard) / INDEX
    try:
        lines = path.read_bytes().splitlines()
    except OSError:
        return False
    return len(lines) == expected


def plan(scene_files: list, shard_size: int) -> list:
    """``[(first_sample, n_frames), ...]`` per scene, in draw order: where each scene's samples go."""
    out, first = [], 0
    for path in scene_files:
        n = len(load_scene(path).joints)
        out.append((first, n))
        first += n
    return out


def build_dataset(suite: str, n: int, seed: int, out, cache_dir, shard_size: int = 256, scale: float = 1.0,
                  max_pixels: int | None = None, depth: bool = False, overwrite: bool = False, quiet: bool = False,
                  map_fn=map, log=None) -> dict:
    """Write (or finish) a dataset of the suite's scenes in ``out``; returns its ``dataset.json``.

    Parameters
    ----------
    suite, n, seed
        What :func:`twin.scenegen.generate_suite` draws.
    out : path
        The dataset directory (docs/dataset.md).
    cache_dir : path
        The render cache; sessions go to its ``sessions/`` (as ``bench --suite``'s).
    shard_size : int
        At most this many samples per shard.
    scale : float
        Image scale of the renders (1: the drawn sensor sizes).
    max_pixels : int, optional
        Draw only sensors of at most this many pixels.
    depth : bool
        Also store the depth maps (``depth_mm_<camera>``).
    overwrite : bool
        ``out`` holds another dataset (or other files): remove what a dataset writes there and start again.
    map_fn : callable
        ``map_fn(write_scene, tasks)`` yields each task's rows, in any order as they finish (default: the builtin ``map``).
    log : callable, optional
        One line at a time (default: stderr).

    Raises
    ------
    rig.rundir.RunDirError
        ``out`` holds another dataset or files not written by one, and not ``overwrite``.
    """
    if shard_size < 1:
        raise ValueError(f"--shard-size must be >= 1, got {shard_size}")
    if not scale > 0:
        raise ValueError(f"--scale must be > 0, got {scale}")
    log = log or (lambda line: print(line, file=sys.stderr))
    out = Path(out)
    params = _params(suite, n, seed, shard_size, scale, max_pixels, depth)
    state = _claim(out, params, overwrite)
    with writing(out):
        out.mkdir(parents=True, exist_ok=True)
    head = {"format": FORMAT, "version": VERSION, "params": params, "complete": False,
            "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "units": {"length": "mm", "image": "px"},
            "labels": {"0": "background (no tube seen)", "1 + i": "tube i, outermost first (1 outer, 2 next in, ...)"}}
    if state == "resume":
        head["created"] = json.loads((out / META).read_text()).get("created", head["created"])
    write_json_atomic(out / META, head)
    scenes = write_suite(suite, n, seed, out / SCENES, max_pixels)
    layout = plan([p for p, _ in scenes], shard_size)
    total = sum(k for _, k in layout)
    n_shards = -(-total // shard_size)
    expected = {s: min(shard_size, total - s * shard_size) for s in range(n_shards)}
    finished = {s for s in range(n_shards) if state == "resume" and _shard_finished(out, s, expected[s])}
    tasks = []
    for (path, classes), (first, count) in zip(scenes, layout):
        shards = set(range(first // shard_size, (first + count - 1) // shard_size + 1))
        if shards - finished:
            tasks.append(SceneTask(str(path), dict(classes), first, str(out), str(cache_dir), shard_size, scale, depth,
                                   tuple(sorted(shards & finished)), suite, seed))
    log(f"dataset {out}: {len(scenes)} {suite!r} scenes (seed {seed}), {total} samples in {n_shards} shards of at most "
        f"{shard_size}" + (f"; resuming: {len(finished)} of {n_shards} shards finished (skipped), {len(tasks)} scene(s) to write"
                           if state == "resume" else ""))
    if seed == 1 and suite == "wide":
        log("note: seed 1 is the set `bench --suite wide` reports on by default; training on it leaks the benchmark")
    pending = {s: [] for s in range(n_shards) if s not in finished}
    progress = Progress(enabled=not quiet, units={"dataset": "scene"})
    try:
        for done, rows in enumerate(map_fn(write_scene, tasks), start=1):
            for row in rows:
                pending[int(row["sample"]) // shard_size].append(row)
            for s in [s for s, r in pending.items() if len(r) == expected[s]]:
                text = "".join(json_text(r, indent=None) + "\n" for r in sorted(pending.pop(s), key=lambda r: r["sample"]))
                _write_bytes(out / shard_name(s) / INDEX, text.encode())
                finished.add(s)
            progress("dataset", done, len(tasks))
    finally:
        progress.close()
    if pending:  # pragma: no cover - a map that lost a task's rows
        raise RuntimeError(f"{out}: shards {sorted(pending)} are missing samples after every scene was written")
    tmp = out / f".{INDEX}.tmp"
    with writing(out / INDEX):
        with open(tmp, "wb") as fh:
            for s in range(n_shards):
                fh.write((out / shard_name(s) / INDEX).read_bytes())
        os.replace(tmp, out / INDEX)
    head.update(complete=True, scenes=len(scenes), samples=total,
                shards=[{"name": shard_name(s), "samples": expected[s]} for s in range(n_shards)],
                finished=time.strftime("%Y-%m-%dT%H:%M:%S%z"))
    write_json_atomic(out / META, head)
    return head
