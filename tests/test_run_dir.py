"""The output directory is the run's (issue 15, items 2, 3, 7 and the disk-full message of 9).

* A run into a directory holding an earlier run is refused unless ``--overwrite``
  (removes what the earlier run wrote, nothing else) or ``--resume`` (keeps its
  finished frames; same method and parameters, else refused naming the difference).
* ``report`` and ``verify`` read only the files the summary lists.
* Every finished frame is a flushed line of ``frames.jsonl``: a SIGKILL loses none,
  and ``--resume`` finishes the run.
* NaN and infinities never abort a run: JSON says null, a non-finite backbone fails its frame.
* A failed write is one line naming the file; the frames finished before are kept.

One twin frame is rendered once; the sessions repeat it (the bookkeeping is under
test, not the reconstruction). Fake methods (``recon.methods.METHODS``) fail or
return non-finite values on chosen frames.
"""
from __future__ import annotations

import csv
import errno
import itertools
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from recon.errors import FrameError
from recon.methods import METHODS, Method
from rig import rundir, scoring
from rig.bench.reconstruct import reconstruct_session
from rig.rundir import read_run
from rig.session import Session, SessionWriter

N_BACKGROUND = 8
N_FRAMES = 4
TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent


# ----------------------------------------------------------------------------- fake methods
@dataclass(frozen=True)
class FakeParams:
    outer_tube_radius_mm: float = 0.8
    inner_tube_radius_mm: float = 0.5
    limit_mm: float = float("inf")  # a limit that is off: written as null, never an aborted write


def fake_method(name: str, answer, calls: list | None = None, sleep_s: float = 0.0) -> Method:
    """A method whose k-th call returns the backbone ``answer(k)`` (which may raise ``FrameError``)."""
    def prepare(rig, background_frames, params):
        counter = itertools.count()

        def reconstruct(images):
            k = next(counter)
            if calls is not None:
                calls.append(k)
            time.sleep(sleep_s)
            pts = np.asarray(answer(k), float)
            return SimpleNamespace(points_world_mm=pts, tip_world_mm=pts[-1], length_mm=float("nan"),
                                   transition_s_mm=float("inf"), timings_ms={"total": float("nan")})
        return reconstruct

    return Method(name, FakeParams, prepare, "test: " + name)


def _line(k=0) -> np.ndarray:
    """A straight backbone along the insertion axis."""
    return np.linspace([0.0, 0.0, 0.0], [40.0, 0.0, 0.0], 21)


def run_slow(session, out) -> None:
    """The run the SIGKILL test kills (in a subprocess): 0.25 s per frame, no self-check."""
    METHODS["slow"] = fake_method("slow", _line, sleep_s=0.25)
    reconstruct_session(session, out, "slow", selfcheck=None)


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def rendered(paper_twin):
    """Background images and one frame (its images, joints and truth)."""
    from twin.record import truth_arrays

    backgrounds = [paper_twin.background(i).images for i in range(N_BACKGROUND)]
    frame = paper_twin.frame(3)
    return SimpleNamespace(backgrounds=backgrounds, frame=frame, truth=truth_arrays(frame),
                           points=frame.backbone.p_world_mm)


def write_session(directory: Path, rendered, scene, n_frames: int = N_FRAMES) -> Path:
    """A session repeating the rendered frame ``n_frames`` times (joints and truth included, for verify)."""
    from twin.robotfile import robot_to_dict

    meta = {"scene": scene.source, "scene_name": scene.name, "robot": robot_to_dict(scene.robot, scene.model)}
    with SessionWriter(directory, scene.rig, source="twin", n_tubes=scene.robot.n_tubes, meta=meta) as w:
        for i, imgs in enumerate(rendered.backgrounds):
            w.add_background(i, imgs)
        for i in range(n_frames):
            w.add_frame(i, rendered.frame.images, t_s=float(i), joints=rendered.frame.joints, truth=rendered.truth)
    return directory


@pytest.fixture(scope="module")
def session(tmp_path_factory, rendered, paper_scene) -> Path:
    return write_session(tmp_path_factory.mktemp("rundir") / "session", rendered, paper_scene)


def cli(*argv) -> int:
    from rig.cli import main

    return main([str(a) for a in argv])


