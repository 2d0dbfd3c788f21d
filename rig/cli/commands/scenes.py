"""``ctr-bench scenes generate --suite wide --n N --seed S --out DIR [--render]``: write generated twin scenes.

Writes ``DIR/<name>.toml`` (one scene each, readable by every command that takes a
scene) and ``DIR/index.json`` (name, file and class labels of each scene). With
``--render`` every scene is also rendered into the render cache, a scene a task on a
Dask sweep (:mod:`rig.bench.sweep`).
"""
from __future__ import annotations

from pathlib import Path

from rig.bench.render_cache import DEFAULT_CACHE_DIR, render_into_cache
from rig.bench.sweep import Journal, Task, dask_client, require_all, run_sweep, task_digest
from rig.cli.options import add_sweep_options
from rig.progress import Progress
from twin.scenegen import SUITES, generate_suite, write_suite


def _positive_int(text: str, option: str, minimum: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise ValueError(f"{option}: expected an integer, got {text!r}") from None
    if value < minimum:
        raise ValueError(f"{option}: must be >= {minimum}, got {value}")
    return value


def _generate(args) -> int:
    if args.suite not in SUITES:
        raise ValueError(f"--suite: unknown suite {args.suite!r}; one of {', '.join(SUITES)}")
    n = _positive_int(args.n, "--n", 1)
    seed = _positive_int(args.seed, "--seed", 0)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out: {out} exists and is not a directory")
    scenes = generate_suite(args.suite, n, seed)
    paths = write_suite(scenes, out)
    print(f"wrote {len(scenes)} {args.suite!r} scenes (seed {seed}) and {out / 'index.json'}")
    if args.render:
        _render(paths, args)
    return 0


def _render(paths: list, args) -> None:
    """Render every scene into the cache on the sweep's workers, journalled (a re-run renders only what is missing)."""
    cache = Path(args.cache_dir)
    tasks = [Task(p.stem, render_into_cache, (str(p), str(cache)), task_digest("render", p.read_text(), str(cache)))
             for p in paths]
    progress = Progress(enabled=not args.quiet, units={"render": "scene"})
    journal = Journal(cache / "render-journal.jsonl")
    with dask_client(args.scheduler, args.workers) as client:
        done = require_all(tasks, run_sweep(client, tasks, journal, progress, stage="render"), journal, "render")
    progress.close()
    print(f"rendered {len(done)} scenes into {cache} ({sum(d['frames'] for d in done)} frame pairs)")


def register(sub) -> None:
    p = sub.add_parser("scenes", help="generate suites of twin scenes (wide scene distributions)",
                       description="Generate seeded suites of twin scenes: non-orthogonal rigs, many backdrops, "
                       "robots entering at the border, masks-only sessions. See docs/scenes.md.")
    actions = p.add_subparsers(dest="action", metavar="ACTION")
    actions.required = True
    g = actions.add_parser("generate", help="write DIR/<name>.toml and DIR/index.json",
                           description="Write N scenes of a suite, reproducibly from a seed, as TOML files with an index.")
    g.add_argument("--suite", default="wide", help="suite to draw from (default: wide)")
    g.add_argument("--n", default="40", help="number of scenes (default: 40)")
    g.add_argument("--seed", default="0", help="seed (default: 0); same suite, n and seed: same files")
    g.add_argument("--out", required=True, help="directory to write the scenes into")
    g.add_argument("--render", action="store_true", help="also render every scene into the render cache (a Dask sweep)")
    g.add_argument("--cache-dir", default=str(DEFAULT_CACHE_DIR / "sessions"),
                   help="--render: where the sessions go (default %(default)s, where bench --suite looks)")
    g.add_argument("--quiet", action="store_true", help="--render: no progress bar")
    add_sweep_options(g, "--render: ")
    g.set_defaults(func=_generate)
