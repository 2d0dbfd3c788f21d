"""``ctr-bench tune SCENES... --method paper|fast --out tuned.toml``: tune a method on twin scenes.

Renders the scenes once (cached), searches the method's parameters with
differential evolution (see :mod:`rig.bench.tune`), sweeps each parameter alone for
the sensitivity plots, and writes a parameter file that ``ctr-bench
reconstruct --params`` reads. With ``--holdout``, the default and the tuned
parameters are also scored on scenes the search never saw.
"""
from __future__ import annotations

import csv
import math
import time
from dataclasses import asdict
from pathlib import Path

from recon.params import dumps_toml, params_to_dict
from rig.bench.render_cache import DEFAULT_CACHE_DIR
from rig.bench.tune import KNOBS, Evaluator, tune, tune_session_dirs, tuned_dict
from rig.bench.tuneplot import plot_sensitivity
from rig.cli.options import add_sweep_options, method_name, method_params
from rig.progress import Progress
from rig.rundir import write_json_atomic
from rig.session import Session


def _scene_files(items, option: str) -> list:
    """Scene TOML files from files and directories (a directory means its *.toml, sorted)."""
    out = []
    for item in items:
        p = Path(item)
        if p.is_dir():
            found = sorted(p.glob("*.toml"))
            if not found:
                raise ValueError(f"{option} {p}: directory holds no .toml scene")
            out += found
        elif p.is_file():
            out.append(p)
        else:
            raise ValueError(f"{option} {p}: no such scene file or directory")
    return out


def _knobs(method: str, text: str | None):
    """The knobs named in ``--knobs`` (comma-separated paths), all of the method's when None."""
    known = {k.path: k for k in KNOBS.get(method, ())}
    if not known:
        raise ValueError(f"--method {method}: no tunable parameters are defined for it (tunable: {', '.join(KNOBS)})")
    if text is None:
        return tuple(known.values())
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in known]
    if unknown or not names:
        raise ValueError(f"--knobs {text!r}: unknown {', '.join(unknown) or 'empty list'} (known for {method}: {', '.join(known)})")
    return tuple(known[n] for n in dict.fromkeys(names))


_FIGURES = ("objective", "penalized_error_mm", "mean_error_mm", "tip_error_mm", "max_error_mm", "failures", "ms_median")


class _CsvLog:
    """Rows appended to a CSV as they come (an interrupted search keeps every evaluation it made)."""

    def __init__(self, path: Path, knobs):
        self.path = path
        self.fields = ["stage", "knob", "value", *(k.path for k in knobs), *_FIGURES]
        with open(path, "w", newline="") as fh:
            csv.DictWriter(fh, fieldnames=self.fields).writeheader()

    def __call__(self, row: dict) -> None:
        with open(self.path, "a", newline="") as fh:
            csv.DictWriter(fh, fieldnames=self.fields, restval="").writerow(
                {k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})


def _fmt(v, p=3):
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.{p}f}"


def _table(title: str, default, tuned) -> str:
    lines = [title, f"{'scene':<34} {'params':<8} {'failed':>6} {'mean mm':>8} {'tip mm':>7} {'max mm':>7}"]
    for name in default.per_session:
        for label, ev in (("default", default), ("tuned", tuned)):
            s = ev.per_session[name]
            lines.append(f"{name:<34} {label:<8} {s['failures']:>3}/{s['frames']:<2} {_fmt(s['mean_error_mm']):>8} "
                         f"{_fmt(s['tip_error_mm']):>7} {_fmt(s['max_error_mm']):>7}")
    for label, ev in (("default", default), ("tuned", tuned)):
        lines.append(f"{'all':<34} {label:<8} {ev.failures:>3}/{ev.frames:<2} {_fmt(ev.mean_error_mm):>8} "
                     f"{_fmt(ev.tip_error_mm):>7} {_fmt(ev.max_error_mm):>7}   median {_fmt(ev.ms_median, 1)} ms/pair")
    return "\n".join(lines)


def _output_paths(args) -> tuple:
    """The parameter file and report directory to write, refused when either would overwrite something.

    Parameters
    ----------
    args : argparse.Namespace
        ``out`` and ``report`` (None: next to ``out``, named ``<out>-tune``).

    Returns
    -------
    (Path, Path)
        The ``.toml`` parameter file and the report directory.
    """
    out = Path(args.out)
    if out.suffix != ".toml":
        raise ValueError(f"--out {out}: must name a .toml parameter file")
    if out.exists():
        raise ValueError(f"--out {out}: exists (nothing is overwritten; choose another name)")
    report = Path(args.report) if args.report else out.with_name(out.stem + "-tune")
    if report.exists() and any(report.iterdir()):
        raise ValueError(f"--report {report}: exists and is not empty (nothing is overwritten)")
    return out, report