@pytest.fixture(scope="module")
def fast_run(session, tmp_path_factory) -> Path:
    """A finished ``reconstruct --method fast`` run, with its report: copied by the tests that need an earlier run."""
    from rig.bench.report import build_report

    out = tmp_path_factory.mktemp("fast") / "out"
    assert cli("reconstruct", session, "--out", out, "--method", "fast", "--no-report", "--quiet") == 0
    build_report(out, meshes=False, overlays=False)
    return out


@pytest.fixture
def earlier(fast_run, tmp_path) -> Path:
    out = tmp_path / "out"
    shutil.copytree(fast_run, out)
    return out


def _summary(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())


def _last_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err, "no error line"
    return err[-1]


def _strict_json(path: Path):
    """Parse ``path`` refusing NaN and Infinity tokens (which JSON does not have)."""
    def refuse(token):
        raise AssertionError(f"{path}: {token} written")

    text = path.read_text()
    if path.suffix == ".jsonl":
        return [json.loads(line, parse_constant=refuse) for line in text.splitlines()]
    return json.loads(text, parse_constant=refuse)


# ----------------------------------------------------------------------------- the live view
def test_the_live_view_reads_the_journal_and_the_backbone_its_record_lists(fast_run, session):
    import io

    from rig.live import LiveLogger

    calls, msg = [], io.StringIO()
    fake = SimpleNamespace(
        init=lambda *a, **k: None, set_time=lambda name, **k: None, log=lambda path, obj: calls.append((path, obj)),
        Image=lambda d: ("Image", d.shape), LineStrips2D=lambda s, colors: ("L2", len(s[0])),
        LineStrips3D=lambda s, colors: ("L3", len(s[0])), Scalars=lambda v: ("S", v), TextLog=lambda t: ("T", t))
    LiveLogger(rr=fake, stream=msg).watch(session, fast_run)("reconstruct", N_FRAMES, N_FRAMES)
    assert msg.getvalue() == ""
    summary, backbones = read_run(fast_run)
    last = summary["per_frame"][-1]
    logged = dict(calls)
    assert logged["world/reconstruction"] == ("L3", len(backbones[last["frame"]]))
    assert logged["errors/mean_error_mm"] == ("S", last["mean_error_mm"])


# ----------------------------------------------------------------------------- refuse / overwrite
def test_a_run_into_an_earlier_runs_directory_is_refused(earlier, session, capsys):
    before = _summary(earlier)
    assert before["method"] == "fast" and before["complete"] and before["frames"] == N_FRAMES
    assert cli("reconstruct", session, "--out", earlier, "--method", "paper", "--no-report", "--quiet") == 2
    line = _last_error(capsys)
    assert f"{earlier}: holds an earlier run (method 'fast', {N_FRAMES} frames)" in line
    assert "--overwrite" in line and "--resume" in line
    assert _summary(earlier)["run_id"] == before["run_id"]  # nothing touched


def test_a_directory_with_only_user_files_is_used_and_the_files_kept(session, tmp_path, monkeypatch):
    monkeypatch.setitem(METHODS, "line", fake_method("line", _line))
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    reconstruct_session(session, out, "line", selfcheck=None)
    assert (out / "notes.txt").read_text() == "mine"


def test_a_session_directory_is_never_an_output_directory(session, tmp_path, monkeypatch):
    monkeypatch.setitem(METHODS, "line", fake_method("line", _line))
    copy = tmp_path / "session"
    shutil.copytree(session, copy)
    with pytest.raises(rundir.RunDirError, match="is a session directory"):
        reconstruct_session(copy, copy, "line", selfcheck=None, existing="overwrite")
    assert len(Session(copy).frames) == N_FRAMES


