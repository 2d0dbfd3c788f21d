"""What several sub-commands do the same way: reconstruct a session into a run directory, print its table and
build its report (``run`` and ``reconstruct``)."""
from __future__ import annotations

from pathlib import Path

from rig.bench.reconstruct import format_table, reconstruct_session
from rig.bench.report import report_or_warn
from rig.cli.options import existing_mode, method_params, one_core
from rig.live import LiveLogger
from rig.progress import Progress

__all__ = ["reconstruct_and_report"]


def reconstruct_and_report(session_dir: Path, out: Path, args) -> dict:
    params = method_params(args, session_dir)
    one_core()
    progress = Progress(enabled=not getattr(args, "quiet", False))
    live = None
    if getattr(args, "live", False):
        live = LiveLogger()
    try:
        summary = reconstruct_session(session_dir, out, method=args.method, params=params, existing=existing_mode(args),
                                      progress=live.watch(session_dir, out, progress) if live else progress)
    finally:
        progress.close()
    print(format_table(summary))
    for note in summary.get("session_notes") or ():
        print(f"note: {note}")
    print(f"\noutputs in {out}: frames/*.csv, frames.jsonl, frames.csv, backbones.npz, summary.json")
    if not getattr(args, "no_report", False):
        report_or_warn(out)
    return summary
