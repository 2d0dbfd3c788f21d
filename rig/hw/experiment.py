"""Experiments: a sequence of steps run on a rig, recorded into a session as it happens.

A *sequence file* (TOML, documented in ``docs/experiments.md``; example
``scenes/paper-sequence.toml``) lists steps -- ``home``, ``background``,
``move`` (absolute ``to`` or relative ``by``), ``dwell``, ``grab`` and
``repeat`` (a block of steps n times).  :class:`ExperimentRunner` executes them
on an opened :class:`rig.hw.rigfile.Rig` -- whichever cameras and actuator its rig
file chose: the code path is the same for the twin and for the physical rig.

Everything is recorded with :class:`rig.session.SessionWriter` the moment it
exists (a frame is committed by its ``frames.csv`` row), so a run that is
interrupted -- Ctrl-C, SIGTERM, even SIGKILL -- leaves every frame before that
readable and reconstructable.  With a reconstruction method the runner prepares
it from the recorded background frames and reconstructs every pair live,
writing ``SESSION/live/`` through the writer of ``ctr-bench reconstruct --out``
(:class:`rig.rundir.RunWriter`: journal, frame CSVs, table, summary, backbones.npz;
docs/outputs.md), so the two can be compared file for file, and scoring each frame
on the twin as ``reconstruct`` does (:func:`rig.scoring.score_frame`).
"""
from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from recon.errors import FrameError
from recon.methods import get_method
from rig.hw.actuator import JOINTS, JointValues, SoftLimits
from rig.rundir import RunWriter, describe_result, journal_header, jump_record, params_as_dict, record_doubt
from rig.scoring import score_frame
from rig.session import SessionWriter
from twin.schema import NONNEGATIVE, POSITIVE, REQUIRED, SceneError, Table, read_toml

__all__ = ["SequenceError", "ExperimentError", "Step", "Sequence", "load_sequence", "sequence_from_dict",
           "flatten", "check_limits", "check_background_first", "grab_targets", "ExperimentRunner", "STEP_KINDS"]

FORMAT = "ctr-bench-sequence"
STEP_KINDS = ("home", "background", "move", "dwell", "grab", "repeat")
#: The session's subdirectory the live reconstruction goes to, a run directory (rig.rundir).
LIVE_DIR = "live"


class SequenceError(ValueError):
    """A sequence file that cannot be used; the message names the file and the key."""


class ExperimentError(RuntimeError):
    """An experiment that cannot go on (the message says why and what to do)."""


# ----------------------------------------------------------------------------- sequence file
@dataclass(frozen=True)
class Step:
    """One step of a sequence; ``key`` locates it in the file (``steps[3].steps[1]``)."""

    kind: str
    key: str
    to: dict | None = None
    by: dict | None = None
    wait: bool = True
    timeout_s: float | None = None
    seconds: float = 0.0
    pairs: int = 1
    interval_s: float = 0.0
    settle: bool = True
    frames: int = 0
    retract: dict | None = None
    prompt: str | None = None
    times: int = 1
    steps: tuple = ()


@dataclass(frozen=True)
class Sequence:
    """A validated sequence file."""

    source: str
    name: str
    steps: tuple
    settle_timeout_s: float = 30.0
    home_timeout_s: float = 60.0

    @property
    def grab_count(self) -> int:
        return sum(s.pairs for s, _ in flatten(self.steps) if s.kind == "grab")

    @property
    def background_count(self) -> int:
        return sum(s.frames for s, _ in flatten(self.steps) if s.kind == "background")


def _joint_table(t: Table, key: str) -> dict | None:
    if key not in t.data:
        return None
    sub = t.table(key)
    out = {}
    for j in JOINTS:
        v = sub.get(j, None, float, lambda v: math.isfinite(v), "must be finite")
        if v is not None:
            out[j] = v
    sub.done()
    if not out:
        t.fail(key, f"must give at least one of {', '.join(JOINTS)}")
    return out


