"""The run directory: its formats, the one writer of a run and the one reader of it.

One owner for these formats (docs/outputs.md); :class:`RunWriter` writes them
(``reconstruct``, ``run``, the bench's runs and ``experiment``'s ``live/``) and
:func:`read_run` reads them back (``report``, ``verify``, ``fit``, ``export``):

* ``frames.jsonl``, the run's journal: line 1 is a header (``format``
  ``"ctr-bench-frames"``, ``run_id``, ``method``, ``params``, ``selfcheck``,
  ``session``, ``mm_per_px``); every further line is the record of one finished
  frame (the per-frame dict of summary.json), appended and flushed as the frame
  finishes and fsynced every :data:`FSYNC_EVERY_S`. A killed run keeps every
  line it flushed; ``--resume`` and ``report`` rebuild the run from it.
* ``frames/NNNNNN.csv`` (:mod:`rig.backbone_csv`) and ``frames.csv``: each
  finished frame's backbone and table row, written with its journal line.
* ``summary.json``: the aggregates with the run's ``run_id``, ``complete`` and
  the ``files`` it wrote, replaced atomically (:func:`write_json_atomic`).
* ``backbones.npz``: every backbone, written at the end; the summary records its SHA-1.

A frame's record describes its backbone (:func:`describe_result`) and, where
there is ground truth, its errors (:func:`rig.scoring.score_frame`: over what every camera
sees, for every command that scores).

A directory holding an earlier run's files (:func:`earlier_files`) is refused
(:func:`check_claim`) unless the earlier run is removed (``overwrite``: exactly
those files, nothing a user put there) or continued (``resume``: the same
method, parameters, self-check and session, else the difference is named).

JSON has no NaN or infinity: every JSON written here (summary, journal lines)
goes through :func:`json_safe`, so an unknown figure is ``null``, never an
aborted write.
"""
from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import os
import re
import secrets
import shutil
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from recon.params import params_to_dict
from recon.selfcheck import SelfCheckParams
from rig.backbone_csv import FrameTable, read_backbone_csv, write_backbone_csv

__all__ = ["summarize", "params_as_dict", "finite_or_none", "SUMMARY", "JOURNAL", "TABLE", "BACKBONES", "FRAMES_DIR", "RunDirError", "WriteError", "writing",
           "json_safe", "json_text", "write_json_atomic", "write_summary_json", "new_run_id", "earlier_files", "remove_files",
           "check_claim", "journal_header", "Journal", "read_journal", "read_summary", "write_backbones_npz", "read_backbones_npz",
           "MODES", "last_journal_record", "RunWriter", "read_run", "kept_frames", "describe_result",
           "jump_record", "record_doubt", "record_backbone", "SUMMARY_EVERY_S", "SUMMARY_COST_FACTOR"]

SUMMARY = "summary.json"
JOURNAL = "frames.jsonl"
TABLE = "frames.csv"
BACKBONES = "backbones.npz"
FRAMES_DIR = "frames"
JOURNAL_FORMAT = "ctr-bench-frames"
SUMMARY_FORMAT = "ctr-bench-summary"
#: What a run does with a directory holding an earlier run.
MODES = ("refuse", "overwrite", "resume")
#: The journal is synced to disk at most this often (a flush per line already survives SIGKILL;
#: the sync bounds what a power cut can take).
FSYNC_EVERY_S = 2.0
#: summary.json is rewritten at most this often while a run goes (the journal has every frame at once)...
SUMMARY_EVERY_S = 5.0
#: ...and at most once per this many times its own writing time: its size grows with the run, its share of the time does not.
SUMMARY_COST_FACTOR = 20.0

# Files (relative to the run directory) that a run, or a report built on it, writes.
_RUN_FILES = (SUMMARY, JOURNAL, TABLE, BACKBONES, f".{SUMMARY}.tmp", f".{JOURNAL}.tmp", f".{BACKBONES}.tmp.npz")
_RUN_DIRS = ("report", ".report-tmp")
_FRAME_FILE = re.compile(r"\d{6}\.csv")
_MESH_FILE = re.compile(r"\d{6}(_both)?\.(ply|obj|glb)")


class RunDirError(FileExistsError):
    """An output directory this run may not write into (holds another run); one line naming it.

    A ``FileExistsError`` rather than a ``ValueError``: callers that turn a
    ``ValueError`` into failed frames must not take a refusal for one.
    """


