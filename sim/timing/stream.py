"""Emulate and time at once: the timing model runs beside the emulator on the trace as it is made.

The emulator records the trace in chunks (sim/guest/trace.py; CHUNK instructions here) and finds each
chunk's static instructions; instead of joining the chunks into one trace and then timing it, a
worker thread times each chunk as soon as it arrives (all but its last instruction, which waits
for the next chunk's first PC: a branch's outcome), and drops it. Both sides run without the GIL
most of the time (Unicorn in C, the native trace hooks, the cores compiled with numba's nogil), so
on two cores the run takes about as long as the slower of the two instead of their sum, and a
trace is never held whole: at most QUEUE_CHUNKS chunks wait.

The cycle counts are those of timing the joined trace (a core's state is carried between chunks:
sim/cpus/session.py; tests/test_stream.py checks every counter, per-static sum and RDTSC value
against the whole-trace run). A kernel that reads RDTSC is timed the classic way afterwards (its
answers need a first timing pass: sim/timing/kernel.py), as is a run that asks for a timeline window
(chosen from the whole trace).
"""

from __future__ import annotations

import queue
import threading
from pathlib import Path
from typing import Callable

from sim.guest.decode import Decoder
from sim.guest.emu import Machine

# Instructions per chunk: small enough that the model starts soon after the emulator (the run takes
# the model's time plus about one chunk of emulation), large enough that a chunk's fixed costs (a
# Python call, a core call, decoding the chunk's PCs) stay small. Measured on the bench workload
# (P6, pentium2-233), end to end: 1 M instructions 0.58 s, 256 K 0.55 s, 128 K 0.57 s, 64 K 0.58 s.
CHUNK = 1 << 18
QUEUE_CHUNKS = 16  # chunks (a few MB each) waiting for the model at most
_END = object()


class _Consumer(threading.Thread):
    """Feeds the chunks to a core session in order; a chunk's last instruction waits for the next."""

    def __init__(self, session, repeat: int):
        super().__init__(name="retrosim-model", daemon=True)
        self.session = session
        self.repeat = repeat
        self.items: queue.Queue = queue.Queue(maxsize=QUEUE_CHUNKS)
        self.error: BaseException | None = None
        self.run_result = None
        self.stopped = threading.Event()

    def put(self, item) -> None:
        """Queue an item; waits while the queue is full, and stops the emulation if the model failed."""
        while True:
            if self.stopped.is_set():  # the model thread ended early (with an error, kept in self.error)
                raise _ModelStopped()
            try:
                self.items.put(item, timeout=0.2)
                return
            except queue.Full:
                continue

    def run(self) -> None:
        try:
            session = self.session
            last = None  # the latest chunk's last instruction, waiting for the PC after it
            while True:
                item = self.items.get()
                if item is _END:
                    break
                if item is None:  # the emulation failed: nothing more comes
                    return
                kind, value = item
                if kind == "chunk":
                    chunk, (index, added) = value
                    n = chunk.instructions
                    if last is not None:
                        session.feed(last[0], int(chunk.pc[0]), prepared=last[1])
                    if n > 1:
                        session.feed(chunk.part(0, n - 1), int(chunk.pc[n - 1]), prepared=(index[:n - 1], added))
                        added = []
                    last = (chunk.part(n - 1, n), (index[n - 1:], added))
                else:  # ("call_end", k): the waiting instruction ends call k
                    end = session.base + (1 if last is not None else 0)
                    session.end_segment(value, end)
                    if value == self.repeat - 2:
                        session.stat_first = end  # per-instruction sums cover the last call
            if last is not None:
                session.feed(last[0], -1, prepared=last[1])
            self.run_result = session.finish()
        except BaseException as e:  # handed to the emulating thread, which raises it
            self.error = e
        finally:
            self.stopped.set()


class _ModelStopped(Exception):
    """The model thread stopped early (its error is raised instead)."""


def emulate_and_time(source: str | Path, entry: str, setup, model, cpu, repeat: int, budget: int,
                     assembler: str | None = None, progress: Callable[[int, int], None] | None = None,
                     check: Callable | None = None):
    """Emulate `repeat` calls of `entry` (traced), assembled for `cpu` (the model's preset as a
    sim.guest.cpu.GuestCpu), and time them on `model` as they run. Returns (machine, CoreRun).
    `check(machine, records)` sees each chunk's new static instructions (the ISA check); an error
    it raises ends the run."""
    from sim.errors import RetrosimError

    if repeat < 1:
        raise RetrosimError(f"--repeat must be at least 1, got {repeat}")
    machine = Machine.from_source(source, assembler=assembler, cpu=cpu)
    machine.trace_chunk = CHUNK
    if check is not None:  # an instruction the CPU lacks is the error, not the fault it caused later
        machine.before_fault = lambda pcs: check(machine, Decoder(machine.image.fetch).decode_trace(pcs)[0])
    args = setup(machine) if setup else []
    session = model.session(Decoder(machine.image.fetch), [1 << 62] * repeat, stat_first=0 if repeat == 1 else 1 << 62,
                            check=(lambda records: check(machine, records)) if check else None)
    consumer = _Consumer(session, repeat)
    limit = _StreamLimit()
    consumer.start()

    def on_chunk(chunk):
        limit.add(chunk)
        # the emulating thread also finds each chunk's static instructions (it has time to spare)
        consumer.put(("chunk", (chunk, session.prepare(chunk))))

    try:
        for k in range(repeat):
            limit.reset()
            machine.call(entry, *args, budget=budget, trace=True, on_chunk=on_chunk)
            consumer.put(("call_end", k))
            if progress is not None:
                progress(k + 1, repeat)
        consumer.put(_END)
    except _ModelStopped:
        pass
    except BaseException:
        _abandon(consumer)
        raise
    consumer.join()
    if consumer.error is not None:
        raise consumer.error
    return machine, consumer.run_result


class _StreamLimit:
    """RETROSIM_TRACE_MB bounds a streamed call as it bounds a held trace (sim/guest/trace.py): a
    streamed trace is dropped chunk by chunk, so memory never runs out, but without this an endless
    kernel under --budget 0 would run until killed. Counted as the bytes the call's trace would
    hold, so a call streams exactly as far as it could be held."""

    def __init__(self):
        from sim.guest.trace import trace_limit_bytes

        self.limit = trace_limit_bytes()
        self.reset()

    def reset(self) -> None:
        self.bytes = self.instructions = 0

    def add(self, chunk) -> None:
        from sim.errors import LimitError
        from sim.guest.trace import TRACE_LIMIT_ENV

        self.instructions += len(chunk.pc)
        self.bytes += 4 * len(chunk.pc) + 10 * len(chunk.mem_addr) + 6 * len(chunk.cw_at)
        if self.bytes > self.limit:
            mb = self.limit >> 20
            raise LimitError(f"the streamed trace passed {mb:,} MB after {self.instructions:,} instructions of one "
                             f"call (limit {TRACE_LIMIT_ENV}={mb}; raise it, or lower --budget or --repeat)")


def _abandon(consumer: _Consumer) -> None:
    """The emulation failed: tell the model thread that nothing more comes, and wait for it."""
    while consumer.is_alive():
        try:
            consumer.items.put(None, timeout=0.2)
            break
        except queue.Full:
            try:
                consumer.items.get_nowait()
            except queue.Empty:
                pass
    consumer.join()

