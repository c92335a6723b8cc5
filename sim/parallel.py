"""Timing one emulation on several machines at once, in forked worker processes: one
:class:`SharedPool` for every scene kind, warmed by :func:`warm` before it forks.

An emulation's trace (tens to hundreds of MB for the article scene) is the same for every CPU
model, so the workers must not each get a copy: they are forked after the trace exists and read it
through the parent's pages (copy-on-write; numpy arrays that are only read are never copied). The
parent times one machine of each family first, so the numba-compiled cores are loaded before any
fork and the children inherit them instead of compiling or reading the on-disk cache all at once
(which has been seen to stall on a cold cache); with more than one job it compiles the cores side
by side first (:func:`warm`). A Dask sweep (sim.sweep) warms the same way before
its workers start, so they find the on-disk cache filled.

Results do not depend on the number of workers: each task is a pure function of the shared
emulation and its machine, and results are collected in submission order.

Progress. A task may call :func:`report` as it goes (a scene's timings report each machine run:
sim.scenes.progress); each report reaches the `progress` callable the pool was made with, in the
process that made it. A forked worker cannot call it: a pool made with `progress` opens a pipe before
it forks, its workers send their reports down it, and a thread of the parent reads them and calls
`progress` as they arrive, so the display moves while the parent waits for results or emulates the
next variant. With jobs == 1 the task runs here and `report` calls `progress` directly.
"""

from __future__ import annotations

import multiprocessing
import os
import threading
from concurrent.futures import Future, ProcessPoolExecutor
from typing import Callable

# What forked workers read: set in the parent just before the pool forks, never sent by pickle.
_SHARED: dict = {}
_WARM: set = set()  # families whose compiled core this process has run
_CHANNELS: dict = {}  # pool token -> (pipe's write end, lock): where that pool's workers send reports
_reporting: Callable | None = None  # where report() sends while a pool's task runs in this process


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


def warm(models, jobs: int = 1) -> None:
    """Load each model's compiled core into this process (once per family) by timing an empty
    trace: the same argument types as a real run, so the same compiled function, and the same
    entry in numba's on-disk cache. Timed twice, the second time with a timeline: a core may be
    compiled in two versions, one without its rare paths (the P6's: sim.cpus.p6.core simulate's `rare`).

    `jobs` > 1: this process compiles the family whose core is largest while up to `jobs` - 1
    forked children compile the others, filling numba's on-disk cache; then each of those is
    loaded here from that cache (a tenth of a second each). From an empty cache the P6's takes
    about 39 s of CPU, the K6's 22 s and the P5's 12 s (compile time grows with the code: the
    largest first), so on two cores the three take about as long as the P6's alone; on a filled
    cache a child only loads. Only where this process forks next anyway (SharedPool): a fork must
    not happen while another thread of it may hold a lock (a compile's), and a pool's fork has the
    same condition."""
    cold = list({m.family: m for m in models if m.family not in _WARM}.values())
    if jobs > 1 and len(cold) > 1:
        cold.sort(key=_core_bytes, reverse=True)
        children = [_fork(_warm_families, cold[1 + k::jobs - 1]) for k in range(min(jobs - 1, len(cold) - 1))]
        _warm_families(cold[:1])
        for pid in children:
            os.waitpid(pid, 0)
    _warm_families(cold)


def _core_bytes(model) -> int:
    """The size of the family's compiled core's source (its package's core.py: docs/ARCHITECTURE.md)."""
    import importlib

    return os.path.getsize(importlib.import_module(type(model).__module__.rsplit(".", 1)[0] + ".core").__file__)


def _warm_families(models) -> None:
    from sim.guest.decode import Decoder
    from sim.guest.trace import Trace

    for model in models:
        if model.family not in _WARM:
            for timeline in ((0, 0), (0, 1)):
                model.run(Trace.empty(), Decoder(lambda address, n: b""), [0], timeline, 0)
            _WARM.add(model.family)