def test_overwrite_removes_the_earlier_run_and_report_and_verify_see_only_the_new_one(earlier, session, rendered,
                                                                                    monkeypatch, capsys):
    """A frame that failed this time leaves no old file; report and verify draw the new run only."""
    from rig.bench.modeldata import load_dataset
    from rig.bench.report import load_run

    old = _summary(earlier)
    assert (earlier / "report" / "index.html").exists() and (earlier / "frames" / "000001.csv").exists()
    (earlier / "notes.txt").write_text("mine")

    def odd_fail(k):
        if k % 2:
            raise FrameError("no silhouette (test)", "side")
        return rendered.points

    monkeypatch.setitem(METHODS, "odd-fail", fake_method("odd-fail", odd_fail))
    assert cli("reconstruct", session, "--out", earlier, "--method", "odd-fail", "--overwrite", "--no-report", "--quiet") == 0
    new = _summary(earlier)
    assert new["run_id"] != old["run_id"] and new["method"] == "odd-fail" and new["failed_frames"] == 2
    assert sorted(p.name for p in (earlier / "frames").iterdir()) == ["000000.csv", "000002.csv"]
    assert not (earlier / "report").exists()  # a stale report naming the other method is gone
    assert (earlier / "notes.txt").read_text() == "mine"
    with np.load(earlier / "backbones.npz") as z:
        assert list(z["frames"]) == [0, 2]

    run = load_run(earlier)
    assert run.summary["method"] == "odd-fail" and sorted(run.backbones) == [0, 2]
    ds = load_dataset(earlier)
    assert [f.index for f in ds.frames] == [0, 2]
    assert dict(ds.skipped) == {1: "no backbone (side: no silhouette (test))", 3: "no backbone (side: no silhouette (test))"}
    np.testing.assert_allclose(ds.frames[0].points_mm, rendered.points, atol=1e-3)


def test_a_stale_backbones_file_is_an_error_naming_it(earlier, capsys):
    """Another run's backbones.npz (here: one frame of this one) is never drawn under this run's method."""
    with np.load(earlier / "backbones.npz") as z:
        other = {0: z["frame_000000"]}
    rundir.write_backbones_npz(earlier / "backbones.npz", other)
    with pytest.raises(ValueError, match="not the file the run wrote"):
        read_run(earlier)
    for command in (["report", earlier, "--no-overlays", "--quiet"], ["verify", earlier, "--no-plots"]):
        assert cli(*command) == 2
        line = _last_error(capsys)
        assert f"{earlier / 'backbones.npz'}: not the file the run wrote" in line, line


def test_a_stale_frame_csv_of_a_run_cut_short_is_an_error_naming_it(earlier):
    summary = _summary(earlier)
    summary.update(complete=False, files={**summary["files"], "backbones": None, "backbones_sha1": None})  # killed before its end
    rundir.write_json_atomic(earlier / "summary.json", summary)
    (earlier / "backbones.npz").unlink()
    assert sorted(read_run(earlier)[1]) == list(range(N_FRAMES))
    stale = earlier / "frames" / "000002.csv"
    stale.write_text(stale.read_text().replace("0.", "1.", 3))
    with pytest.raises(ValueError) as err:
        read_run(earlier)
    assert str(err.value).startswith(f"{stale}: not the file the run wrote")


def test_a_summary_without_run_id_reads_only_the_frames_it_lists(earlier):
    """Summaries of older versions (and experiment's live view) list frames, not files: no other frame is drawn."""
    summary = _summary(earlier)
    for key in ("run_id", "complete", "files"):
        summary.pop(key)
    summary["per_frame"][1].update(status="failed", reason="failed this time")
    rundir.write_json_atomic(earlier / "summary.json", summary)
    assert sorted(read_run(earlier)[1]) == [0, 2, 3]
    (earlier / "backbones.npz").unlink()
    assert sorted(read_run(earlier)[1]) == [0, 2, 3]


# ----------------------------------------------------------------------------- resume
def test_resume_skips_finished_frames_and_refuses_another_method_or_parameters(session, tmp_path, monkeypatch, capsys):
    calls = []
    monkeypatch.setitem(METHODS, "line", fake_method("line", _line, calls))
    out = tmp_path / "out"
    first = reconstruct_session(session, out, "line", frames={0, 1}, selfcheck=None)
    assert first["frames"] == 2 and len(calls) == 2
    calls.clear()
    done = reconstruct_session(session, out, "line", selfcheck=None, existing="resume")
    assert len(calls) == N_FRAMES - 2  # frames 0 and 1 were kept, not done again
    assert done["run_id"] == first["run_id"] and done["complete"] and [r["frame"] for r in done["per_frame"]] == [0, 1, 2, 3]
    assert len((out / "frames.jsonl").read_text().splitlines()) == 1 + N_FRAMES
    assert [int(r["frame"]) for r in csv.DictReader((out / "frames.csv").open())] == [0, 1, 2, 3]

    assert cli("reconstruct", session, "--out", out, "--method", "fast", "--resume", "--no-report", "--quiet") == 2
    assert "--resume: the earlier run used method 'line', not 'fast'" in _last_error(capsys)
    with pytest.raises(rundir.RunDirError, match=r"had params inner_tube_radius_mm = 0.5, not 0.4"):
        reconstruct_session(session, out, "line", params=replace(FakeParams(), inner_tube_radius_mm=0.4),
                            selfcheck=None, existing="resume")
    with pytest.raises(rundir.RunDirError, match="had the self-check off"):
        reconstruct_session(session, out, "line", existing="resume")


