"""``ctr-bench experiment SEQUENCE --rig RIG.toml --out SESSION_DIR``: run a sequence on a rig and record it.

The rig file (docs/rig-file.md) picks the cameras and the actuator -- the twin,
the Arduino (real or emulated) or a recorded session; the sequence file
(docs/experiments.md) says what to do. The session directory is written as the
experiment goes: Ctrl-C or SIGTERM stop the motors and keep every frame
recorded so far.
"""
from __future__ import annotations

import signal
import sys
from pathlib import Path

from recon.methods import get_method
from recon.params import load_params
from rig.bench.report import report_or_warn
from rig.cli import CLIError
from rig.cli.options import add_report_options, method_name, one_core
from rig.hw.actuator import ActuatorError
from rig.hw.camera import CameraError, EndOfStream
from rig.hw.experiment import (
    ExperimentError,
    ExperimentRunner,
    check_background_first,
    check_limits,
    grab_targets,
    load_sequence,
)
from rig.hw.rigfile import load_rig_file
from rig.live import LiveLogger
from rig.session import SessionError


def _sigterm(signum, frame):
    raise KeyboardInterrupt


def _describe(step) -> str:
    if step.kind == "move":
        what = f"to {step.to}" if step.to is not None else f"by {step.by}"
        return f"move {what}" + ("" if step.wait else " (no wait)")
    if step.kind == "background":
        return f"background {step.frames} pair(s)" + (f", retract to {step.retract}" if step.retract else "")
    if step.kind == "grab":
        return f"grab {step.pairs} pair(s)"
    if step.kind == "dwell":
        return f"dwell {step.seconds:g} s"
    if step.kind == "repeat":
        return f"repeat {step.times} times:"
    return step.kind


def _plan(seq, spec) -> None:
    print(f"rig {spec.name!r} ({spec.source}): cameras {spec.cameras['kind']}, actuator {spec.actuator['kind']}, "
          f"soft limits {spec.limits.to_dict()}")
    print(f"sequence {seq.name!r} ({seq.source}): {seq.background_count} background pairs, {seq.grab_count} frame pairs")

    def show(steps, depth):
        for step in steps:
            print(f"  {'  ' * depth}{step.key:<22s} {_describe(step)}")
            if step.kind == "repeat":
                show(step.steps, depth + 1)

    show(seq.steps, 0)
    print("joints commanded at each grab (insertion mm, rotation deg; ? = not known before a home or absolute move):")
    for i, t in enumerate(grab_targets(seq)):
        print(f"  frame {i:4d}: {t.get('insertion_mm', '?'):>8}  {t.get('rotation_deg', '?'):>8}")


def _run(args) -> int:
    seq = load_sequence(args.sequence)
    spec = load_rig_file(args.rig, serial=args.serial)
    check_limits(seq, spec.limits)
    if args.dry_run:
        _plan(seq, spec)
        return 0
    params = None
    if args.reconstruct:
        check_background_first(seq)

        m = get_method(args.reconstruct)
        params = load_params(m.params_type, args.params, args.reconstruct) if args.params else m.params_type()
        one_core()
    elif args.params:
        raise CLIError("--params needs --reconstruct METHOD")
    out = Path(args.out)
    if (out / "session.json").exists():
        raise CLIError(f"{out}: already holds a session; choose another --out or remove it")
    log = (lambda line: None) if args.quiet else (lambda line: print(line, flush=True))
    on_frame = None
    if args.live:
        if not args.reconstruct:
            raise CLIError("--live needs --reconstruct METHOD (it shows the live reconstruction)")

        # The live logger reads what the runner has just written to OUT/live after each frame.
        watcher = LiveLogger().watch(out, out / "live")
        if watcher is not None:
            def log_frame(index, pair, joints, result):
                watcher("experiment", index + 1, index + 1)

            on_frame = log_frame
    old = signal.signal(signal.SIGTERM, _sigterm)
    runner = None
    status = 0
    try:
        with spec.open(serial=args.serial) as rig:
            print(f"rig {spec.name!r}: cameras {rig.cameras.describe()}, actuator {rig.actuator!r}; "
                  f"recording into {out}", flush=True)
            runner = ExperimentRunner(rig, seq, out, method=args.reconstruct, params=params, log=log,
                                      assume_yes=args.yes, on_frame=on_frame)
            runner.run()
    except KeyboardInterrupt:
        status = 130
        print("ctr-bench experiment: interrupted; motors stopped", file=sys.stderr)
    except EndOfStream as exc:
        print(f"ctr-bench experiment: {exc}: replay ended", file=sys.stderr)
    except (ExperimentError, ActuatorError, CameraError, SessionError, TimeoutError) as exc:
        kept = f" ({len(runner.result.frames)} frame pairs kept in {out})" if runner is not None and runner._writer else ""
        raise CLIError(f"{str(exc).splitlines()[0]}{kept}") from None
    finally:
        signal.signal(signal.SIGTERM, old)
    if runner is not None:
        _report(runner, out)
        if args.reconstruct and not args.no_report and (out / "live" / "summary.json").exists():
            report_or_warn(out / "live")
    return status