class WriteError(OSError):
    """An output file that could not be written (disk full, permission): one line naming the file.

    Parameters
    ----------
    path : path
        The file being written.
    exc : OSError
        What the system said.
    """

    def __init__(self, path, exc: OSError):
        super().__init__(exc.errno, exc.strerror or str(exc))
        self.filename = str(path)
        self.note = ""

    def __str__(self) -> str:
        code = f" [errno {self.errno}]" if self.errno is not None else ""
        return f"{self.filename}: cannot write: {self.strerror}{code}" + (f"; {self.note}" if self.note else "")


@contextmanager
def writing(path):
    """Context in which an ``OSError`` becomes a :class:`WriteError` naming ``path``.

    An ``OSError`` raised on an open file (``write``, ``flush``) names no file:
    "[Errno 28] No space left on device" alone does not say what was being written.
    """
    try:
        yield
    except WriteError:
        raise
    except OSError as exc:
        raise WriteError(path, exc) from exc


# ----------------------------------------------------------------------------- JSON
def json_safe(o):
    """``o`` with every non-finite float (NumPy's too) replaced by None, NumPy scalars and arrays as Python ones."""
    if isinstance(o, dict):
        return {k: json_safe(v) for k, v in o.items()}
    if isinstance(o, np.ndarray):
        return json_safe(o.tolist())
    if isinstance(o, (list, tuple)):
        return [json_safe(v) for v in o]
    if isinstance(o, (float, np.floating)):
        return float(o) if np.isfinite(o) else None
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.bool_):
        return bool(o)
    return o


def _json_default(o):
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serializable: {type(o).__name__}")


def json_text(data, indent: int | None = 2) -> str:
    """JSON of ``data`` with unknown (non-finite) numbers as null; one line when ``indent`` is None."""
    return json.dumps(json_safe(data), indent=indent, allow_nan=False, default=_json_default)


def write_json_atomic(path, data) -> None:
    """Write JSON to a temporary name and rename it: readers never see half a file.

    JSON has no NaN or infinity: such values (an unknown figure, a limit that
    is off) are written as null rather than aborting the write. A failed write
    (disk full) raises :class:`WriteError` naming ``path`` and leaves the
    earlier file as it was.
    """
    _write_text_atomic(path, json_text(data) + "\n")


def write_summary_json(path, head: dict, record_lines: list) -> None:
    """Write summary.json atomically: ``head``'s keys, then ``per_frame`` from the records' JSON lines.

    The lines are the journal's (:meth:`Journal.add` returns them): each frame is
    encoded once, when it finishes, so a rewrite of a 10,000-frame summary is a
    join, not a re-encoding. One frame a line, under an indented head.
    """
    text = json_text(head)[:-2] + ',\n  "per_frame": [' + ",".join(f"\n    {line}" for line in record_lines)
    text += ("\n  " if record_lines else "") + "]\n}\n"
    _write_text_atomic(path, text)


def _write_text_atomic(path, text: str) -> None:
    """Write ``text`` under a temporary name and rename it; a failure names ``path`` and leaves the old file."""
    _write_bytes_atomic(path, text.encode("utf-8"))


def _write_bytes_atomic(path, data: bytes, suffix: str = ".tmp") -> None:
    """Write ``data`` under a temporary name (``.NAME`` + ``suffix``) and rename it; a failure names ``path``
    and leaves the old file."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}{suffix}")
    with writing(path):
        try:
            tmp.write_bytes(data)
            os.replace(tmp, path)
        except OSError:
            tmp.unlink(missing_ok=True)
            raise


def read_summary(path) -> dict:
    """A run's summary.json; ``FileNotFoundError``/``ValueError`` with one line naming it."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: missing (not a ctr-bench run or reconstruct output directory)")
    try:
        summary = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc.msg})") from None
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text file") from None
    if not isinstance(summary, dict) or summary.get("format") != SUMMARY_FORMAT:
        got = summary.get("format") if isinstance(summary, dict) else type(summary).__name__
        raise ValueError(f"{path}: format is {got!r}, expected {SUMMARY_FORMAT!r}")
    return summary


# ----------------------------------------------------------------------------- the directory
def new_run_id() -> str:
    """A run's id: its start time and a random tag (two runs started in the same second differ)."""
    return f"{time.strftime('%Y%m%dT%H%M%S')}-{secrets.token_hex(4)}"


