"""The generalization benchmark: every method on a fixed, seeded set of wide twin scenes.

``ctr-bench bench --suite wide --n N --seed S`` draws ``N`` scenes from the wide
distribution (:func:`twin.scenegen.generate_suite`: backdrops, rigs, robots,
light, masks-only inputs), renders each once into a cache keyed by the scene's
content, reconstructs every frame with every method through the same loop as
``ctr-bench reconstruct`` (:func:`rig.bench.reconstruct.reconstruct_session`, self-check
included), and scores each frame against the twin's ground truth (the run's records:
:func:`rig.scoring.score_frame`, over what every camera sees, as every command scores).

Errors are given in mm and in *pixel footprints*: a frame's footprint is the
mean, over both cameras and the true backbone's points, of the size of one pixel
at that point's depth (mm). A frame is

* ``ok``: reconstructed and passed the self-check;
* ``flagged``: reconstructed but the self-check called it ``suspect``;
* ``failed``: the method refused it (a one-line reason);
* ``silent_wrong``: ``ok`` although its max error exceeds
  :data:`SILENT_WRONG_PX` footprints: the count that must be 0;
* ``good``: reconstructed with a max error within :data:`SILENT_WRONG_PX`
  footprints (``good_flagged`` counts those the self-check flagged anyway).

Error statistics are over the reconstructed frames (ok and flagged), whatever
their status. Each scene is one task of a Dask sweep (:mod:`rig.bench.sweep`): its
frames' rows go to the sweep's journal (``sweep.jsonl``) as the scene finishes, so
an interrupted bench resumes; at the end every row goes to ``frames.csv``, the
aggregates to ``summary.json``, and pictures of each method's worst frames and of
every silent wrong one to ``pictures/`` (:func:`write_pictures`). A frame whose ground
truth cannot be used (its truth file missing, unreadable, of the wrong shape or
not finite) keeps its row, unscored, with a ``note`` that names the file; the
other frames are scored as usual.
"""
from __future__ import annotations

import csv
import json
import shutil
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from recon.methods import METHODS, Method, get_method, register_method
from recon.metrics import seen_by_all
from recon.selfcheck import SelfCheckParams
from rig.bench.compare import PEERS, method_status
from rig.bench.cores import pin_worker
from rig.bench.peers import prepare_peer
from rig.bench.reconstruct import reconstruct_session
from rig.bench.report import frame_overlay, load_run
from rig.bench.render_cache import cached_session
from rig.bench.sweep import Journal, Task, dask_client, require_all, run_sweep, task_digest
from rig.progress import Progress
from rig.rundir import write_json_atomic
from rig.session import Session, TruthError
from rig.tables import cell
from twin import scenegen
from twin.scene import load_scene

__all__ = ["SILENT_WRONG_PX", "CLASS_KEYS", "thinnest_tube_px", "tube_px_class", "write_suite", "frame_footprint_mm", "score_run", "aggregate",
           "run_suite", "scene_rows", "format_suite", "JSON_KEYS",
           "write_pictures"]

#: A frame reported ok whose max error exceeds this many pixel footprints is a silent wrong shape.
SILENT_WRONG_PX = 10.0

#: Scene classes the tables are broken down by (keys of the generator's ``classes``).
CLASS_KEYS = ("backdrop", "contrast", "camera_angle", "resolution", "base", "tubes", "input", "tube_px")

#: Bounds (px) of the ``tube_px`` classes: the thinnest tube's width in the images; both
#: methods refuse tubes under 4 px (docs/envelope.md, "Tube too thin to resolve").
TUBE_PX_CLASSES = (4.0, 6.0)

#: Keys of each method's entry in ``--json`` output (always present, None when undefined).
JSON_KEYS = ("frames", "ok", "flagged", "failed", "silent_wrong", "good_flagged", "mean_error_px_median",
             "tip_error_px_median", "ms_per_pair_median")

