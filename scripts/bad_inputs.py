#!/usr/bin/env python
"""Survey of the bad-input classes of issue 15 against the real ``ctr-bench`` command line.

One small twin session is rendered once (scenes/paper.toml at 640x480 px with the same
field of view, 6 frames, 8 background frames, ground truth); every case copies it, spoils
one thing the way a careless or unlucky user would, runs ``ctr-bench`` as a subprocess
(``reconstruct``, ``render``, ``report``, ``verify`` or ``calibrate``) and classifies what
came out:

* ``one-line error naming the file``: rc != 0, stderr one line that names the file at
  fault, no traceback;
* ``flagged/failed frame with reason``: the run finished; the spoiled frame is failed or
  flagged with a reason (or left unscored with a note), the others are reconstructed;
* ``correct result``: the run finished and every ``ok`` frame is within 2 mm of the truth;
* a ``DEFECT``: a traceback; a silent drop (committed frames missing without a note); a
  silent duplicate; silent wrong (an ``ok`` frame more than 2 mm from the truth, which
  is recomputed here from the untouched session, not taken from the run); mixed runs
  (files of an earlier run read or left behind); an unclear message (several lines, no
  file named, a misleading reason); a resource bound not enforced.

Prints a markdown table (class | input | outcome | message) and the totals; exits 1 when
any case is a DEFECT. The disk-full case mounts a 64 KB tmpfs and needs root; it is
skipped with a note otherwise. Issue item 7 (time per frame on long runs) is not a bad
input: scripts/bench_run_dir.py measures it. Issue item 10 (hardware tests under load) is
not one either.

Usage::

    .venv/bin/python scripts/bad_inputs.py [--work DIR] [--keep] [--only TEXT]

About 5 minutes on 2 shared cores (54 cases).
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

ERR = "one-line error naming the file"
FLAG = "flagged/failed frame with reason"
OK = "correct result"
SKIP = "skipped"
D_TRACEBACK = "DEFECT: traceback"
D_DROP = "DEFECT: silent drop"
D_DUP = "DEFECT: silent duplicate"
D_WRONG = "DEFECT: silent wrong"
D_MIXED = "DEFECT: mixed runs"
D_MESSAGE = "DEFECT: unclear message"
D_BOUND = "DEFECT: unbounded"

TOLERANCE_MM = 2.0
N_FRAMES = 6
N_BACKGROUND = 8


@dataclass
class Result:
    cls: str
    input: str
    outcome: str
    message: str


@dataclass
class Proc:
    rc: int
    out: str
    err: str
    seconds: float

    @property
    def text(self) -> str:
        return self.out + self.err


def _cli() -> list:
    exe = Path(sys.executable).with_name("ctr-bench")
    if exe.is_file():
        return [str(exe)]
    found = shutil.which("ctr-bench")
    return [found] if found else [sys.executable, "-m", "rig.cli"]


CLI = _cli()


def _env(extra: dict | None = None) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("CTR_BENCH_DEBUG", "CTR_BENCH_MEMORY_LIMIT_GB")}
    env.update(extra or {})
    return env


def run(*args, env: dict | None = None, timeout: float = 300) -> Proc:
    t0 = time.monotonic()
    try:
        p = subprocess.run(CLI + [str(a) for a in args], capture_output=True, text=True, env=_env(env), timeout=timeout,
                           cwd=ROOT, errors="replace")
        return Proc(p.returncode, p.stdout, p.stderr, time.monotonic() - t0)
    except subprocess.TimeoutExpired as exc:
        out = exc.stdout.decode(errors="replace") if isinstance(exc.stdout, bytes) else (exc.stdout or "")
        err = exc.stderr.decode(errors="replace") if isinstance(exc.stderr, bytes) else (exc.stderr or "")
        return Proc(-9, out, err + f"\n[timed out after {timeout:g} s]", time.monotonic() - t0)


# ----------------------------------------------------------------------------- the session and its spoiling
class Work:
    def __init__(self, root: Path):
        self.root = root
        self.base = root / "base"
        self.scene = root / "small.toml"
        self._n = 0

    def scene_text(self, **subs) -> str:
        """scenes/paper.toml at 640x480 px (pixel pitch scaled by 1.6: the same field of view), with ``subs`` (old -> new lines)."""
        text = (ROOT / "scenes" / "paper.toml").read_text()
        repl = {'name = "paper"': 'name = "small"', "width = 1024": "width = 640", "height = 768": "height = 480",
                "pixel_size_um = 4.65": "pixel_size_um = 7.44"}
        repl.update(subs)
        for old, new in repl.items():
            assert text.count(old) >= 1, old
            text = text.replace(old, new, 1)
        return text

    def render_base(self) -> None:
        self.scene.write_text(self.scene_text())
        p = run("render", self.scene, "--n-frames", N_FRAMES, "--n-background-frames", N_BACKGROUND, "--quiet", "--out", self.base)
        if p.rc != 0:
            raise SystemExit(f"rendering the base session failed:\n{p.text}")

    def new(self, tag: str) -> Path:
        self._n += 1
        return self.root / f"{self._n:02d}-{tag}"

    def session(self, tag: str) -> Path:
        d = self.new(tag)
        shutil.copytree(self.base, d / "S")
        return d / "S"


def edit_json(path: Path, fn) -> None:
    data = json.loads(path.read_text())
    data = fn(data) or data
    path.write_text(json.dumps(data, indent=1))  # NaN/inf as NaN/Infinity, as Python writes them


def csv_lines(s: Path) -> list:
    return (s / "frames.csv").read_text().splitlines()


def write_csv(s: Path, lines: list, end: str = "\n") -> None:
    (s / "frames.csv").write_text("\n".join(lines) + end)


def set_field(s: Path, frame: int, column: str, value: str) -> None:
    lines = csv_lines(s)
    cols = lines[0].split(",")
    fields = lines[1 + frame].split(",")
    fields[cols.index(column)] = value
    lines[1 + frame] = ",".join(fields)
    write_csv(s, lines)


def white_frame(s: Path, frame: int, camera: str) -> None:
    import cv2

    p = s / "frames" / camera / f"{frame:06d}.png"
    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(p), np.full_like(img, 255))


def rig_camera(fn, camera: str = "side"):
    def mutate(rig):
        fn(rig["cameras"][camera])
    return mutate


# ----------------------------------------------------------------------------- judging
def _first_line(text: str) -> str:
    lines = [ln for ln in text.strip().splitlines() if ln.strip()]
    return lines[-1] if lines else ""


def judge_error(p: Proc, names, contains=()) -> tuple:
    """``(outcome, message)`` of a run that should stop with one line naming ``names`` (a file name, or a tuple of them)."""
    if "Traceback" in p.text:
        return D_TRACEBACK, _first_line(p.text)
    lines = [ln for ln in p.err.strip().splitlines() if ln.strip()]
    if len(lines) != 1:
        return D_MESSAGE, f"{len(lines)} lines on stderr: " + " / ".join(lines[:3])
    msg = lines[0]
    names = (names,) if isinstance(names, str) else tuple(names)
    if not any(n in msg for n in names):
        return D_MESSAGE, f"names no {' or '.join(names)}: {msg}"
    missing = [c for c in contains if c not in msg]
    if missing:
        return D_MESSAGE, f"does not say {missing[0]!r}: {msg}"
    return ERR, msg


def _truth_backbone(session: Path, frame: int):
    path = session / "truth" / f"{frame:06d}.npz"
    with np.load(path) as d:
        return np.asarray(d["backbone_world_mm"], float)


def _backbone_csv(path: Path) -> np.ndarray:
    lines = path.read_text().splitlines()
    cols = lines[0].split(",")
    idx = [cols.index(c) for c in ("x_mm", "y_mm", "z_mm")]
    rows = [ln.split(",") for ln in lines[1:] if ln.strip()]
    return np.array([[float(r[i]) for i in idx] for r in rows])


def max_error_mm(rec: np.ndarray, truth: np.ndarray) -> float:
    """Largest closest-point distance, both ways (mm); the truth is densely sampled."""
    d = np.linalg.norm(rec[:, None, :] - truth[None, :, :], axis=2)
    return float(max(d.min(axis=1).max(), d.min(axis=0).max()))


def judge_run(p: Proc, out: Path, expected: list, truth_session: Path, affected=(), reason_has=(), need_note=False,
              error_names=None, must_mark=False) -> tuple:
    """``(outcome, message)`` of a reconstruction: a finished run judged frame by frame against ``truth_session``'s truth.

    ``expected``: the frames that must be in the summary (others missing without a session
    note: a silent drop). ``affected``: the spoiled frames, which may be failed/flagged/noted.
    ``reason_has``: words one of which an affected frame's reason must hold. ``need_note``:
    the session must carry a note (a forgiven cut row). ``must_mark``: an affected frame must be
    failed, flagged or noted, and not scored (spoiled truth). A run that stopped is judged by
    :func:`judge_error` with ``error_names``.
    """
    if "Traceback" in p.text:
        return D_TRACEBACK, _first_line(p.text)
    if p.rc != 0:
        return judge_error(p, error_names or "?")
    summary_path = out / "summary.json"
    if not summary_path.is_file():
        return D_DROP, f"rc 0 and no summary.json: {_first_line(p.text)}"
    summary = json.loads(summary_path.read_text())
    per = summary.get("per_frame") or []
    notes = summary.get("session_notes") or []
    idx = [r["frame"] for r in per]
    if len(set(idx)) != len(idx):
        return D_DUP, f"frames {idx} reconstructed, a frame index twice, no error"
    missing = [f for f in expected if f not in idx]
    if missing and not notes:
        return D_DROP, f"frames {missing} missing, {len(per)} of {len(expected)} reconstructed, no note"
    if need_note and not notes:
        return D_DROP, f"{len(per)} frames and no session note"
    worst, wrong = 0.0, []
    for r in per:
        if r["status"] != "ok":
            if not r.get("reason"):
                return D_MESSAGE, f"frame {r['frame']} {r['status']} without a reason"
            continue
        csv = r.get("backbone_csv")
        if not csv:
            continue
        err = max_error_mm(_backbone_csv(out / csv), _truth_backbone(truth_session, r["frame"]))
        worst = max(worst, err)
        if err > TOLERANCE_MM:
            wrong.append((r["frame"], err))
    if wrong:
        f, e = wrong[0]
        return D_WRONG, f"{len(wrong)} ok frames beyond {TOLERANCE_MM:g} mm: frame {f} max error {e:.1f} mm"
    marked = [r for r in per if r["status"] != "ok" or r.get("note")]
    if must_mark:
        for r in per:
            if r["frame"] in affected and r not in marked:
                return D_MESSAGE, f"frame {r['frame']} {r['status']} without a note (scored: max error {r.get('max_error_mm')})"
            if r["frame"] in affected and r.get("max_error_mm") is not None:
                return D_WRONG, f"frame {r['frame']} scored against its spoiled truth: max error {r['max_error_mm']:.1f} mm"
    if reason_has:
        for r in marked:
            if r["frame"] in affected:
                why = (r.get("reason") or r.get("note") or "").lower()
                if not any(w in why for w in reason_has):
                    return D_MESSAGE, f"frame {r['frame']}: misleading reason: {why}"
    unexpected = [r["frame"] for r in marked if affected and r["frame"] not in affected]
    if missing or marked:
        if marked:
            r = next((r for r in marked if r["frame"] in affected), marked[0])
            msg = f"frame {r['frame']} {r['status']}: {r.get('reason') or r.get('note')}"
        else:
            msg = f"note: {notes[0]}"
        if unexpected:
            msg += f" (also marked: frames {unexpected})"
        if need_note:
            return OK, f"{len(per)} frames ok (max error {worst:.2f} mm); note: {notes[0]}"
        return FLAG, msg
    msg = f"{len(per)} frames ok, max error {worst:.2f} mm"
    if notes:
        msg += f"; note: {notes[0]}"
    return OK, msg


def reconstruct(work: Work, s: Path, *extra, method: str = "fast", env=None, tag="out") -> tuple:
    out = s.parent / tag
    return run("reconstruct", s, "--method", method, "--out", out, "--quiet", "--no-report", *extra, env=env), out


def case_session(work: Work, tag: str, mutate, names, *, method="fast", extra=(), env=None, expected=None,
                 affected=(), reason_has=(), contains=(), need_note=False, must_mark=False) -> tuple:
    """Spoil a copy of the session with ``mutate(S)`` and reconstruct it.

    ``None`` in ``extra`` stands for the case's own parameter file, ``p.toml`` beside the copy.
    """
    s = work.session(tag)
    mutate(s)
    extra = [s.parent / "p.toml" if a is None else a for a in extra]
    p, out = reconstruct(work, s, *extra, method=method, env=env)
    if p.rc != 0 and "Traceback" not in p.text:
        return judge_error(p, names, contains)
    return judge_run(p, out, list(range(N_FRAMES)) if expected is None else expected, work.base, affected, reason_has,
                     need_note, names, must_mark)


# ----------------------------------------------------------------------------- the cases
def frames_csv_cases(work: Work):
    cls = "1 frames.csv"

    def short_middle(s):
        lines = csv_lines(s)
        lines[3] = lines[3].rsplit(",", 1)[0]
        write_csv(s, lines)

    def long_middle(s):
        lines = csv_lines(s)
        lines[3] += ",7"
        write_csv(s, lines)

    def inserted(s):  # sed -i '3a hello,world'
        lines = csv_lines(s)
        lines.insert(3, "hello,world")
        write_csv(s, lines)

    def long_first(s):
        lines = csv_lines(s)
        lines[1] += ",0"
        write_csv(s, lines)

    def duplicate(s):
        lines = csv_lines(s)
        lines[4] = "2" + lines[4][lines[4].index(","):]
        write_csv(s, lines)

    def cut_last(s):
        text = (s / "frames.csv").read_text().rstrip("\n")
        (s / "frames.csv").write_text(text[: text.rindex(",") - 3])

    yield cls, "middle row too short (row 3 loses its last field)", lambda: case_session(work, "short", short_middle, "frames.csv")
    yield cls, "middle row too long (row 3 has an extra field)", lambda: case_session(work, "long", long_middle, "frames.csv")
    yield cls, "`sed -i '3a hello,world'`", lambda: case_session(work, "hello", inserted, "frames.csv")
    yield cls, "extra field in row 1", lambda: case_session(work, "long1", long_first, "frames.csv")
    yield cls, "duplicate frame index (row 4 says frame 2)", lambda: case_session(work, "dup", duplicate, "frames.csv")
    yield cls, "last row cut short by a crash (the one thing forgiven)", lambda: case_session(
        work, "cut", cut_last, "frames.csv", expected=list(range(N_FRAMES - 1)), need_note=True)


def out_dir_cases(work: Work):
    cls = "2 output dir"
    state = {}

    def refused():
        s = work.session("again")
        p, out = reconstruct(work, s)
        if p.rc != 0:
            return judge_error(p, "?")
        p, out = reconstruct(work, s)
        return judge_error(p, out.name, contains=("--overwrite",))

    def overwrite():
        d = work.new("overwrite")
        out = d / "out"
        p = run("reconstruct", work.base, "--method", "fast", "--out", out, "--quiet", "--no-report")
        if p.rc != 0:
            return judge_error(p, "?")
        s2 = d / "S2"
        shutil.copytree(work.base, s2)
        white_frame(s2, 2, "side")
        white_frame(s2, 2, "top")
        p = run("reconstruct", s2, "--method", "paper", "--out", out, "--quiet", "--no-report", "--overwrite")
        outcome, msg = judge_run(p, out, list(range(N_FRAMES)), work.base, affected=(2,), error_names=out.name)
        if outcome.startswith("DEFECT") or outcome == ERR:
            return outcome, msg
        summary = json.loads((out / "summary.json").read_text())
        failed = [r["frame"] for r in summary["per_frame"] if r["status"] == "failed"]
        stale = [f for f in failed if (out / "frames" / f"{f:06d}.csv").exists()]
        with np.load(out / "backbones.npz") as npz:
            in_npz = sorted(int(f) for f in npz["frames"])
        header = json.loads((out / "frames.jsonl").read_text().splitlines()[0])
        problems = []
        if summary["method"] != "paper" or header.get("method") != "paper":
            problems.append(f"summary/journal method {summary['method']}/{header.get('method')}")
        if stale:
            problems.append(f"stale frames/{stale[0]:06d}.csv of the fast run kept")
        if any(f in in_npz for f in failed):
            problems.append(f"backbones.npz holds failed frames {failed}")
        state["overwrite"] = (out, failed)
        if problems:
            return D_MIXED, "; ".join(problems)
        return OK, (f"method paper, failed frames {failed} have no CSV and are not in backbones.npz ({len(in_npz)} frames)"
                    if failed else f"method paper, no stale file (no frame failed: {msg})")

    def report_after():
        if "overwrite" not in state:
            return SKIP, "needs the --overwrite case"
        out, failed = state["overwrite"]
        p = run("report", out)
        if p.rc != 0 or "Traceback" in p.text:
            return judge_error(p, out.name)
        html = (out / "report" / "index.html").read_text(errors="replace")
        if "method fast" in html or "method paper" not in html:
            return D_MIXED, "report names the earlier run's method"
        return OK, f"report of method paper only ({p.out.strip().splitlines()[-1][:60]})"

    def verify_after():
        if "overwrite" not in state:
            return SKIP, "needs the --overwrite case"
        out, failed = state["overwrite"]
        p = run("verify", out, "--model", "bending", "--no-plots")
        if p.rc != 0 or "Traceback" in p.text:
            return judge_error(p, out.name)
        v = json.loads((out / "verify-bending" / "verify.json").read_text())
        summary = json.loads((out / "summary.json").read_text())
        want = sorted(r["frame"] for r in summary["per_frame"] if r["status"] != "failed")
        got = sorted(r["frame"] for r in v["per_frame"])
        if got != want:
            return D_MIXED, f"verify compared frames {got}, the summary reconstructed {want}"
        return OK, f"verify compared the {len(got)} frames the summary lists (not failed frames {failed})"

    def no_report():
        d = work.new("noreport")
        out = d / "out"
        p = run("reconstruct", work.base, "--method", "fast", "--out", out, "--quiet")
        if p.rc != 0:
            return judge_error(p, "?")
        had = (out / "report" / "index.html").is_file()
        p = run("reconstruct", work.base, "--method", "paper", "--out", out, "--quiet", "--no-report", "--overwrite")
        if p.rc != 0:
            return judge_error(p, out.name)
        index = out / "report" / "index.html"
        if index.is_file() and "method fast" in index.read_text(errors="replace"):
            return D_MIXED, "the fast run's report survives --overwrite --no-report"
        return OK, f"the earlier run's report ({'built' if had else 'none'}) is gone"

    def resume():
        d = work.new("resume")
        out = d / "out"
        cmd = CLI + ["reconstruct", str(work.base), "--method", "paper", "--out", str(out), "--quiet", "--no-report"]
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=_env(), cwd=ROOT)
        journal, t0, killed_at = out / "frames.jsonl", time.monotonic(), None
        while proc.poll() is None and time.monotonic() - t0 < 120:
            try:
                n = journal.read_text().count("\n")
            except OSError:
                n = 0
            if n >= 3:  # header + 2 finished frames
                proc.send_signal(signal.SIGKILL)
                killed_at = n - 1
                break
            time.sleep(0.005)
        proc.wait()
        if killed_at is None:
            return SKIP, "the run finished before it could be killed"
        run_id = json.loads(journal.read_text().splitlines()[0])["run_id"]
        p = run("reconstruct", work.base, "--method", "paper", "--out", out, "--quiet", "--no-report", "--resume")
        outcome, msg = judge_run(p, out, list(range(N_FRAMES)), work.base, error_names=out.name)
        if outcome != OK:
            return outcome, msg
        summary = json.loads((out / "summary.json").read_text())
        if summary["run_id"] != run_id or not summary["complete"]:
            return D_MIXED, f"run_id {summary['run_id']} (was {run_id}), complete {summary['complete']}"
        state["resume"] = out
        return OK, f"SIGKILL after {killed_at} frames, --resume: {msg}, same run_id"

    def resume_other():
        out = state.get("resume")
        if out is None:
            return SKIP, "needs the --resume case"
        p = run("reconstruct", work.base, "--method", "fast", "--out", out, "--quiet", "--no-report", "--resume")
        return judge_error(p, out.name, contains=("paper",))

    yield cls, "reconstruct into an earlier run's directory (no flag)", refused
    yield cls, "--overwrite with another method (paper over fast), frame 2 blank this time", overwrite
    yield cls, "report after that --overwrite", report_after
    yield cls, "verify after that --overwrite", verify_after
    yield cls, "--overwrite --no-report over a run with a report", no_report
    yield cls, "--resume of a run killed (SIGKILL) after 2 frames", resume
    yield cls, "--resume with another method", resume_other


def nan_cases(work: Work):
    cls = "3 NaN/inf"

    def params(text):
        def mutate(s):
            (s.parent / "p.toml").write_text(text)
        return mutate

    def scene_inf():
        d = work.new("inf-scene")
        d.mkdir()
        scene = d / "inf.toml"
        scene.write_text(work.scene_text(**{"outer_diameter_mm = 1.0": "outer_diameter_mm = inf"}))
        p = run("render", scene, "--n-frames", 2, "--n-background-frames", N_BACKGROUND, "--quiet", "--out", d / "S")
        if p.rc != 0 or "Traceback" in p.text:
            return judge_error(p, "inf.toml")
        p = run("reconstruct", d / "S", "--method", "paper", "--out", d / "out", "--quiet", "--no-report")
        return judge_run(p, d / "out", [0, 1], d / "S", error_names="S")

    yield cls, "t_s = nan in frames.csv (frame 2)", lambda: case_session(
        work, "tnan", lambda s: set_field(s, 2, "t_s", "nan"), "frames.csv", affected=(2,))
    yield cls, "params file knot_mm = inf", lambda: case_session(
        work, "knot", params('method = "fast"\nknot_mm = inf\n'), "p.toml", extra=("--params", None))
    yield cls, "params file max_ray_gap_mm = nan", lambda: case_session(
        work, "gap", params('method = "fast"\nmax_ray_gap_mm = nan\n'), "p.toml", extra=("--params", None))
    yield cls, "rig.json fx = 0", lambda: case_session(
        work, "fx0", lambda s: edit_json(s / "rig.json", rig_camera(lambda c: c["K"][0].__setitem__(0, 0.0))), "rig.json")
    yield cls, "scene outer_diameter_mm = inf (render, then paper)", scene_inf


def calibration_cases(work: Work):
    cls = "4 calibration"

    def shear(c):
        T = np.array(c["T_cam_world"])
        T[:3, :3] = T[:3, :3] @ np.array([[1.0, 0.1, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        c["T_cam_world"] = T.tolist()

    def scale(c):
        T = np.array(c["T_cam_world"])
        T[:3, :3] *= 1.2
        c["T_cam_world"] = T.tolist()

    def rounded(c):
        T = np.array(c["T_cam_world"])
        T[:3, :3] = np.round(T[:3, :3], 4)
        c["T_cam_world"] = T.tolist()

    def k1(c):
        c["dist"][0] = 50.0

    def nan_k(c):
        c["K"][0][2] = float("nan")

    def pp_out(c):
        c["K"][0][2] = 2000.0

    def rig_edit(fn):
        return lambda s: edit_json(s / "rig.json", rig_camera(fn))

    def calibrate_k1():
        from recon.calibration_io import save_ros_camera_info, save_world_file
        from recon.camera import Camera
        from recon.geometry import invert_transform
        from recon.rigcal import load_rig_calibration

        d = work.new("calibrate")
        d.mkdir()
        rig = load_rig_calibration(work.base / "rig.json")
        side, top = rig["side"], rig["top"]
        bad = Camera("side", side.width, side.height, side.K, dist=np.array([50.0, 0, 0, 0, 0]), T_cam_world=side.T_cam_world)
        save_ros_camera_info(d / "side.yaml", bad)
        save_ros_camera_info(d / "top.yaml", top)
        save_world_file(d / "world.yaml", top.T_cam_world, side.T_cam_world @ invert_transform(top.T_cam_world))
        out = d / "cal" / "rig.json"
        p = run("calibrate", "--import-ros", d / "side.yaml", d / "top.yaml", "--world-from", d / "world.yaml", "--out", out)
        if p.rc == 0 and out.exists():
            return D_WRONG, f"wrote {out} with k1 = 50 (refused only at the next load)"
        outcome, msg = judge_error(p, "rig.json")
        if out.exists():
            return D_MIXED, f"{msg} (but {out} was written)"
        return outcome, msg

    yield cls, "sheared rotation in side T_cam_world (shear 0.1)", lambda: case_session(work, "shear", rig_edit(shear), "rig.json")
    yield cls, "side rotation scaled by 1.2", lambda: case_session(work, "scale", rig_edit(scale), "rig.json")
    yield cls, "side rotation typed to 4 decimals", lambda: case_session(work, "round", rig_edit(rounded), "rig.json")
    yield cls, "k1 = 50 (paper)", lambda: case_session(work, "k1", rig_edit(k1), "rig.json", method="paper")
    yield cls, "NaN in K", lambda: case_session(work, "nanK", rig_edit(nan_k), "rig.json")
    yield cls, "principal point outside the image (cx = 2000)", lambda: case_session(work, "pp", rig_edit(pp_out), "rig.json")
    yield cls, "calibrate --import-ros with k1 = 50 (written?)", calibrate_k1


def traceback_cases(work: Work):
    cls = "5 structure"

    def drop_top(rig):
        del rig["cameras"]["top"]

    def rename_top(rig):
        cam = rig["cameras"].pop("top")
        cam["name"] = "cam2"
        rig["cameras"]["cam2"] = cam

    def as_list(rig):
        rig["cameras"] = list(rig["cameras"].values())

    def meta_list(s):
        (s / "session.json").write_text(json.dumps([json.loads((s / "session.json").read_text())]))

    def robot_inf(meta):
        meta["robot"]["tubes"][1]["outer_diameter_mm"] = float("inf")

    yield cls, "camera 'top' missing from rig.json", lambda: case_session(
        work, "notop", lambda s: edit_json(s / "rig.json", drop_top), "rig.json")
    yield cls, "camera 'top' renamed 'cam2' in rig.json", lambda: case_session(
        work, "rename", lambda s: edit_json(s / "rig.json", rename_top), "rig.json")
    yield cls, "rig.json cameras given as a list", lambda: case_session(
        work, "camlist", lambda s: edit_json(s / "rig.json", as_list), "rig.json")
    yield cls, "session.json given as a list", lambda: case_session(work, "metalist", meta_list, "session.json")
    yield cls, "session.json robot tube outer_diameter_mm = Infinity (paper)", lambda: case_session(
        work, "robotinf", lambda s: edit_json(s / "session.json", robot_inf), "session.json", method="paper")


def resource_cases(work: Work):
    cls = "6 resources"

    def carving(s):
        (s.parent / "p.toml").write_text('method = "paper"\n[carving]\nresolution = 2000\n')

    def claim(width, height):
        def mutate(s):
            def fn(c):
                c["width"], c["height"] = width, height
            edit_json(s / "rig.json", rig_camera(fn, "top"))
        return mutate

    def big_scene():
        d = work.new("bigscene")
        d.mkdir()
        scene = d / "big.toml"
        scene.write_text(work.scene_text(**{"width = 640": "width = 8192", "height = 480": "height = 8192"}))
        p = run("render", scene, "--n-frames", 1, "--n-background-frames", 6, "--quiet", "--out", d / "S", timeout=60)
        if p.rc == -9:
            return D_BOUND, f"still rendering after {p.seconds:.0f} s"
        if p.rc == 0:
            return D_BOUND, "rendered an 8192x8192 scene without a check"
        outcome, msg = judge_error(p, "big.toml", contains=("GB",))
        return outcome, msg + f" [{p.seconds:.1f} s]"

    yield cls, "params [carving] resolution = 2000 (paper)", lambda: case_session(
        work, "carve", carving, "p.toml", method="paper", extra=("--params", None), contains=("GB",))
    yield cls, "8192x8192 scene (render)", big_scene
    yield cls, "8000x6000 session (rig.json top camera)", lambda: case_session(
        work, "8000", claim(8000, 6000), "rig.json", contains=("GB",))
    yield cls, "rig.json says 1280x960, the images are 640x480", lambda: case_session(
        work, "size", claim(1280, 960), ("rig.json", ".png"))


def truth_cases(work: Work):
    cls = "8 ground truth"
    runs = {}

    def missing(s):
        (s / "truth" / "000002.npz").unlink()

    def two_columns(s):
        p = s / "truth" / "000002.npz"
        with np.load(p) as d:
            arrays = {k: d[k] for k in d}
        arrays["backbone_world_mm"] = arrays["backbone_world_mm"][:, :2]
        np.savez(p, **arrays)

    def corrupt(s):
        (s / "truth" / "000002.npz").write_bytes(b"PK\x03\x04 this is no npz archive" * 10)

    def reconstructed(tag, mutate):
        def case():
            s = work.session(tag)
            mutate(s)
            p, out = reconstruct(work, s)
            runs[tag] = (s, out)
            return judge_run(p, out, list(range(N_FRAMES)), work.base, affected=(2,), reason_has=("000002.npz",),
                             error_names="000002.npz", must_mark=True)
        return case

    def reported(tag):
        def case():
            if tag not in runs:
                return SKIP, "needs the reconstruction case"
            s, out = runs[tag]
            p = run("report", out)
            if p.rc != 0 or "Traceback" in p.text:
                return judge_error(p, "000002.npz")
            return OK, f"report built ({_first_line(p.text)})"
        return case

    def verified(tag):
        def case():
            if tag not in runs:
                return SKIP, "needs the reconstruction case"
            s, out = runs[tag]
            p = run("verify", s, "--model", "bending", "--no-plots", "--out", s.parent / "verify")
            if p.rc != 0 or "Traceback" in p.text:
                return judge_error(p, "000002.npz")
            v = json.loads((s.parent / "verify" / "verify.json").read_text())
            frames = sorted(r["frame"] for r in v["per_frame"])
            skipped = v.get("skipped") or []
            if 2 in frames:
                return D_WRONG, f"frame 2 compared with its spoiled truth: {v['per_frame'][frames.index(2)]}"
            return (FLAG if skipped else D_DROP), f"frames {frames} compared, skipped: {skipped}"
        return case

    def with_report():
        s = work.session("corrupt-report")
        corrupt(s)
        out = s.parent / "out"
        p = run("reconstruct", s, "--method", "fast", "--out", out, "--quiet")
        outcome, msg = judge_run(p, out, list(range(N_FRAMES)), work.base, affected=(2,), error_names="000002.npz",
                                 must_mark=True)
        if outcome.startswith("DEFECT") or outcome == ERR:
            return outcome, msg
        note = [ln for ln in p.err.splitlines() if ln.startswith("report: not built")]
        if note:
            return D_MESSAGE, note[0]
        return OK, f"report built; {msg}"

    for tag, name, mutate in (("truthmissing", "truth/000002.npz missing", missing),
                              ("truth2", "(n, 2) truth backbone in truth/000002.npz", two_columns),
                              ("truthbad", "corrupt truth/000002.npz", corrupt)):
        yield cls, f"{name}: reconstruct", reconstructed(tag, mutate)
        yield cls, f"{name}: report of that run", reported(tag)
        yield cls, f"{name}: verify the session (truth as the measurement)", verified(tag)
    yield cls, "corrupt truth/000002.npz: reconstruct with its report", with_report


def message_cases(work: Work):
    cls = "9 messages"

    def binary(name):
        def mutate(s):
            (s / name).write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe\x00\x00garbage" * 4)
        return mutate

    def n_tubes(meta):
        meta["n_tubes"] = "two"

    def cameras_side(meta):
        meta["cameras"] = "side"

    def white(s):
        white_frame(s, 2, "side")
        white_frame(s, 2, "top")

    def zero_frames(s):
        write_csv(s, csv_lines(s)[:1])

    def directory(s):
        p = s / "frames" / "top" / "000002.png"
        p.unlink()
        p.mkdir()

    def truncated_png(s):
        p = s / "frames" / "side" / "000002.png"
        p.write_bytes(p.read_bytes()[:200])

    def few_backgrounds(s):
        for cam in ("side", "top"):
            for p in sorted((s / "background" / cam).glob("*.png"))[3:]:
                p.unlink()
        edit_json(s / "session.json", lambda m: m.__setitem__("background_frames", 3))

    def disk_full():
        if os.geteuid() != 0:
            return SKIP, "needs root to mount a 64 KB tmpfs"
        d = work.new("diskfull")
        mnt = d / "full"
        mnt.mkdir(parents=True)
        m = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)], capture_output=True, text=True)
        if m.returncode != 0:
            return SKIP, f"cannot mount a tmpfs: {m.stderr.strip()[:60]}"
        try:
            p = run("reconstruct", work.base, "--method", "fast", "--out", mnt / "out", "--quiet", "--no-report")
            if p.rc == 0:
                return D_DROP, "rc 0 on a full disk"
            outcome, msg = judge_error(p, str(mnt / "out"))
            if outcome == ERR and "errno 28" not in msg.lower() and "no space" not in msg.lower():
                return D_MESSAGE, f"does not say the disk is full: {msg}"
            return outcome, msg
        finally:
            subprocess.run(["umount", str(mnt)], capture_output=True)

    yield cls, "binary session.json", lambda: case_session(work, "binmeta", binary("session.json"), "session.json")
    yield cls, "binary frames.csv", lambda: case_session(work, "bincsv", binary("frames.csv"), "frames.csv")
    yield cls, 'session.json n_tubes: "two"', lambda: case_session(
        work, "ntubes", lambda s: edit_json(s / "session.json", n_tubes), "session.json", contains=("n_tubes",))
    yield cls, "all-white frame 2 (both cameras)", lambda: case_session(
        work, "white", white, "000002.png", affected=(2,), reason_has=("blank", "flat", "uniform", "white", "saturat"))
    yield cls, 'session.json cameras: "side"', lambda: case_session(
        work, "camstr", lambda s: edit_json(s / "session.json", cameras_side), "session.json", contains=("cameras",))
    yield cls, "disk full (64 KB tmpfs as --out)", disk_full
    yield cls, "0 frames (frames.csv header only)", lambda: case_session(work, "zero", zero_frames, "frames.csv")
    yield cls, "frame path frames/top/000002.png is a directory", lambda: case_session(
        work, "isdir", directory, "000002.png", affected=(2,), reason_has=("directory",))
    yield cls, "truncated PNG frames/side/000002.png", lambda: case_session(
        work, "trunc", truncated_png, "000002.png", affected=(2,), reason_has=("000002.png",))
    yield cls, "3 background frames (eigenbackgrounds need 6)", lambda: case_session(
        work, "fewbg", few_backgrounds, "background")


GROUPS = (frames_csv_cases, out_dir_cases, nan_cases, calibration_cases, traceback_cases, resource_cases, truth_cases,
          message_cases)


def _short(text: str, root: Path) -> str:
    """A message without the ``ctr-bench CMD: error:`` prefix, case folders shown as ``W/NN-case/``."""
    text = re.sub(r"^ctr-bench [a-z-]+: error: ", "", str(text))
    return text.replace(str(root), "W")


def _cell(text: str, n: int = 100) -> str:
    text = " ".join(str(text).split())
    text = text if len(text) <= n else text[: n - 1] + "…"
    return text.replace("|", "\\|")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", type=Path, default=None, help="work directory (default: a new temporary one)")
    ap.add_argument("--keep", action="store_true", help="keep the work directory")
    ap.add_argument("--only", default=None, help="run only the cases whose class or input contains TEXT")
    args = ap.parse_args(argv)
    root = args.work or Path(tempfile.mkdtemp(prefix="ctr-bad-inputs-"))
    root.mkdir(parents=True, exist_ok=True)
    work = Work(root)
    results = []
    t0 = time.monotonic()
    try:
        work.render_base()
        for group in GROUPS:
            for cls, name, fn in group(work):
                if args.only and args.only.lower() not in f"{cls} {name}".lower():
                    continue
                try:
                    outcome, msg = fn()
                except Exception as exc:  # noqa: BLE001 (the survey itself went wrong: say so, go on)
                    outcome, msg = "SURVEY ERROR", f"{type(exc).__name__}: {exc}"
                results.append(Result(cls, name, outcome, msg))
                print(f"  {cls:15s} {name[:60]:60s} {outcome}", file=sys.stderr, flush=True)
    finally:
        if not args.keep and args.work is None:
            shutil.rmtree(root, ignore_errors=True)
    print("| class | input | outcome | message |")
    print("|---|---|---|---|")
    for r in results:
        print(f"| {r.cls} | {_cell(r.input, 80)} | {r.outcome} | {_cell(_short(r.message, root))} |")
    totals = {}
    for r in results:
        key = "DEFECT" if r.outcome.startswith("DEFECT") else r.outcome
        totals[key] = totals.get(key, 0) + 1
    print()
    print(f"{len(results)} cases in {time.monotonic() - t0:.0f} s: " + ", ".join(f"{v} {k}" for k, v in totals.items()))
    print("Not inputs, not surveyed here: issue item 7 (time per frame over long runs: scripts/bench_run_dir.py) and item 10 "
          "(hardware tests under load).")
    if any(r.outcome == "SURVEY ERROR" for r in results):
        return 2
    return 1 if totals.get("DEFECT") else 0


if __name__ == "__main__":
    sys.exit(main())
