"""One core per process: the timing protocol of the benchmarks.

A bench times each method on one core (docs/fast-method.md); a sweep's workers each pin
themselves to a core of their own (:func:`pin_worker`).
"""
from __future__ import annotations

import os

import cv2
from distributed import get_worker

__all__ = ["pin_one_core", "worker_index", "pin_worker"]


def pin_one_core(index: int | None = None) -> int:
    """Pin this process to one CPU and keep OpenCV/BLAS single-threaded; returns the CPU.

    ``index``: which of the CPUs this process may use (modulo their count; a sweep's
    worker k takes the k-th); default the last.
    """
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    cpu = -1
    if hasattr(os, "sched_setaffinity"):
        cpus = sorted(os.sched_getaffinity(0))
        cpu = cpus[-1] if index is None else cpus[index % len(cpus)]
        os.sched_setaffinity(0, {cpu})

    cv2.setNumThreads(1)
    try:  # numpy may have been imported before the variables were set
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)
    except ImportError:
        pass
    return cpu


def worker_index() -> int | None:
    """In a sweep task: the LocalCluster worker's number (0, 1, ...), to pin it to a core of its own; else None.

    Workers started by hand (``dask worker``) are named by their address: the operating
    system places them.
    """
    try:
        name = get_worker().name
    except ValueError:  # not inside a worker (the task runs in this process)
        return None
    return name if isinstance(name, int) else None


def pin_worker() -> int:
    """At the start of a sweep task: this worker on one thread and (LocalCluster) on its own core; the CPU."""
    return pin_one_core(worker_index())
