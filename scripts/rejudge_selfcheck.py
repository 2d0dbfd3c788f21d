"""Re-judge a wide bench's frames under other self-check limits, offline, from the figures its runs recorded.

``ctr-bench bench --suite wide --out DIR`` keeps every frame's self-check figures in
``DIR/runs/<method>/<scene>/frames.jsonl`` and every frame's errors in ``DIR/sweep.jsonl``. The
verdict is the figure furthest beyond its limit (:func:`recon.selfcheck._verdict`), so changing a
pure limit needs no new reconstruction: this prints, per method, the silent-wrong frames and the
good frames flagged under the given limits, and (``--search``) the coordinate search of docs/envelope.md
for the fewest silent frames without more good frames flagged. ``max_unexplained_px`` is not
searched: it also decides when specks are dropped, so its figure depends on it.

Usage::

    .venv/bin/python scripts/rejudge_selfcheck.py out/bench-wide-n70-seed2 [--set max_tip_off_foreground_px=4] [--search]

Search on tuning seeds (2, 3), not on the reported seed 1.
"""
from __future__ import annotations

import argparse
import json
from dataclasses import fields
from pathlib import Path

from recon.selfcheck import FIGURE_LIMITS, SelfCheckParams
from rig.bench.widebench import SILENT_WRONG_PX

#: Figure -> the limit it is judged against (SelfCheckParams field), as the self-check judges it.
LIMITS = {figure: limit for figure, (limit, _) in FIGURE_LIMITS.items()}
#: Limits that are pure thresholds (searchable offline).
SEARCHED = tuple(v for v in LIMITS.values() if v != "max_unexplained_px")


def defaults() -> dict:
    """Today's limits (SelfCheckParams' defaults)."""
    p = SelfCheckParams()
    return {f.name: getattr(p, f.name) for f in fields(p) if f.name in LIMITS.values()}


def load(bench_dir: Path) -> list:
    """Every reconstructed frame: method, scene, frame, max error (footprints), self-check figures, method doubt."""
    items = []
    for line in (bench_dir / "sweep.jsonl").read_text().splitlines():
        try:
            rows = json.loads(line)["result"]["rows"]
        except (json.JSONDecodeError, KeyError, TypeError):
            continue
        for r in rows:
            if r["status"] not in ("ok", "suspect") or r.get("max_error_px") is None:
                continue
            journal = bench_dir / "runs" / r["method"] / r["scene"] / "frames.jsonl"
            rec = next(x for x in map(json.loads, journal.read_text().splitlines()[1:]) if x.get("frame") == r["frame"])
            check = rec.get("selfcheck") or {}
            items.append({"method": r["method"], "scene": r["scene"], "frame": r["frame"], "max_px": r["max_error_px"],
                          "views": check.get("views") or {},
                          # suspect by the method's own doubt, the self-check satisfied: no limit changes that
                          "doubt": r["status"] == "suspect" and check.get("ok", True)})
    return items


def flagged(item: dict, limits: dict) -> bool:
    """The frame's status under ``limits``: any figure beyond its limit, or the method's own doubt."""
    return item["doubt"] or any(f.get(k) is not None and f[k] > limits[lim]
                                for f in item["views"].values() for k, lim in LIMITS.items())


def counts(items: list, limits: dict) -> dict:
    """Per method: (silent wrong, good flagged, good)."""
    out = {}
    for m in sorted({i["method"] for i in items}):
        mine = [i for i in items if i["method"] == m]
        good = [i for i in mine if i["max_px"] <= SILENT_WRONG_PX]
        out[m] = (sum(not flagged(i, limits) and i["max_px"] > SILENT_WRONG_PX for i in mine),
                  sum(flagged(i, limits) for i in good), len(good))
    return out


def search(items: list, factors=(0.5, 0.6, 0.7, 0.8, 0.9, 1.1, 1.25, 1.5, 2.0), rounds: int = 4) -> dict:
    """Coordinate descent over :data:`SEARCHED`: fewest silent frames, no more good frames flagged, then fewest flagged."""
    base = defaults()
    flagged0 = sum(c[1] for c in counts(items, base).values())
    lim, best = dict(base), tuple(sum(c[k] for c in counts(items, base).values()) for k in (0, 1))
    for _ in range(rounds):
        moved = False
        for key in SEARCHED:
            for f in factors:
                trial = dict(lim, **{key: base[key] * f})
                c = counts(items, trial).values()
                score = (sum(x[0] for x in c), sum(x[1] for x in c))
                if score[1] <= flagged0 and score < best:
                    lim, best, moved = trial, score, True
        if not moved:
            break
    return lim


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("bench_dirs", nargs="+", type=Path, help="output directories of bench --suite wide")
    ap.add_argument("--set", action="append", default=[], metavar="LIMIT=VALUE", help="judge under this limit instead")
    ap.add_argument("--search", action="store_true", help="search the limits (on tuning seeds only)")
    args = ap.parse_args(argv)
    items = [i for d in args.bench_dirs for i in load(d)]
    limits = defaults()
    for kv in args.set:
        key, value = kv.split("=", 1)
        if key not in limits:
            ap.error(f"--set {kv}: not a limit; one of {', '.join(limits)}")
        limits[key] = float(value)
    if args.search:
        limits = search(items)
        print("searched limits (changed):", {k: v for k, v in limits.items() if v != defaults()[k]})
    for m, (silent, gf, good) in counts(items, limits).items():
        print(f"{m}: {silent} silent wrong, {gf} of {good} good frames flagged")
        for i in items:
            if i["method"] == m and i["max_px"] > SILENT_WRONG_PX and not flagged(i, limits):
                ratios = [(f[k] / limits[lim], cam, k) for cam, f in i["views"].items() for k, lim in LIMITS.items()
                          if f.get(k) is not None]
                r, cam, k = max(ratios) if ratios else (0.0, "-", "-")
                print(f"  silent {i['scene']} frame {i['frame']}: {i['max_px']:.1f} footprints; worst figure {cam} {k} "
                      f"at {r:.2f} of its limit")


if __name__ == "__main__":
    main()