def _parse_steps(tables: list, depth: int = 0) -> tuple:
    steps = []
    for t in tables:
        kind = t.get("kind", REQUIRED, str, lambda v: v in STEP_KINDS, f"must be one of {', '.join(STEP_KINDS)}")
        kw: dict = {"kind": kind, "key": t.path}
        if kind == "home":
            kw["timeout_s"] = t.get("timeout_s", None, float, *POSITIVE)
        elif kind == "move":
            kw["to"] = _joint_table(t, "to")
            kw["by"] = _joint_table(t, "by")
            if (kw["to"] is None) == (kw["by"] is None):
                t.fail("to", "give exactly one of 'to' (absolute targets) or 'by' (relative to the last target)")
            kw["wait"] = t.get("wait", True, bool)
            kw["timeout_s"] = t.get("timeout_s", None, float, *POSITIVE)
        elif kind == "dwell":
            kw["seconds"] = t.get("seconds", REQUIRED, float, *NONNEGATIVE)
        elif kind == "grab":
            kw["pairs"] = t.get("pairs", 1, int, lambda v: v >= 1, "must be >= 1")
            kw["interval_s"] = t.get("interval_s", 0.0, float, *NONNEGATIVE)
            kw["settle"] = t.get("settle", True, bool)
            kw["timeout_s"] = t.get("timeout_s", None, float, *POSITIVE)
        elif kind == "background":
            kw["frames"] = t.get("frames", REQUIRED, int, lambda v: v >= 1, "must be >= 1")
            kw["retract"] = _joint_table(t, "retract")
            kw["prompt"] = t.get("prompt", None, str)
        elif kind == "repeat":
            kw["times"] = t.get("times", REQUIRED, int, lambda v: v >= 0, "must be >= 0")
            if depth >= 8:
                t.fail("steps", "repeat blocks nest too deep (more than 8)")
            inner = t.tables("steps")
            if not inner:
                t.fail("steps", "a repeat needs its steps ([[...steps]] tables after it)")
            kw["steps"] = _parse_steps(inner, depth + 1)
        t.done()
        steps.append(Step(**kw))
    return tuple(steps)


def sequence_from_dict(data: dict, source: str = "<sequence>") -> Sequence:
    """Validate a parsed TOML document and build a :class:`Sequence`."""
    try:
        top = Table(data, "", source)
        top.get("format", FORMAT, str, lambda v: v == FORMAT, f'must be "{FORMAT}"')
        top.get("version", 1, int, lambda v: v == 1, "must be 1 (the only version this ctr-bench reads)")
        name = top.get("name", Path(source).stem, str)
        st = top.table("settings")
        settle = st.get("settle_timeout_s", 30.0, float, *POSITIVE)
        home = st.get("home_timeout_s", 60.0, float, *POSITIVE)
        st.done()
        tables = top.tables("steps")
        if not tables:
            top.fail("steps", "at least one [[steps]] is required")
        steps = _parse_steps(tables)
        top.done()
    except SceneError as exc:
        raise SequenceError(str(exc)) from None
    seq = Sequence(source=source, name=name, steps=steps, settle_timeout_s=settle, home_timeout_s=home)
    return seq


def load_sequence(path) -> Sequence:
    """Load and validate a sequence TOML file; every error names the file and the key."""
    path = Path(path)
    data = read_toml(path, "sequence file", SequenceError)
    return sequence_from_dict(data, source=str(path))


def flatten(steps, label: str = ""):
    """Yield ``(step, label)`` in execution order, repeats unrolled (label says which repetition)."""
    for s in steps:
        if s.kind == "repeat":
            for r in range(s.times):
                yield from flatten(s.steps, f"{label}{s.key} {r + 1}/{s.times}; ")
        else:
            yield s, label


def grab_targets(seq: Sequence) -> list:
    """The commanded joints (dict; joints not known yet are left out) at each grabbed pair, in order."""
    out = []
    target: dict = {}
    for s, _ in flatten(seq.steps):
        if s.kind == "home":
            target = {j: 0.0 for j in JOINTS}
        elif s.kind == "background" and s.retract:
            target = {**target, **s.retract}
        elif s.kind == "move":
            if s.to is not None:
                target = {**target, **s.to}
            else:
                target = {j: target[j] + s.by.get(j, 0.0) for j in target} if set(s.by) <= set(target) else {}
        elif s.kind == "grab":
            out += [dict(target)] * s.pairs
    return out