def test_sigkill_mid_run_keeps_every_finished_frame_and_resume_finishes(session, tmp_path, monkeypatch):
    out = tmp_path / "out"
    journal = out / "frames.jsonl"
    code = f"import test_run_dir as t; t.run_slow({str(session)!r}, {str(out)!r})"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(TESTS), os.environ.get("PYTHONPATH")])))
    proc = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while not (journal.exists() and len(journal.read_text().splitlines()) >= 3):  # header + 2 frames
            assert proc.poll() is None, proc.stderr.read().decode()
            assert time.monotonic() < deadline, "the run did not start"
            time.sleep(0.05)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait()
    kept = len(journal.read_text().splitlines()) - 1
    assert 2 <= kept < N_FRAMES, kept
    assert not _summary(out)["complete"]
    summary, backbones = read_run(out)  # rebuilt from the journal: summary.json is only rewritten every few seconds
    assert summary["frames"] == kept and sorted(backbones) == list(range(kept))

    calls = []
    monkeypatch.setitem(METHODS, "slow", fake_method("slow", _line, calls))
    done = reconstruct_session(session, out, "slow", selfcheck=None, existing="resume")
    assert len(calls) == N_FRAMES - kept
    assert done["complete"] and done["frames"] == N_FRAMES and done["failed_frames"] == 0
    assert sorted(read_run(out)[1]) == list(range(N_FRAMES))


def test_the_journal_forgives_only_a_torn_last_line(tmp_path):
    path = tmp_path / "frames.jsonl"
    header = rundir.journal_header("line", {}, None, tmp_path)
    path.write_text(json.dumps(header) + '\n{"frame": 0}\n{"frame": 1}\n{"fra')
    assert [r["frame"] for r in rundir.read_journal(path)[1]] == [0, 1]
    path.write_text(json.dumps(header) + '\n{"frame": 0}\nhello, world\n{"frame": 2}\n')
    with pytest.raises(ValueError, match=f"^{path}:3: not a JSON record$"):
        rundir.read_journal(path)


# ----------------------------------------------------------------------------- NaN and inf
def test_nan_time_and_non_finite_results_give_nulls_and_failed_frames(session, rendered, tmp_path, monkeypatch):
    import rig.bench.reconstruct as rr

    class NanTimes(Session):  # as a frames.csv with t_s = nan would give, whatever the session reader allows
        def __init__(self, directory):
            super().__init__(directory)
            self.frames = [replace(f, t_s=float("nan")) if f.index == 0 else f for f in self.frames]

    answers = {0: rendered.points, 1: np.full((5, 3), np.nan), 2: np.vstack([rendered.points, [[np.inf, 0, 0]]]),
               3: rendered.points}
    monkeypatch.setattr(rr, "Session", NanTimes)
    monkeypatch.setattr(scoring, "backbone_errors", lambda pts, truth, rig=None: {"mean_error_mm": float("inf"), "max_error_mm": float("nan"),
                                                                                 "tip_error_mm": 0.1, "length_error_mm": -float("inf")})
    monkeypatch.setitem(METHODS, "nan", fake_method("nan", answers.__getitem__))
    summary = reconstruct_session(session, tmp_path / "out", "nan")
    recs = summary["per_frame"]
    assert [r["status"] for r in recs] == ["ok", "failed", "failed", "ok"]
    assert recs[1]["reason"] == "the reconstruction has 5 non-finite backbone points of 5"
    assert recs[2]["reason"] == f"the reconstruction has 1 non-finite backbone points of {len(rendered.points) + 1}"
    assert recs[0]["t_s"] is None and recs[0]["length_mm"] is None and recs[0]["transition_s_mm"] is None
    assert recs[0]["mean_error_mm"] is None and recs[0]["tip_error_mm"] == 0.1 and recs[0]["timings_ms"]["total"] is None
    assert summary["params"]["limit_mm"] is None and summary["mean_error_mm"] is None
    out = tmp_path / "out"
    on_disk = _strict_json(out / "summary.json")
    assert on_disk["per_frame"][0]["t_s"] is None and on_disk["frames"] == N_FRAMES
    lines = _strict_json(out / "frames.jsonl")
    assert lines[0]["params"]["limit_mm"] is None and lines[1]["t_s"] is None
    rows = list(csv.DictReader((out / "frames.csv").open()))
    assert rows[0]["t_s"] == "" and rows[0]["mean_error_mm"] == "" and rows[1]["status"] == "failed"
    assert sorted(p.name for p in (out / "frames").iterdir()) == ["000000.csv", "000003.csv"]


