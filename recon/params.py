"""Parameter files: nested frozen dataclasses to and from TOML-like dicts, and the one TOML writer.

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

import numpy as np
import tomli_w

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
_POSITIVE = frozenset({"max_ray_gap_mm", "footprint_scale"})


def params_from_dict(cls, data: dict, source: str = "params", path: str = ""):
    """Build ``cls`` (a frozen dataclass, possibly nested) from ``data``; missing keys keep defaults.

    Every value is checked before the dataclass sees it: its type, finite (TOML has
    ``inf`` and ``nan``), >= 0 (> 0 for steps and gaps, see ``_POSITIVE``), and a carving
    resolution within the memory bound (:func:`recon.memory.carving_bytes`).

    Parameters
    ----------
    cls : type
        A method's parameter dataclass (e.g. :class:`recon.paper.PaperParams`).
    data : dict
        Its fields by name, a nested dataclass as a nested dict (a TOML table). Values
        are in the units their field names say (mm, px, voxels).
    source : str, optional
        The file or option the values came from, for messages.
    path : str, optional
        Dotted key of ``data`` in the whole document (nested tables), for messages.

    Returns
    -------
    cls
        The parameters.

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
    """Nested dict of a parameter dataclass (tuples as lists), ready for TOML/JSON.

    Parameters
    ----------
    params : dataclass instance
        A method's parameters (nested dataclasses become nested dicts).

    Returns
    -------
    dict
        Field name -> value; :func:`params_from_dict` reads it back (None values are
        left out of a TOML file by :func:`dumps_toml`).
    """
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


def _plain(value, where: str):
    """``value`` as the Python types tomli_w writes (numpy scalars and arrays converted); TypeError naming ``where``."""
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            key = f"{where}.{k}" if where else str(k)
            if not isinstance(k, str):
                raise TypeError(f"{key}: a TOML key must be a string, got {type(k).__name__}")
            if v is not None:  # TOML has no null: an unset optional value leaves its key out
                out[k] = _plain(v, key)
        return out
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, (list, tuple)):
        return [_plain(v, f"{where}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, np.generic):
        value = value.item()  # np.float64 -> float, np.int64 -> int, np.bool_ -> bool, np.str_ -> str
    if isinstance(value, (bool, int, float, str)):
        return value
    raise TypeError(f"{where or 'top level'}: cannot write {type(value).__name__} to TOML")


def dumps_toml(data: dict, header: str = "") -> str:
    """TOML text of ``data`` (tomli_w), after an optional comment header: the one TOML writer of ctr-bench.

    Parameter files, robot files (:mod:`twin.robotfile`) and generated scenes
    (:mod:`twin.scenegen`) are written through it.

    Parameters
    ----------
    data : dict
        Tables (dicts, nested), arrays (lists, tuples, numpy arrays) and scalars (bool,
        int, float, str and their numpy types). A table's None values are left out:
        TOML has no null.
    header : str, optional
        Comment text put before the document, one ``# `` line per line (``#`` for an
        empty one) and a blank line after it.

    Returns
    -------
    str
        The document; :mod:`tomllib` reads it back to ``data`` (numpy values as Python ones).

    Raises
    ------
    TypeError
        One line naming the key of a value TOML cannot hold (None in an array, an object).
    """
    if not isinstance(data, dict):
        raise TypeError(f"TOML document: must be a dict of keys and tables, got {type(data).__name__}")
    text = tomli_w.dumps(_plain(data, ""))
    if not header:
        return text
    return "".join(f"# {line}".rstrip() + "\n" for line in header.splitlines()) + "\n" + text


def read_params_file(path, method: str | None = None) -> dict:
    """The tables of a TOML parameter file, without its top-level ``method`` key.

    Parameters
    ----------
    path : str or Path
        The parameter file (``ctr-bench tune`` writes them).
    method : str, optional
        The method the parameters are for; a file written for another one is refused.

    Returns
    -------
    dict
        The file's keys and tables, unchecked (:func:`params_from_dict` checks them).

    Raises
    ------
    ValueError
        One line naming the file: missing or unreadable, not TOML, or written for
        another method than ``method``.
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
    """Read a TOML parameter file into ``cls`` (see :func:`read_params_file`); unset keys keep defaults.

    Parameters
    ----------
    cls : type
        The method's parameter dataclass.
    path : str or Path
        The parameter file.
    method : str, optional
        The method the parameters are for (see :func:`read_params_file`).

    Returns
    -------
    cls

    Raises
    ------
    ValueError
        One line naming the file and the key (:func:`params_from_dict`).
    """
    return params_from_dict(cls, read_params_file(path, method), source=str(path))
