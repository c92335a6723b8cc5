"""A timing run fed in chunks: the static program grows as the trace brings new instructions.

A core times a trace in one pass, in program order, so it can equally take the trace a chunk at a
time (a streamed emulation: sim/timing/stream.py) if its loop-carried state survives between chunks (each
family's core keeps it in a state vector and arrays, :func:`sim.cpus.p6.core.new_state`). What
the chunks change is the static program: a chunk may run instructions no earlier chunk ran, or a
precision-dependent x87 instruction at a new precision (sim/cpus/precision.py). :class:`Statics`
gives every static instruction one id for the whole run, in order of first appearance, so the
core's per-static state and sums stay where they are; :meth:`Statics.canonical` is the order one
whole-trace decode gives (every PC's first precision in order of first appearance, then the other
precisions), so a run fed in any number of chunks reports exactly what one fed whole does.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from sim.guest.decode import Decoder, InsnRecord
from sim.guest.trace import Trace
from sim.cpus.precision import split_by_precision
from sim.cpus.table import InstructionTable


# Lowered programs shared between sessions (:func:`lowered`): key -> (the records, the program)
_LOWERED: OrderedDict = OrderedDict()
_LOWERED_LOCK = threading.Lock()
LOWERED_KEEP = 16  # a scene's re-timings lower the same few traces over and over


def lowered(model, records: list[InsnRecord], precisions: list) -> "object":
    """``model.lower(records, precisions)``, shared by the sessions that lower the same record
    objects for models with the same :meth:`~sim.cpus.contract.FamilyModel.lowering_key`: a
    scene's claims re-time one trace on a new model per estimate, and the sort scene spent 9 % of
    its time lowering the same traces again. A program is never changed once lowered. The entry
    holds its records, so an id in the key cannot be reused while it lives."""
    lowering = model.lowering_key()
    if lowering is None:
        return model.lower(records, precisions)
    key = (type(model), lowering, tuple(map(id, records)), tuple(precisions))
    with _LOWERED_LOCK:
        hit = _LOWERED.get(key)
        if hit is not None:
            _LOWERED.move_to_end(key)
            return hit[1]
    program = model.lower(records, precisions)
    with _LOWERED_LOCK:
        _LOWERED[key] = (list(records), program)
        while len(_LOWERED) > LOWERED_KEEP:
            _LOWERED.popitem(last=False)
    return program


class Statics:
    """Static instructions of a run, keyed by (PC, precision index or None), in order of first appearance.
    One thread indexes chunks (:meth:`index`); another may read a consistent :meth:`snapshot`."""

    def __init__(self, decoder: Decoder, table: InstructionTable):
        self.decoder = decoder
        self.table = table
        self.records: list[InsnRecord] = []
        self.precisions: list[int | None] = []
        self._id: dict[tuple[int, int | None], int] = {}
        self._first_of_pc: dict[int, int] = {}  # pc -> the id of its first appearance
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self.records)

    def index(self, chunk: Trace) -> tuple[np.ndarray, list[InsnRecord]]:
        """The chunk's dynamic static-id array (int32, ids of the whole run), and the records that
        this chunk added (in id order)."""
        records, index = self.decoder.decode_trace(chunk.pc)
        records, index, precisions = split_by_precision(records, index, chunk, self.table)
        before = len(self.records)
        ids = np.empty(len(records), np.int32)
        for k, (rec, prec) in enumerate(zip(records, precisions)):
            key = (rec.pc, prec)
            sid = self._id.get(key)
            if sid is None:
                with self._lock:
                    sid = self._id[key] = len(self.records)
                    self.records.append(rec)
                    self.precisions.append(prec)
                self._first_of_pc.setdefault(rec.pc, sid)
            ids[k] = sid
        if np.array_equal(ids, np.arange(ids.size)):
            return index, self.records[before:]  # the chunk's own order is the run's (one whole trace)
        return ids[index], self.records[before:]

    def snapshot(self) -> tuple[list[InsnRecord], list[int | None]]:
        """The records and precisions so far (a chunk being indexed meanwhile adds at the end)."""
        with self._lock:
            return list(self.records), list(self.precisions)

    def canonical(self) -> np.ndarray:
        """Permutation `order` such that ``[self.records[s] for s in order]`` is the order of one
        whole-trace decode (sim/cpus/precision.py): first appearances of each PC, then each PC's
        other precisions in ascending order, by its first appearance."""
        base_rank = {pc: rank for rank, pc in enumerate(sorted(self._first_of_pc, key=self._first_of_pc.get))}
        def key(sid):
            rec = self.records[sid]
            if self._first_of_pc[rec.pc] == sid:
                return (0, base_rank[rec.pc], 0)
            return (1, base_rank[rec.pc], self.precisions[sid])
        return np.array(sorted(range(len(self.records)), key=key), np.int64)


def _rdtsc_statics(records) -> np.ndarray:
    return np.array([int(r.mnemonic == "rdtsc") for r in records], np.int64)


def resized_ring(ring: np.ndarray, pos: int, count: int, n: int) -> tuple[np.ndarray, int]:
    """A core's ring of the cycles of the last `n` events (a queue's entries: slot ``count % n``
    holds the oldest) made from one of another size (`ring`, `pos` = count % its size), and the new
    position. The events both rings hold keep their cycles; older ones the old ring did not hold take
    its oldest (cycles do not decrease from one event to the next, so that is the latest they can
    have been)."""
    old = ring.shape[0]
    out = np.zeros(n, ring.dtype)
    known = min(old, count)
    for k in range(1, min(n, count) + 1):
        out[(count - k) % n] = ring[(pos - min(k, known)) % old]
    return out, count % n


def grown_state(state: tuple, pos: int, rows: int, fill: int = 0) -> tuple:
    """A core's state tuple whose array at `pos` has at least `rows` rows (contents kept, new rows
    `fill`): room for the resources or static instructions a later chunk brought."""
    old = state[pos]
    if old.shape[0] >= rows:
        return state
    grown = np.full((rows,) + old.shape[1:], fill, old.dtype)
    grown[:old.shape[0]] = old
    return state[:pos] + (grown,) + state[pos + 1:]


def grow_rows(a: np.ndarray, rows: int) -> np.ndarray:
    """`a` with at least `rows` rows plus its last (sink) row; grown geometrically, contents kept."""
    if a.shape[0] >= rows + 1:
        return a
    grown = np.zeros((max(rows + 1, 2 * a.shape[0]),) + a.shape[1:], a.dtype)
    grown[:a.shape[0] - 1] = a[:-1]
    return grown


@dataclass(frozen=True)
class SessionStart:
    """A run's machine state between two feeds (:meth:`CoreSession.snapshot`): the core's state, the
    counts so far and the caches' contents, copied; and the run's statics, shared (they only grow).
    :meth:`CoreSession.restore` continues another model's session of the same trace from it."""

    statics: Statics
    base: int
    total: int
    state: tuple
    counters: np.ndarray
    per_static: np.ndarray
    dstats: np.ndarray
    istats: np.ndarray
    rdtsc: tuple
    family: dict       # the family session's own state (:meth:`CoreSession.family_state`)
    dside: tuple       # the data and instruction sides' contents (sim.memory.hierarchy Hierarchy.contents)
    iside: tuple