def check_limits(seq: Sequence, limits: SoftLimits) -> None:
    """Follow the targets through the sequence and refuse, before anything moves,
    a move that would leave the soft limits (relative moves are followed from the
    last ``home`` or absolute move; before those the position is unknown)."""
    target: dict = {}
    for s, label in flatten(seq.steps):
        if s.kind == "home":
            target = {j: 0.0 for j in JOINTS}
            continue
        if s.kind == "move" or (s.kind == "background" and s.retract):
            new = dict(target)
            if s.kind == "background":
                new.update(s.retract)
                key = f"{s.key}.retract"
            elif s.to is not None:
                new.update(s.to)
                key = f"{s.key}.to"
            else:
                key = f"{s.key}.by"
                if set(s.by) - set(target):
                    target = {}
                    continue
                for j, d in s.by.items():
                    new[j] = target[j] + d
            for j, v in new.items():
                lo, hi = getattr(limits, j)
                if not lo <= v <= hi:
                    where = f" ({label.rstrip('; ')})" if label else ""
                    raise SequenceError(f"{seq.source}: {key}: {j} would be {v:g}{where}, outside the rig's soft "
                                        f"limits [{lo:g}, {hi:g}]")
            target = new


def check_background_first(seq: Sequence) -> None:
    """Live reconstruction needs background frames before the first grab."""
    for s, _ in flatten(seq.steps):
        if s.kind == "background":
            return
        if s.kind == "grab":
            raise SequenceError(f"{seq.source}: {s.key}: live reconstruction needs a 'background' step "
                                f"before the first grab (the method is prepared from the background frames)")
    raise SequenceError(f"{seq.source}: steps: live reconstruction needs a 'background' step")


# ----------------------------------------------------------------------------- runner
def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


@dataclass
class FrameLog:
    """What the runner measured for one committed frame."""

    index: int
    t_s: float
    joints: JointValues
    skew_ms: float
    settle_ms: float
    grab_ms: float
    write_ms: float
    recon_ms: float | None = None
    cycle_ms: float | None = None
    record: dict | None = None


@dataclass
class ExperimentResult:
    frames: list = field(default_factory=list)
    background_frames: int = 0
    interrupted: bool = False
    error: str | None = None
    duration_s: float = 0.0

    def stats(self) -> dict:
        def med_max(key):
            v = np.array([getattr(f, key) for f in self.frames if getattr(f, key) is not None], float)
            return (None, None) if v.size == 0 else (float(np.median(v)), float(np.max(v)))

        out = {"frames": len(self.frames), "background_frames": self.background_frames,
               "interrupted": self.interrupted, "error": self.error, "duration_s": round(self.duration_s, 3)}
        for key in ("skew_ms", "settle_ms", "grab_ms", "write_ms", "recon_ms", "cycle_ms"):
            med, mx = med_max(key)
            out[f"{key}_median"] = None if med is None else round(med, 3)
            out[f"{key}_max"] = None if mx is None else round(mx, 3)
        return out