def _check_counts(args) -> None:
    """Refuse a search size (generations, population, sweep points) below one."""
    for name in ("maxiter", "popsize", "points"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name}: must be >= 1, got {getattr(args, name)}")


def _scene_lists(args) -> tuple:
    """The tuning and held-out scene files; a scene in both is refused (held-out scenes must be unseen).

    Returns
    -------
    (list of Path, list of Path)
        Tuning scenes, held-out scenes (empty without ``--holdout``).
    """
    scenes = _scene_files(args.scenes, "SCENES")
    holdout = _scene_files(args.holdout, "--holdout") if args.holdout else []
    overlap = {p.resolve() for p in scenes} & {p.resolve() for p in holdout}
    if overlap:
        raise ValueError(f"--holdout {sorted(overlap)[0]}: also a tuning scene (held-out scenes must be unseen)")
    return scenes, holdout


def _score_holdout(args, result, holdout: list, progress) -> tuple:
    """Score the default and the tuned parameters on the held-out scenes and print the table.

    Returns
    -------
    (Evaluation, Evaluation)
        Default, tuned (errors in mm).
    """
    dirs = tune_session_dirs(holdout, args.cache, progress=progress)
    with Evaluator(args.method, dirs, args.failure_penalty_mm, _journal(args), args.scheduler, args.workers) as ev:
        held = tuple(ev.many([result.default_params, result.tuned_params]))
    print(_table("\nheld-out scenes (never seen by the search):", *held))
    return held


def _journal(args) -> Path:
    """The evaluations' journal: ``--journal``, or one beside the render cache that every search shares."""
    return Path(args.journal) if args.journal else Path(args.cache) / "tune-journal.jsonl"


def _changed_lines(result) -> list:
    """One ``path = tuned (default default)`` line per searched knob."""
    changed = []
    tuned_flat, default_flat = tuned_dict(result), params_to_dict(result.default_params)
    for k in result.knobs:
        d, t = default_flat, tuned_flat
        for part in k.path.split("."):
            d, t = d[part], t[part]
        changed.append(f"{k.path} = {t!r} (default {d!r})")
    return changed


def _params_header(args, scenes: list, out: Path, result, held) -> str:
    """The parameter file's comment header: when, on what, the objective, the mean errors (mm) and how to use it."""
    return "\n".join([
        f"ctr-bench tune --method {args.method}: {time.strftime('%Y-%m-%d %H:%M')}",
        f"scenes: {', '.join(str(p) for p in scenes)}",
        f"objective: mean backbone error, a failed frame = {args.failure_penalty_mm} mm, "
        f"time tie-break {args.tie_mm} mm per default time per pair",
        f"tuning scenes: default mean {_fmt(result.default.mean_error_mm, 4)} mm ({result.default.failures} failed), "
        f"tuned mean {_fmt(result.tuned.mean_error_mm, 4)} mm ({result.tuned.failures} failed)",
    ] + ([f"held-out scenes: default mean {_fmt(held[0].mean_error_mm, 4)} mm ({held[0].failures} failed), "
          f"tuned mean {_fmt(held[1].mean_error_mm, 4)} mm ({held[1].failures} failed)"] if held else [])
      + ["read by: ctr-bench reconstruct SESSION --method " + args.method + f" --params {out.name}",
         "parameters not listed keep their defaults; tube radii come from the session's robot"])


