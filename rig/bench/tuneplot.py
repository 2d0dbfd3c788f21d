"""Sensitivity plots of ``ctr-bench tune``: error against each searched parameter (PNG)."""
from __future__ import annotations

from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from rig.bench.tune import knob_values

__all__ = ["plot_sensitivity"]


def _axes_one(ax, knob, rows, default_value, tuned_value, method):
    v = np.array([r["value"] for r in rows])
    err = np.array([r["mean_error_mm"] for r in rows], float)
    pen = np.array([r["penalized_error_mm"] for r in rows], float)
    fails = np.array([r["failures"] for r in rows], int)
    order = np.argsort(v)
    v, err, pen, fails = v[order], err[order], pen[order], fails[order]
    ax.plot(v, pen, "-o", color="#0072b2", ms=4, label="objective error (failed frame = penalty)")
    ok = fails == 0
    ax.plot(v[ok], err[ok], "s", color="#009e73", ms=4, mfc="none", label="mean error, all frames ok")
    bad = ~ok
    if bad.any():
        ax.plot(v[bad], err[bad], "x", color="#d55e00", ms=6, label="mean error of the frames that did not fail")
        for x, y, n in zip(v[bad], pen[bad], fails[bad]):
            ax.annotate(f"{n} failed", (x, y), textcoords="offset points", xytext=(0, 5), ha="center", fontsize=7,
                        color="#d55e00")
    ax.axvline(default_value, color="0.4", ls="--", lw=1, label=f"default {default_value:g}")
    ax.axvline(tuned_value, color="#cc79a7", ls="-", lw=1.5, label=f"tuned {tuned_value:g}")
    ax.set_xlabel(knob.label)
    ax.set_ylabel("mean backbone error (mm)")
    finite = pen[np.isfinite(pen)]
    if finite.size and finite.max() > 5 * max(np.nanmin(finite), 1e-3):
        ax.set_yscale("log")  # failures (penalty) would flatten the interesting part
    ax.set_title(f"{method}: {knob.path}", fontsize=10)
    ax.grid(alpha=0.3)


def plot_sensitivity(result, out_dir) -> list:
    """Write ``sensitivity.png`` (all knobs) and ``sensitivity_<knob>.png`` (one each) into ``out_dir``.

    Returns the paths written.
    """
    matplotlib.use("Agg")

    out_dir = Path(out_dir)

    defaults = knob_values(result.default_params, result.knobs)
    tuned = knob_values(result.tuned_params, result.knobs)
    by_knob = {k.path: [r for r in result.sensitivity if r["knob"] == k.path] for k in result.knobs}
    paths = []
    n = len(result.knobs)
    cols = min(3, n)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(5.2 * cols, 3.9 * rows), squeeze=False)
    for i, k in enumerate(result.knobs):
        _axes_one(axes.flat[i], k, by_knob[k.path], defaults[i], tuned[i], result.method)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7, loc="best")
    fig.suptitle(f"ctr-bench tune, method {result.method}: error against each parameter, the others at their tuned values",
                 fontsize=11)
    fig.tight_layout()
    paths.append(out_dir / "sensitivity.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    for i, k in enumerate(result.knobs):
        fig, ax = plt.subplots(figsize=(6, 4.2))
        _axes_one(ax, k, by_knob[k.path], defaults[i], tuned[i], result.method)
        ax.legend(fontsize=7, loc="best")
        fig.tight_layout()
        paths.append(out_dir / f"sensitivity_{k.path.replace('.', '_')}.png")
        fig.savefig(paths[-1], dpi=110)
        plt.close(fig)
    return paths
