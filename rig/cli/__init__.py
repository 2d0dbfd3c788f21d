"""The ``ctr-bench`` command line.

Each sub-command lives in its own module under ``rig/cli/commands/`` exposing
``register(subparsers)``, which adds its parser and sets ``func`` to a callable
taking the parsed arguments and returning an exit code. Errors a user can fix
(bad files, bad options) are raised as :class:`CLIError` or ``ValueError`` and
printed as one line, never as a traceback.
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys

__all__ = ["main", "CLIError", "COMMANDS"]

#: Sub-command modules, in the order ``ctr-bench --help`` lists them.
COMMANDS = ("run", "render", "reconstruct", "import_session", "bench", "render_bench", "calibrate", "experiment", "report",
            "export", "verify", "fit", "tune", "scenes", "dataset")


class CLIError(Exception):
    """A user-facing error: printed as ``ctr-bench <cmd>: error: <message>``."""


def _version() -> str:
    """The installed distribution's version (``unknown`` when run from a tree that is not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("ctr-bench")
    except PackageNotFoundError:
        return "unknown"


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ctr-bench",
        description="Real-time 3D reconstruction of concentric tube robots from two orthogonal cameras, "
        "with a digital twin and a hardware layer.",
    )
    parser.add_argument("--version", action="version", version=f"ctr-bench {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"rig.cli.commands.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"rig.cli.commands.{name}":
                continue  # that command is not part of this build
            raise
        module.register(sub)
    return parser


def main(argv=None) -> int:
    """Entry point of the ``ctr-bench`` console script."""
    # Reconstruction figures are one-core figures: keep BLAS/OpenMP pools at one thread
    # (must happen before numpy is imported).
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print(f"ctr-bench {args.command}: interrupted", file=sys.stderr)
        return 130
    except (CLIError, ValueError, FileNotFoundError, TimeoutError, OSError) as exc:
        if os.environ.get("CTR_BENCH_DEBUG"):
            raise
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else exc.__class__.__name__
        print(f"ctr-bench {args.command}: error: {msg}", file=sys.stderr)
        return 2

