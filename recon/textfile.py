"""Reading the text and JSON files the pipeline loads: one owner of their one-line errors.

Every message starts with the file's path and says what the file should have been,
e.g. ``rig.json: not UTF-8 text (binary?), so not a rig calibration JSON file``.
"""

from __future__ import annotations

import json
from pathlib import Path


def read_text(path, what: str, kind: str, error=ValueError) -> str:
    """The UTF-8 text of ``path``; a missing, binary or unreadable file is ``error`` in one line.

    Parameters
    ----------
    path : path
    what : str
        The file's role, e.g. ``"rig calibration"`` ("rig calibration file not found").
    kind : str
        What a binary file is not, e.g. ``"rig calibration JSON file"``.
    error : type
        The exception raised (a ``ValueError`` subclass the CLI prints as one line).

    Returns
    -------
    str
        The file's whole text.

    Raises
    ------
    error
        The file is missing, not UTF-8, a directory or not readable; the message starts with ``path``.
    """
    path = Path(path)
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise error(f"{path}: {what} file not found") from None
    except UnicodeDecodeError:
        raise error(f"{path}: not UTF-8 text (binary?), so not a {kind}") from None
    except (IsADirectoryError, PermissionError) as exc:
        raise error(f"{path}: cannot read the {what} ({exc.__class__.__name__})") from None


def parse_json(text: str, path, error=ValueError):
    """``json.loads(text)``; invalid or too deeply nested JSON is ``error`` in one line naming ``path``.

    Parameters
    ----------
    text : str
        The JSON text (e.g. from :func:`read_text`).
    path : path or str
        The file it came from, named at the start of the error message.
    error : type
        The exception raised (a ``ValueError`` subclass the CLI prints as one line).

    Returns
    -------
    object
        The decoded JSON value (dict, list, str, number, bool or None).

    Raises
    ------
    error
        The text is not valid JSON (message gives the reason and line) or is nested too deeply.
    """
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise error(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    except RecursionError:
        raise error(f"{path}: not valid JSON (nested too deeply)") from None