def earlier_files(out) -> list:
    """The files and directories in ``out`` that a run (or a report of it) wrote; [] when it holds none.

    Only names a run writes count: a user's own files in ``out`` are neither
    a run nor removed by ``overwrite``.
    """
    out = Path(out)
    if not out.is_dir():
        return []
    found = [out / n for n in _RUN_FILES if (out / n).is_file()] + [out / n for n in _RUN_DIRS if (out / n).is_dir()]
    for sub, pattern in ((FRAMES_DIR, _FRAME_FILE), ("meshes", _MESH_FILE)):
        if (out / sub).is_dir():
            found += sorted(p for p in (out / sub).iterdir() if p.is_file() and pattern.fullmatch(p.name))
    return found


def remove_files(out, files) -> None:
    """Remove ``files`` (from :func:`earlier_files`), then ``frames/`` and ``meshes/`` when that left them empty."""
    out = Path(out)
    for p in files:
        with writing(p):
            if p.is_dir():
                shutil.rmtree(p)
            else:
                p.unlink(missing_ok=True)
    for sub in (FRAMES_DIR, "meshes"):
        d = out / sub
        if d.is_dir() and not any(d.iterdir()):
            d.rmdir()


def _describe_earlier(out: Path, files: list) -> str:
    """A few words on what the earlier run in ``out`` was (method, frames), else the files found."""
    try:
        s = json.loads((out / SUMMARY).read_text())
        return f"method {s.get('method')!r}, {s.get('frames')} frames"
    except (OSError, ValueError, AttributeError):
        names = sorted({p.relative_to(out).parts[0] for p in files})
        return ", ".join(names)


def _flat(d, prefix="") -> dict:
    """Nested dict -> {"a.b": value} (to name the parameter that differs)."""
    out = {}
    for k, v in (d or {}).items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _difference(earlier: dict, header: dict) -> str | None:
    """What differs between the earlier run's journal header and this run's, in words; None when they agree."""
    if earlier.get("method") != header["method"]:
        return f"used method {earlier.get('method')!r}, not {header['method']!r}"
    if (earlier.get("selfcheck") is None) != (header["selfcheck"] is None):
        return f"had the self-check {'off' if earlier.get('selfcheck') is None else 'on'}"
    for key in ("params", "selfcheck"):
        # compared as JSON reads them back: an infinite limit is null on both sides
        a, b = _flat(json_safe(earlier.get(key))), _flat(json_safe(header[key]))
        diff = sorted(k for k in a.keys() | b.keys() if a.get(k, "missing") != b.get(k, "missing"))
        if diff:
            k = diff[0]
            more = f" (and {len(diff) - 1} more)" if len(diff) > 1 else ""
            return f"had {key} {k} = {a.get(k, 'missing')!r}, not {b.get(k, 'missing')!r}{more}"
    if Path(earlier.get("session") or "").resolve() != Path(header["session"]).resolve():
        return f"reconstructed session {earlier.get('session')!r}, not {header['session']!r}"
    return None


def check_claim(out, mode: str, header: dict):
    """Whether this run may write into ``out``, and what it continues.

    Parameters
    ----------
    out : path
        The output directory.
    mode : {"refuse", "overwrite", "resume"}
        What to do when ``out`` holds an earlier run.
    header : dict
        This run's journal header (method, params, selfcheck, session...).

    Returns
    -------
    (files, earlier) : (list of Path, (header, records) or None)
        The earlier run's files (to remove before writing, for ``overwrite``)
        and, for ``resume``, the earlier journal's header and records.

    Raises
    ------
    RunDirError
        ``out`` is a session directory, or holds an earlier run and ``mode`` is
        ``refuse``, or ``resume`` finds a run it cannot continue (one line naming it).
    """
    out = Path(out)
    if mode not in MODES:
        raise ValueError(f"existing={mode!r}: expected one of {', '.join(MODES)}")
    if (out / "session.json").exists():
        raise RunDirError(f"{out}: is a session directory; choose another output directory")
    files = earlier_files(out)
    if not files:
        return [], None
    if mode == "refuse":
        raise RunDirError(f"{out}: holds an earlier run ({_describe_earlier(out, files)}); "
                          "--overwrite replaces it, --resume continues it, or choose another --out")
    if mode == "overwrite":
        return files, None
    journal = out / JOURNAL
    if not journal.exists():
        raise RunDirError(f"{out}: --resume: the earlier run has no {JOURNAL} (written by an older ctr-bench, "
                          "or cut before its first frame); --overwrite replaces it")
    earlier, records = read_journal(journal)
    why = _difference(earlier, header)
    if why is not None:
        raise RunDirError(f"{out}: --resume: the earlier run {why}; --overwrite replaces it, or choose another --out")
    return [p for p in files if p.name in _RUN_DIRS or p.parent.name == "meshes"], (earlier, records)


