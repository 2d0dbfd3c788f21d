"""``ctr-bench fit RECON_DIR --model M --fit-params LIST --out robot_fitted.toml``: calibrate a kinematic model.

Estimates robot parameters by nonlinear least squares (scipy.optimize.least_squares,
robust loss) over every frame with joint values and a measured backbone: the
residuals are the measured backbone points minus the model backbone at matching
arc lengths, plus the tip. Reports each value with its 95 % confidence interval
(cov = s^2 (J^T J)^-1 at the solution, and a frame-clustered one that allows
correlated errors along a backbone). With --holdout-every K every K-th frame is left
out of the fit and the nominal and fitted models are compared on those frames.
Writes the fitted robot as a TOML robot file (its [robot] table is a scene's; its
[actuator] table holds joint offsets) and a JSON report next to it.

Only ratios of the tubes' E I are identifiable from shapes without external
loads: fit ``stiffness_ratio``, not every tube's ``youngs_modulus_gpa``.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from rig.bench.modeldata import load_dataset
from rig.cli.options import add_data_options, parse_frames
from rig.tables import cell
from twin.modelfit import aggregate, fit, parse_params, robot_to_toml, split_holdout, verify

PARAMS_EPILOG = """parameter names (--fit-params, comma separated; <tube> is a tube name or index, 0 = outermost):
  <tube>.precurvature_per_mm   <tube>.curved_length_mm   <tube>.youngs_modulus_gpa (relative to the other tubes)
  <tube>.length_mm, <tube>.poisson_ratio (compliant model: transmission twist, E I / G J)
  stiffness_ratio (2 tubes: E I inner / E I outer)   stiffness_ratio.<tube> (E I tube / E I outermost)
  rotation_offset_deg.<tube>   insertion_offset_mm.<tube>   (true joint = recorded + offset)
  base.position_mm (x, y, z world)   base.rotation_deg (rotation vector about the base's x, y, z)

example:
  ctr-bench fit out/plastic --model compliant --robot scenes/plastic-nominal.toml \\
      --fit-params inner.precurvature_per_mm,stiffness_ratio,rotation_offset_deg.inner --holdout-every 4 \\
      --out robot_fitted.toml
  ctr-bench verify out/plastic --model compliant --robot robot_fitted.toml
"""


def _param_table(res) -> str:
    lines = [f"{'parameter':<32} {'start':>12} {'fitted':>12} {'95% CI':>27} {'95% CI (frames)':>27}  unit"]
    for row in res.table():
        ci = row["ci95"]
        cf = row["ci95_frames"]

        def g(v):
            return f"{v:.6g}" if v is not None else "-"

        lines.append(f"{row['name']:<32} {row['initial']:>12.6g} {row['value']:>12.6g} "
                     f"{'[' + g(ci[0]) + ', ' + g(ci[1]) + ']':>27} {'[' + g(cf[0]) + ', ' + g(cf[1]) + ']':>27}  {row['unit']}")
    return "\n".join(lines)


def _compare_table(name: str, nom: dict, fit: dict) -> str:
    def row(label, key):
        return f"  {label:<38} {cell(nom.get(key), 9)} {cell(fit.get(key), 9)}"

    return "\n".join([
        f"{name}: {fit['ok_frames']} frames", f"  {'':<38} {'nominal':>9} {'fitted':>9}",
        row("tip error mean (mm)", "tip_error_mm_mean"), row("tip error max (mm)", "tip_error_mm_max"),
        row("mean shape error mean (mm)", "mean_error_mm_mean"), row("mean shape error max (mm)", "mean_error_mm_max"),
        row("RMS error at matching arc length (mm)", "along_error_mm_rms"),
    ])


def _run(args) -> int:
    out = Path(args.out)
    if out.suffix != ".toml":
        raise ValueError(f"--out {out}: expected a .toml robot file name")
    ds = load_dataset(args.recon, args.session, args.robot, args.model, parse_frames(args.frames))
    params = parse_params(args.fit_params, ds.state)  # bad names fail before any work
    fit_frames, held = split_holdout(ds.frames, args.holdout_every)
    print(f"fitting {len(params)} parameters of the {ds.state.model} model to {len(fit_frames)} frames "
          f"({ds.source}; {len(held)} held out, {len(ds.skipped)} skipped); starting from {ds.robot_source}")
    t0 = time.perf_counter()
    res = fit(fit_frames, ds.state, params, loss=args.loss, f_scale_mm=args.f_scale, step_mm=args.step,
              tip_weight=args.tip_weight, ds_mm=args.ds, verbose=0)
    secs = time.perf_counter() - t0
    print(f"done in {secs:.1f} s ({res.nfev} evaluations over all fit frames plus finite-difference Jacobians; RMS residual {res.rms_mm:.3f} mm over {res.n_residuals} residuals): {res.message}")
    print(_param_table(res))
    for w in res.warnings:
        print(f"warning: {w}")
    for i, why in res.dropped:
        print(f"frame {i} left out: the starting model fails there ({why})")

    report = {"format": "ctr-bench-fit", "version": 1, "model": ds.state.model, "measured": ds.source,
              "recon_dir": str(ds.recon_dir), "session": str(ds.session_dir), "start_robot": ds.robot_source,
              "loss": args.loss, "f_scale_mm": args.f_scale, "step_mm": args.step, "tip_weight": args.tip_weight,
              "holdout": args.holdout_every, "fit_frames": res.frames, "held_out_frames": [f.index for f in held],
              "dropped_frames": [{"frame": i, "reason": w} for i, w in res.dropped],
              "parameters": res.table(), "rms_mm": res.rms_mm, "nfev": res.nfev, "seconds": secs,
              "message": res.message, "warnings": res.warnings}
    sets = [("fit frames", fit_frames)] + ([("held-out frames", held)] if held else [])
    for label, frs in sets:
        nom, fitted = aggregate(verify(frs, ds.state, args.ds)), aggregate(verify(frs, res.state, args.ds))
        print()
        print(_compare_table(label, nom, fitted))
        report["held_out" if label.startswith("held") else "training"] = {"nominal": nom, "fitted": fitted}

    fit_table = {"from": str(ds.recon_dir), "measured": ds.source, "rms_mm": res.rms_mm}
    for row in res.table():
        fit_table[row["name"]] = row["value"]
        if row["ci95"][0] is not None:
            fit_table[row["name"] + ".ci95"] = row["ci95"]
    header = (
        f"Robot fitted by ctr-bench fit ({ds.state.model} model) to {len(res.frames)} frames of {ds.recon_dir} ({ds.source}),\n"
        f"starting from {ds.robot_source}; parameters: {', '.join(res.names)}.\n"
        "Use: ctr-bench verify RECON_DIR --robot THIS_FILE (joint offsets in [actuator] are applied), or copy the\n"
        "[robot] table and its [[robot.tubes]] into a scene to render the twin with this robot; a scene has no\n"
        "[actuator] table: add the offsets to the scene's joint values instead."
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(robot_to_toml(res.state, header=header, fit_table=fit_table))
    rep = out.with_suffix(".json")
    rep.write_text(json.dumps(report, indent=2) + "\n")
    print(f"\nfitted robot written to {out}; report {rep}")
    return 0


def register(sub) -> None:
    p = sub.add_parser("fit", help="estimate robot parameters from reconstructed backbones (model calibration)",
                       description=__doc__.split("\n\n", 1)[1].strip(), epilog=PARAMS_EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    add_data_options(p)
    # not --params (a method's parameter FILE in run, reconstruct, experiment, tune) nor --holdout (tune's held-out scenes)
    p.add_argument("--fit-params", required=True, metavar="LIST", help="comma-separated robot parameters to estimate (below)")
    p.add_argument("--holdout-every", type=int, default=None, metavar="K",
                   help="hold every K-th frame out of the fit and test on them")
    p.add_argument("--loss", default="soft_l1", choices=("linear", "soft_l1", "huber", "cauchy", "arctan"),
                   help="least-squares loss (default soft_l1: robust to reconstruction outliers)")
    p.add_argument("--f-scale", type=float, default=1.0, metavar="MM", help="residual scale of the robust loss (mm, default 1)")
    p.add_argument("--step", type=float, default=1.0, metavar="MM", help="resample measured backbones at this arc-length step (mm, default 1)")
    p.add_argument("--tip-weight", type=float, default=1.0, help="weight of the tip residual relative to one point's (default 1)")
    p.add_argument("--out", required=True, metavar="ROBOT.toml", help="fitted robot file to write (a JSON report goes next to it)")
    p.set_defaults(func=_run)
