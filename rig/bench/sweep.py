"""Sweeps on Dask distributed: one task a scene, results journalled as they finish, a re-run resumes.

The wide benchmark, tuning and ``scenes generate --render`` evaluate many scenes. Each scene is
one task (render through the cache, reconstruct, score), submitted to a Dask scheduler:

* ``scheduler=None``: an in-process ``LocalCluster`` sized to the machine (one single-threaded
  worker process a core, the machine's memory shared among them), with no set-up;
* ``scheduler="tcp://host:port"``: a running ``dask scheduler`` and its ``dask worker``
  processes, on this machine or a cluster's nodes (docs/scale.md).

Every finished task is appended to a journal (JSON lines, flushed and fsynced), which is what
a re-run reads to skip the tasks already done: a sweep killed half-way resumes where it was.
A task is keyed by its name and the digest of what it depends on (its arguments and the code of
recon/ and twin/), so a change of code or arguments does not reuse a stale result. A worker
that dies mid-task is replaced by the scheduler and its task run again elsewhere; the journal
gets one line a key whatever happens, because only this process writes it.
"""
from __future__ import annotations

import functools
import hashlib
import json
import os
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from distributed import Client, LocalCluster, as_completed

from rig.bench.render_cache import code_digest
from rig.rundir import json_safe

__all__ = ["SweepError", "Task", "Journal", "dask_client", "run_sweep", "task_digest", "dask_map", "require_all"]

#: Worker processes keep every numerical library on one thread: a task's time is one core's.
_ONE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}


class SweepError(ValueError):
    """A sweep that cannot start (no scheduler at the address, an unreadable journal); one line."""


@dataclass(frozen=True)
class Task:
    """One unit of a sweep: ``fn(*args)`` run on a worker, its result journalled under ``key``.

    ``key`` names the task in the journal and on the scheduler's dashboard (e.g. the scene's
    file stem); ``digest`` is what the result depends on (:func:`task_digest`).
    """

    key: str
    fn: object
    args: tuple
    digest: str


def task_digest(*parts) -> str:
    """Hash of a task's inputs: ``parts`` as JSON (paths as strings), plus the code of recon/, twin/ and rig/.

    Parameters
    ----------
    *parts
        JSON-serialisable values (``str()`` for anything else, e.g. Paths).

    Returns
    -------
    str
        16 hex digits.
    """
    h = hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode())
    h.update(code_digest("recon", "twin", "rig").encode())
    return h.hexdigest()[:16]


class Journal:
    """The finished tasks of a sweep: one JSON line ``{"key", "digest", "result"}`` a task, in finishing order.

    Parameters
    ----------
    path : Path
        The JSONL file; made with its folder if missing. A last line cut short (the sweep was
        killed while writing it) is dropped and rewritten when that task runs again.
    """

    def __init__(self, path):
        self.path = Path(path)
        self.done: dict = {}
        if self.path.exists():
            self._read()
        self.path.parent.mkdir(parents=True, exist_ok=True)

    def _read(self) -> None:
        try:
            lines = self.path.read_text(encoding="utf-8").splitlines()
        except (OSError, UnicodeDecodeError) as exc:
            raise SweepError(f"{self.path}: cannot read the sweep journal ({type(exc).__name__})") from None
        good = []
        for i, line in enumerate(lines):
            try:
                rec = json.loads(line)
                self.done[(rec["key"], rec["digest"])] = rec["result"]
                good.append(line)
            except (json.JSONDecodeError, KeyError, TypeError):
                if i < len(lines) - 1:
                    raise SweepError(f"{self.path}:{i + 1}: not a sweep journal line") from None
        if len(good) < len(lines):  # drop the torn last line so appends start on a line of their own
            self.path.write_text("".join(g + "\n" for g in good), encoding="utf-8")

    def get(self, task: Task):
        """The journalled result of ``task`` (same key and digest), or None."""
        return self.done.get((task.key, task.digest))

    def append(self, task: Task, result) -> None:
        """Record ``result`` of ``task``: one line, flushed to disk before this returns."""
        result = json_safe(result)
        line = json.dumps({"key": task.key, "digest": task.digest, "result": result}, default=str)
        with self.path.open("a", encoding="utf-8") as fh:
            fh.write(line + "\n")
            fh.flush()
            os.fsync(fh.fileno())
        self.done[(task.key, task.digest)] = result


@contextmanager
def dask_client(scheduler: str | None = None, n_workers: int | None = None, memory_per_worker: str = "auto",
                timeout_s: float = 10.0):
    """A ``distributed.Client``: on the scheduler at ``scheduler``, or on a new in-process LocalCluster.

    Parameters
    ----------
    scheduler : str, optional
        ``tcp://host:port`` of a running ``dask scheduler``; None starts a LocalCluster.
    n_workers : int, optional
        LocalCluster workers (default: one a core). Each is a process with one thread, so a
        task's timings are one core's, as the benchmark reports them. 0: no cluster, the
        tasks run one after another in this process (debugging, profiling).
    memory_per_worker : str
        LocalCluster memory limit per worker (``"auto"``: the machine's memory divided among
        the workers; ``"4GB"``...). A worker past it is restarted by Dask and its task rerun.
    timeout_s : float
        How long to try to reach ``scheduler`` (s).

    Yields
    ------
    distributed.Client, or None with ``n_workers=0``

    Raises
    ------
    SweepError
        No scheduler answers at ``scheduler`` within ``timeout_s``.
    """
    if scheduler:
        try:
            client = Client(scheduler, timeout=f"{timeout_s}s")
        except (OSError, TimeoutError) as exc:
            raise SweepError(f"--scheduler {scheduler}: no Dask scheduler answers there ({type(exc).__name__})") from None
        except ValueError as exc:  # e.g. "missing port number in address"
            raise SweepError(f"--scheduler {scheduler}: not a scheduler address ({exc}); expected tcp://host:port") from None
        with client:
            yield client
        return
    if n_workers == 0:
        yield None
        return
    n = n_workers or os.cpu_count() or 1
    with _local_cluster(n, memory_per_worker) as cluster, Client(cluster) as client:
        yield client


