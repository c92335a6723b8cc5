"""How a scene run reports its progress, counted in machine runs: one timing of a variant's emulation
on a machine, each of the claims' robustness re-timings (sim.scenes.claims.perturbed_timings)
included, and, for the texture kind, a machine's probes (measure_probes) as one run.

A runner calls its `progress` (a :data:`Progress`) as ``progress(what, done=0, more=0)``: `what`
(None: unchanged) says what runs now, `done` machine runs have just finished, `more` are now known to
be coming (negative: fewer than announced). The timings themselves run in forked workers
(sim.parallel.SharedPool): a task reports through :func:`sim.parallel.report`, which reaches the
`progress` the pool was made with, in the parent. Nothing here changes a result.
"""

from __future__ import annotations

import threading
from contextlib import contextmanager
from typing import Callable

from sim.parallel import report

Progress = Callable[..., None]


@contextmanager
def machine_run(what: str):
    """The block is one machine run named `what` (from a pool's task: see sim.parallel.report)."""
    report(what)
    yield
    report(done=1)


def timed_run(what: str, emulation, model, **kw):
    """time_emulation(emulation, model, **kw), reported as one machine run named `what`."""
    from sim.timing.kernel import time_emulation

    with machine_run(what):
        return time_emulation(emulation, model, **kw)


class RunCount:
    """A :data:`Progress` that tallies: machine runs `done` of `total` announced so far, and what runs
    now. Safe to call from several threads (the parent's own and the one sim.parallel reads workers'
    reports with); `show(self)` is called after each change, under the same lock."""

    def __init__(self, show: Callable[[RunCount], None] | None = None):
        self.done = 0
        self.total = 0
        self.what = ""
        self.show = show
        self._lock = threading.Lock()

    def __call__(self, what: str | None = None, done: int = 0, more: int = 0) -> None:
        with self._lock:
            self.done += done
            self.total += more
            if what is not None:
                self.what = what
            if self.show is not None:
                self.show(self)