class ExperimentRunner:
    """Runs a :class:`Sequence` on an opened :class:`rig.hw.rigfile.Rig`, recording into ``out_dir``.

    Parameters
    ----------
    rig : rig.hw.rigfile.Rig
    sequence : Sequence
    out_dir : path
        The session directory (created; must not hold a session already).
    method : str, optional
        Reconstruct every pair live with this method (prepared from the
        background frames recorded by the ``background`` steps).
    params : dataclass, optional
        The method's parameters (defaults when None).
    log : callable(str)
        Receives one line per event and per frame (default: print).
    assume_yes : bool
        Do not ask the operator to clear the cameras' views for background frames.
    ask : callable(str) -> str
        How to ask the operator (default: ``input``).
    on_frame : callable(index, pair, joints, result), optional
        Called after each committed frame (live views).
    extra_meta : dict, optional
        Added to session.json.
    """

    def __init__(self, rig, sequence: Sequence, out_dir, method: str | None = None, params=None, log=print,
                 assume_yes: bool = False, ask=input, on_frame=None, extra_meta: dict | None = None):
        self.rig = rig
        self.seq = sequence
        self.out = Path(out_dir)
        self.method = method
        self.params = params
        self.log = log
        self.assume_yes = assume_yes
        self.ask = ask
        self.on_frame = on_frame
        self.extra_meta = extra_meta or {}
        self.result = ExperimentResult()
        self._reconstruct = None
        self._live_run = None  # RunWriter of live/, opened when the method is first prepared
        self._bg: dict = {}
        self._events = None
        self._writer = None
        self._last_commit = None
        self._joints_unobserved = None
        if method is not None:
            self._m = get_method(method)
            self.params = params if params is not None else self._m.params_type()
            check_background_first(self.seq)

    @property
    def live_records(self) -> list:
        """The records of the frames reconstructed live so far (``live/frames.jsonl``'s), [] without a method."""
        return [] if self._live_run is None else self._live_run.records

    # -- logging -----------------------------------------------------------------
    def _event(self, kind: str, **data) -> None:
        if self._events is None:
            return
        data = {"t_s": round(time.monotonic() - self.t0, 6), "event": kind, **data}
        self._events.write(json.dumps(data, default=_json_default) + "\n")
        self._events.flush()

    # -- run ---------------------------------------------------------------------
    def run(self) -> ExperimentResult:
        """Execute every step. KeyboardInterrupt (Ctrl-C, SIGTERM in the CLI) propagates
        after the recording is closed; ``self.result`` then holds what was done."""
        check_limits(self.seq, self.rig.spec.limits)
        self.t0 = time.monotonic()
        meta = {**self.rig.meta(), "sequence_file": self.seq.source, "sequence_name": self.seq.name,
                "started_unix_s": time.time(), **self.extra_meta}
        if self.method:
            meta["live_method"] = self.method
        self._joints_unobserved = getattr(self.rig, "joints_unobserved", None)
        if self._joints_unobserved:
            self.log(f"joints not recorded (frames.csv leaves them empty): {self._joints_unobserved}")
        self._writer = SessionWriter(self.out, self.rig.calibration, source=self.rig.source,
                                     n_tubes=self.rig.n_tubes, meta=meta)
        self._events = open(self.out / "experiment.jsonl", "a")
        self._event("start", sequence=self.seq.source, rig=self.rig.spec.source,
                    grabs=self.seq.grab_count, background=self.seq.background_count)
        try:
            for step, label in flatten(self.seq.steps):
                self._do(step, label)
        except KeyboardInterrupt:
            self.result.interrupted = True
            self._event("interrupted")
            raise
        except BaseException as exc:
            self.result.error = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            self._event("error", message=self.result.error)
            raise
        finally:
            self.result.duration_s = time.monotonic() - self.t0
            self._finish()
        return self.result

    def _finish(self) -> None:
        try:
            if self._live_run is not None:  # after Ctrl-C too: every committed frame was reconstructed
                self._live_run.finish()
        finally:
            self._event("end", **self.result.stats())
            if self._events is not None:
                self._events.close()
            if self._writer is not None:
                self._writer.close()

    # -- steps -------------------------------------------------------------------
    def _do(self, s: Step, label: str) -> None:
        act = self.rig.actuator
        where = f"{s.key}" + (f" ({label.rstrip('; ')})" if label else "")
        if s.kind == "home":
            self.log(f"home  [{where}]")
            t = time.monotonic()
            act.home(timeout_s=s.timeout_s or self.seq.home_timeout_s)
            self._event("home", step=s.key, ms=round((time.monotonic() - t) * 1e3, 1),
                        position=act.position().as_dict())
        elif s.kind == "move":
            target = self._target(s.to, s.by)
            t = time.monotonic()
            act.move_to(target)
            self._event("move", step=s.key, target=target.as_dict())
            if s.wait:
                pos = act.wait_settled(s.timeout_s or self.seq.settle_timeout_s)
                self._event("settled", step=s.key, position=pos.as_dict(),
                            ms=round((time.monotonic() - t) * 1e3, 1))
        elif s.kind == "dwell":
            self._event("dwell", step=s.key, s=s.seconds)
            time.sleep(s.seconds)
        elif s.kind == "grab":
            for k in range(s.pairs):
                if k and s.interval_s:
                    time.sleep(s.interval_s)
                self._grab(s)
        elif s.kind == "background":
            self._background(s, where)

    def _target(self, to: dict | None, by: dict | None) -> JointValues:
        act = self.rig.actuator
        base = act.target or act.position()
        if to is not None:
            return JointValues.coerce(to, base)
        return JointValues.coerce({j: getattr(base, j) + by.get(j, 0.0) for j in JOINTS})

    def _operator(self, message: str) -> None:
        if self.assume_yes:
            self.log(f"operator step skipped (--yes): {message}")
            return
        stdin = sys.stdin
        if stdin is None or not stdin.isatty():
            raise ExperimentError(f"the background step needs the operator ({message}), but stdin is not a "
                                  f"terminal: run it interactively, or pass --yes when the views are already clear")
        self.ask(f">>> {message} -- press Enter when done (Ctrl-C aborts) ")

    def _background(self, s: Step, where: str) -> None:
        act, cams = self.rig.actuator, self.rig.cameras
        if s.retract:
            act.move_to(self._target(s.retract, None))
            act.wait_settled(s.timeout_s or self.seq.settle_timeout_s)
        operator = cams.needs_operator
        if operator:
            self._operator(s.prompt or "take the robot out of both cameras' views (or retract it behind the "
                                       "actuation unit) for the background frames")
        self.log(f"background: {s.frames} frame pairs  [{where}]")
        t = time.monotonic()
        skews = []
        with cams.background_view():
            for _ in range(s.frames):
                pair = cams.grab()
                self._check_sizes(pair)
                i = self.result.background_frames
                self._writer.add_background(i, pair.images)
                for name, img in pair.images.items():
                    self._bg.setdefault(name, []).append(img)
                self.result.background_frames += 1
                skews.append(pair.skew_ms)
        self._event("background", step=s.key, frames=s.frames, total=self.result.background_frames,
                    ms=round((time.monotonic() - t) * 1e3, 1), skew_ms_max=round(max(skews), 3))
        if operator:
            self._operator("put the robot back into view")
        if self.method:
            self._prepare()

    def _prepare(self) -> None:
        stacks = {name: np.stack(v) for name, v in self._bg.items()}
        t = time.monotonic()
        try:
            self._reconstruct = self._m.prepare(self.rig.calibration, stacks, self.params)
        except (FrameError, ValueError) as exc:
            raise ExperimentError(f"cannot prepare method {self.method!r} from the {self.result.background_frames} "
                                  f"background frames: {exc}") from None
        if self._live_run is None:  # a later background step prepares again, into the same run
            self._live_run = self._open_live()
        ms = (time.monotonic() - t) * 1e3
        self.log(f"method {self.method} prepared from {self.result.background_frames} background pairs ({ms:.0f} ms)")
        self._event("prepared", method=self.method, ms=round(ms, 1))

    def _check_sizes(self, pair) -> None:
        for name, img in pair.images.items():
            c = self.rig.calibration[name]
            if img.shape != (c.height, c.width):
                raise ExperimentError(f"camera {name!r}: frames are {img.shape[1]}x{img.shape[0]} but the "
                                      f"calibration says {c.width}x{c.height}")

    def _grab(self, s: Step) -> None:
        act, cams = self.rig.actuator, self.rig.cameras
        t_start = time.monotonic()
        if s.settle and act.target is not None:
            act.wait_settled(s.timeout_s or self.seq.settle_timeout_s)
        pos = act.position()                         # measured, after settling
        t_settled = time.monotonic()
        pair = cams.grab()
        t_grabbed = time.monotonic()
        self._check_sizes(pair)
        index = len(self.result.frames)
        # Joints the images do not depend on (video files, a simulated actuator) stay empty: never invented.
        joints = None if self._joints_unobserved else self.rig.joint_map.to_joints(pos)
        t_s = pair.timestamp_s - self.t0
        self._writer.add_frame(index, pair.images, t_s=t_s, joints=joints,
                               camera_times_s=pair.times_s(self.t0), truth=pair.truth)
        t_written = time.monotonic()
        log = FrameLog(index=index, t_s=t_s, joints=pos, skew_ms=pair.skew_ms,
                       settle_ms=(t_settled - t_start) * 1e3, grab_ms=(t_grabbed - t_settled) * 1e3,
                       write_ms=(t_written - t_grabbed) * 1e3)
        if self._last_commit is not None:
            log.cycle_ms = (t_written - self._last_commit) * 1e3
        self._last_commit = t_written
        result = None
        if self._reconstruct is not None:
            result = self._live(index, t_s, pair, log)
        self.result.frames.append(log)
        self._event("frame", frame=index, joints=pos.as_dict(), skew_ms=round(pair.skew_ms, 3),
                    camera_times_s={k: round(v, 6) for k, v in pair.times_s(self.t0).items()},
                    settle_ms=round(log.settle_ms, 1), grab_ms=round(log.grab_ms, 1),
                    write_ms=round(log.write_ms, 1), recon_ms=None if log.recon_ms is None else round(log.recon_ms, 1))
        self.log(self._line(log))
        if self.on_frame is not None:
            self.on_frame(index, pair, joints, result)

    def _open_live(self) -> RunWriter:
        """``live/``: a run directory (docs/outputs.md) of the session's frames, written as they are reconstructed."""
        rig = self.rig.calibration
        header = journal_header(self.method, params_as_dict(self.params), None, self.out)
        header["mm_per_px"] = float(np.mean([rig[c].mm_per_pixel_at(rig.base_point_world_mm) for c in rig.names]))
        return RunWriter(self.out / LIVE_DIR, header)

    def _live(self, index: int, t_s: float, pair, log: FrameLog):
        """Reconstruct the pair just committed, score it on the twin, and write it into ``live/``; its result or None."""
        rec = {"frame": index, "t_s": t_s, "status": "ok", "reason": None}
        result = pts = None
        try:
            t = time.perf_counter()
            result = self._reconstruct(pair.images)
            rec["ms"] = 1e3 * (time.perf_counter() - t)
        except FrameError as exc:
            rec.update(status="failed", reason=str(exc).splitlines()[0])
        if result is not None:
            pts = np.asarray(result.points_world_mm, float)
            rec.update(jump_record(result))  # the fast method's temporal check, as reconstruct_session records it
            record_doubt(rec, result)  # no self-check runs live, but the method's own doubt is known: never ok
            rec.update(describe_result(result, pts))
            if pair.truth is not None:
                self._score(rec, pts, pair.truth)
            log.recon_ms = rec["ms"]
        log.record = rec
        self._live_run.add(rec, pts)
        return result

    def _score(self, rec: dict, pts: np.ndarray, truth: dict) -> None:
        """The frame's errors (mm) against the twin's truth, over what every camera sees, as ``reconstruct`` scores.

        A frame that cannot be scored (nothing of it in every view) keeps its record with a ``note``.
        """
        try:
            rec.update(score_frame(pts, truth, self.rig.calibration))
        except ValueError as exc:
            rec["note"] = f"not scored: {str(exc).splitlines()[0]}"

    def _line(self, f: FrameLog) -> str:
        j = f.joints
        s = (f"frame {f.index:4d}  t {f.t_s:8.3f} s  insertion {j.insertion_mm:8.3f} mm  rotation {j.rotation_deg:8.2f} deg"
             f"  skew {f.skew_ms:6.2f} ms  grab {f.grab_ms:6.1f} ms")
        r = f.record
        if r is not None:
            if r["status"] != "ok":
                s += f"  | {self.method}: failed: {r['reason']}"
            else:
                tip = r["tip_world_mm"]
                s += f"  | {self.method} {r['ms']:6.1f} ms  tip ({tip[0]:.2f}, {tip[1]:.2f}, {tip[2]:.2f}) mm"
                if r.get("length_mm") is not None:
                    s += f"  length {r['length_mm']:.2f} mm"
                if r.get("tip_error_mm") is not None:
                    s += f"  tip error {r['tip_error_mm']:.3f} mm  mean error {r['mean_error_mm']:.3f} mm"
        return s
