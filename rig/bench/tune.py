"""Tune a method's parameters on rendered twin scenes (``ctr-bench tune``).

The paper picked its threshold (0.25) and structuring elements "empirically".
Here a set of twin scenes with varied lighting, jitter, noise, tubes and rigs
is rendered once (cached on disk, keyed by the scene file's contents), every
session is held in memory, and a global optimizer (SciPy's differential
evolution, with integer knobs) searches the method's knobs for the lowest
objective:

* the mean, over every frame of every scene, of the frame's mean backbone
  error (mm; :func:`rig.scoring.score_frame`, over what both cameras see, as
  ``reconstruct`` and ``bench`` score), a failed frame counting as
  ``failure_penalty_mm``;
* plus a time tie-break: ``tie_mm * ms / ms_default``, where ``ms`` is the
  median time per frame pair and ``ms_default`` that of the default
  parameters. Twice the default's time costs as much as ``tie_mm`` (0.002 mm
  by default) of error: far below the error differences that matter, so time
  only decides between candidates whose errors are equal within that.

The scenes' tube radii are set from each session's robot (they describe the
robot, they are not tuned). A *knob* is one searched parameter, named by its
dotted path in the method's parameter dataclass. After the search every knob
is swept alone across its range with the others at their tuned values: the
sensitivity curves (error against each parameter) say how much each matters
and how flat the optimum is.
"""
from __future__ import annotations

import contextlib
import dataclasses
import functools
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.optimize import differential_evolution

from recon.errors import FrameError
from recon.methods import get_method
from recon.params import params_to_dict
from rig.bench.cores import pin_worker
from rig.bench.reconstruct import load_background_frames, mm_per_pixel
from rig.bench.render_cache import cached_session
from rig.bench.sweep import Journal, Task, dask_client, require_all, run_sweep, task_digest
from rig.scoring import score_frame
from rig.session import Session
from twin.scene import load_scene

__all__ = [
    "Knob",
    "KNOBS",
    "TuneSession",
    "Evaluation",
    "Evaluator",
    "evaluate",
    "objective_value",
    "tune",
    "sensitivity",
    "load_tune_sessions",
    "tune_session_dirs",
    "load_tune_session",
    "session_records",
    "with_knobs",
    "knob_values",
]


@dataclass(frozen=True)
class Knob:
    """One searched parameter.

    Attributes
    ----------
    path : str
        Dotted path in the method's parameter dataclass, e.g.
        ``"silhouette.threshold"``.
    low, high : float
        Search range (inclusive), in the parameter's unit.
    integer : bool
        Search integers only.
    unit : str
        Unit for plots and tables ("" for dimensionless).
    step : float
        Values are rounded to a multiple of this (0: not rounded): finer
        differences do not matter, and the parameter file stays readable.
    """

    path: str
    low: float
    high: float
    integer: bool = False
    unit: str = ""
    step: float = 0.0

    @property
    def label(self) -> str:
        return f"{self.path} ({self.unit})" if self.unit else self.path


#: The knobs searched per method. Ranges are wide on purpose: the sensitivity
#: sweep shows where each parameter stops working.
KNOBS = {
    "paper": (
        Knob("silhouette.threshold", 0.05, 0.60, unit="normalized |difference|", step=0.005),
        Knob("background.k", 1, 8, integer=True, unit="eigenbackgrounds"),
        Knob("outer_disk_position", 0.1, 0.9, unit="0 = inner tube, 1 = outer tube half-width", step=0.01),
        Knob("inner_disk_margin_px", 0.0, 2.5, unit="px", step=0.05),
        Knob("carving.resolution", 50, 200, integer=True, unit="voxels per axis"),
    ),
    "fast": (
        Knob("background.k", 1, 8, integer=True, unit="eigenbackgrounds"),
        Knob("coarse_threshold_sigma", 3.0, 12.0, unit="noise sigma", step=0.1),
        Knob("view.edge_threshold_sigma", 2.0, 10.0, unit="noise sigma", step=0.1),
        Knob("view.edge_min_dn", 4.0, 30.0, unit="DN", step=0.5),
        Knob("view.min_width_fraction", 0.1, 0.9, unit="of the inner tube's width", step=0.01),
        Knob("view.outlier_sigma", 2.0, 8.0, unit="MAD", step=0.1),
        Knob("view.spline_knot_px", 15.0, 80.0, unit="px", step=1.0),
        Knob("knot_mm", 2.0, 10.0, unit="mm", step=0.1),
    ),
}


