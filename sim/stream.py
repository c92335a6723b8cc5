"""Emulate and time at once: the timing model runs beside the emulator on the trace as it is made.

The emulator records the trace in chunks of about a million instructions (sim/trace.py); instead
of joining them into one trace and then timing it, a worker thread times each chunk as soon as the
next one exists (the last instruction of a chunk needs the PC after it, for branch outcomes), and
drops it. Both sides run without the GIL most of the time (Unicorn in C, the native trace hooks and
the cores compiled with numba's nogil), so on two cores the run takes about as long as the slower
of the two instead of their sum, and a trace is never held whole: at most QUEUE_CHUNKS chunks wait.

The cycle counts are those of timing the joined trace (a core's state is carried between chunks:
sim/cpus/session.py; tests/test_stream.py checks every counter, per-static sum and RDTSC value
against the whole-trace run). A kernel that reads RDTSC is timed the classic way afterwards (its
answers need a first timing pass: sim/timing.py), as is a run that asks for a timeline window
(chosen from the whole trace).
"""

from __future__ import annotations

import queue
import threading
from pathlib import Path
from typing import Callable

from .emu import Machine

QUEUE_CHUNKS = 4  # chunks (about 1 M instructions, ~14 MB each) waiting for the model at most
_END = object()


class _Consumer(threading.Thread):
    """Feeds the chunks to a core session in order, one behind (its successor's first PC)."""

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
            if self.error is not None or self.stopped.is_set():
                raise _ModelStopped()
            try:
                self.items.put(item, timeout=0.2)
                return
            except queue.Full:
                continue

    def run(self) -> None:
        try:
            pending = None
            fed = 0
            while True:
                item = self.items.get()
                if item is _END:
                    break
                if item is None:  # the emulation failed: nothing more comes
                    return
                kind, value = item
                if kind == "chunk":
                    if pending is not None:
                        self.session.feed(pending, int(value.pc[0]))
                        fed += pending.instructions
                    pending = value
                else:  # ("call_end", k): the pending chunk ends call k
                    end = fed + (pending.instructions if pending is not None else 0)
                    self.session.end_segment(value, end)
                    if value == self.repeat - 2:
                        self.session.stat_first = end  # per-instruction sums cover the last call
            if pending is not None:
                self.session.feed(pending, -1)
            self.run_result = self.session.finish()
        except BaseException as e:  # handed to the emulating thread, which raises it
            self.error = e
        finally:
            self.stopped.set()


class _ModelStopped(Exception):
    """The model thread stopped early (its error is raised instead)."""


def emulate_and_time(source: str | Path, entry: str, setup, model, repeat: int, budget: int,
                     assembler: str | None = None, progress: Callable[[int, int], None] | None = None,
                     check: Callable | None = None):
    """Emulate `repeat` calls of `entry` (traced) and time them on `model` as they run.
    Returns (machine, CoreRun). `check(machine, records)` sees each chunk's new static instructions
    (the ISA check); an error it raises ends the run."""
    from .errors import RetrosimError

    if repeat < 1:
        raise RetrosimError(f"--repeat must be at least 1, got {repeat}")
    machine = Machine.from_source(source, assembler=assembler, cpu=model.preset.name)
    args = setup(machine) if setup else []
    session = model.session(machine_decoder(machine), [1 << 62] * repeat, stat_first=0 if repeat == 1 else 1 << 62,
                            check=(lambda records: check(machine, records)) if check else None)
    consumer = _Consumer(session, repeat)
    consumer.start()
    try:
        for k in range(repeat):
            machine.call(entry, *args, budget=budget, trace=True, on_chunk=lambda chunk: consumer.put(("chunk", chunk)))
            consumer.put(("call_end", k))
            if progress is not None:
                progress(k + 1, repeat)
        consumer.put(_END)
    except _ModelStopped:
        pass
    except BaseException:
        consumer.stopped.set()
        _abandon(consumer)
        raise
    consumer.join()
    if consumer.error is not None:
        raise consumer.error
    return machine, consumer.run_result


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


def machine_decoder(machine: Machine):
    from .decode import Decoder

    return Decoder(machine.image.fetch)
