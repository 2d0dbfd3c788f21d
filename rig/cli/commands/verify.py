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

from pathlib import Path

from rig.bench.modeldata import load_dataset
from rig.bench.verification import format_table, write_outputs
from rig.cli.options import add_data_options, parse_frames
from twin.modelfit import aggregate, along_profile, verify

# ----------------------------------------------------------------------------- outputs


def _run(args) -> int:
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
