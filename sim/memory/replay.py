"""Recorded data-cache results, so that re-timing one trace on the same caches skips the cache walk.

Which level serves each data access (and whether it missed the data TLB, and where its page walk's
reads were served) depends only on the order of the accesses and the caches' and TLB's geometry and
policies (all in the configuration array a log is keyed by), never on when the accesses happen: the cores call the hierarchy in program
order (an instruction's loads, then its store), whatever the cycle. A model re-timed with only its
latencies or estimates changed (the claims' robustness pass, sim/scenes/claims.py) therefore sees the same
results again. The first such run records every packed :func:`sim.memory.hierarchy.service` result
of the data side; the others read them back instead of walking the caches.

A log is an int64 array: ``[mode, position, entry...]``, one entry per data-side call. An entry is
the packed result (below bit 40) and what the K6 core reads back from the counts array after a call
(L1 line fills, L1 and L2 writebacks: the increments the call made, 8 bits each). In replay the
counts array gets those increments and nothing else (the models read no other count during a run,
and discard the array after it); the cache arrays are left untouched.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from sim.memory.cache import HOT
from sim.memory.hierarchy import LINES_SHIFT, S_FILLS, S_WRITEBACKS, service

LOG_OFF, LOG_RECORD, LOG_REPLAY, LOG_OVERFLOW = 0, 1, 2, 3
LOG_HEADER = 2
# the entry of a plain L1 hit (one line, nothing filled or written back): the cores take these
# themselves, without calling logged_service
LOGGED_HIT = 1 << LINES_SHIFT
_RESULT_BITS = 40
_FIELD = 0xFF


@njit(**HOT)
def logged_service(log, tags, stamps, dirty, config, work, stats, addr, size, is_write):
    """:func:`sim.memory.hierarchy.service` recorded into `log`, or its recorded result (see the
    module docstring). The cores call it only when a log is on (``log[0] != LOG_OFF``), and
    ``service`` itself otherwise: measured, routing every access through one more function (even
    inlined) slows the K6 core by a fifth with no log at all."""
    k = log[1]
    if log[0] == LOG_REPLAY:
        log[1] = k + 1
        e = log[LOG_HEADER + k]
        stats[0, S_FILLS] += (e >> 40) & _FIELD
        stats[0, S_WRITEBACKS] += (e >> 48) & _FIELD
        stats[1, S_WRITEBACKS] += (e >> 56) & 0x7F
        return e & ((1 << _RESULT_BITS) - 1)
    if log[0] != LOG_RECORD:
        return service(tags, stamps, dirty, config, work, stats, addr, size, is_write)
    f0, w0, w1 = stats[0, S_FILLS], stats[0, S_WRITEBACKS], stats[1, S_WRITEBACKS]
    r = service(tags, stamps, dirty, config, work, stats, addr, size, is_write)
    df, dw0, dw1 = stats[0, S_FILLS] - f0, stats[0, S_WRITEBACKS] - w0, stats[1, S_WRITEBACKS] - w1
    if df > _FIELD or dw0 > _FIELD or dw1 > 0x7F or r >> _RESULT_BITS != 0 or LOG_HEADER + k >= log.shape[0]:
        log[0] = LOG_OVERFLOW  # not representable: this recording is dropped, the run is unaffected
        return r
    log[LOG_HEADER + k] = r | (df << 40) | (dw0 << 48) | (dw1 << 56)
    log[1] = k + 1
    return r


@njit(cache=True, nogil=True, inline="always")
def replayed_hit(log) -> bool:
    """A replayed log's next entry is a plain L1 hit: take it (a core then skips logged_service,
    whose replay of such an entry changes nothing but the position). False otherwise, and when
    the log is not being replayed."""
    if log[0] == LOG_REPLAY and log[LOG_HEADER + log[1]] == LOGGED_HIT:
        log[1] += 1
        return True
    return False


@njit(cache=True, nogil=True, inline="always")
def record_hit(log) -> None:
    """Record a plain L1 hit a core made without logged_service, as logged_service would."""
    k = log[1]
    if LOG_HEADER + k < log.shape[0]:
        log[LOG_HEADER + k] = LOGGED_HIT
        log[1] = k + 1
    else:
        log[0] = LOG_OVERFLOW  # not representable: this recording is dropped, the run is unaffected


NO_LOG = np.zeros(LOG_HEADER, np.int64)  # mode LOG_OFF: never written


class AccessLogs:
    """Data-side results recorded by one timed run, keyed by what decides them: the trace (by
    identity: it lives as long as the emulation that owns this object's user), the family's access
    order and the static program's uop kinds (which accesses a run sends to the caches), and the
    data caches' geometry and policies. Holds at most `keep` logs (each 8 bytes per access)."""

    def __init__(self, keep: int = 1):
        self.keep = keep
        self._logs: dict[tuple, tuple[np.ndarray, int]] = {}  # key -> (log, entries recorded)
        self._live: dict[int, tuple] = {}  # id(log) -> key, for logs handed out and not finished

    @staticmethod
    def _key(family: str, trace, program, dconfig: np.ndarray) -> tuple:
        return (family, id(trace.mem_addr), trace.accesses, dconfig.tobytes(), program.u_kind.tobytes(),
                program.s_nuops.tobytes(), program.s_uop0.tobytes())

    def start(self, family: str, trace, program, dconfig: np.ndarray) -> np.ndarray:
        """The log for a run: a recorded one, rewound for replay, or a new one that records."""
        key = self._key(family, trace, program, dconfig)
        held = self._logs.get(key)
        if held is not None:
            log = held[0]
            log[0], log[1] = LOG_REPLAY, 0
        else:
            log = np.zeros(LOG_HEADER + trace.accesses, np.int64)
            log[0] = LOG_RECORD
        self._live[id(log)] = key
        return log

    def finish(self, log: np.ndarray) -> None:
        """Call after the run returned: keeps a complete recording, checks a replay read it all."""
        key = self._live.pop(id(log))
        if log[0] == LOG_RECORD:
            self._logs[key] = (log, int(log[1]))
            while len(self._logs) > self.keep:
                self._logs.pop(next(iter(self._logs)))
        elif log[0] == LOG_REPLAY and int(log[1]) != self._logs[key][1]:
            raise RuntimeError(f"access log replay read {int(log[1])} of {self._logs[key][1]} results")