def _write_text_atomic(path: Path, text: str) -> None:
    """Write ``text`` to a temporary name and rename it: ``path`` is never half a file."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    tmp.replace(path)


def _summary(args, scenes: list, holdout: list, result, held) -> dict:
    """``summary.json``: the search's settings, the knobs' ranges, the parameters and every evaluation (mm, s)."""
    return {
        "format": "ctr-bench-tune", "version": 1, "method": args.method,
        "scenes": [str(p) for p in scenes], "holdout": [str(p) for p in holdout],
        "search": {"maxiter": args.maxiter, "popsize": args.popsize, "seed": args.seed,
                   "evaluations": len(result.history), "seconds": result.seconds,
                   "failure_penalty_mm": args.failure_penalty_mm, "tie_mm": args.tie_mm},
        "knobs": [{"path": k.path, "low": k.low, "high": k.high, "integer": k.integer, "unit": k.unit} for k in result.knobs],
        "default_params": params_to_dict(result.default_params), "tuned": tuned_dict(result),
        "default": asdict(result.default), "tuned_evaluation": asdict(result.tuned),
        "holdout_default": asdict(held[0]) if held else None,
        "holdout_tuned": asdict(held[1]) if held else None,
    }


def _run(args) -> int:
    """``ctr-bench tune``: check the options, search, write the parameter file and the report; 0 when done."""
    # every option is checked before anything is rendered or written
    out, report = _output_paths(args)
    _check_counts(args)
    scenes, holdout = _scene_lists(args)
    base = method_params(args)
    knobs = _knobs(args.method, args.knobs)
    report.mkdir(parents=True, exist_ok=True)
    history = _CsvLog(report / "history.csv", knobs)
    progress = Progress(enabled=not args.quiet, units={"tune": "eval", "sensitivity": "eval"})
    t0 = time.perf_counter()
    sessions = tune_session_dirs(scenes, args.cache, progress=progress)
    n_frames = sum(len(Session(d).frames) for d in sessions)
    print(f"tuning method {args.method!r} on {len(sessions)} scenes ({n_frames} frame pairs), "
          f"differential evolution: {args.maxiter} generations x {args.popsize} x knobs")
    result = tune(args.method, sessions, base, knobs=knobs, maxiter=args.maxiter, popsize=args.popsize, seed=args.seed,
                  failure_penalty_mm=args.failure_penalty_mm, tie_mm=args.tie_mm, scheduler=args.scheduler,
                  workers=args.workers, journal=_journal(args),
                  sensitivity_points=0 if args.no_sensitivity else args.points, progress=progress, on_row=history)
    if result.sensitivity:
        plot_sensitivity(result, report)
    print(_table("\ntuning scenes (seen by the search):", result.default, result.tuned))
    held = _score_holdout(args, result, holdout, progress) if holdout else None
    progress.close()
    changed = _changed_lines(result)
    _write_text_atomic(out, dumps_toml(tuned_dict(result), _params_header(args, scenes, out, result, held)))
    write_json_atomic(report / "summary.json", _summary(args, scenes, holdout, result, held))
    print("\n" + "\n".join(changed))
    print(f"\nwrote {out} and {report}/ (history.csv: every evaluation, summary.json"
          + ("" if args.no_sensitivity else ", sensitivity*.png") + f") in {time.perf_counter() - t0:.0f} s")
    return 0


def register(sub) -> None:
    p = sub.add_parser("tune", help="tune a method's parameters on twin scenes",
                       description="Render the scenes once (cached), search the method's parameters (threshold, "
                       "structuring elements, eigenbackground count, voxel resolution; or the fast method's) with "
                       "differential evolution to minimize the mean backbone error (failed frames penalized, time as "
                       "tie-break), plot the error against each parameter, and write a parameter file for "
                       "ctr-bench reconstruct --params. See docs/tuning.md.")
    p.add_argument("scenes", nargs="+", help="scene TOML files or directories of them (e.g. scenes/tune)")
    p.add_argument("--method", default="paper", type=method_name, help="method to tune: paper (default) or fast")
    p.add_argument("--params", default=None, metavar="FILE", help="start from this parameter file instead of the defaults")
    p.add_argument("--out", required=True, help="parameter file to write (.toml; not overwritten)")
    p.add_argument("--report", default=None, help="directory for history.csv, summary.json and the sensitivity plots "
                   "(default: next to --out, named <out>-tune)")
    p.add_argument("--knobs", default=None, metavar="A,B",
                   help="search only these parameters (comma-separated dotted names; default: all the method's, "
                   "listed in docs/tuning.md)")
    p.add_argument("--holdout", nargs="+", default=None, metavar="SCENE",
                   help="also score default and tuned parameters on these scenes (never searched on), e.g. scenes/holdout")
    p.add_argument("--cache", default=str(DEFAULT_CACHE_DIR),
                   help="where rendered scenes are kept, shared with run and bench (default %(default)s)")
    p.add_argument("--maxiter", type=int, default=12, help="differential evolution generations (default %(default)s)")
    p.add_argument("--popsize", type=int, default=4, help="population per knob (default %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="search seed (default %(default)s)")
    p.add_argument("--points", type=int, default=9, help="values per parameter in the sensitivity sweep (default %(default)s)")
    p.add_argument("--failure-penalty-mm", type=float, default=5.0, help="error a failed frame counts as (default %(default)s mm)")
    p.add_argument("--tie-mm", type=float, default=0.002,
                   help="error that twice the default's time per pair is worth: the time tie-break (default %(default)s mm)")
    add_sweep_options(p)
    p.add_argument("--journal", default=None, metavar="FILE",
                   help="journal of finished evaluations, which a re-run of the search resumes from "
                   "(default: CACHE/tune-journal.jsonl, shared by every search)")
    p.add_argument("--no-sensitivity", action="store_true", help="skip the one-parameter sweeps and their plots")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_run)