# ----------------------------------------------------------------------------- failed writes
class _FullDisk:
    """A file whose writes fail with ENOSPC after ``left`` more (as a full disk's: the error names no file)."""

    def __init__(self, fh, left: int):
        self._fh, self._left = fh, left

    def write(self, text):
        self._left -= 1
        if self._left < 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return self._fh.write(text)

    def __getattr__(self, name):
        return getattr(self._fh, name)


@pytest.mark.parametrize("target", ["frame csv", "journal"])
def test_a_full_disk_is_one_line_naming_the_file_and_finished_frames_are_kept(target, session, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(METHODS, "line", fake_method("line", _line))
    out = tmp_path / "out"
    if target == "frame csv":
        real, written = rundir.write_backbone_csv, []

        def write(path, pts):
            if len(written) == 2:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            written.append(path)
            return real(path, pts)

        monkeypatch.setattr(rundir, "write_backbone_csv", write)
        failed = out / "frames" / "000002.csv"
    else:
        init = rundir.Journal.__init__

        def full_after_two(self, *a, **k):
            init(self, *a, **k)
            self._fh = _FullDisk(self._fh, 2)

        monkeypatch.setattr(rundir.Journal, "__init__", full_after_two)
        failed = out / "frames.jsonl"
    assert cli("reconstruct", session, "--out", out, "--method", "line", "--no-report", "--quiet") == 2
    line = _last_error(capsys)
    assert line.startswith(f"ctr-bench reconstruct: error: {failed}: cannot write: No space left on device [errno 28]"), line
    assert "the 2 frames finished are kept" in line and "Traceback" not in capsys.readouterr().err
    summary, backbones = read_run(out)
    assert summary["frames"] == 2 and sorted(backbones) == [0, 1]
    monkeypatch.undo()
    monkeypatch.setitem(METHODS, "line", fake_method("line", _line))
    assert cli("reconstruct", session, "--out", out, "--method", "line", "--resume", "--no-report", "--quiet") == 0
    assert _summary(out)["frames"] == N_FRAMES


# ----------------------------------------------------------------------------- ctr-bench run
def test_run_refuses_a_used_directory_before_rendering(session, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    assert cli("run", "--n-frames", "1", "--out", out, "--quiet", "--no-report") == 2
    assert f"--out {out}: exists and is not empty" in _last_error(capsys)
    shutil.copytree(session, out / "session")  # the whole of another scene: --resume must not reuse it
    assert cli("run", "--n-frames", "1", "--out", out, "--quiet", "--no-report", "--resume") == 2
    line = _last_error(capsys)
    assert line.endswith("(a render cut short, or another scene); --overwrite renders it again") and f"{out / 'session'}:" in line


@pytest.mark.parametrize("tail_bytes", [1 << 16, 64])
def test_last_journal_record_reads_the_end(tmp_path, tail_bytes):
    # The live view reads the newest frame after every frame: from the journal's end, a torn line skipped.
    path = tmp_path / rundir.JOURNAL
    head = rundir.journal_header("fast", {}, None, tmp_path)
    assert rundir.last_journal_record(_journal(path, head, [])) is None
    j = rundir.Journal(path, head, [{"frame": 0, "status": "ok"}, {"frame": 1, "status": "failed"}])
    j.close()
    assert rundir.last_journal_record(path, tail_bytes)["frame"] == 1
    with open(path, "a") as fh:
        fh.write('{"frame": 2, "sta')  # a kill in the middle of a line
    assert rundir.last_journal_record(path, tail_bytes)["frame"] == 1


def _journal(path, head, records):
    rundir.Journal(path, head, records).close()
    return path
