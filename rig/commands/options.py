"""Option syntaxes shared by the sub-commands: one parser per syntax, so that one option name means one thing.

* ``--frames LIST`` (verify, fit) and ``--background-frames LIST`` (import) select
  frames by number: ``3,7,10-12``; :func:`parse_frames` reads both.
* ``--n-frames N`` and ``--n-background-frames N`` (render, run, bench,
  render-bench) are counts; :func:`count` checks them when the options are read.
* ``--params FILE`` is a TOML parameter file of a reconstruction method (run,
  reconstruct, experiment, tune); ``fit --fit-params LIST`` names the robot
  parameters to estimate.

Not a sub-command: rig/cli.py registers only the modules it lists.
"""
from __future__ import annotations

__all__ = ["parse_frames", "count"]


def parse_frames(text: str | None, option: str = "--frames") -> set | None:
    """``"3,7,10-12"`` -> ``{3, 7, 10, 11, 12}`` (frame numbers, from 0); None -> None (all frames).

    Raises
    ------
    ValueError
        Not numbers and ``a-b`` ranges, or no frame at all; the message names ``option``.
    """
    if text is None:
        return None
    out = set()
    try:
        for part in text.split(","):
            part = part.strip()
            if not part:
                continue
            a, sep, b = part.partition("-")
            out.update(range(int(a), int(b) + 1) if sep else [int(a)])
    except ValueError:
        raise ValueError(f"{option} {text!r}: expected frame numbers and ranges like 3,7,10-12") from None
    if not out:
        raise ValueError(f"{option} {text!r}: no frames")
    return out


def count(minimum: int):
    """An argparse ``type`` for a whole number >= ``minimum`` (refused when the options are read, before any work)."""
    import argparse

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {value}")
        return value

    return parse