class CoreSession:
    """One run fed in order, chunk by chunk. The family's subclass keeps its core's state between
    chunks (:meth:`grown`, :meth:`time_chunk`) and builds its result (:meth:`result`); this class
    keeps the statics, the static program, the counters and the per-static sums.

    `segments`: the instruction counts at which counters are cut (one segment per call); an end not
    known yet is a large number, set with :meth:`end_segment` before the chunk holding it is fed.
    `timeline`: (first instruction, rows) to record. `stat_first`: per-static sums cover
    instructions from there on (settable until its chunk is fed). `check(records)` sees each
    chunk's new static instructions before they are lowered (the ISA check)."""

    CORE = None    # the family's core module: NC, NS, NT (counter, per-static, timeline widths), new_state
    # the core's queues of another model's size that :meth:`restore` resizes: (the ring's position in
    # the state tuple, the state vector's slots of its position and of its event count)
    QUEUES: tuple[tuple[int, int, int], ...] = ()
    # what :meth:`drain` keeps of the core's state: the state vector's slots and the state arrays
    # (positions in new_state's tuple) that hold what the machine has learned in program order
    # (predictors, return stack, the x87 top, the L1I lines known, where the run is), not when
    KEEP_SLOTS: tuple[int, ...] = ()
    KEEP_ARRAYS: tuple[int, ...] = ()
    TL_STATIC = 1  # the timeline column holding the static id

    def __init__(self, model, decoder: Decoder, segments, timeline: tuple[int, int] = (0, 0),
                 stat_first: int = 0, check=None):
        self.model = model
        self.check = check
        self.statics = Statics(decoder, model.table)
        self.program = model.lower([], [])
        self.seg_end = np.array(segments, dtype=np.int64)
        self.counters = np.zeros((self.seg_end.size, self.CORE.NC), np.int64)
        self.per_static = np.zeros((1, self.CORE.NS), np.int64)  # the last row is the sink
        self.timeline = np.zeros((timeline[1], self.CORE.NT), np.int64)
        self.tl_first = timeline[0]
        self.stat_first = stat_first
        self.rdtsc: list[np.ndarray] = []
        self.base = 0  # instructions fed so far
        self.total = 0
        self.rdtsc_sid = np.zeros(0, np.int64)
        model.reset()
        self.dstats, self.istats = model.dside.new_counts(), model.iside.new_counts()
        self.state = self.CORE.new_state(model.params, 0)

    @classmethod
    def whole(cls, model, trace: Trace, decoder: Decoder, segments=None, timeline: tuple[int, int] = (0, 0),
              stat_first: int = 0, access_logs=None):
        """A run of the whole `trace` (a model's `run`): one feed, so one code path times both."""
        session = cls(model, decoder, segments if segments else [trace.instructions], timeline, stat_first)
        session.feed(trace, -1, access_logs)
        return session.finish()

    def end_segment(self, k: int, end: int) -> None:
        self.seg_end[k] = end

    def prepare(self, chunk: Trace) -> tuple[np.ndarray, list[InsnRecord]]:
        """The chunk's static ids and the static instructions it adds: what :meth:`feed` needs first,
        done ahead by whoever makes the chunks (sim/timing/stream.py: the emulating thread), in chunk order."""
        return self.statics.index(chunk)

    def feed(self, chunk: Trace, next_pc: int, access_logs=None, prepared=None) -> None:
        """Time the chunk's instructions; `next_pc`: the PC that follows the chunk (-1: the run ends).
        `access_logs` (sim.memory.replay) only for a run fed whole; `prepared`: :meth:`prepare`'s
        answer for this chunk, if it was asked already."""
        index = self.indexed(chunk, prepared)
        rdtsc_sid = self.rdtsc_sid
        rdtsc_out = np.zeros(int(rdtsc_sid[index].sum()) if rdtsc_sid.any() else 0, np.int64)
        self.total = self.time_chunk(chunk, index, next_pc, rdtsc_sid, rdtsc_out, access_logs)
        self.rdtsc.append(rdtsc_out)
        self.base += chunk.instructions

    def keep_rooms(self) -> None:
        """Record, from here on, what the core can tell of the parameters that could not have changed
        this run (the run's `rooms`, for FamilyModel.repeats), at some cost in speed; a family whose
        core records nothing of the kind ignores it."""

    def warm(self, chunk: Trace, next_pc: int) -> None:
        """The chunk's instructions as a warm-up: only what the machine learns from them is kept
        (:meth:`drain` after timing them, or :meth:`warm_chunk`'s walk where the family's core has
        one, which must leave the same)."""
        if not self.warm_chunk(chunk, next_pc):
            self.feed(chunk, next_pc)
        self.drain()

    def warm_chunk(self, chunk: Trace, next_pc: int) -> bool:
        """Walk the chunk through the caches, TLB, DRAM pages and predictors without timing it, as
        the core would leave them: the core module's `warm`, which takes simulate's arguments but
        the timeline and RDTSC ones. False when the family has none (it is timed, then drained)."""
        walk = getattr(self.CORE, "warm", None)
        if walk is None:
            return False
        index = self.indexed(chunk)
        model = self.model
        walk(self.base, next_pc, index, chunk.pc, chunk.mem_insn, chunk.mem_addr, chunk.mem_size, chunk.mem_write,
             self.seg_end, *self.program.arrays(), *self.family_statics(), model.params, *model.dside.arrays(),
             self.dstats, *model.iside.arrays(), self.istats, *self.state)
        self.base += chunk.instructions
        return True

    def family_statics(self) -> tuple:
        """The family's own per-static arrays, passed to its core after the program's (the K6's)."""
        return ()

    def drain(self) -> None:
        """Empty the pipeline between two feeds: the core's queues, rings and times back to reset
        (the next feed's cycles count from 0), keeping what the machine has learned
        (:attr:`KEEP_SLOTS`, :attr:`KEEP_ARRAYS`); the caches, TLB and DRAM pages are the model's and
        stay as they are. A scene's last frame is timed from here (sim.timing.kernel
        time_emulation's `warm_start`), so that its timing depends on the frames before it only
        through what they left learned: the same for every timing parameter."""
        old = self.state
        self.state = self.CORE.new_state(self.model.params, 0)
        self.grown(self.program)
        sv = self.state[0]
        for slot in self.KEEP_SLOTS:
            sv[slot] = old[0][slot]
        self.state = tuple(old[k].copy() if k in self.KEEP_ARRAYS else a for k, a in enumerate(self.state))
        self.total = 0

    def indexed(self, chunk: Trace, prepared=None) -> np.ndarray:
        """The chunk's static ids (:meth:`prepare`'s, if it was asked already), its new statics lowered."""
        index, added = prepared if prepared is not None else self.statics.index(chunk)
        if added:
            if self.check is not None:
                self.check(added)
            # every static a later chunk prepared meanwhile is lowered too: harmless, and it means
            # a chunk that adds nothing finds its statics in the program
            records, precisions = self.statics.snapshot()
            self.program = lowered(self.model, records, precisions)
            self.per_static = grow_rows(self.per_static, len(records))
            self.grown(self.program)
            self.rdtsc_sid = _rdtsc_statics(records)
        return index

    def grown(self, program) -> None:
        """The static program gained instructions: make room in the core's state."""

    def fitted(self, state: tuple, shapes: list) -> tuple:
        """Another model's core state (a copy) with each of the core's queues (:attr:`QUEUES`) resized
        to its length in `shapes`, this model's state shapes (:func:`resized_ring`)."""
        sv = state[0]
        for pos, at, count in self.QUEUES:
            n = shapes[pos][0]
            if state[pos].shape[0] != n:
                ring, sv[at] = resized_ring(state[pos], int(sv[at]), int(sv[count]), n)
                state = state[:pos] + (ring,) + state[pos + 1:]
        return state

    def family_state(self) -> dict:
        """The family session's state beyond the core's (attribute name -> value, not changed in
        place by later feeds), for :meth:`snapshot`."""
        return {}

    def snapshot(self) -> SessionStart:
        """The machine state after the chunks fed so far, for :meth:`restore`."""
        return SessionStart(self.statics, self.base, self.total, tuple(a.copy() for a in self.state),
                            self.counters.copy(), self.per_static.copy(), self.dstats.copy(), self.istats.copy(),
                            tuple(self.rdtsc), self.family_state(), self.model.dside.contents(),
                            self.model.iside.contents())

    def restore(self, start: SessionStart) -> bool:
        """Continue from `start`, a snapshot of another session of the same trace and segments,
        whose model may differ from this one in its timing parameters, its queues' sizes (:meth:`fitted`)
        and its DRAM page geometry (the pages then start closed, Hierarchy.restore). False when it
        differs in more (the caches' or TLB's geometry, or the size of another core state array): this
        session must then not be used."""
        model = self.model
        if not (model.dside.restore(start.dside) and model.iside.restore(start.iside)):
            return False
        records, precisions = start.statics.snapshot()
        self.statics = start.statics
        self.program = model.lower(records, precisions)
        self.grown(self.program)
        fresh = [a.shape for a in self.state]
        self.state = self.fitted(tuple(a.copy() for a in start.state), fresh)
        self.grown(self.program)
        if [a.shape for a in self.state] != fresh:
            return False
        for name, value in start.family.items():
            setattr(self, name, value)
        self.base, self.total = start.base, start.total
        self.counters, self.dstats, self.istats = start.counters.copy(), start.dstats.copy(), start.istats.copy()
        self.per_static = grow_rows(start.per_static.copy(), len(records))
        self.rdtsc = list(start.rdtsc)
        self.rdtsc_sid = _rdtsc_statics(records)
        return True

    def time_chunk(self, chunk: Trace, index: np.ndarray, next_pc: int, rdtsc_sid: np.ndarray,
                   rdtsc_out: np.ndarray, access_logs) -> int:
        """Run the core on the chunk; returns the latest retire cycle so far."""
        raise NotImplementedError

    def result(self, program, counters, per_static, timeline, rdtsc, total):
        raise NotImplementedError

    def finish(self):
        order = self.statics.canonical()
        program, per_static, timeline = self.program, self.per_static[:len(self.statics)], self.timeline
        if not np.array_equal(order, np.arange(order.size)):
            # a chunk met a precision variant before a later PC's first appearance: report in the
            # order one whole-trace decode gives
            program = self.model.lower([self.statics.records[s] for s in order],
                                       [self.statics.precisions[s] for s in order])
            per_static = per_static[order]
            rank = np.empty_like(order)
            rank[order] = np.arange(order.size)
            timeline = timeline.copy()
            written = min(timeline.shape[0], max(0, self.base - self.tl_first))
            timeline[:written, self.TL_STATIC] = rank[timeline[:written, self.TL_STATIC]]
        rdtsc = np.concatenate(self.rdtsc) if self.rdtsc else np.zeros(0, np.int64)
        return self.result(program, self.counters, per_static, timeline, rdtsc, int(self.total))
