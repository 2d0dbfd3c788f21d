"""``ctr-bench verify RECON_DIR --model bending|compliant``: compare a kinematic model with measured backbones.

RECON_DIR is a reconstruction output directory (docs/outputs.md): its
summary.json names the session, whose frames.csv holds the joint values and
whose session.json the nominal robot. RECON_DIR may also be a twin session
directory: its ground-truth backbones are then the measurement (to study the
models apart from reconstruction errors). For every frame with joint values and
a backbone the model's prediction is compared with the measurement; results go
to ``--out`` (default RECON_DIR/verify-<model>): verify.json, verify.csv,
along_arc_length.csv and three PNG plots.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rig.rundir import write_json_atomic

from .options import parse_frames  # the one --frames LIST parser (rig/commands/import_session.py imports it from here)


@dataclass
class Dataset:
    """Measured frames with their recorded joints, and the nominal model."""

    frames: list
    state: object                 # twin.modelfit.ModelState (nominal, or --robot)
    source: str                   # "reconstruction" or "ground truth"
    recon_dir: Path
    session_dir: Path
    robot_source: str
    skipped: list = field(default_factory=list)   # (frame, reason)


def _resolve_session(recon: Path, named: str | None) -> Path:
    if named is None:
        raise ValueError(f"{recon / 'summary.json'}: names no session; pass --session DIR")
    p = Path(named)
    cands = [p] if p.is_absolute() else [Path.cwd() / p, recon / p, recon.parent / p, recon / "session"]
    if not p.is_absolute():
        # a path recorded relative to wherever reconstruct ran: try its tail under the recon dir's parents
        cands += [anc / p.name for anc in (recon, recon.parent)]
    for c in cands:
        if (c / "session.json").exists():
            return c
    raise ValueError(f"{recon / 'summary.json'}: its session {named!r} was not found (looked in {', '.join(str(c) for c in cands[:4])}); pass --session DIR")


def load_dataset(path, session=None, robot=None, model=None, frames=None) -> Dataset:
    """Frames (recorded joints + measured backbone) and the nominal model state.

    Parameters
    ----------
    path : reconstruction output directory, or a twin session with ground truth
    session : session directory overriding the one summary.json names
    robot : robot TOML file overriding the session's nominal robot
    model : "bending" or "compliant" (default: the robot's model)
    frames : set of frame indices to use (default: all)
    """
    from rig.session import Session
    from twin.modelfit import Frame, ModelFitError, ModelState, load_robot_file, robot_from_dict
    from twin.robot import Joints

    path = Path(path)
    if not path.is_dir():
        raise ValueError(f"{path}: not a directory (expected a reconstruction output directory or a session)")
    measured, failed = {}, {}
    if (path / "summary.json").exists():
        from rig.reconstruct import read_run

        # only what the summary lists: never a stale backbones.npz or frame CSV of another run
        summary, measured = read_run(path)
        sdir = Path(session) if session else _resolve_session(path, summary.get("session"))
        failed = {int(r["frame"]): r.get("reason") or "failed" for r in summary.get("per_frame", []) if r.get("status") != "ok"}
        source = "reconstruction"
        sess = Session(sdir)
    elif (path / "session.json").exists():
        sdir = Path(session) if session else path
        sess = Session(sdir)
        if not sess.has_truth:
            raise ValueError(f"{path}: a session without ground truth; reconstruct it first (ctr-bench reconstruct) and verify the output directory")
        for fr in sess.frames:
            t = sess.truth(fr.index)
            if t is not None:
                measured[fr.index] = np.asarray(t["backbone_world_mm"], float)
        source = "ground truth"
    else:
        raise ValueError(f"{path}: neither a reconstruction output directory (summary.json) nor a session directory (session.json)")
    if robot is not None:
        state = load_robot_file(robot)
        robot_source = str(robot)
    else:
        if "robot" not in sess.meta:
            raise ValueError(f"{sess.dir / 'session.json'}: no nominal robot recorded; pass --robot ROBOT.toml")
        if sess.meta["robot"].get("diameters_only"):
            raise ValueError(f"{sess.dir / 'session.json'}: records only the tube diameters (ctr-bench import "
                             "--tube-diameters-mm), not a robot model; pass --robot ROBOT.toml")
        r, m = robot_from_dict(sess.meta["robot"], str(sess.dir / "session.json"))
        state = ModelState(r, m)
        robot_source = str(sess.dir / "session.json")
    if model is not None:
        state = ModelState(state.robot, model, state.offsets)
    if sess.n_tubes and sess.n_tubes != state.robot.n_tubes:
        raise ModelFitError(f"{robot_source}: robot has {state.robot.n_tubes} tubes but the session records joints of {sess.n_tubes}")
    wanted = frames
    frames, skipped = [], []
    for fr in sess.frames:
        if wanted is not None and fr.index not in wanted:
            continue
        if fr.extension_mm is None:
            skipped.append((fr.index, "no joint values"))
        elif fr.index not in measured:
            skipped.append((fr.index, f"no backbone ({failed[fr.index]})" if fr.index in failed else "no backbone"))
        elif len(measured[fr.index]) < 2:
            skipped.append((fr.index, "backbone has fewer than 2 points"))
        else:
            frames.append(Frame(fr.index, Joints(fr.extension_mm, fr.rotation_deg), measured[fr.index]))
    if not frames:
        nj = sum(1 for _, why in skipped if why == "no joint values")
        raise ModelFitError(
            f"{path}: no frame has both joint values and a measured backbone "
            f"({nj} of {len(skipped)} frames without joint values, {len(skipped) - nj} without a backbone)"
        )
    return Dataset(frames, state, source, path, sess.dir, robot_source, skipped)


# ----------------------------------------------------------------------------- outputs
def _f(v, w=7, p=3):
    return f"{v:{w}.{p}f}" if v is not None and np.isfinite(v) else f"{'-':>{w}}"


def format_table(records: list, agg: dict, title: str) -> str:
    lines = [f"{'frame':>5}  {'tip mm':>7}  {'mean mm':>7}  {'max mm':>7}  {'dlen mm':>7}  status"]
    for r in records:
        st = "ok" if r["status"] == "ok" else f"{r['status']}: {r['reason']}"
        lines.append(f"{r['frame']:>5}  {_f(r.get('tip_error_mm'))}  {_f(r.get('mean_error_mm'))}  {_f(r.get('max_error_mm'))}  {_f(r.get('length_error_mm'))}  {st}")
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
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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


def add_data_options(p) -> None:
    """Options shared by verify and fit."""
    p.add_argument("recon", metavar="RECON_DIR", help="reconstruction output directory (or a twin session: its ground truth is the measurement)")
    p.add_argument("--model", choices=("bending", "compliant"), default=None, help="kinematic model (default: the robot's)")
    p.add_argument("--robot", default=None, metavar="ROBOT.toml",
                   help="robot file ([robot] table as in a scene, optional [actuator] offsets) instead of the session's nominal robot")
    p.add_argument("--session", default=None, metavar="DIR", help="session directory (default: the one summary.json names)")
    p.add_argument("--frames", default=None, metavar="LIST", help="use only these frames, e.g. 3,7,10-12 (default: all)")
    p.add_argument("--ds", type=float, default=0.25, metavar="MM", help="model sample spacing (mm, default 0.25)")


def _run(args) -> int:
    from twin.modelfit import aggregate, along_profile, verify

    ds = load_dataset(args.recon, args.session, args.robot, args.model, parse_frames(args.frames))
    out = Path(args.out) if args.out else Path(args.recon) / f"verify-{ds.state.model}"
    records = verify(ds.frames, ds.state, args.ds)
    agg = aggregate(records)
    profile = along_profile(records)
    write_outputs(out, ds, records, agg, profile, plots=not args.no_plots)
    print(format_table(records, agg, f"{ds.state.model} model ({ds.robot_source}) vs {ds.source}: {agg['ok_frames']} frames, "
                                     f"{agg['failed_frames']} model failures, {len(ds.skipped)} frames skipped"))
    for i, why in ds.skipped[:5]:
        print(f"skipped frame {i}: {why}")
    if len(ds.skipped) > 5:
        print(f"... and {len(ds.skipped) - 5} more skipped")
    print(f"\noutputs in {out}: verify.json, verify.csv, along_arc_length.csv" + ("" if args.no_plots else
          ", per_frame_errors.png, error_along_arc_length.png, backbones.png"))
    return 0 if agg["ok_frames"] else 1


def register(sub) -> None:
    p = sub.add_parser("verify", help="compare a kinematic model's predictions with reconstructed backbones",
                       description=__doc__.split("\n\n", 1)[1].strip())
    add_data_options(p)
    p.add_argument("--out", default=None, help="output directory (default RECON_DIR/verify-<model>)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.set_defaults(func=_run)