# ----------------------------------------------------------------------------- parameters
def _get(params, path: str):
    obj = params
    for part in path.split("."):
        obj = getattr(obj, part)
    return obj


def _set(params, path: str, value):
    head, _, rest = path.partition(".")
    if not rest:
        return replace(params, **{head: value})
    return replace(params, **{head: _set(getattr(params, head), rest, value)})


def knob_values(params, knobs) -> np.ndarray:
    """The knobs' current values in ``params`` as a float vector."""
    return np.array([float(_get(params, k.path)) for k in knobs])


def with_knobs(params, knobs, x):
    """``params`` with each knob set from the vector ``x`` (clipped to range, rounded to the knob's step)."""
    for k, v in zip(knobs, x):
        v = float(np.clip(v, k.low, k.high))
        if k.integer:
            v = int(round(v))
        elif k.step > 0:
            # round() of the quotient, then trim float noise: 0.25 stays 0.25 in the file.
            v = float(np.clip(round(round(v / k.step) * k.step, 10), k.low, k.high))
        params = _set(params, k.path, v)
    return params


# ----------------------------------------------------------------------------- sessions
@dataclass(frozen=True, eq=False)
class TuneSession:
    """A rendered scene held in memory for repeated reconstruction.

    Attributes
    ----------
    name : str
    rig : recon.rigcal.RigCalibration
    backgrounds : dict
        Camera -> (N, H, W) uint8 background stack.
    frames : list of dict
        Camera -> (H, W) uint8 image, per robot frame, in order.
    truths : list of (n, 3) arrays
        True backbone per frame (world, mm).
    tube_radii_mm : (float, float)
        The robot's outer and inner tube radii (mm).
    mm_per_px : float
        Mean pixel footprint at the robot base (mm).
    """

    name: str
    rig: object
    backgrounds: dict
    frames: list
    truths: list
    tube_radii_mm: tuple
    mm_per_px: float


def tune_session_dirs(scene_paths, cache_dir, progress=None, log=print) -> list:
    """Render (or reuse from ``cache_dir``) each scene; the rendered session directories, checked for tuning.

    A scene is rendered again only when its file's contents changed: the cache
    directory's name holds a hash of them (:mod:`rig.bench.render_cache`). Nothing is
    held in memory: a sweep's workers load the sessions they evaluate (:func:`load_tune_session`).

    Raises
    ------
    ValueError
        A session without the robot's two tube radii, or a frame without ground truth.
    """
    out = []
    for path in map(Path, scene_paths):
        target = cached_session(load_scene(path), 1.0, Path(cache_dir), quiet=progress is None, log=log)
        session = Session(target)
        if session.robot_tube_radii_mm is None:
            raise ValueError(f"{target}/session.json: no robot with two tubes (tuning needs the tube radii)")
        for fr in session.frames:
            if session.truth(fr.index) is None:
                raise ValueError(f"{target}: frame {fr.index} has no ground truth (tuning needs twin sessions)")
        out.append(target)
    return out


@functools.lru_cache(maxsize=4)
def load_tune_session(session_dir) -> TuneSession:
    """A rendered session in memory (a few at a time per process: a worker holds what it evaluates)."""
    session = Session(Path(session_dir))
    frames = [session.frame_images(fr.index) for fr in session.frames]
    truths = [session.truth(fr.index)["backbone_world_mm"] for fr in session.frames]
    return TuneSession(session.meta.get("scene_name") or Path(session_dir).name, session.rig,
                       load_background_frames(session), frames, truths, session.robot_tube_radii_mm, mm_per_pixel(session))


