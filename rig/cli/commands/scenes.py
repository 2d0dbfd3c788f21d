"""``ctr-bench scenes generate --suite wide --n N --seed S --out DIR``: write generated twin scenes.

Writes ``DIR/<name>.toml`` (one scene each, readable by every command that takes a
scene) and ``DIR/index.json`` (name, file and class labels of each scene).
"""
from __future__ import annotations

from pathlib import Path

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
    write_suite(scenes, out)
    print(f"wrote {len(scenes)} {args.suite!r} scenes (seed {seed}) and {out / 'index.json'}")
    return 0


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
    g.set_defaults(func=_generate)