_CSV_FIELDS = ("scene", "method", "frame", "status", "reason", *CLASS_KEYS, "footprint_mm", "mean_error_mm",
               "max_error_mm", "tip_error_mm", "mean_error_px", "max_error_px", "tip_error_px", "voxel_mm",
               "mean_error_voxels", "ms",
               "silent_wrong", "selfcheck_reason", "note")


# ----------------------------------------------------------------------------- scenes
def write_suite(suite: str, n: int, seed: int, directory: Path, max_pixels: int | None = None) -> list:
    """Write the suite's scene TOMLs into ``directory``; returns ``[(path, classes), ...]`` in draw order.

    See :func:`twin.scenegen.write_suite`; ``max_pixels`` bounds the sensor sizes
    drawn (:func:`twin.scenegen.generate_suite`).
    """
    scenes = scenegen.generate_suite(suite, n, seed, max_pixels=max_pixels)
    paths = scenegen.write_suite(scenes, directory)
    return [(p, {k: str(v) for k, v in g.classes.items()}) for p, g in zip(paths, scenes)]


def frame_footprint_mm(rig, backbone_world_mm) -> float:
    """Mean pixel footprint (mm) over both cameras at the points of a backbone (world, mm)."""
    pts = np.asarray(backbone_world_mm, float).reshape(-1, 3)
    pts = pts[:: max(1, len(pts) // 50)]
    sizes = []
    for name in rig.names:
        cam = rig[name]
        z = cam.world_to_camera(pts)[:, 2]
        sizes.append(z[z > 0] / np.sqrt(cam.K[0, 0] * cam.K[1, 1]))
    sizes = np.concatenate(sizes)
    return float(np.mean(sizes)) if sizes.size else float("nan")


def thinnest_tube_px(session) -> float:
    """Width (px) of the thinnest tube where the robot is seen: the narrower view's median over frame 0's seen backbone."""
    tubes = (session.meta.get("robot") or {}).get("tubes") or []
    truth = None
    for fr in session.frames if tubes else ():  # frame 0's truth, or the first usable one when it is corrupt
        truth, _ = _truth_or_note(session, fr.index)
        if truth is not None:
            break
    if not tubes or truth is None:
        return float("nan")
    od_mm = min(float(t["outer_diameter_mm"]) for t in tubes)
    pts = np.asarray(truth["backbone_world_mm"], float)
    seen = seen_by_all(session.rig, pts)
    pts = pts[seen] if seen.any() else pts
    widths = []
    for name in session.rig.names:
        cam = session.rig[name]
        z = cam.world_to_camera(pts)[:, 2]
        widths.append(float(np.median(od_mm * np.sqrt(cam.K[0, 0] * cam.K[1, 1]) / z[z > 0])))
    return min(widths)


def tube_px_class(width_px: float) -> str:
    """``"<4"``, ``"4-6"`` or ``">=6"`` (px), from :data:`TUBE_PX_CLASSES`; ``"?"`` when unknown."""
    lo, hi = TUBE_PX_CLASSES
    if not np.isfinite(width_px):
        return "?"
    return f"<{lo:g}" if width_px < lo else (f"{lo:g}-{hi:g}" if width_px < hi else f">={hi:g}")


# ----------------------------------------------------------------------------- scoring
def _selfcheck_reason(rec: dict):
    sc = rec.get("selfcheck")
    return sc.get("reason") if isinstance(sc, dict) else None


def _truth_or_note(session, index: int) -> tuple:
    """``(truth, None)``, or ``(None, "not scored: <why>")`` for a frame whose ground truth is unusable or absent.

    A :class:`rig.session.TruthError` (the truth file missing in a ground-truth session,
    unreadable, of the wrong shape, not finite) concerns that frame only: its one-line
    message, which names the file, becomes the frame's note and the other frames are scored.
    """
    try:
        truth = session.truth(index)
    except TruthError as exc:
        return None, f"not scored: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
    if truth is None:
        where = getattr(session, "dir", None)
        return None, f"not scored: {where}: the session has no ground truth" if where else "not scored: no ground truth"
    return truth, None


def score_run(summary: dict, session, scene: str, method: str, classes: dict) -> list:
    """One row per frame of a reconstruct summary, with errors in pixel footprints.

    A frame whose ground truth cannot be used stays a row, unscored (its errors None),
    with ``note`` saying why and naming the truth file (:func:`_truth_or_note`);
    otherwise ``note`` is the reconstruct summary's own note for the frame, if any.
    """
    rows = []
    for rec in summary["per_frame"]:
        truth, note = _truth_or_note(session, rec["frame"])
        px = frame_footprint_mm(session.rig, truth["backbone_world_mm"]) if truth is not None else float("nan")
        row = {"scene": scene, "method": method, "frame": rec["frame"], "status": rec["status"],
               "reason": rec.get("reason"), **{k: classes.get(k, "") for k in CLASS_KEYS}, "footprint_mm": px,
               "ms": rec.get("ms"), "selfcheck_reason": _selfcheck_reason(rec), "note": note or rec.get("note")}
        for key in ("mean_error_mm", "max_error_mm", "tip_error_mm"):
            v = rec.get(key) if truth is not None else None  # no errors against a truth that is not there
            row[key] = v
            row[key.replace("_mm", "_px")] = v / px if v is not None and np.isfinite(px) else None
        voxel = rec.get("voxel_size_mm")
        row["voxel_mm"] = max(voxel) if voxel else None
        row["mean_error_voxels"] = row["mean_error_mm"] / row["voxel_mm"] if voxel and row["mean_error_mm"] is not None else None
        row["silent_wrong"] = bool(rec["status"] == "ok" and row["max_error_px"] is not None
                                   and row["max_error_px"] > SILENT_WRONG_PX)
        rows.append(row)
    return rows


def _stat(rows, key, fn):
    vals = np.array([r[key] for r in rows if r.get(key) is not None], float)
    vals = vals[np.isfinite(vals)]
    return float(fn(vals)) if vals.size else None


def aggregate(rows: list) -> dict:
    """Counts and error statistics of a set of frame rows (see the module doc)."""
    done = [r for r in rows if r["status"] in ("ok", "suspect")]
    good = [r for r in done if r.get("max_error_px") is not None and r["max_error_px"] <= SILENT_WRONG_PX]
    return {
        "frames": len(rows),
        "ok": sum(r["status"] == "ok" for r in rows),
        "flagged": sum(r["status"] == "suspect" for r in rows),
        "failed": sum(r["status"] == "failed" for r in rows),
        "silent_wrong": sum(bool(r["silent_wrong"]) for r in rows),
        "good": len(good),
        "good_flagged": sum(r["status"] == "suspect" for r in good),
        "reconstructed_fraction": len(done) / len(rows) if rows else None,
        "mean_error_px_median": _stat(done, "mean_error_px", np.median),
        "mean_error_px_p95": _stat(done, "mean_error_px", lambda v: np.percentile(v, 95)),
        "max_error_px_median": _stat(done, "max_error_px", np.median),
        "tip_error_px_median": _stat(done, "tip_error_px", np.median),
        "mean_error_mm_median": _stat(done, "mean_error_mm", np.median),
        "max_error_mm_max": _stat(done, "max_error_mm", np.max),
        "tip_error_mm_median": _stat(done, "tip_error_mm", np.median),
        "mean_error_voxels_median": _stat(done, "mean_error_voxels", np.median),
        "ms_per_pair_median": _stat(done, "ms", np.median),
    }


def _by_class(rows: list) -> dict:
    out = {}
    for key in CLASS_KEYS:
        values = sorted({r[key] for r in rows if r.get(key)})
        out[key] = {v: aggregate([r for r in rows if r[key] == v]) for v in values}
    return out


# ----------------------------------------------------------------------------- the run
def _register_peer(name: str) -> None:
    """Make a peer (rig/bench/peers.py) callable through reconstruct_session like any method."""
    if name in METHODS:
        return

    @dataclass(frozen=True)
    class PeerParams:
        """A peer runs with its own defaults."""

    register_method(Method(name, PeerParams, lambda rig, bg, params: prepare_peer(name, rig, bg), f"peer {name}"))


def scene_rows(path, classes: dict, methods: list, out_dir, cache_dir, selfcheck: bool) -> dict:
    """One sweep task: render a scene (cached), reconstruct it with every method, score every frame.

    Runs on a sweep worker (:mod:`rig.bench.sweep`), pinned to a core of its own on a
    LocalCluster, so each frame's time is one core's, as the one-scene bench measures it.

    Parameters
    ----------
    path : Path
        The scene TOML (written by :func:`write_suite`).
    classes : dict
        Its generator classes; ``tube_px`` is added from the rendered images.
    methods : list of str
        Available methods and peers (``method_status`` checked by the caller).
    out_dir, cache_dir : Path
        The bench's output (``runs/<method>/<scene>/``) and the render cache.
    selfcheck : bool
        Apply the self-check.

    Returns
    -------
    dict
        ``{"rows": [row per frame per method], "wall_s": {method: seconds}}``.
    """
    pin_worker()
    path, out_dir = Path(path), Path(out_dir)
    session_dir = cached_session(load_scene(path), 1.0, Path(cache_dir) / "sessions")
    session = Session(session_dir)  # read once: every method runs on it, and its rows are scored against it
    classes = dict(classes, tube_px=tube_px_class(thinnest_tube_px(session)))
    rows, wall = [], {}
    for name in methods:
        if name in PEERS:
            _register_peer(name)
        t0 = time.perf_counter()
        try:
            # The bench owns its runs/ tree: a second bench into the same --out replaces them.
            summary = reconstruct_session(session_dir, out_dir / "runs" / name / path.stem, name,
                                          params=_robot_params(name, session),
                                          selfcheck=SelfCheckParams() if selfcheck else None, existing="overwrite")
        except ValueError as exc:  # set-up refused for the whole scene: every frame failed
            summary = {"per_frame": [{"frame": f.index, "status": "failed", "reason": str(exc).splitlines()[0]}
                                     for f in session.frames]}
        rows += score_run(summary, session, path.stem, name, classes)
        wall[name] = time.perf_counter() - t0
    return {"rows": rows, "wall_s": wall}


def _available(methods: list) -> tuple:
    """``(runnable, skipped)``: the methods (and installed peers) to run, and ``{name: why}`` of the others."""
    runnable, skipped = [], {}
    for name in methods:
        ok, why = method_status(name)
        if ok:
            runnable.append(name)
        else:
            skipped[name] = why
    return runnable, skipped


def run_suite(suite: str, n: int, seed: int, methods: list, out_dir: Path, cache_dir: Path, selfcheck=True,
              quiet: bool = False, max_pixels: int | None = None, scheduler: str | None = None,
              workers: int | None = None) -> dict:
    """Render (cached), reconstruct and score every scene of the suite with every method, a sweep task a scene.

    Parameters
    ----------
    suite, n, seed
        What :func:`twin.scenegen.generate_suite` draws.
    methods : list of str
        Method names (``paper``, ``fast``) or peers (``icp-epipolar``); unavailable peers are skipped with the reason.
    out_dir : Path
        ``frames.csv``, ``summary.json``, the sweep's journal ``sweep.jsonl`` (a re-run into the
        same directory resumes from it) and per-run reconstruct outputs (``runs/<method>/<scene>/``).
    cache_dir : Path
        Scene TOMLs and rendered sessions, reused across runs.
    selfcheck : bool
        Apply the self-check (False measures the methods as they would be reported without it).
    max_pixels : int, optional
        Draw only sensors of at most this many pixels (a quick set; the other ranges unchanged).
    scheduler : str, optional
        ``tcp://host:port`` of a Dask scheduler; None: an in-process LocalCluster (:func:`rig.bench.sweep.dask_client`).
    workers : int, optional
        LocalCluster workers (default one a core).

    Returns
    -------
    dict
        ``{"suite", "n", "seed", "methods": {name: aggregate | {"skipped": why}}, "classes": {name: by class}}``.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    tag = f"-max{max_pixels}" if max_pixels else ""
    scenes = write_suite(suite, n, seed, cache_dir / f"{suite}-seed{seed}{tag}-scenes", max_pixels)
    runnable, skipped = _available(methods)
    tasks = [Task(path.stem, scene_rows, (str(path), classes, runnable, str(out_dir), str(cache_dir), bool(selfcheck)),
                  task_digest("wide-scene", path.read_text(), classes, runnable, bool(selfcheck)))
             for path, classes in scenes]
    progress = Progress(enabled=not quiet, units={"scenes": "scene"})
    journal = Journal(out_dir / "sweep.jsonl")
    with dask_client(scheduler, workers) as client:
        done = require_all(tasks, run_sweep(client, tasks, journal, progress, stage="scenes"), journal, "scene")
    progress.close()
    rows = [r for name in runnable for d in done for r in d["rows"] if r["method"] == name]
    _write_rows(out_dir / "frames.csv", rows)
    results = {name: {"skipped": why} for name, why in skipped.items()}
    for name in runnable:
        results[name] = aggregate([r for r in rows if r["method"] == name])
        results[name]["wall_s"] = sum(d["wall_s"][name] for d in done)
    results = {name: results[name] for name in methods}
    report = {"suite": suite, "n": n, "seed": seed, "max_pixels": max_pixels, "selfcheck": bool(selfcheck), "methods": results,
              "classes": {m: _by_class([r for r in rows if r["method"] == m]) for m in runnable},
              "worst": _worst(rows)}
    report["pictures"] = write_pictures(out_dir, report["worst"] + [r for r in rows if r["silent_wrong"]])
    write_json_atomic(out_dir / "summary.json", report)
    return report


def write_pictures(out_dir: Path, rows: list) -> list:
    """PNGs of the frames ``rows`` names (``method``, ``scene``, ``frame``), each from its run under ``out_dir / "runs"``:
    ``out_dir/pictures/<method>-<scene>-f<frame>.png``, each camera's image with the backbone and the truth
    reprojected (:func:`rig.bench.report.frame_overlay`). Returns their paths relative to ``out_dir``, each frame once;
    a frame whose run cannot be read is left out with a one-line note on stderr.

    The bench draws each method's worst frames and every silent wrong one: the frames to look at.
    """
    shutil.rmtree(out_dir / "pictures", ignore_errors=True)  # the bench's own: a re-run replaces them, as its runs
    names, seen = [], set()
    for r in rows:
        name = f"{r['method']}-{r['scene']}-f{int(r['frame'])}.png"
        if name in seen:  # a worst frame that is also silent, or one whose run could not be read: once
            continue
        seen.add(name)
        try:
            run = load_run(out_dir / "runs" / r["method"] / r["scene"])
            rec = next((x for x in run.records if x["frame"] == int(r["frame"])), None)
            drawn = rec is not None and frame_overlay(run, rec, out_dir / "pictures" / name) is not None
        except (OSError, ValueError) as exc:  # a run that cannot be read costs its picture, not the bench's summary
            print(f"{name}: not drawn ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})", file=sys.stderr)
            continue
        if drawn:
            names.append(name)
    return [f"pictures/{n}" for n in names]


def _write_rows(path: Path, rows: list) -> None:
    """``frames.csv``: a row per frame per method, methods in the order asked, scenes in suite order."""
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=_CSV_FIELDS, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)


def _robot_params(method: str, session: Session):
    """The method's defaults with the session's tube radii, as ``ctr-bench reconstruct`` runs it.

    The tube radii describe the robot, not the method; with the defaults
    (0.8/0.5 mm) the paper method sized its erosions for tubes up to twice the
    drawn robot's.
    """
    params = get_method(method).params_type()
    radii = session.robot_tube_radii_mm
    if radii is not None and hasattr(params, "outer_tube_radius_mm") and hasattr(params, "inner_tube_radius_mm"):
        params = replace(params, outer_tube_radius_mm=radii[0], inner_tube_radius_mm=radii[1])
    return params


def _worst(rows: list, k: int = 5) -> list:
    """The reconstructed frames with the largest max error in footprints, per method."""
    out = []
    for m in sorted({r["method"] for r in rows}):
        done = [r for r in rows if r["method"] == m and r.get("max_error_px") is not None]
        done.sort(key=lambda r: -r["max_error_px"])
        out += [{key: r[key] for key in ("method", "scene", "frame", "status", "max_error_px", "max_error_mm",
                                         "mean_error_px", "selfcheck_reason")} for r in done[:k]]
    return out


# ----------------------------------------------------------------------------- tables


_HEAD = (f"{'':>22}  {'frames':>6}  {'ok':>4}  {'flag':>4}  {'fail':>4}  {'silent':>6}  {'goodflg':>7}  "
         f"{'mean px':>7}  {'p95 px':>7}  {'tip px':>7}  {'mean mm':>7}  {'tip mm':>7}  {'ms':>7}")


def _line(label: str, a: dict) -> str:
    return (f"{label[:22]:>22}  {a['frames']:>6}  {a['ok']:>4}  {a['flagged']:>4}  {a['failed']:>4}  {a['silent_wrong']:>6}  "
            f"{a['good_flagged']:>7}  {cell(a['mean_error_px_median'], precision=2)}  {cell(a['mean_error_px_p95'], precision=2)}  "
            f"{cell(a['tip_error_px_median'], precision=2)}  {cell(a['mean_error_mm_median'], precision=3)}  {cell(a['tip_error_mm_median'], precision=3)}  "
            f"{cell(a['ms_per_pair_median'], precision=1)}")


def format_suite(report: dict) -> str:
    """The printed tables: each method overall, then by scene class."""
    lines = [f"suite {report['suite']}: {report['n']} scenes, seed {report['seed']}"
             + ("" if report.get("selfcheck", True) else " (self-check off)")
             + f"; errors over reconstructed frames, px = pixel footprints; silent = ok with max error > {SILENT_WRONG_PX:g} px"]
    for name, a in report["methods"].items():
        lines.append("")
        if "skipped" in a:
            lines.append(f"{name}: skipped: {a['skipped']}")
            continue
        lines.append(f"method {name}")
        lines.append(_HEAD)
        lines.append(_line("all", a))
        for key, values in report["classes"][name].items():
            for value, agg in values.items():
                lines.append(_line(f"{key}={value}", agg))
    return "\n".join(lines)


def json_summary(report: dict) -> dict:
    """``--json``: per method the keys of :data:`JSON_KEYS` (and the rest of its aggregate), plus its classes."""
    out = {}
    for name, a in report["methods"].items():
        if "skipped" in a:
            out[name] = a
            continue
        out[name] = {**{k: a.get(k) for k in JSON_KEYS}, **a, "classes": report["classes"][name]}
    return out


def print_worst(report: dict, file=sys.stdout) -> None:
    """The worst frames of each method, for looking at their overlays."""
    print("\nworst frames (max error in footprints):", file=file)
    for w in report["worst"]:
        print(f"  {w['method']:>6} {w['scene']} frame {w['frame']}: {w['status']}, max {cell(w['max_error_px'], precision=1)} px "
              f"({cell(w['max_error_mm'], precision=2)} mm), mean {cell(w['mean_error_px'], precision=2)} px"
              + (f"; self-check: {w['selfcheck_reason']}" if w.get("selfcheck_reason") else ""), file=file)


def dump(report: dict) -> str:
    return json.dumps(json_summary(report), indent=2, default=float)