#: Starts of a LocalCluster tried before a sweep gives up.
_CLUSTER_TRIES = 3


def _local_cluster(n_workers: int, memory_per_worker: str) -> LocalCluster:
    """A LocalCluster of ``n_workers`` one-thread worker processes, its start tried up to :data:`_CLUSTER_TRIES`
    times.

    Its IO loop must start within 10 s (``distributed``'s own limit, an ``AssertionError`` when missed). On a
    2-core machine busy with a 5 MP bench beside the test suite's two workers it once did not; a second start
    is cheaper than a lost sweep. Raises :class:`SweepError` (one line) when no try starts.
    """
    for _ in range(_CLUSTER_TRIES):
        try:
            return LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, memory_limit=memory_per_worker,
                                dashboard_address=None, env=_ONE_THREAD)
        except (AssertionError, TimeoutError, OSError) as exc:
            last = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
    raise SweepError(f"the local Dask cluster did not start in {_CLUSTER_TRIES} tries ({last}): the machine may be "
                     "overloaded; run again, or with --workers 0 (in this process)")


def run_sweep(client, tasks: list, journal: Journal, progress=None, stage: str = "sweep", retries: int = 2) -> list:
    """Run ``tasks`` on ``client``'s workers, skipping those ``journal`` has; their results in task order.

    Parameters
    ----------
    client : distributed.Client or None
        None runs the tasks here, one after another (:func:`dask_client` with 0 workers).
    tasks : list of Task
        Keys must be unique.
    journal : Journal
        Read for finished tasks, appended to as each of the others finishes.
    progress : callable, optional
        ``progress(stage, done, total)`` (:class:`rig.progress.Progress`), over all tasks.
    stage : str
        The progress bar's label.
    retries : int
        Times Dask reruns a task that raised (a task whose worker died is rerun regardless).

    Returns
    -------
    list
        Each task's result, in the order of ``tasks``. A task that still raised after its
        retries has ``{"error": "<Type>: <message>"}``, which is not journalled: a re-run
        tries it again.
    """
    keys = [t.key for t in tasks]
    if len(set(keys)) != len(keys):
        raise ValueError("run_sweep: task keys must be unique")
    todo = [t for t in tasks if journal.get(t) is None]
    done = len(tasks) - len(todo)
    if progress:
        progress(stage, done, len(tasks))
    errors = {}
    for task, outcome in _outcomes(client, todo, retries):
        try:
            journal.append(task, outcome())
        except Exception as exc:  # the task's own failure, after its retries: reported, and retried by a re-run
            errors[task.key] = {"error": f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"}
        done += 1
        if progress:
            progress(stage, done, len(tasks))
    return [errors[t.key] if t.key in errors else journal.get(t) for t in tasks]


def require_all(tasks: list, results: list, journal: Journal, what: str = "task") -> list:
    """``results`` of :func:`run_sweep`, or a one-line :class:`SweepError` naming the first task that failed.

    A task that raised (after its retries) is a bug or a broken worker, not a frame a method
    refused: nothing downstream can use a sweep with a hole in it. The others stay journalled,
    and a re-run retries only the failed ones.
    """
    failed = [(t.key, r["error"]) for t, r in zip(tasks, results) if isinstance(r, dict) and "error" in r]
    if failed:
        raise SweepError(f"{journal.path}: {len(failed)} of {len(tasks)} {what}s failed ({failed[0][0]}: {failed[0][1]}); "
                         "the others are journalled and a re-run retries these")
    return results


def _outcomes(client, tasks: list, retries: int):
    """``(task, outcome)`` as each task finishes; ``outcome()`` returns its result or raises its exception."""
    if client is None:
        for t in tasks:
            yield t, functools.partial(t.fn, *t.args)
        return
    futures = {client.submit(t.fn, *t.args, key=f"{t.key}-{t.digest}", pure=False, retries=retries): t for t in tasks}
    for future in as_completed(futures):
        yield futures.pop(future), future.result
        future.release()


def dask_map(client, retries: int = 2):
    """A ``map`` over ``client``'s workers that yields each result as its task finishes (any order).

    For work with its own resume (the dataset's finished shards): ``map_fn(fn, items)``
    submits ``fn(item)`` for every item and yields the results in the order they finish; a
    task that raised re-raises here, after its retries. Without a client, the builtin ``map``.
    """
    if client is None:
        return map

    def map_fn(fn, items):
        futures = [client.submit(fn, item, pure=False, retries=retries) for item in items]
        for future in as_completed(futures):
            yield future.result()
            future.release()
    return map_fn
