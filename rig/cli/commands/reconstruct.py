"""``ctr-bench reconstruct SESSION_DIR --out DIR``: reconstruct (and score) every frame of a session."""
from __future__ import annotations

from pathlib import Path

from rig.cli.options import add_existing_options, add_method_options, add_report_options
from rig.cli.shared import reconstruct_and_report
from rig.rundir import json_text


def _run(args) -> int:
    summary = reconstruct_and_report(Path(args.session), Path(args.out), args)
    if args.json:
        print(json_text({k: v for k, v in summary.items() if k != "per_frame"}))
    return 0 if summary["failed_frames"] < summary["frames"] else 1


def register(sub) -> None:
    p = sub.add_parser("reconstruct", help="reconstruct every frame of a session directory",
                       description="Build the background model from the session's background frames, reconstruct every frame, "
                       "write a CSV per frame, one NPZ and summary.json, and score against ground truth when the session has it.")
    p.add_argument("session", help="session directory (docs/session-format.md)")
    add_method_options(p)
    p.add_argument("--out", required=True, help="output directory (one holding an earlier run is refused unless "
                   "--overwrite or --resume)")
    add_existing_options(p)
    p.add_argument("--json", action="store_true", help="also print the summary (without per-frame list) as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    add_report_options(p)
    p.set_defaults(func=_run)