# ----------------------------------------------------------------------------- frames.jsonl
def journal_header(method: str, params: dict, selfcheck: dict | None, session_dir) -> dict:
    """The header of a new run's journal: what it reconstructs, how, and its new ``run_id``.

    The caller adds ``mm_per_px`` once the session's calibration is known.
    """
    return {"format": JOURNAL_FORMAT, "version": 1, "run_id": new_run_id(), "method": method, "params": params,
            "selfcheck": selfcheck, "session": str(session_dir), "mm_per_px": None,
            "started": time.strftime("%Y-%m-%dT%H:%M:%S%z")}


class Journal:
    """``frames.jsonl`` open for appending: one flushed line per finished frame.

    Parameters
    ----------
    path : path
    header : dict
        The run's header, line 1.
    records : list of dict, optional
        The frames a resumed run keeps: the journal is rewritten with them
        (under a temporary name, then renamed, so that a kill while rewriting
        loses none), and a line a kill had torn is gone.
    """

    def __init__(self, path, header: dict, records=()):
        self.path = Path(path)
        tmp = self.path.with_name(f".{self.path.name}.tmp")
        with writing(self.path):
            with open(tmp, "w", encoding="utf-8") as fh:
                fh.writelines(json_text(r, indent=None) + "\n" for r in [header, *records])
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, self.path)
            self._fh = open(self.path, "a", encoding="utf-8")
        self._synced = time.monotonic()

    def add(self, rec: dict) -> str:
        """Append one frame's record; flushed at once (a SIGKILL keeps it), synced every :data:`FSYNC_EVERY_S`.

        Returns the line written (without its newline).
        """
        line = json_text(rec, indent=None)
        with writing(self.path):
            self._fh.write(line + "\n")
            self._fh.flush()
            if time.monotonic() - self._synced >= FSYNC_EVERY_S:
                self.sync()
        return line

    def sync(self) -> None:
        """Flush and fsync what was appended."""
        with writing(self.path):
            self._fh.flush()
            os.fsync(self._fh.fileno())
        self._synced = time.monotonic()

    def close(self) -> None:
        if not self._fh.closed:
            try:
                self.sync()
            finally:
                self._fh.close()


def read_journal(path):
    """A journal's header and its records.

    A last line without its newline or not valid JSON was cut by a kill: it is
    left out (its frame was not finished). A bad line before the last is an
    error naming the file and line.

    Returns
    -------
    (header, records) : (dict, list of dict)
    """
    path = Path(path)
    data = path.read_bytes()
    lines = data.split(b"\n")
    torn = lines[-1] != b""  # what follows the last newline: empty, or a line a kill cut short (left out)
    parsed = []
    for n, line in enumerate(lines[:-1], start=1):
        try:
            parsed.append(json.loads(line))
        except (ValueError, UnicodeDecodeError):
            if n == len(lines) - 1 and n > 1 and not torn:
                break  # the last line, cut inside (a partial write at a kill or a full disk)
            raise ValueError(f"{path}:{n}: not a JSON record") from None
    if not parsed or not isinstance(parsed[0], dict) or parsed[0].get("format") != JOURNAL_FORMAT:
        raise ValueError(f"{path}: not a ctr-bench frames journal (line 1 is no {JOURNAL_FORMAT!r} header)")
    for n, rec in enumerate(parsed[1:], start=2):
        if not isinstance(rec, dict) or "frame" not in rec:
            raise ValueError(f"{path}:{n}: not a frame record")
    return parsed[0], parsed[1:]


def last_journal_record(path, tail_bytes: int = 1 << 16) -> dict | None:
    """The last finished frame's record in a journal (None before the first), read from its end only.

    For watchers called after every frame (the live view): reading the whole
    journal each time would grow with the run. A record longer than
    ``tail_bytes`` is not found (None).
    """
    path = Path(path)
    with open(path, "rb") as fh:
        fh.seek(0, os.SEEK_END)
        size = fh.tell()
        fh.seek(max(0, size - tail_bytes))
        lines = fh.read().split(b"\n")
    for line in reversed(lines[1:-1] if size > tail_bytes else lines[:-1]):  # whole lines only
        try:
            rec = json.loads(line)
        except (ValueError, UnicodeDecodeError):
            continue
        return rec if isinstance(rec, dict) and "frame" in rec else None
    return None


