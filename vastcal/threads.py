"""Threads of the cost evaluations: independent slices of one evaluation computed side by side.

A cost evaluation is a few large NumPy and OpenCV operations (projections, bilinear samples, minima
over views) on disjoint slices of the views; both libraries release the GIL inside such operations,
so slices computed on two cores take about half the wall time. Every slice is computed exactly as
it would be alone and written to its own part of the output, so the result is bit-identical to
the sequential one whatever the number of threads.

How many: ``VASTCAL_THREADS`` when set (1 turns threading off), else the CPUs this process may run
on, at most :data:`MAX_THREADS`. A Dask worker of ``vastcal batch``'s embedded cluster gets its
``threads_per_worker`` this way, so that workers sharing a machine do not oversubscribe it; on an
existing cluster set ``VASTCAL_THREADS`` in the workers' environment.
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

log = logging.getLogger(__name__)

MAX_THREADS = 4
"""Default ceiling: beyond a few threads the slices get small and memory bandwidth, not cores, limits."""

ENV = "VASTCAL_THREADS"

T = TypeVar("T")

_lock = threading.Lock()
_pool: ThreadPoolExecutor | None = None
_pool_size = 0


def compute_threads() -> int:
    """Threads for one evaluation: ``VASTCAL_THREADS`` if set (≥ 1), else the usable CPUs, at most
    :data:`MAX_THREADS`."""
    value = os.environ.get(ENV, "").strip()
    if value:
        try:
            n = int(value)
        except ValueError:
            log.warning("%s=%r is not a whole number; using 1 thread", ENV, value)
            return 1
        return max(1, n)
    try:
        cpus = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not on Linux
        cpus = os.cpu_count() or 1
    return max(1, min(cpus, MAX_THREADS))


def run_slices(work: Callable[[T], None], slices: Iterable[T]) -> None:
    """Call ``work(s)`` for every slice, on up to :func:`compute_threads` threads; returns when all are done.

    ``work`` must write only its own slice's outputs. An exception in any slice is raised here.
    """
    items = list(slices)
    n = compute_threads()
    if n <= 1 or len(items) <= 1:
        for s in items:
            work(s)
        return
    global _pool, _pool_size
    with _lock:
        if _pool is None or _pool_size != n:
            if _pool is not None:
                _pool.shutdown(wait=False)
            _pool, _pool_size = ThreadPoolExecutor(max_workers=n, thread_name_prefix="vastcal-cost"), n
        pool = _pool
    for future in [pool.submit(work, s) for s in items]:
        future.result()