def _report(runner, out: Path) -> None:
    st = runner.result.stats()

    def fmt(key, unit="ms", p=1):
        med, mx = st.get(f"{key}_median"), st.get(f"{key}_max")
        return "-" if med is None else f"median {med:.{p}f} {unit}, max {mx:.{p}f} {unit}"

    print(f"\n{st['frames']} frame pairs and {st['background_frames']} background pairs recorded in {out} "
          f"({st['duration_s']:.1f} s)")
    print(f"camera skew: {fmt('skew_ms', p=3)}; settle wait: {fmt('settle_ms')}; grab: {fmt('grab_ms')}; "
          f"write: {fmt('write_ms')}; frame cycle: {fmt('cycle_ms')}")
    if runner.method:
        done = [r for r in runner.live_records if r["status"] != "failed"]
        suspect = sum(1 for r in done if r["status"] == "suspect")
        print(f"live {runner.method}: {len(done)}/{len(runner.live_records)} frames reconstructed ({suspect} suspect), "
              f"{fmt('recon_ms')}; outputs in {out / 'live'}")


def register(sub) -> None:
    p = sub.add_parser(
        "experiment", help="run a sequence of moves and grabs on a rig (twin or physical) and record it",
        description="Open the rig of RIG.toml (cameras and actuator: twin, arduino, opencv or replay; docs/rig-file.md), "
                    "run the steps of SEQUENCE (home, background, move, dwell, grab, repeat; docs/experiments.md) and "
                    "record every frame pair into a session directory as it is grabbed (docs/session-format.md). "
                    "Optionally reconstruct each pair live. Ctrl-C stops the motors and keeps what was recorded.")
    p.add_argument("sequence", help="sequence TOML file, e.g. scenes/paper-sequence.toml")
    p.add_argument("--rig", required=True, help="rig TOML file, e.g. scenes/rig-twin.toml")
    p.add_argument("--out", required=True, help="session directory to create")
    p.add_argument("--reconstruct", metavar="METHOD", default=None, type=method_name,
                   help="reconstruct every pair live with METHOD (paper, fast); outputs in OUT/live/")
    p.add_argument("--params", metavar="FILE", default=None, help="TOML parameter file of the --reconstruct method")
    p.add_argument("--serial", metavar="URL", default=None,
                   help="serial port of an arduino actuator (device, pty or socket://host:port); overrides actuator.port")
    p.add_argument("--yes", action="store_true",
                   help="do not ask the operator to clear the views for background frames (they are clear already)")
    p.add_argument("--dry-run", action="store_true", help="check the files and print the steps; open nothing")
    p.add_argument("--quiet", action="store_true", help="no per-frame lines")
    add_report_options(p)
    p.set_defaults(func=_run)
