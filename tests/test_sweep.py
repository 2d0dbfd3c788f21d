"""Sweeps on Dask distributed (rig/bench/sweep.py): real schedulers and workers, a killed worker, resuming.

The task functions live in this module: the scheduler and worker processes the tests start get
tests/ on their PYTHONPATH, as a lab's workers get the environment the sweep's code is in.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rig.bench.sweep import Journal, SweepError, Task, dask_client, require_all, run_sweep, task_digest

DASK = Path(sys.executable).with_name("dask")


def slow_square(x: int, marks: str, seconds: float) -> dict:
    """x squared after ``seconds``, leaving a file in ``marks`` for each execution (pid and time in its name)."""
    time.sleep(seconds)
    Path(marks, f"{x}-{os.getpid()}-{time.monotonic_ns()}").touch()
    return {"x": x, "square": x * x, "pid": os.getpid()}


def fails(x: int) -> dict:
    raise RuntimeError(f"task {x} cannot be done\nsecond line")


def _tasks(n: int, marks: Path, seconds: float) -> list:
    return [Task(f"t{x}", slow_square, (x, str(marks), seconds), task_digest("square", x)) for x in range(n)]


def _executions(marks: Path) -> dict:
    out: dict = {}
    for p in marks.iterdir():
        out[int(p.name.split("-")[0])] = out.get(int(p.name.split("-")[0]), 0) + 1
    return out


@pytest.fixture
def scheduler(tmp_path):
    """A real ``dask scheduler`` and two ``dask worker`` processes (one thread each) on 127.0.0.1."""
    sched_file = tmp_path / "scheduler.json"
    here = str(Path(__file__).parent)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [here, os.environ.get("PYTHONPATH")])))
    procs = [subprocess.Popen([str(DASK), "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(sched_file)], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    deadline = time.monotonic() + 60
    while not sched_file.exists() and time.monotonic() < deadline:
        time.sleep(0.2)
    assert sched_file.exists(), "dask scheduler did not start within 60 s"
    address = json.loads(sched_file.read_text())["address"]
    for _ in range(2):
        procs.append(subprocess.Popen([str(DASK), "worker", address, "--nthreads", "1", "--nworkers", "1",
                                       "--no-nanny", "--no-dashboard", "--host", "127.0.0.1", "--death-timeout", "30"], env=env,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
    try:
        yield address, procs[1:]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
            p.wait(timeout=30)


def _wait_workers(client, n: int) -> None:
    client.wait_for_workers(n, timeout=60)


def test_sweep_on_a_real_scheduler_equals_the_serial_run(tmp_path, scheduler):
    address, _ = scheduler
    marks = tmp_path / "marks"
    marks.mkdir()
    tasks = _tasks(4, marks, 0.2)
    serial = [t.fn(*t.args) for t in tasks]
    with dask_client(address) as client:
        _wait_workers(client, 2)
        results = run_sweep(client, tasks, Journal(tmp_path / "journal.jsonl"))
    assert [(r["x"], r["square"]) for r in results] == [(s["x"], s["square"]) for s in serial]
    assert len({r["pid"] for r in results}) == 2, "both workers should have taken tasks"
    lines = [json.loads(line) for line in (tmp_path / "journal.jsonl").read_text().splitlines()]
    assert sorted(rec["key"] for rec in lines) == ["t0", "t1", "t2", "t3"]


def test_a_worker_killed_mid_sweep_loses_and_duplicates_nothing(tmp_path, scheduler):
    address, workers = scheduler
    marks = tmp_path / "marks"
    marks.mkdir()
    tasks = _tasks(8, marks, 0.6)
    killed = []

    def progress(stage, done, total):
        if done == 2 and not killed:  # both workers busy with their next tasks
            workers[0].send_signal(signal.SIGKILL)
            killed.append(done)

    with dask_client(address) as client:
        _wait_workers(client, 2)
        results = run_sweep(client, tasks, Journal(tmp_path / "journal.jsonl"), progress=progress)
    assert killed, "the worker was never killed"
    assert [r["square"] for r in results] == [x * x for x in range(8)]
    keys = [json.loads(line)["key"] for line in (tmp_path / "journal.jsonl").read_text().splitlines()]
    assert sorted(keys) == sorted(t.key for t in tasks), "each task journalled exactly once"
    assert workers[0].poll() is not None


def test_a_resumed_sweep_does_no_task_twice(tmp_path):
    marks = tmp_path / "marks"
    marks.mkdir()
    tasks = _tasks(6, marks, 0.05)
    journal_path = tmp_path / "journal.jsonl"
    with dask_client(n_workers=2) as client:
        first = Journal(journal_path)
        for t in tasks[:3]:  # a sweep that got this far before it was stopped
            first.append(t, client.submit(t.fn, *t.args).result())
        with journal_path.open("a") as fh:
            fh.write('{"key": "t3", "digest": "')  # and was killed while writing the next line
        before = _executions(marks)
        results = run_sweep(client, tasks, Journal(journal_path))
    after = _executions(marks)
    assert [r["square"] for r in results] == [x * x for x in range(6)]
    assert {x: after.get(x, 0) - before.get(x, 0) for x in range(6)} == {0: 0, 1: 0, 2: 0, 3: 1, 4: 1, 5: 1}
    assert len(journal_path.read_text().splitlines()) == 6


def test_a_changed_digest_runs_the_task_again_and_a_failure_is_reported_not_journalled(tmp_path):
    marks = tmp_path / "marks"
    marks.mkdir()
    journal = Journal(tmp_path / "j.jsonl")
    with dask_client(n_workers=1) as client:
        run_sweep(client, _tasks(2, marks, 0.0), journal)
        changed = [Task(t.key, t.fn, t.args, t.digest + "x") for t in _tasks(2, marks, 0.0)]
        run_sweep(client, changed, journal)
        bad = run_sweep(client, [Task("bad", fails, (7,), "d")], journal, retries=0)
    assert _executions(marks) == {0: 2, 1: 2}
    assert bad == [{"error": "RuntimeError: task 7 cannot be done"}]
    assert Journal(tmp_path / "j.jsonl").get(Task("bad", fails, (7,), "d")) is None, "a re-run must try it again"
    with pytest.raises(SweepError, match=r"j.jsonl: 1 of 1 scenes failed \(bad: RuntimeError: task 7 cannot be done\)"):
        require_all([Task("bad", fails, (7,), "d")], bad, journal, "scene")


def test_no_scheduler_at_the_address_is_one_line():
    with pytest.raises(SweepError, match=r"--scheduler tcp://127.0.0.1:9: no Dask scheduler answers there"):
        with dask_client("tcp://127.0.0.1:9", timeout_s=1.0):
            pass
    with pytest.raises(SweepError, match=r"--scheduler notaurl: not a scheduler address \(.*\); expected tcp://host:port"):
        with dask_client("notaurl", timeout_s=1.0):
            pass


def test_a_damaged_journal_line_in_the_middle_is_refused(tmp_path):
    p = tmp_path / "j.jsonl"
    p.write_text('{"key": "a", "digest": "d", "result": 1}\nnot json\n{"key": "b", "digest": "d", "result": 2}\n')
    with pytest.raises(SweepError, match=r"j.jsonl:2: not a sweep journal line"):
        Journal(p)


def test_scenes_generate_render_fills_the_cache_once(tmp_path, capsys):
    """``scenes generate --render`` renders each scene into the cache on the sweep; a re-run renders nothing."""
    from rig.cli import main

    argv = ["scenes", "generate", "--suite", "wide", "--n", "1", "--seed", "5", "--out", str(tmp_path / "scenes"),
            "--render", "--cache-dir", str(tmp_path / "cache"), "--workers", "1", "--quiet"]
    assert main(argv) == 0
    sessions = sorted(p.name for p in (tmp_path / "cache").iterdir() if p.is_dir())
    assert len(sessions) == 1 and sessions[0].startswith("wide-5-0-"), sessions
    assert "rendered 1 scenes" in capsys.readouterr().out
    journal = (tmp_path / "cache" / "render-journal.jsonl").read_text()
    assert main(argv) == 0
    assert (tmp_path / "cache" / "render-journal.jsonl").read_text() == journal, "nothing rendered again"
    assert "rendering" not in capsys.readouterr().err


def test_a_wide_bench_on_a_real_scheduler_equals_the_serial_run(tmp_path, scheduler):
    """Two scenes of the wide suite, rendered, reconstructed and scored by both methods on the dask workers,
    give the rows the same bench gives run one scene after another in this process (timings aside)."""
    import csv

    from rig.bench import widebench

    address, _ = scheduler
    opts = dict(quiet=True, max_pixels=310_000)
    cache = tmp_path / "cache"
    serial = widebench.run_suite("wide", 2, 5, ["paper", "fast"], tmp_path / "serial", cache, workers=0, **opts)
    spread = widebench.run_suite("wide", 2, 5, ["paper", "fast"], tmp_path / "spread", cache, scheduler=address, **opts)

    def rows(name):
        return [{k: v for k, v in r.items() if k != "ms"} for r in csv.DictReader((tmp_path / name / "frames.csv").open())]

    assert rows("spread") == rows("serial") and len(rows("serial")) == 2 * 2 * 3
    for m in ("paper", "fast"):
        drop = ("ms_per_pair_median", "wall_s")
        assert {k: v for k, v in spread["methods"][m].items() if k not in drop} == \
               {k: v for k, v in serial["methods"][m].items() if k not in drop}
    keys = [json.loads(line)["key"] for line in (tmp_path / "spread" / "sweep.jsonl").read_text().splitlines()]
    assert sorted(keys) == ["wide-5-0", "wide-5-1"]


def test_a_local_cluster_that_does_not_start_is_tried_again_then_one_line(monkeypatch):
    """distributed's IO loop must start within 10 s; on a loaded machine it once did not (AssertionError in
    LoopRunner). A failed start is tried again; where every try fails the sweep stops with one line."""
    import rig.bench.sweep as sweep

    real, calls = sweep.LocalCluster, []

    def flaky(**kw):
        calls.append(kw)
        if len(calls) == 1:
            raise AssertionError
        return real(**kw)

    monkeypatch.setattr(sweep, "LocalCluster", flaky)
    with dask_client(None, 1) as client:
        assert client.submit(lambda x: x + 1, 1).result() == 2
    assert len(calls) == 2

    def never(**kw):
        raise AssertionError

    monkeypatch.setattr(sweep, "LocalCluster", never)
    with pytest.raises(SweepError, match=r"^the local Dask cluster did not start in 3 tries \(AssertionError\): the machine may be overloaded"):
        with dask_client(None, 1):
            pass