def load_tune_sessions(scene_paths, cache_dir, progress=None, log=print) -> list:
    """Render (or reuse) each scene and load it into memory: :func:`tune_session_dirs`, then :func:`load_tune_session`."""
    return [load_tune_session(str(d)) for d in tune_session_dirs(scene_paths, cache_dir, progress, log)]


# ----------------------------------------------------------------------------- evaluation
@dataclass(frozen=True)
class Evaluation:
    """One parameter set scored over the tuning sessions.

    Attributes
    ----------
    mean_error_mm : float
        Mean over the frames that succeeded of their mean backbone error (mm); NaN if none did.
    penalized_error_mm : float
        Mean over all frames, a failed frame counting as the failure penalty (mm).
    tip_error_mm : float
        Median tip error of the frames that succeeded (mm).
    max_error_mm : float
        Largest backbone error of any frame that succeeded (mm).
    failures : int
    frames : int
    ms_median : float
        Median time per frame pair (ms).
    per_session : dict
        Session name -> dict with the same figures for that session.
    """

    mean_error_mm: float
    penalized_error_mm: float
    tip_error_mm: float
    max_error_mm: float
    failures: int
    frames: int
    ms_median: float
    per_session: dict


def _figures(records, penalty_mm: float) -> dict:
    ok = [r for r in records if r is not None]
    mean = [r["mean_error_mm"] for r in ok]
    return {
        "mean_error_mm": float(np.mean(mean)) if ok else float("nan"),
        "penalized_error_mm": float(np.mean([r["mean_error_mm"] if r else penalty_mm for r in records])),
        "tip_error_mm": float(np.median([r["tip_error_mm"] for r in ok])) if ok else float("nan"),
        "max_error_mm": float(np.max([r["max_error_mm"] for r in ok])) if ok else float("nan"),
        "failures": len(records) - len(ok),
        "frames": len(records),
    }


#: The errors (mm) the evaluation aggregates: a frame lacking one is a failure.
_FIGURES = ("mean_error_mm", "max_error_mm", "tip_error_mm")


def _frame_errors(result, truth, rig) -> dict | None:
    """A frame's errors (mm, :func:`rig.scoring.score_frame`); None (a failure) when it cannot be scored.

    A backbone nothing of which every camera sees, or one with unknown (non-finite)
    errors, is no shape the tuner may prefer: it costs the failure penalty.
    """
    try:
        errs = score_frame(result, truth, rig)
    except ValueError:
        return None
    return errs if all(errs[k] is not None for k in _FIGURES) else None


def session_records(method: str, params, s: TuneSession) -> tuple:
    """``(records, ms)``: each frame's errors (None: failed) and each reconstructed frame's time (ms) on session ``s``.

    The session is prepared afresh (methods keep state between frames) with its robot's
    tube radii; frames run in order. A frame that raises :class:`FrameError`, one that
    cannot be scored (:func:`_frame_errors`), or a session whose preparation fails, counts
    as failed. Any other exception is a bug and propagates.
    """
    p = replace(params, outer_tube_radius_mm=s.tube_radii_mm[0], inner_tube_radius_mm=s.tube_radii_mm[1])
    try:
        rec = get_method(method).prepare(s.rig, s.backgrounds, p)
    except ValueError:  # e.g. k larger than the background frames allow
        return [None] * len(s.frames), []
    records, ms = [], []
    for images, truth in zip(s.frames, s.truths):
        t0 = time.perf_counter()
        try:
            r = rec(images)
        except FrameError:
            records.append(None)
            continue
        ms.append(1e3 * (time.perf_counter() - t0))
        records.append(_frame_errors(r, truth, s.rig))
    return records, ms


def _evaluation(parts: list, penalty_mm: float) -> Evaluation:
    """The :class:`Evaluation` of ``(session name, records, ms)`` parts."""
    records = [r for _, recs, _ in parts for r in recs]
    ms = [t for _, _, times in parts for t in times]
    return Evaluation(**_figures(records, penalty_mm), ms_median=float(np.median(ms)) if ms else float("nan"),
                      per_session={name: _figures(recs, penalty_mm) for name, recs, _ in parts})


