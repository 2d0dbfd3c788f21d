"""What ``verify`` writes: the per-frame table, the CSV/JSON outputs and the pictures of a model's predictions
against the measured backbones."""
from __future__ import annotations

import csv
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from rig.bench.modeldata import Dataset
from rig.rundir import write_json_atomic
from rig.tables import cell

__all__ = ["format_table", "write_outputs", "plot_verification"]


def format_table(records: list, agg: dict, title: str) -> str:
    lines = [f"{'frame':>5}  {'tip mm':>7}  {'mean mm':>7}  {'max mm':>7}  {'dlen mm':>7}  status"]
    for r in records:
        st = "ok" if r["status"] == "ok" else f"{r['status']}: {r['reason']}"
        lines.append(f"{r['frame']:>5}  {cell(r.get('tip_error_mm'))}  {cell(r.get('mean_error_mm'))}  {cell(r.get('max_error_mm'))}  {cell(r.get('length_error_mm'))}  {st}")
    lines.append("")
    lines.append("dlen: measured minus predicted length from where the measurement starts (a reconstruction cut short "
                 "shows as a large negative dlen and tip error)")
    lines.append(title)
    if agg.get("ok_frames"):
        lines.append(
            f"tip error mean {agg['tip_error_mm_mean']:.3f} mm (median {agg['tip_error_mm_median']:.3f}, max {agg['tip_error_mm_max']:.3f}); "
            f"mean shape error mean {agg['mean_error_mm_mean']:.3f} mm (max {agg['mean_error_mm_max']:.3f}); "
            f"RMS error at matching arc length {agg['along_error_mm_rms']:.3f} mm"
        )
    return "\n".join(lines)


def _json_records(records):
    """The per-frame records without their arrays (those go to along_arc_length.csv and the plots)."""
    return [{k: v for k, v in r.items() if k not in ("s_mm", "along_error_mm", "predicted_mm")} for r in records]


def write_outputs(out: Path, ds: Dataset, records: list, agg: dict, profile: dict, plots: bool = True) -> None:
    out.mkdir(parents=True, exist_ok=True)
    doc = {
        "format": "ctr-bench-verify", "version": 1,
        "model": ds.state.model, "measured": ds.source, "recon_dir": str(ds.recon_dir), "session": str(ds.session_dir),
        "robot_source": ds.robot_source,
        "joint_offsets": {"rotation_deg": ds.state.offsets.rotation_deg.tolist(), "insertion_mm": ds.state.offsets.extension_mm.tolist()},
        "aggregate": agg, "skipped": [{"frame": i, "reason": why} for i, why in ds.skipped],
        "per_frame": _json_records(records), "along_arc_length": profile,
    }
    write_json_atomic(out / "verify.json", doc)  # unknown (non-finite) figures as null
    with open(out / "verify.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["frame", "status", "tip_error_mm", "mean_error_mm", "max_error_mm", "length_error_mm", "s_start_mm", "reason"])
        for r in records:
            w.writerow([r["frame"], r["status"]] + [("" if r.get(k) is None else f"{r[k]:.4f}") for k in
                        ("tip_error_mm", "mean_error_mm", "max_error_mm", "length_error_mm", "s_start_mm")] + [r.get("reason") or ""])
    with open(out / "along_arc_length.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["s_mm", "mean_error_mm", "p90_error_mm", "n"])
        for row in zip(profile["s_mm"], profile["mean_mm"], profile["p90_mm"], profile["n"]):
            w.writerow([f"{row[0]:.2f}", f"{row[1]:.4f}", f"{row[2]:.4f}", row[3]])
    if plots:
        plot_verification(out, ds, records, profile)


def plot_verification(out: Path, ds: Dataset, records: list, profile: dict, label: str | None = None) -> None:
    """per_frame_errors.png, error_along_arc_length.png, backbones.png."""
    matplotlib.use("Agg")

    label = label or f"{ds.state.model} model vs {ds.source}"
    ok = [r for r in records if r["status"] == "ok"]
    idx = [r["frame"] for r in ok]
    fig, ax = plt.subplots(figsize=(8, 3.6))
    ax.plot(idx, [r["tip_error_mm"] for r in ok], "o-", label="tip error")
    ax.plot(idx, [r["mean_error_mm"] for r in ok], "s-", label="mean shape error")
    bad = [r["frame"] for r in records if r["status"] != "ok"]
    if bad:
        ax.plot(bad, np.zeros(len(bad)), "rx", label="model failed")
    ax.set_xlabel("frame")
    ax.set_ylabel("error (mm)")
    ax.set_title(label)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "per_frame_errors.png", dpi=120)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(8, 3.6))
    for r in ok:
        ax.plot(r["s_mm"], r["along_error_mm"], color="0.75", lw=0.7)
    if profile["s_mm"]:
        ax.plot(profile["s_mm"], profile["mean_mm"], "k-", lw=2, label="mean over frames")
        ax.plot(profile["s_mm"], profile["p90_mm"], "k--", lw=1, label="90th percentile")
    ax.set_xlabel("arc length s (mm)")
    ax.set_ylabel("error at matching arc length (mm)")
    ax.set_title(label)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "error_along_arc_length.png", dpi=120)
    plt.close(fig)

    meas = {f.index: f.points_mm for f in ds.frames}
    fig, axes = plt.subplots(2, 1, figsize=(8, 8), sharex=True)
    cmap = plt.get_cmap("viridis")
    for k, r in enumerate(ok):
        c = cmap(k / max(1, len(ok) - 1))
        q, p = meas[r["frame"]], r["predicted_mm"]
        for ax, (a, b) in zip(axes, ((0, 1), (0, 2))):
            ax.plot(q[:, a], q[:, b], "-", color=c, lw=1.6)
            ax.plot(p[:, a], p[:, b], "--", color=c, lw=1.0)
    axes[0].set_title(f"top view (x-y): measured solid, predicted dashed; {label}")
    axes[1].set_title("side view (x-z)")
    axes[0].set_ylabel("y (mm)")
    axes[1].set_ylabel("z (mm)")
    axes[1].set_xlabel("x (mm)")
    for ax in axes:
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "backbones.png", dpi=120)
    plt.close(fig)