# ----------------------------------------------------------------------------- backbones.npz
def write_backbones_npz(path, backbones: dict) -> str:
    """All backbones (``frame_NNNNNN`` arrays, ``frames``), replaced atomically; returns the file's SHA-1 (hex).

    The summary records the SHA-1: a reader can then tell this run's file from
    a stale one of another run (:func:`read_backbones_npz`).
    """
    path = Path(path)
    buf = io.BytesIO()
    np.savez_compressed(buf, frames=np.array(sorted(backbones), dtype=np.int64),
                        **{f"frame_{i:06d}": p for i, p in backbones.items()})
    data = buf.getvalue()
    _write_bytes_atomic(path, data, ".tmp.npz")
    return hashlib.sha1(data).hexdigest()


def read_backbones_npz(path, sha1: str | None = None, frames=None) -> dict:
    """Frame -> (n, 3) backbone of a ``backbones.npz``.

    Parameters
    ----------
    path : path
    sha1 : str, optional
        The SHA-1 the writing run recorded in its summary: other bytes are a
        stale file of another run (or one changed since), an error naming it.
    frames : set of int, optional
        Read only these frames (a summary without file list lists its frames).

    Raises
    ------
    ValueError
        Missing, unreadable, or not the file the run wrote.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ValueError(f"{path}: unreadable ({exc.strerror or exc})") from None
    if sha1 is not None and hashlib.sha1(data).hexdigest() != sha1:
        raise ValueError(f"{path}: not the file the run wrote (its SHA-1 differs from summary.json's: a stale file of "
                         "another run, or changed since; reconstruct again with --overwrite)")
    try:
        with np.load(io.BytesIO(data)) as z:
            keys = [k for k in z.files if k.startswith("frame_") and (frames is None or int(k[6:]) in frames)]
            return {int(k[6:]): np.asarray(z[k], float).reshape(-1, 3) for k in keys}
    except (OSError, ValueError, KeyError, EOFError) as exc:
        raise ValueError(f"{path}: unreadable ({type(exc).__name__}: {' '.join(str(exc).split())})") from None


def finite_or_none(x):
    """JSON has no NaN: report unknown values as null."""
    if x is None:
        return None
    x = float(x)
    return x if np.isfinite(x) else None


def _error_aggregates(records: list) -> dict:
    """Error aggregates (mm) over the scored frames among ``records``."""
    scored = [r for r in records if r.get("mean_error_mm") is not None]

    def agg(key, fn):
        vals = np.array([r[key] for r in scored], float)
        return finite_or_none(fn(vals)) if vals.size else None

    return {
        "scored_frames": len(scored),
        "mean_error_mm": agg("mean_error_mm", np.mean),
        "max_error_mm": agg("max_error_mm", np.max),
        "tip_error_mm_median": agg("tip_error_mm", np.median),
        "tip_error_mm_max": agg("tip_error_mm", np.max),
        "length_error_mm_median": agg("length_error_mm", np.median),
    }


def params_as_dict(params):
    """A parameter dataclass as a dict (a dict, e.g. read back from a journal, or None as it is)."""
    return params_to_dict(params) if dataclasses.is_dataclass(params) else params


def summarize(records: list, method: str, params, session_dir, mm_px: float, selfcheck: SelfCheckParams | None = None,
              run_id: str | None = None, complete: bool = False, files: dict | None = None, session_notes=()) -> dict:
    """Aggregate per-frame records into the summary.json document.

    Error and time aggregates are over the ``ok`` frames (as before the
    self-check existed); ``reconstructed`` holds the same over ``ok`` and
    ``suspect`` frames together. ``params`` and ``selfcheck`` are dataclasses
    or their dicts. With a ``run_id`` the summary also names the run, whether
    it is ``complete`` and the ``files`` it wrote (default: the journal and the
    table; :class:`RunWriter` adds ``backbones`` and ``backbones_sha1`` at the end).
    ``session_notes`` are what reading the session forgave (a frames.csv row
    cut short by a crash), kept in the summary so that nothing is dropped unsaid.
    """
    ok = [r for r in records if r["status"] == "ok"]
    suspect = [r for r in records if r["status"] == "suspect"]
    done = [r for r in records if r["status"] in ("ok", "suspect")]
    errors = _error_aggregates(ok)
    ms = np.array([r["ms"] for r in ok]) if ok else np.array([])
    ms_done = np.array([r["ms"] for r in done]) if done else np.array([])
    # Largest voxel edge of each frame (methods that carve voxels).
    voxel = np.array([max(r["voxel_size_mm"]) for r in ok if r.get("voxel_size_mm")], float)
    check_ms = np.array([r["selfcheck"]["ms"] for r in done if (r.get("selfcheck") or {}).get("ms") is not None], float)

    run = {} if run_id is None else {
        "run_id": run_id, "complete": bool(complete),
        "files": files or {"journal": JOURNAL, "table": TABLE, "backbones": None, "backbones_sha1": None},
    }
    return {
        "format": "ctr-bench-summary",
        "version": 1,
        **run,
        "method": method,
        "params": params_as_dict(params),
        "session": str(session_dir),
        "session_notes": list(session_notes),
        "frames": len(records),
        "ok_frames": len(ok),
        "suspect_frames": len(suspect),
        "failed_frames": sum(r["status"] == "failed" for r in records),
        "jump_frames": sum(bool(r.get("jump_flag")) for r in records),
        "suspect_list": [r["frame"] for r in suspect],
        "mm_per_px": mm_px,
        **errors,
        "reconstructed": {
            "frames": len(done),
            **_error_aggregates(done),
            "ms_per_pair_median": finite_or_none(np.median(ms_done)) if ms_done.size else None,
            "ms_per_pair_p95": finite_or_none(np.percentile(ms_done, 95)) if ms_done.size else None,
        },
        "selfcheck": params_as_dict(selfcheck),
        "selfcheck_ms_median": finite_or_none(np.median(check_ms)) if check_ms.size else None,
        "selfcheck_ms_max": finite_or_none(np.max(check_ms)) if check_ms.size else None,
        "voxel_edge_mm_median": finite_or_none(np.median(voxel)) if voxel.size else None,
        "voxel_edge_mm_max": finite_or_none(np.max(voxel)) if voxel.size else None,
        "ms_per_pair_median": finite_or_none(np.median(ms)) if ms.size else None,
        "ms_per_pair_p95": finite_or_none(np.percentile(ms, 95)) if ms.size else None,
        "per_frame": records,
    }


# ----------------------------------------------------------------------------- a frame's record
def describe_result(result, pts: np.ndarray) -> dict:
    """What a frame's record says of its reconstruction: points, length, tip, stages' times, voxels.

    Parameters
    ----------
    result : a method's result
        Its ``length_mm``, ``tip_world_mm`` (world, mm), ``transition_s_mm``,
        ``timings_ms`` and, for the methods that carve, ``voxel_size_mm``.
    pts : (n, 3) array
        Its backbone (world, mm).
    """
    out = {
        "n_points": int(len(pts)),
        "length_mm": finite_or_none(result.length_mm),
        "tip_world_mm": [float(v) for v in result.tip_world_mm],
        "transition_s_mm": finite_or_none(result.transition_s_mm),
        "timings_ms": {k: round(float(v), 3) for k, v in result.timings_ms.items()},
    }
    voxel = getattr(result, "voxel_size_mm", None)
    if voxel is not None:
        out["voxel_size_mm"] = [float(v) for v in np.broadcast_to(np.asarray(voxel, float), (3,))]
    return out


def jump_record(result) -> dict:
    """The fast method's temporal check as a frame's record holds it: ``jump_flag`` and its ``jump_reason``.

    Recorded only: the frame's status stays what the self-check makes it.
    """
    flag = bool(getattr(result, "jump_flag", False))
    return {"jump_flag": flag, "jump_reason": getattr(result, "jump_reason", None) if flag else None}


def record_doubt(rec: dict, result, checked: bool = False) -> None:
    """Make a frame the method itself cannot vouch for (its ``suspect_reason``) ``suspect`` with that reason.

    Only an ``ok`` record changes: a self-check's verdict, recorded first, keeps its reason.
    A doubt that the method says an image check answers (its ``check_answers_doubt``, e.g.
    the fast method's tips cut to what both views see) is lifted where the frame was
    ``checked`` and passed: the record keeps it as ``doubt_answered``. Unchecked (live, or a
    bench run with ``--no-selfcheck``) every doubt makes the frame suspect.
    """
    own = getattr(result, "suspect_reason", None)
    if not own or rec["status"] != "ok":
        return
    if checked and getattr(result, "check_answers_doubt", False):
        rec["doubt_answered"] = str(own)
    else:
        rec.update(status="suspect", reason=str(own))


# ----------------------------------------------------------------------------- the writer
class RunWriter:
    """The files of one run as it goes (docs/outputs.md): the one writer of a run directory.

    Per finished frame: its backbone CSV, a journal line (flushed: the frame is
    kept from then on, SIGKILL included) and a frames.csv row; summary.json
    every :data:`SUMMARY_EVERY_S` at most (never more than 1/:data:`SUMMARY_COST_FACTOR`
    of the time), so that the cost per frame does not grow with the run.
    A write that fails raises :class:`WriteError` naming the file.

    Parameters
    ----------
    out : Path
        The run directory (claimed: :func:`check_claim`; created when missing).
    header : dict
        The journal header (:func:`journal_header`, with ``mm_per_px``).
    kept : list of dict, optional
        Records of the frames a resumed run keeps, and ``backbones`` their backbones
        (:func:`kept_frames`).
    """

    def __init__(self, out, header: dict, kept=(), backbones=None):
        self.out, self.header = Path(out), header
        self.records, self.backbones = list(kept), dict(backbones or {})
        self._lines = [json_text(r, indent=None) for r in self.records]  # each frame's JSON, encoded once
        self.files = {"journal": JOURNAL, "table": TABLE, "backbones": None, "backbones_sha1": None}
        with writing(self.out / FRAMES_DIR):
            (self.out / FRAMES_DIR).mkdir(parents=True, exist_ok=True)
        self._journal = Journal(self.out / JOURNAL, header, self.records)
        with writing(self.out / TABLE):
            self._table = FrameTable(self.out / TABLE, self.records)
        self._next_summary = 0.0
        self.write_summary()  # the directory names its run from the start

    def add(self, rec: dict, pts: np.ndarray | None) -> None:
        """Write a finished frame: its backbone (world, mm; None: failed), journal line, table row; the summary when due."""
        name = f"{FRAMES_DIR}/{rec['frame']:06d}.csv"
        with writing(self.out / name):
            if pts is not None:
                rec.update(backbone_csv=name, backbone_sha1=write_backbone_csv(self.out / name, pts))
                self.backbones[rec["frame"]] = pts
            else:  # an earlier try of this frame, cut by a kill before its journal line, may have left one
                (self.out / name).unlink(missing_ok=True)
        self._lines.append(self._journal.add(rec))
        with writing(self._table.path):
            self._table.add(rec)
        self.records.append(rec)
        if time.monotonic() >= self._next_summary:
            self.write_summary()

    def summary(self, complete: bool = False) -> dict:
        """The summary of the frames written so far."""
        h = self.header
        return summarize(self.records, h["method"], h["params"], h["session"], h["mm_per_px"], h["selfcheck"],
                         run_id=h["run_id"], complete=complete, files=self.files, session_notes=h.get("session_notes", ()))

    def write_summary(self, complete: bool = False) -> dict:
        """Write summary.json now; the next one while the run goes is due after a pause proportional to its cost."""
        t0 = time.monotonic()
        summary = self.summary(complete)
        write_summary_json(self.out / SUMMARY, {k: v for k, v in summary.items() if k != "per_frame"}, self._lines)
        cost = time.monotonic() - t0
        self._next_summary = time.monotonic() + max(SUMMARY_EVERY_S, SUMMARY_COST_FACTOR * cost)
        return summary

    def finish(self) -> dict:
        """Write backbones.npz and the complete summary; close. Returns the summary (unknown values as None)."""
        self._journal.sync()
        sha1 = write_backbones_npz(self.out / BACKBONES, self.backbones)
        self.files.update(backbones=BACKBONES, backbones_sha1=sha1)  # listed once it is all there
        summary = self.write_summary(complete=True)
        self.close()
        return json_safe(summary)

    def abort(self, exc: BaseException) -> None:
        """After an error or an interrupt: keep what is finished (journal synced, summary of it), best effort."""
        if isinstance(exc, WriteError):
            exc.note = f"the {len(self.records)} frames finished are kept in {self.out / JOURNAL} (--resume continues)"
        try:
            self.write_summary()
        except OSError:
            pass  # the disk that refused a frame may refuse the summary too; the journal has the frames
        try:
            self.close()
        except OSError:
            pass

    def close(self) -> None:
        self._journal.close()
        self._table.close()


def kept_frames(out, records: list) -> tuple:
    """The records and backbones a resumed run keeps: every finished frame whose backbone file is as written.

    A reconstructed frame whose CSV is missing or changed is done again.

    Returns
    -------
    (records, backbones) : (list of dict, dict frame -> (n, 3) world mm)
    """
    kept, backbones = [], {}
    for rec in {r["frame"]: r for r in records}.values():
        try:
            pts = record_backbone(out, rec)
        except (OSError, ValueError):
            continue
        if pts is not None:
            backbones[rec["frame"]] = pts
        kept.append(rec)
    return kept, backbones


def record_backbone(out, rec: dict) -> np.ndarray | None:
    """The backbone (n, 3) world mm a frame's record lists (``backbone_csv``, checked against its ``backbone_sha1``).

    None when the record lists none (a failed frame).

    Raises
    ------
    ValueError
        The file is missing, unreadable, or not the one the run wrote (one line naming it).
    """
    if not rec.get("backbone_csv"):
        return None
    path = Path(out) / rec["backbone_csv"]
    if not path.is_file():
        raise ValueError(f"{path}: missing (the record of frame {rec['frame']} lists it)")
    return read_backbone_csv(path, sha1=rec.get("backbone_sha1"))


# ----------------------------------------------------------------------------- the reader
def read_run(out_dir) -> tuple:
    """A run directory's summary and backbones, read only from the files its summary lists.

    A summary that is not ``complete`` (the run was killed or is still going:
    summary.json is rewritten every few seconds) is rebuilt from the journal.
    Backbones come from the ``backbones.npz`` the summary lists, else the
    per-frame CSVs its records list; a file of another run (another SHA-1
    than the summary records) is an error naming it. A summary without ``run_id``
    (older ctr-bench, ``experiment``'s ``live/`` before it had a journal) lists frames
    only: the backbones of its reconstructed frames are read, and no others.

    Returns
    -------
    (summary, backbones) : (dict, dict frame -> (n, 3) world mm)

    Raises
    ------
    FileNotFoundError, ValueError
        One line naming the file.
    """
    out = Path(out_dir)
    summary = read_summary(out / SUMMARY)
    if summary.get("run_id") is None:
        return summary, _unlisted_backbones(out, summary)
    if not summary.get("complete"):
        summary = _rebuilt_summary(out, summary)
    return summary, _listed_backbones(out, summary)


def _rebuilt_summary(out: Path, summary: dict) -> dict:
    """The summary of a run cut short, rebuilt from its journal (which has every finished frame)."""
    path = out / ((summary.get("files") or {}).get("journal") or JOURNAL)
    if not path.exists():
        return summary
    header, records = read_journal(path)
    if header.get("run_id") != summary["run_id"]:
        raise ValueError(f"{path}: written by run {header.get('run_id')}, not by run {summary['run_id']} that "
                         f"{out / SUMMARY} describes (a stale file of another run)")
    records = list({r["frame"]: r for r in records}.values())
    return json_safe(summarize(records, header.get("method"), header.get("params"), header.get("session"),
                               header.get("mm_per_px"), header.get("selfcheck"), run_id=header["run_id"],
                               session_notes=header.get("session_notes", ())))


def _listed_backbones(out: Path, summary: dict) -> dict:
    """Backbones from the files a summary with a run id lists: its backbones.npz, else its per-frame CSVs."""
    files = summary.get("files") or {}
    if files.get("backbones"):
        return read_backbones_npz(out / files["backbones"], sha1=files.get("backbones_sha1"))
    found = {}
    for rec in summary.get("per_frame", []):
        pts = record_backbone(out, rec)
        if pts is not None:
            found[int(rec["frame"])] = pts
    return found


def _unlisted_backbones(out: Path, summary: dict) -> dict:
    """Backbones of the frames a summary without run id says were reconstructed (backbones.npz, else their CSVs)."""
    wanted = {int(r["frame"]) for r in summary.get("per_frame", []) if r.get("status") in ("ok", "suspect")}
    if (out / BACKBONES).exists():
        return read_backbones_npz(out / BACKBONES, frames=wanted)
    found = {}
    for i in sorted(wanted):
        path = out / FRAMES_DIR / f"{i:06d}.csv"
        try:
            found[i] = read_backbone_csv(path)
        except (OSError, ValueError):
            continue  # a run cut short may not have written it; the frame is drawn without a backbone
    return found
