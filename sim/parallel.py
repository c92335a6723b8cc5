"""Timing one emulation on several machines at once, in forked worker processes: one
:class:`SharedPool` for every scene kind, warmed by :func:`warm` before it forks.

An emulation's trace (tens to hundreds of MB for the article scene) is the same for every CPU
model, so the workers must not each get a copy: they are forked after the trace exists and read it
through the parent's pages (copy-on-write; numpy arrays that are only read are never copied). The
parent times one machine of each family first, so the numba-compiled cores are loaded before any
fork and the children inherit them instead of compiling or reading the on-disk cache all at once
(which has been seen to stall on a cold cache). A Dask sweep (sim.sweep) warms the same way before
its workers start, so they find the on-disk cache filled.

Results do not depend on the number of workers: each task is a pure function of the shared
emulation and its machine, and results are collected in submission order.
"""

from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import Future, ProcessPoolExecutor
from typing import Callable

# What forked workers read: set in the parent just before the pool forks, never sent by pickle.
_SHARED: dict = {}
_WARM: set = set()  # families whose compiled core this process has run


def default_jobs() -> int:
    """Every core this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def check_jobs(jobs: int | None) -> int:
    from sim.errors import ArgumentError

    if jobs is None:
        return default_jobs()
    if jobs < 1:
        raise ArgumentError(f"--jobs must be at least 1, got {jobs}")
    return jobs


def warm(models) -> None:
    """Load each model's compiled core into this process (once per family) by timing an empty
    trace: the same argument types as a real run, so the same compiled function, and the same
    entry in numba's on-disk cache."""
    from sim.guest.decode import Decoder
    from sim.guest.trace import Trace

    for model in models:
        if model.family not in _WARM:
            model.run(Trace.empty(), Decoder(lambda address, n: b""), [0], (0, 0), 0)
            _WARM.add(model.family)


def _call(token: int, task: Callable, args: tuple):
    return task(_SHARED[token], *args)


class SharedPool:
    """Run ``task(shared, *args)`` for many `args`, in `jobs` forked processes that inherit `shared`
    (or in this process when jobs == 1). Use as a context manager; `submit` returns a Future.

    `models`: the timing models the tasks run; with jobs > 1 their compiled cores are loaded here
    (:func:`warm`) before the workers fork, so they inherit them."""

    def __init__(self, shared, jobs: int, models=()):
        self.shared = shared
        self.pool = None
        self.token = id(self)
        if jobs > 1:
            warm(models)
            # forked at the first submit (a fork-context pool starts all its workers then)
            _SHARED[self.token] = shared
            self.pool = ProcessPoolExecutor(max_workers=jobs, mp_context=multiprocessing.get_context("fork"))

    def submit(self, task: Callable, *args) -> Future:
        if self.pool is None:
            f: Future = Future()
            try:
                f.set_result(task(self.shared, *args))
            except BaseException as e:  # re-raised by result(), as a pool's would be
                f.set_exception(e)
            return f
        return self.pool.submit(_call, self.token, task, args)

    def release(self) -> None:
        """Drop this process's references to the shared object once every task is submitted: the
        workers (forked at the first submit) keep their view, and the parent's memory can go to
        the next emulation (a fork-context pool never forks again)."""
        if self.pool is not None:
            _SHARED.pop(self.token, None)
        self.shared = None

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=True)
            self.pool = None
        _SHARED.pop(self.token, None)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
