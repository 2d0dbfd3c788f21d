"""Figures the tests measure (timings, latencies, counts), printed once at the end of the run.

A test calls :func:`record`; the conftest hook ``pytest_terminal_summary`` prints every
section, whatever order the tests ran in or whichever of them were selected.
"""
from __future__ import annotations

#: section -> {figure name -> value as printed}
FIGURES: dict[str, dict[str, str]] = {}


def record(section: str, key: str, value) -> None:
    """Keep ``value`` (printed with ``str``) under ``section``/``key``; a later value of the same key replaces it."""
    FIGURES.setdefault(section, {})[key] = str(value)
