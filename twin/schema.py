"""Typed, checked access to TOML tables: the schema helpers every twin file reader shares.

Scene files (:mod:`twin.scene`), robot files (:mod:`twin.robotfile`), board files and the
rig's own files read their tables through :class:`Table`, so every error is one line
naming the file, the key and what is wrong (``scenes/x.toml: robot.tubes[1].outer_diameter_mm:
must be > 0, got -1``), and an unknown key is an error.
"""
from __future__ import annotations

import sys

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

from recon.textfile import read_text

__all__ = ["SceneError", "Table", "REQUIRED", "POSITIVE", "NONNEGATIVE", "read_toml"]


class SceneError(ValueError):
    """A scene file (or a file read with the same helpers) that cannot be used; the message names file and key."""


class Table:
    """Typed, checked access to one TOML table; unknown keys are errors."""

    def __init__(self, data, path: str, source: str):
        if not isinstance(data, dict):
            raise SceneError(f"{source}: {path or 'top level'}: must be a table, got {type(data).__name__}")
        self.data = data
        self.path = path
        self.source = source
        self.used: set = set()

    def _key(self, key):
        return f"{self.path}.{key}" if self.path else key

    def fail(self, key, why):
        raise SceneError(f"{self.source}: {self._key(key)}: {why}")

    def get(self, key, default=None, kind=None, check=None, why=None):
        """Value of ``key`` (``default`` when absent; :data:`REQUIRED` makes it an error).

        ``kind`` is ``float`` (finite, returned as float), ``int``, ``str``, ``bool`` or
        ``("vec", n)`` (a list of ``n`` finite numbers, None for any length, returned as
        floats); ``check(value)`` false fails with ``why``.
        """
        self.used.add(key)
        if key not in self.data:
            if default is REQUIRED:
                self.fail(key, "missing (required)")
            return default
        value = self.data[key]
        if kind is float:
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                self.fail(key, f"must be a number, got {value!r}")
            # TOML has inf and nan literals: a length of inf renders and then overflows the methods.
            if not _finite_number(value):
                self.fail(key, f"must be finite (and within +-{_MAX_MAGNITUDE:g}), got {value!r}")
            value = float(value)
        elif kind is int:
            if isinstance(value, bool) or not isinstance(value, int):
                self.fail(key, f"must be an integer, got {value!r}")
        elif kind is str:
            if not isinstance(value, str):
                self.fail(key, f"must be a string, got {value!r}")
        elif kind is bool:
            if not isinstance(value, bool):
                self.fail(key, f"must be true or false, got {value!r}")
        elif isinstance(kind, tuple) and kind[0] == "vec":
            n = kind[1]
            if (
                not isinstance(value, list)
                or (n is not None and len(value) != n)
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
            ):
                self.fail(key, f"must be a list of {n if n is not None else 'some'} numbers, got {value!r}")
            if not all(_finite_number(v) for v in value):
                self.fail(key, f"must be finite (and within +-{_MAX_MAGNITUDE:g}), got {value!r}")
            value = [float(v) for v in value]
        if check is not None and not check(value):
            self.fail(key, f"{why}, got {value!r}")
        return value

    def table(self, key, required=False):
        self.used.add(key)
        if key not in self.data:
            if required:
                self.fail(key, "missing table (required)")
            return Table({}, self._key(key), self.source)
        return Table(self.data[key], self._key(key), self.source)

    def tables(self, key):
        self.used.add(key)
        items = self.data.get(key, [])
        if not isinstance(items, list):
            self.fail(key, "must be an array of tables ([[...]])")
        return [Table(item, f"{self._key(key)}[{i}]", self.source) for i, item in enumerate(items)]

    def done(self):
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            self.fail(unknown[0], "unknown key")


#: Largest magnitude of a scene number (mm, px, ...): far beyond any rig, and small enough that
#: the squares and products of geometry (norms, projections) cannot overflow.
_MAX_MAGNITUDE = 1e12


def _finite_number(value) -> bool:
    """Whether the number ``value`` (int or float) is finite and within :data:`_MAX_MAGNITUDE`."""
    return abs(value) <= _MAX_MAGNITUDE  # False for NaN and inf (and no float conversion of big ints)


#: ``default`` of :meth:`Table.get` for a key that must be present.
REQUIRED = object()
POSITIVE = (lambda v: v > 0, "must be > 0")
NONNEGATIVE = (lambda v: v >= 0, "must be >= 0")


def read_toml(path, what: str, error=SceneError) -> dict:
    """Parse a TOML file; ``error`` (one line) names the file and says whether it is missing, unreadable or not TOML."""
    role = what.removesuffix(" file")
    text = read_text(path, role, f"{role} TOML file", error)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path}: not valid TOML ({exc})") from None
