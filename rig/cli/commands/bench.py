"""``ctr-bench bench [SCENE]``: every method on the same rendered frames, side by side, on one core
(the protocol: :mod:`rig.bench.compare`); ``bench --suite wide``: the generalization benchmark
(:mod:`rig.bench.widebench`)."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from rig.bench import widebench
from rig.bench.compare import METHODS, bench, format_ratios, format_scaling, format_table, scaling
from rig.bench.cores import pin_one_core
from rig.bench.render_cache import DEFAULT_CACHE_DIR
from rig.cli.options import add_scene_options, add_sweep_options, load_scene_from_args, megapixels_limit


def method_list(text: str) -> list:
    """``--methods``'s type: known names, comma-separated, checked when the options are read (before any render).

    A peer that is known but not installed is accepted here and skipped with its reason later.
    """
    names = [m.strip() for m in text.split(",")]
    bad = [m for m in names if m not in METHODS]
    if bad or len(set(names)) != len(names):
        why = f"unknown method {bad[0]!r}" if bad else "a method named twice"
        raise argparse.ArgumentTypeError(f"{why} in {text!r} (known: {', '.join(METHODS)})")
    return names


def _run_suite(args) -> int:
    """``bench --suite NAME``: the generalization benchmark of :mod:`rig.bench.widebench`."""
    if args.scene is not None:
        raise ValueError(f"--suite {args.suite} draws its own scenes: give either a SCENE or --suite, not both")
    if args.n < 1:
        raise ValueError(f"--n must be >= 1, got {args.n}")
    if args.seed < 0:
        raise ValueError(f"--seed must be >= 0, got {args.seed}")
    max_pixels = megapixels_limit(args.max_megapixels)
    methods = args.methods or list(METHODS)
    out = Path(args.out) if args.out else Path("out") / f"bench-{args.suite}-n{args.n}-seed{args.seed}"
    # No pin here: the sweep's workers pin themselves, one core each.
    report = widebench.run_suite(args.suite, args.n, args.seed, methods, out, Path(args.cache_dir),
                                 selfcheck=not args.no_selfcheck, quiet=args.quiet, max_pixels=max_pixels,
                                 scheduler=args.scheduler, workers=args.workers)
    if args.json:
        print(widebench.dump(report))
        return 0
    print(widebench.format_suite(report))
    widebench.print_worst(report)
    print(f"\nper-frame rows: {out / 'frames.csv'}; summary: {out / 'summary.json'}; runs: {out / 'runs'}; "
          f"pictures of the worst and silent frames: {out / 'pictures'}")
    return 0


def _run(args) -> int:
    if args.suite:
        return _run_suite(args)
    cpu = pin_one_core()
    scene = load_scene_from_args(args)
    methods = args.methods or list(METHODS)
    cache = Path(args.cache_dir)
    results = bench(scene, methods, cache, args.repeats, args.quiet)
    report = {"bench": results}
    if args.scaling:
        report["scaling"] = scaling(scene, [m for m in methods], cache, args)
    if args.json:
        out = dict(results)
        if args.scaling:
            out = {"bench": results, "scaling": report["scaling"]}
        print(json.dumps(out, indent=2, default=float))
        return 0
    size = next((r["image_size"] for r in results.values() if "image_size" in r), None)
    print(format_table(results, f"{scene.name}: {len(scene.joints)} frame pairs"
                       + (f" at {size[0]}x{size[1]}" if size else "") + f", one core (cpu {cpu}), best of {args.repeats} passes per frame"))
    rat = format_ratios(results)
    if rat:
        print("\n" + rat)
    _print_score_notes(results)
    if "icp-epipolar" in results and "skipped" not in results["icp-epipolar"]:
        print("\nicp-epipolar runs with two compatibility shims (NumPy 2 int() of 1-element arrays, OpenCV 5 1-D points); see rig/bench/peers.py.")
    if args.scaling:
        print()
        print(format_scaling(report["scaling"]))
        _print_score_notes(report["scaling"])
    return 0


def _print_score_notes(results: dict, file=None) -> None:
    """The frames left unscored (their ground truth unusable), once each, under the table (on ``file``, stdout by default)."""
    file = file or sys.stdout
    notes = list(dict.fromkeys(n for r in results.values() for n in r.get("score_notes", ())))
    if notes:
        print(f"\n{len(notes)} frame(s) not scored (errors are over the other frames):", file=file)
        for note in notes:
            print(f"  {note}", file=file)


def register(sub) -> None:
    p = sub.add_parser("bench", help="all methods on the same rendered frames, one core: speed, accuracy, memory",
                       description="Render a scene once (cached), then time and score the paper method, the fast method and "
                       "icpReconstructor's EpipolarReconstructor (when installed) on the same frames, pinned to one core.")
    add_scene_options(p)
    p.add_argument("--methods", type=method_list, default=None, metavar="LIST",
                   help=f"comma-separated subset of {','.join(METHODS)} (default: all)")
    p.add_argument("--repeats", type=int, default=3, help="passes over the sequence per method; a frame's time is its fastest (default 3)")
    p.add_argument("--cache-dir", default=str(DEFAULT_CACHE_DIR), help="where rendered sessions are cached (default %(default)s)")
    p.add_argument("--scaling", action="store_true", help="also the resolution (0.5x, 1x, 2x) and voxel (50^3, 100^3, 200^3) study")
    p.add_argument("--scaling-frames", type=int, default=6, help="frames per scene in the scaling study (default 6)")
    p.add_argument("--json", action="store_true", help="print one JSON object keyed by method name")
    p.add_argument("--suite", choices=["wide"], default=None,
                   help="the generalization benchmark on a seeded set of generated scenes instead of one SCENE (docs/scenes.md)")
    p.add_argument("--n", type=int, default=40, help="--suite: number of scenes (default 40)")
    p.add_argument("--seed", type=int, default=1, help="--suite: seed of the scene draw (default 1, the reported set)")
    p.add_argument("--out", default=None, help="--suite: where frames.csv, summary.json and the runs go "
                   "(default out/bench-SUITE-nN-seedS)")
    p.add_argument("--max-megapixels", type=float, default=None,
                   help="--suite: draw only sensors up to this size (a quick set; other ranges unchanged)")
    p.add_argument("--no-selfcheck", action="store_true", help="--suite: report frames as the methods return them, unchecked")
    add_sweep_options(p, "--suite: ")
    p.set_defaults(func=_run)
