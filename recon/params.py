"""Parameter files: nested frozen dataclasses to and from TOML-like dicts.

``ctr-bench reconstruct --params FILE`` reads a TOML file whose tables mirror a
method's parameter dataclass (``[silhouette] threshold = 0.3``); ``ctr-bench
tune`` writes one. Unknown keys and wrong types are errors naming the key.
"""
from __future__ import annotations

import dataclasses
import sys
import typing
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["params_from_dict", "params_to_dict", "load_params", "read_params_file", "dumps_toml"]


def _is_dataclass_type(tp) -> bool:
    return isinstance(tp, type) and dataclasses.is_dataclass(tp)


def params_from_dict(cls, data: dict, source: str = "params", path: str = ""):
    """Build ``cls`` (a frozen dataclass, possibly nested) from ``data``; missing keys keep defaults."""
    if not isinstance(data, dict):
        raise ValueError(f"{source}: {path or 'top level'}: must be a table")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    kwargs = {}
    for key, value in data.items():
        where = f"{path}.{key}" if path else key
        if key not in fields:
            raise ValueError(f"{source}: {where}: unknown parameter (known: {', '.join(sorted(fields))})")
        tp = hints.get(key)
        if _is_dataclass_type(tp):
            kwargs[key] = params_from_dict(tp, value, source, where)
            continue
        default = getattr(cls(), key) if _all_defaults(cls) else None
        kwargs[key] = _coerce(value, tp, default, source, where)
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{source}: {path or 'top level'}: {exc}") from None


def _all_defaults(cls) -> bool:
    return all(f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING for f in dataclasses.fields(cls) if f.init)


def _coerce(value, tp, default, source, where):
    def bad(kind):
        raise ValueError(f"{source}: {where}: must be {kind}, got {value!r}")

    probe = default if default is not None else None
    if tp is bool or isinstance(probe, bool):
        if not isinstance(value, bool):
            bad("true or false")
        return value
    if tp is int or (isinstance(probe, int) and not isinstance(probe, bool)):
        if isinstance(value, bool) or not isinstance(value, int):
            bad("an integer")
        return value
    if tp is float or isinstance(probe, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            bad("a number")
        return float(value)
    if tp is str or isinstance(probe, str):
        if not isinstance(value, str):
            bad("a string")
        return value
    if isinstance(probe, tuple) or isinstance(value, list):
        if not isinstance(value, list):
            bad("a list")
        return tuple(value)
    return value


def params_to_dict(params) -> dict:
    """Nested dict of a parameter dataclass (tuples as lists), ready for TOML/JSON."""
    out = {}
    for f in dataclasses.fields(params):
        v = getattr(params, f.name)
        if dataclasses.is_dataclass(v):
            out[f.name] = params_to_dict(v)
        elif isinstance(v, tuple):
            out[f.name] = list(v)
        else:
            out[f.name] = v
    return out


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def dumps_toml(data: dict, header: str = "") -> str:
    """A small TOML writer for parameter files (scalars, lists, nested tables)."""
    lines = [f"# {h}" for h in header.splitlines()] if header else []

    def emit(table: dict, prefix: str):
        scalars = {k: v for k, v in table.items() if not isinstance(v, dict) and v is not None}
        tables = {k: v for k, v in table.items() if isinstance(v, dict)}
        if prefix and scalars:
            lines.append(f"\n[{prefix}]")
        for k, v in scalars.items():
            lines.append(f"{k} = {_toml_value(v)}")
        for k, v in tables.items():
            emit(v, f"{prefix}.{k}" if prefix else k)

    emit(data, "")
    return "\n".join(lines).lstrip("\n") + "\n"


def read_params_file(path, method: str | None = None) -> dict:
    """The tables of a TOML parameter file, without its top-level ``method`` key.

    Raises ValueError (one line, naming the file) when the file is missing, is
    not TOML, or was written for another method than ``method``.
    """
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"{path}: parameter file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML ({exc})") from None
    written_for = data.pop("method", None)
    if method is not None and written_for is not None and written_for != method:
        raise ValueError(f"{path}: parameters of method {written_for!r}, not {method!r} (pass --method {written_for})")
    return data


def load_params(cls, path, method: str | None = None):
    """Read a TOML parameter file into ``cls`` (see :func:`read_params_file`); unset keys keep defaults."""
    return params_from_dict(cls, read_params_file(path, method), source=str(path))