def _fork(task: Callable, *args) -> int:
    """Run task(*args) in a forked child that exits without running this process's exit handlers
    (its output, if any, is its side effects: numba's on-disk cache). Returns the child's pid."""
    pid = os.fork()
    if pid == 0:  # pragma: no cover (the child)
        code = 1
        try:
            task(*args)
            code = 0
        finally:
            os._exit(code)
    return pid


def report(*args, **kw) -> None:
    """From a pool's task: ``progress(*args, **kw)`` in the process that made the pool (see the
    module's docstring); nothing when the pool has no `progress` or when no task of a pool runs."""
    if _reporting is not None:
        _reporting(args, kw)


def _run_reporting(to: Callable | None, task: Callable, shared, args: tuple):
    global _reporting
    _reporting = to
    try:
        return task(shared, *args)
    finally:
        _reporting = None


def _call(token: int, task: Callable, args: tuple):
    channel = _CHANNELS.get(token)
    return _run_reporting(channel and (lambda args, kw: _send(channel, (args, kw))), task, _SHARED[token], args)


def _send(channel, report: tuple) -> None:
    writer, lock = channel
    with lock:  # the pool's workers share the pipe: one whole report at a time
        writer.send(report)


class _Reader(threading.Thread):
    """The parent's reader of a pool's reports: calls `progress` with each until stopped (after the
    pool's workers have exited), then with those still in the pipe."""

    def __init__(self, pipe, progress: Callable):
        super().__init__(daemon=True, name="retrosim-progress")
        self.pipe, self.progress = pipe, progress
        self.stopping = threading.Event()
        self.error: BaseException | None = None

    def run(self) -> None:
        while True:
            last = self.stopping.is_set()  # set once no worker writes any more: drain, then stop
            while self.pipe.poll(0 if last else 0.1):
                args, kw = self.pipe.recv()
                if self.error is None:  # a failing display must not stop the draining (workers would block)
                    try:
                        self.progress(*args, **kw)
                    except BaseException as e:  # raised again by SharedPool.close
                        self.error = e
            if last:
                return


class SharedPool:
    """Run ``task(shared, *args)`` for many `args`, in `jobs` forked processes that inherit `shared`
    (or in this process when jobs == 1). Use as a context manager; `submit` returns a Future.

    `models`: the timing models the tasks run; with jobs > 1 their compiled cores are loaded here
    (:func:`warm`) before the workers fork, so they inherit them. `progress`: what the tasks'
    :func:`report` calls reach, in this process."""

    def __init__(self, shared, jobs: int, models=(), progress: Callable | None = None):
        self.shared = shared
        self.pool = None
        self.token = id(self)
        self.progress = progress
        self.reader: _Reader | None = None
        if jobs > 1:
            warm(models, jobs)
            # forked at the first submit (a fork-context pool starts all its workers then)
            _SHARED[self.token] = shared
            context = multiprocessing.get_context("fork")
            if progress is not None:  # made before the fork, so that the workers inherit its write end
                receive, send = context.Pipe(duplex=False)
                _CHANNELS[self.token] = (send, context.Lock())
                self.reader = _Reader(receive, progress)
            self.pool = ProcessPoolExecutor(max_workers=jobs, mp_context=context)

    def submit(self, task: Callable, *args) -> Future:
        if self.pool is None:
            f: Future = Future()
            to = self.progress and (lambda args, kw: self.progress(*args, **kw))
            try:
                f.set_result(_run_reporting(to, task, self.shared, args))
            except BaseException as e:  # re-raised by result(), as a pool's would be
                f.set_exception(e)
            return f
        future = self.pool.submit(_call, self.token, task, args)
        if self.reader is not None and self.reader.ident is None:
            self.reader.start()  # after the fork: no thread of this pool's is copied into a worker
        return future

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
        channel = _CHANNELS.pop(self.token, None)
        reader, self.reader = self.reader, None
        if reader is not None:
            if reader.is_alive():  # the workers have exited: what they sent is all in the pipe
                reader.stopping.set()
                reader.join()
            reader.pipe.close()
            channel[0].close()
            if reader.error is not None:
                raise reader.error

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
