"""``ctr-bench dataset --suite wide --n N [--seed S] --out DIR``: a sharded dataset for learned methods.

Per frame pair: the images (PNG), per-pixel tube labels (PNG), the projected
centerlines, the 3D backbone and the calibration (NPZ, JSON), and an index
(``index.jsonl``, one line per sample), readable with numpy, PIL and json
alone: docs/dataset.md. Built by :mod:`rig.bench.dataset` from the twin's sessions,
rendered through the render cache that ``bench --suite`` uses, a scene a task on the same
Dask sweep (:mod:`rig.bench.sweep`: ``--scheduler`` or an in-process cluster).
"""
from __future__ import annotations

import argparse
from pathlib import Path

from rig.bench.dataset import build_dataset
from rig.bench.render_cache import DEFAULT_CACHE_DIR
from rig.bench.sweep import dask_client, dask_map
from rig.cli.options import add_sweep_options, count, megapixels_limit


def _scale(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not 0 < value <= 4:
        raise argparse.ArgumentTypeError(f"must be in (0, 4], got {value:g}")
    return value


def _run(args) -> int:
    with dask_client(args.scheduler, args.workers) as client:
        meta = build_dataset(args.suite, args.n, args.seed, Path(args.out), Path(args.cache_dir), shard_size=args.shard_size,
                             scale=args.scale, max_pixels=megapixels_limit(args.max_megapixels), depth=args.depth,
                             overwrite=args.overwrite, quiet=args.quiet, map_fn=dask_map(client))
    print(f"wrote {meta['samples']} samples of {meta['scenes']} {args.suite!r} scenes (seed {args.seed}) in "
          f"{len(meta['shards'])} shards into {args.out}; index: {Path(args.out) / 'index.jsonl'} (docs/dataset.md)")
    return 0


def register(sub) -> None:
    p = sub.add_parser("dataset", help="a sharded dataset of twin frames for learned methods (images, labels, truth)",
                       description="Draw a seeded suite of scenes, render each once (cached, as bench --suite does) and write "
                       "per frame pair the images, per-pixel tube labels, projected centerlines, 3D backbone and calibration "
                       "in shards with a JSONL index, readable without ctr-bench (docs/dataset.md). A re-run into the same "
                       "DIR with the same options skips the finished shards.")
    p.add_argument("--suite", choices=["wide"], default="wide", help="suite to draw from (default: wide)")
    p.add_argument("--n", type=count(1), default=40, help="number of scenes (default 40; each gives its frame pairs)")
    p.add_argument("--seed", type=count(0), default=0,
                   help="seed of the scene draw (default 0; seed 1 is the set bench --suite reports on)")
    p.add_argument("--out", required=True, help="dataset directory")
    p.add_argument("--shard-size", type=count(1), default=256, metavar="K", help="at most K samples per shard (default 256)")
    p.add_argument("--scale", type=_scale, default=1.0,
                   help="image scale of the renders, same field of view (default 1: the drawn sensor sizes)")
    p.add_argument("--max-megapixels", type=float, default=None, metavar="MP",
                   help="draw only sensors of at most MP megapixels (default: 0.3-5 MP)")
    p.add_argument("--depth", action="store_true", help="also store each camera's depth map (mm) in the NPZ")
    p.add_argument("--cache-dir", default=str(DEFAULT_CACHE_DIR),
                   help="render cache, shared with bench (sessions go to its sessions/; default %(default)s)")
    p.add_argument("--overwrite", action="store_true",
                   help="DIR holds another dataset (or other files): remove what a dataset writes there "
                   "(dataset.json, index.jsonl, scenes/, shard-*/; nothing else) and start again")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_sweep_options(p)
    p.set_defaults(func=_run)