def evaluate(method: str, params, sessions, failure_penalty_mm: float = 5.0) -> Evaluation:
    """Reconstruct every frame of ``sessions`` (in memory) with ``params`` and score it (:func:`session_records`)."""
    return _evaluation([(s.name, *session_records(method, params, s)) for s in sessions], failure_penalty_mm)


def evaluate_session_dir(method: str, params, session_dir: str) -> dict:
    """A sweep task: :func:`session_records` of the session in ``session_dir``, loaded on the worker.

    Returns ``{"name", "records", "ms"}``; the worker is pinned to a core of its own on a LocalCluster.
    """
    pin_worker()
    s = load_tune_session(str(session_dir))
    records, ms = session_records(method, params, s)
    return {"name": s.name, "records": records, "ms": ms}


def objective_value(ev: Evaluation, ms_default: float, tie_mm: float) -> float:
    """The tuner's objective (mm): penalized mean error plus the time tie-break."""
    ms = ev.ms_median if np.isfinite(ev.ms_median) else 10.0 * ms_default
    return ev.penalized_error_mm + tie_mm * ms / ms_default


# ----------------------------------------------------------------------------- search
@dataclass
class TuneResult:
    """What :func:`tune` found.

    Attributes
    ----------
    method : str
    knobs : tuple of Knob
    default_params, tuned_params : dataclass
    default, tuned : Evaluation
    history : list of dict
        Every evaluation of the search: knob values, objective and figures.
    sensitivity : list of dict
        Every evaluation of the one-knob-at-a-time sweeps.
    seconds : float
    """

    method: str
    knobs: tuple
    default_params: object
    tuned_params: object
    default: Evaluation
    tuned: Evaluation
    history: list
    sensitivity: list = dataclasses.field(default_factory=list)
    seconds: float = 0.0


def _row(knobs, x, ev: Evaluation, objective: float, **extra) -> dict:
    row = dict(extra)
    row.update({k.path: (int(round(v)) if k.integer else float(v)) for k, v in zip(knobs, x)})
    row.update(objective=objective, penalized_error_mm=ev.penalized_error_mm, mean_error_mm=ev.mean_error_mm,
               tip_error_mm=ev.tip_error_mm, max_error_mm=ev.max_error_mm, failures=ev.failures, ms_median=ev.ms_median)
    return row


class Evaluator:
    """Evaluates parameter sets over the tuning sessions on a Dask sweep (:mod:`rig.bench.sweep`).

    A task is one parameter set on one session (its directory: the worker loads it, a few
    sessions at a time, so no process holds them all). Every finished task goes to the
    journal: a re-run of the same search (same seed, scenes and code) finds its evaluations
    there and resumes. With more than one worker, times per pair are measured with the
    workers competing for the machine, which only the time tie-break sees. Use as a context
    manager.

    Parameters
    ----------
    method : str
    session_dirs : list of path
        Rendered sessions (:func:`tune_session_dirs`).
    failure_penalty_mm : float
    journal : path, optional
        The sweep's JSONL journal (None: a temporary one, nothing resumes).
    scheduler : str, optional
        ``tcp://host:port`` of a Dask scheduler; None: an in-process LocalCluster.
    workers : int, optional
        LocalCluster workers (default one a core).
    progress : callable, optional
        ``progress(stage, done, total)`` of each batch of tasks.
    """

    def __init__(self, method: str, session_dirs, failure_penalty_mm: float = 5.0, journal=None,
                 scheduler: str | None = None, workers: int | None = None, progress=None):
        self.method, self.dirs, self.penalty = method, [str(d) for d in session_dirs], failure_penalty_mm
        self.scheduler, self.workers, self.progress = scheduler, workers, progress
        self._journal_path, self._stack = journal, None

    def __enter__(self):
        self._stack = contextlib.ExitStack()
        if self._journal_path is None:
            self._journal_path = Path(self._stack.enter_context(tempfile.TemporaryDirectory())) / "tune.jsonl"
        self.journal = Journal(self._journal_path)
        self.client = self._stack.enter_context(dask_client(self.scheduler, self.workers))
        return self

    def __exit__(self, *exc):
        self._stack.close()

    def many(self, params_list) -> list:
        """Evaluation of each parameter set, in order."""
        tasks = []
        for params in params_list:
            key = task_digest("tune-params", self.method, params_to_dict(params))
            tasks += [Task(f"{key}-{i}", evaluate_session_dir, (self.method, params, d),
                           task_digest("tune", self.method, params_to_dict(params), Path(d).name))
                      for i, d in enumerate(self.dirs)]
        done = require_all(tasks, run_sweep(self.client, tasks, self.journal, self.progress, stage="evaluate"),
                           self.journal, "evaluation")
        n = len(self.dirs)
        return [_evaluation([(d["name"], d["records"], d["ms"]) for d in done[k * n:(k + 1) * n]], self.penalty)
                for k in range(len(params_list))]

    def one(self, params) -> Evaluation:
        """Evaluation of one parameter set."""
        return self.many([params])[0]


