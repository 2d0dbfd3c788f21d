"""Parameter files: nested frozen dataclasses to and from TOML-like dicts.

``ctr-bench reconstruct --params FILE`` reads a TOML file whose tables mirror a
method's parameter dataclass (``[silhouette] threshold = 0.3``); ``ctr-bench
tune`` writes one. Unknown keys, wrong types, non-finite or negative numbers and a
carving grid beyond the memory bound (:mod:`recon.memory`) are errors naming the key.
"""
from __future__ import annotations

import dataclasses
import math
import sys
import types
import typing
from pathlib import Path

from .memory import carving_bytes, check_memory
from .textfile import read_text

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["params_from_dict", "params_to_dict", "load_params", "read_params_file", "dumps_toml"]


def _is_dataclass_type(tp) -> bool:
    return isinstance(tp, type) and dataclasses.is_dataclass(tp)


#: Parameters that must be > 0 beyond what their dataclasses check: zero would refuse every
#: frame (a ray gap) or stall a loop (a step, a footprint). Every other number must be >= 0:
#: no parameter of ctr-bench's methods is signed.
_POSITIVE = frozenset({"max_ray_gap_mm", "sparse_step_px", "footprint_scale"})


def params_from_dict(cls, data: dict, source: str = "params", path: str = ""):
    """Build ``cls`` (a frozen dataclass, possibly nested) from ``data``; missing keys keep defaults.

    Every value is checked before the dataclass sees it: its type, finite (TOML has
    ``inf`` and ``nan``), >= 0 (> 0 for steps and gaps, see ``_POSITIVE``), and a carving
    resolution within the memory bound (:func:`recon.memory.carving_bytes`).

    Raises
    ------
    ValueError
        One line: ``"<source>: <table.key>: <what is wrong>"``.
    """
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
        table_type = _base_type(tp)[0]  # ``SubvoxelParams | None`` is a table too
        if _is_dataclass_type(table_type):
            kwargs[key] = params_from_dict(table_type, value, source, where)
            continue
        default = getattr(cls(), key) if _all_defaults(cls) else None
        kwargs[key] = _checked(key, _coerce(value, tp, default, source, where), source, where)
    try:
        params = cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{source}: {path or 'top level'}: {exc}") from None
    _check_memory(params, source, path)
    return params


def _all_defaults(cls) -> bool:
    return all(f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING for f in dataclasses.fields(cls) if f.init)


def _base_type(tp) -> tuple:
    """``(type, optional)`` behind a hint: ``tuple | None`` is ``(tuple, True)``; a wider union's type is None."""
    if isinstance(tp, types.UnionType) or typing.get_origin(tp) is typing.Union:
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        base = (typing.get_origin(args[0]) or args[0]) if len(args) == 1 else None
        return base, len(args) < len(typing.get_args(tp))
    return typing.get_origin(tp) or tp, False


def _coerce(value, tp, default, source, where):
    """``value`` as the parameter's type (a hint, else its default's type); ValueError naming ``where``."""
    def bad(kind):
        raise ValueError(f"{source}: {where}: must be {kind}, got {_show(value)}")

    probe = default
    tp, optional = _base_type(tp)
    if value is None and optional:  # only from a dict: TOML has no null
        return None
    if tp is bool or isinstance(probe, bool):
        if not isinstance(value, bool):
            bad("true or false")
        return value
    if tp is int or (isinstance(probe, int) and not isinstance(probe, bool)):
        if isinstance(value, bool) or not isinstance(value, int):
            bad("an integer")
        return value
    if tp is float or isinstance(probe, float):
        if not _is_number(value):
            bad("a number")
        try:
            return float(value)
        except OverflowError:  # an integer beyond the float range
            bad("a finite number")
    if tp is str or isinstance(probe, str):
        if not isinstance(value, str):
            bad("a string")
        return value
    if tp is tuple or isinstance(probe, tuple) or isinstance(value, list):
        if not isinstance(value, list):
            bad("a list")
        return tuple(value)
    return value


def _show(value, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters: a message stays one readable line."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _checked(key: str, value, source: str, where: str):
    """``value`` (or each number of a list) finite, 64-bit, >= 0 (> 0 for ``_POSITIVE``); ValueError naming ``where``."""
    for v in value if isinstance(value, tuple) else (value,):
        if not _is_number(v):
            continue
        if isinstance(v, int) and not -(2**63) <= v < 2**63:
            why = "must be a 64-bit integer"
        elif isinstance(v, float) and not math.isfinite(v):
            why = "must be a finite number"
        elif key in _POSITIVE and not v > 0:
            why = "must be > 0"
        elif v < 0:
            why = "must be >= 0"
        else:
            continue
        raise ValueError(f"{source}: {where}: {why}, got {_show(value)}")
    return value


def _check_memory(params, source: str, path: str) -> None:
    """Refuse a carving grid beyond the memory bound (:func:`recon.memory.check_memory`)."""
    from .carving import CarvingParams  # noqa: PLC0415 (cv2 only when parameters are read)

    if not isinstance(params, CarvingParams):
        return
    for key in ("resolution", "coarse_resolution"):
        n = int(getattr(params, key))
        where = f"{path}.{key}" if path else key
        check_memory(carving_bytes(n), f"{source}: {where}", f"carving {n}^3 voxels", ValueError)


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

    Raises ValueError (one line, naming the file) when the file is missing or
    unreadable, is not TOML, or was written for another method than ``method``.
    """
    path = Path(path)
    text = read_text(path, "parameter", "TOML parameter file")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML ({exc})") from None
    written_for = data.pop("method", None)
    if written_for is not None and not isinstance(written_for, str):
        raise ValueError(f"{path}: method: must be a method name, got {written_for!r}")
    if method is not None and written_for is not None and written_for != method:
        raise ValueError(f"{path}: parameters of method {written_for!r}, not {method!r} (pass --method {written_for})")
    return data


def load_params(cls, path, method: str | None = None):
    """Read a TOML parameter file into ``cls`` (see :func:`read_params_file`); unset keys keep defaults."""
    return params_from_dict(cls, read_params_file(path, method), source=str(path))