def tune(method: str, session_dirs, base_params=None, *, maxiter: int = 12, popsize: int = 4, seed: int = 0,
         failure_penalty_mm: float = 5.0, tie_mm: float = 0.002, knobs=None, scheduler: str | None = None,
         workers: int | None = None, journal=None, sensitivity_points: int = 0, progress=None, on_row=None) -> TuneResult:
    """Search the method's knobs with differential evolution over ``sessions``.

    Parameters
    ----------
    method : str
        "paper" or "fast".
    session_dirs : list of path
        Rendered tuning sessions (:func:`tune_session_dirs`).
    base_params : dataclass, optional
        Values of everything not searched (default: the method's defaults).
    maxiter, popsize : int
        Differential evolution's generations and population size multiplier
        (the population is ``popsize * len(knobs)``, at least 5); the search costs at most
        ``(maxiter + 1) * popsize * len(knobs)`` evaluations, each one pass
        over every frame (repeated parameter sets are evaluated once).
    seed : int
        The search is deterministic for a seed (timings aside).
    failure_penalty_mm : float
        Error (mm) a failed frame counts as.
    tie_mm : float
        Error (mm) that twice the default's time per pair is worth (tie-break).
    knobs : sequence of Knob, optional
        Default: ``KNOBS[method]``.
    scheduler, workers, journal
        Where the evaluations run and are journalled (:class:`Evaluator`): a re-run with
        the same journal resumes.
    sensitivity_points : int
        When > 0, also sweep each knob alone over this many values (see
        :func:`sensitivity`).
    progress : callable(stage, done, total, **postfix), optional
    on_row : callable(dict), optional
        Called with every evaluation's row as soon as it is made (the caller
        writes them out, so an interrupted search keeps what it did).

    Returns
    -------
    TuneResult
        The default parameters are part of the initial population, so the
        tuned objective is never worse than the default's on these sessions.
    """
    t_start = time.perf_counter()
    m = get_method(method)
    base = base_params if base_params is not None else m.params_type()
    knobs = tuple(knobs if knobs is not None else KNOBS[method])
    with Evaluator(method, session_dirs, failure_penalty_mm, journal, scheduler, workers) as ev_many:
        default = ev_many.one(base)
        ms_default = default.ms_median if np.isfinite(default.ms_median) else 100.0
        x0 = knob_values(base, knobs)
        history = [_row(knobs, x0, default, objective_value(default, ms_default, tie_mm), stage="default")]
        record = on_row or (lambda row: None)
        record(history[0])
        n_pop = max(5, popsize * len(knobs))  # SciPy's differential evolution needs at least 5 members
        total = (maxiter + 1) * n_pop
        cache = {tuple(x0): (history[0]["objective"], default)}

        def population(_func, xs):
            # DE hands over a whole generation (deferred updating): evaluate the
            # new parameter sets together, record them here in the parent.
            params = [with_knobs(base, knobs, x) for x in xs]
            keys = [tuple(knob_values(p, knobs)) for p in params]
            todo = list(dict.fromkeys(k for k in keys if k not in cache))
            todo_params = [params[keys.index(k)] for k in todo]
            for key, ev in zip(todo, ev_many.many(todo_params)):
                cache[key] = (objective_value(ev, ms_default, tie_mm), ev)
                history.append(_row(knobs, key, ev, cache[key][0], stage="search"))
                record(history[-1])
            if progress:
                best = min(r["objective"] for r in history)
                progress("tune", min(len(history) - 1, total), total, best=f"{best:.4f}")
            return [cache[k][0] for k in keys]

        # The default parameters seed the population: the search starts from the
        # documented values and can only improve on them.
        rng = np.random.default_rng(seed)
        lows, highs = np.array([k.low for k in knobs], float), np.array([k.high for k in knobs], float)
        init = lows + rng.random((n_pop, len(knobs))) * (highs - lows)
        init[0] = np.clip(x0, lows, highs)
        differential_evolution(
            lambda x: 0.0, list(zip(lows, highs)), maxiter=maxiter, init=init, seed=seed, polish=False, tol=0.0,
            integrality=[k.integer for k in knobs], updating="deferred", workers=population,
        )
        if progress:
            progress("tune", total, total)
        # The best evaluation seen; the default wins a tie.
        best_row = min(history, key=lambda r: r["objective"])
        if best_row["stage"] == "default":
            tuned_params, tuned = base, default
        else:
            tuned_params = with_knobs(base, knobs, [best_row[k.path] for k in knobs])
            tuned = cache[tuple(knob_values(tuned_params, knobs))][1]
        result = TuneResult(method, knobs, base, tuned_params, default, tuned, history)
        if sensitivity_points > 0:
            sensitivity(result, ev_many, sensitivity_points, ms_default, tie_mm, progress, record)
    result.seconds = time.perf_counter() - t_start
    return result


def sensitivity(result: TuneResult, evaluator: Evaluator, points: int, ms_default: float, tie_mm: float,
                progress=None, on_row=None) -> list:
    """Sweep each knob alone across its range, the others at their tuned values.

    Integer knobs with at most ``points`` values are swept over all of them.
    Returns one row per evaluation (``knob``, ``value`` and the figures), also
    stored in ``result.sensitivity``.
    """
    knobs = result.knobs
    x_t = knob_values(result.tuned_params, knobs)
    jobs = []
    for i, k in enumerate(knobs):
        if k.integer and k.high - k.low + 1 <= points:
            vals = np.arange(int(k.low), int(k.high) + 1, dtype=float)
        else:
            vals = np.linspace(k.low, k.high, points)
            if k.integer:
                vals = np.unique(np.round(vals))
        for v in vals:
            x = x_t.copy()
            x[i] = v
            jobs.append((k, float(v), x))
    rows = []
    # One knob at a time, so progress moves and a long sweep shows its knob.
    for k in knobs:
        mine = [j for j in jobs if j[0] is k]
        evs = evaluator.many([with_knobs(result.tuned_params, knobs, x) for _, _, x in mine])
        for (_, v, x), ev in zip(mine, evs):
            rows.append(_row(knobs, x, ev, objective_value(ev, ms_default, tie_mm), stage="sensitivity", knob=k.path,
                             value=v))
            if on_row:
                on_row(rows[-1])
        if progress:
            progress("sensitivity", len(rows), len(jobs), knob=k.path)
    result.sensitivity = rows
    return rows


def tuned_dict(result: TuneResult) -> dict:
    """The parameter file's content: ``method`` and the tuned knobs only (everything else stays default)."""
    out = {"method": result.method}
    full = params_to_dict(result.tuned_params)
    for k in result.knobs:
        parts = k.path.split(".")
        src, dst = full, out
        for p in parts[:-1]:
            src = src[p]
            dst = dst.setdefault(p, {})
        dst[parts[-1]] = src[parts[-1]]
    return out
