"""Time a kernel on a CPU model: emulate (traced), decode, and run the family's timing model.

The kernel's entry point is called `repeat` times in one machine state, so caches and predictors
carry over from call to call as they would in a program; the report is the last call. RDTSC inside
a kernel returns the simulated cycle count: a first pass times the run, a second pass replays it
with RDTSC answering the first pass's cycles (the instruction stream does not depend on the values
RDTSC returns unless the kernel branches on them; the replay checks that it did not).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from sim.cpus.build import make_model
from sim.cpus.session import SessionStart
from sim.errors import LimitError, RetrosimError
from sim.guest.cpu import GuestCpu
from sim.guest.decode import Decoder
from sim.guest.emu import Machine
from sim.guest.trace import Trace, check_trace_bytes

Setup = Callable[[Machine], list]  # builds the call's arguments (and buffers) in a fresh machine


@dataclass
class TimingResult:
    cpu: str
    memory: str
    entry: str
    source: Path
    repeat: int
    calls: list[dict]                 # counters per call
    model: object = field(repr=False)
    run: object = field(repr=False)
    trace: Trace | None = field(repr=False)  # None when the run was streamed (sim/timing/stream.py)
    # the machine state at the last call's start (time_emulation's `resumable`): for resume_last_call
    last_call_start: SessionStart | None = field(default=None, repr=False)

    @property
    def last(self) -> dict:
        return self.calls[-1]

    def summary(self) -> dict:
        d = {"cpu": self.cpu, "memory": self.memory, "entry": self.entry, "repeat": self.repeat}
        d.update(self.last)
        return d


def hot_loop_window(pc: np.ndarray, start: int, iterations: int, cap: int = 256) -> tuple[int, int]:
    """(first instruction, count) covering `iterations` passes through the most executed PC of
    pc[start:], taken from the middle of that range (steady state, caches and predictors warm)."""
    if iterations <= 0 or start >= pc.size:
        return (0, 0)
    part = pc[start:]
    values, counts = np.unique(part, return_counts=True)
    head = values[np.argmax(counts)]
    where = np.flatnonzero(part == head)
    k = max(0, len(where) // 2 - 1)
    end = where[min(k + iterations, len(where) - 1)] if len(where) > k + 1 else part.size
    return (start + int(where[k]), int(min(cap, max(1, end - where[k]))))


@dataclass
class Emulation:
    """A kernel's traced run: `repeat` calls in one machine state. The trace does not depend on
    the CPU model, so one emulation serves every preset (unless the kernel reads RDTSC)."""

    source: Path
    entry: str
    setup: Setup | None
    repeat: int
    budget: int
    assembler: str | None
    machine: Machine = field(repr=False)
    trace: Trace = field(repr=False)
    bounds: list[int]
    isa_cpu: GuestCpu | None = None  # the CPU the kernel was assembled for (None: plain i686)
    # one decoder per emulation: its records and its trace index are computed once however many
    # machines (and claim re-timings) time the trace
    _decoder: Decoder | None = field(default=None, init=False, repr=False, compare=False)
    _parts: tuple[Trace, Trace] | None = field(default=None, init=False, repr=False, compare=False)
    _records: list | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def last_call(self) -> int:
        return self.bounds[-2] if len(self.bounds) > 1 else 0

    def decoder(self) -> Decoder:
        if self._decoder is None:
            self._decoder = Decoder(self.machine.image.fetch)
        return self._decoder

    def records(self) -> list:
        """The trace's distinct static instructions (decoded records), in order of first appearance,
        decoded once: each machine's ISA check reads them (the decoder itself keeps only the indexes
        of its last two traces, the parts a resumable timing feeds)."""
        if self._records is None:
            self._records = self.decoder().decode_trace(self.trace.pc)[0]
        return self._records

    def parts(self) -> tuple[Trace, Trace]:
        """(the calls before the last, the last call) as traces of their own; the same two objects
        each time, so an access log recorded on them (sim.memory.replay, keyed by the trace) replays."""
        if self._parts is None:
            self._parts = (self.trace.part(0, self.last_call), self.trace.part(self.last_call, self.trace.instructions))
        return self._parts

    def replay(self, rdtsc_values: list[int]) -> Emulation:
        return emulate(self.source, self.entry, self.setup, self.repeat, self.budget, self.assembler, rdtsc_values,
                       self.isa_cpu)


def guest_cpu(cpu: str | GuestCpu | None) -> GuestCpu | None:
    """The guest stages' view of a CPU preset (a name or machine label): the preset is read here,
    above the guest stages, which never read presets. A GuestCpu or None is returned as it is."""
    if cpu is None or isinstance(cpu, GuestCpu):
        return cpu
    from sim.cpus.overrides import load_preset

    return GuestCpu.from_preset(load_preset(cpu))


def emulate(source: str | Path, entry: str, setup: Setup | None = None, repeat: int = 2,
            budget: int = 200_000_000, assembler: str | None = None,
            rdtsc_values: list[int] | None = None, isa_cpu: str | GuestCpu | None = None,
            progress: Callable[[int, int], None] | None = None) -> Emulation:
    """`isa_cpu` (a preset name or a GuestCpu): assemble for that CPU's instruction set (shipped
    kernels stay plain i686, so one emulation serves every preset). `progress(done, repeat)` is
    called after each call."""
    if repeat < 1:
        raise RetrosimError(f"--repeat must be at least 1, got {repeat}")
    isa_cpu = guest_cpu(isa_cpu)
    answers = iter(rdtsc_values or [])
    clock = (lambda ev: next(answers, 0)) if rdtsc_values is not None else None
    machine = Machine.from_source(source, assembler=assembler, cpu=isa_cpu, rdtsc=clock)
    if isa_cpu is not None:  # an instruction the CPU lacks is the error, not the fault it caused later
        machine.before_fault = lambda pcs: check_records(Decoder(machine.image.fetch).decode_trace(pcs)[0], isa_cpu,
                                                         Path(source), machine, assembler, isa_cpu)
    args = setup(machine) if setup else []
    parts = []
    for k in range(repeat):
        parts.append(machine.call(entry, *args, budget=budget, trace=True).trace)
        # the calls' traces are all kept (the model times them in one machine state): bound them
        check_trace_bytes(sum(p.nbytes for p in parts), sum(p.instructions for p in parts))
        if progress is not None:
            progress(k + 1, repeat)
    bounds = np.cumsum([p.instructions for p in parts]).tolist()
    return Emulation(Path(source), entry, setup, repeat, budget, assembler, machine, Trace.concatenate(parts), bounds,
                     isa_cpu)


# The timing models keep per-instruction state (decoded uops, issue and retire cycles, the timeline):
# about 90 bytes per traced instruction, measured on `retrosim time` (1 M and 4 M instruction loops:
# +88 MB per million). Bounded so that a long run stops with a message instead of exhausting memory.
MODEL_LIMIT_ENV = "RETROSIM_MODEL_MB"
DEFAULT_MODEL_LIMIT_MB = 8192
MODEL_BYTES_PER_INSTRUCTION = 90


def check_model_memory(instructions: int) -> None:
    raw = os.environ.get(MODEL_LIMIT_ENV, "").strip()
    try:
        limit_mb = int(raw) if raw else DEFAULT_MODEL_LIMIT_MB
    except ValueError:
        raise LimitError(f"{MODEL_LIMIT_ENV}={raw!r}: expected a whole number of megabytes") from None
    need_mb = instructions * MODEL_BYTES_PER_INSTRUCTION >> 20
    if need_mb > limit_mb:
        raise LimitError(f"timing {instructions:,} instructions needs about {need_mb:,} MB of host memory, more than "
                         f"the limit {MODEL_LIMIT_ENV}={limit_mb}; raise it, or lower --budget or --repeat")


def time_emulation(emu: Emulation, cpu="pentium2-233", memory: str | None = None,
                   timeline_iterations: int = 0, access_logs=None, resumable: bool = False,
                   warm_start: bool = False, rooms: bool = False) -> TimingResult:
    """Time an emulation on one CPU preset (a name, or a model from make_model).
    `timeline_iterations`: record a per-instruction timeline of that many iterations of the hot
    loop (the last call's most executed PC), from the middle of the last call. `access_logs`
    (a sim.memory.replay.AccessLogs): re-timings of the same emulation on the same data caches
    reuse the first one's cache results (the P6 and K6 cores; the P5 core walks its caches each time).
    `resumable`: keep the machine state at the last call's start (``last_call_start``, for
    :func:`resume_last_call`; the calls before it and the last are fed apart, which times them the
    same); not with a timeline, and not kept for a kernel that reads RDTSC. `warm_start`: the calls
    before the last only warm the machine (caches, TLB, DRAM pages, predictors: CoreSession.drain,
    and warm where the family walks them without timing them) and the last call is timed from an
    empty pipeline; their counters are then not timings (zero where walked). A scene's frames are
    timed so; with `resumable`, a re-timing that resumes then times exactly what a whole one does
    (but for another DRAM page geometry: sim.scenes.claims). Neither with a timeline: `warm_start`
    with one is refused (a ValueError), `resumable` is ignored. `rooms`: with `resumable` or
    `warm_start`, the run (``run``) also tells which parameters could not have changed it, where
    the family's core can (CoreSession.keep_rooms; FamilyModel.repeats); a run replayed for its
    RDTSC values has none."""
    if warm_start and timeline_iterations:
        raise ValueError("time_emulation: a warm start has no timeline (the calls before the last are not timed)")
    model = make_model(cpu, memory) if isinstance(cpu, str) else cpu
    cpu = model.preset.name
    check_model_memory(emu.trace.instructions)
    timeline = hot_loop_window(emu.trace.pc, emu.last_call, timeline_iterations)
    decoder = emu.decoder()
    check_isa(emu, GuestCpu.from_preset(model.preset))
    if (resumable or warm_start) and timeline_iterations == 0 and emu.last_call > 0:
        session = model.session(decoder, emu.bounds, emu.last_call)
        if rooms:
            session.keep_rooms()
        head, last = emu.parts()
        if warm_start:
            session.warm(head, int(last.pc[0]))
        else:
            session.feed(head, int(last.pc[0]), access_logs)
        start = session.snapshot() if resumable else None
        session.feed(last, -1, access_logs)
        run = session.finish()
        if run.rdtsc.size == 0:
            calls = [run.segment(k) for k in range(len(emu.bounds))]
            return TimingResult(cpu, model.dram.name, emu.entry, emu.source, emu.repeat, calls, model, run, emu.trace,
                                start)
        if warm_start:  # the replay below times the whole run
            raise RetrosimError(f"{emu.source}: {emu.entry} reads RDTSC: its calls cannot be timed from a warm start")
    else:
        run = model.run(emu.trace, decoder, emu.bounds, timeline, emu.last_call, access_logs=access_logs)
    if run.rdtsc.size:
        replay = emu.replay([int(c) for c in run.rdtsc])
        if not np.array_equal(replay.trace.pc, emu.trace.pc):
            raise RetrosimError(f"{emu.source}: {emu.entry} branches on RDTSC values; its timing cannot be replayed")
        emu = replay
        run = model.run(emu.trace, emu.decoder(), emu.bounds, timeline, emu.last_call, access_logs=access_logs)
    calls = [run.segment(k) for k in range(len(emu.bounds))]
    return TimingResult(cpu, model.dram.name, emu.entry, emu.source, emu.repeat, calls, model, run, emu.trace)


def resume_last_call(emu: Emulation, model, start: SessionStart, access_logs=None) -> dict | None:
    """The counters of the emulation's last call on `model` (from make_model, not yet run), timed
    from `start`, the machine state another model's resumable timing of `emu` left at that call's
    start (time_emulation): caches, TLB, predictors and the core's queues as that run left them,
    and only the last call timed. None when `model`'s machine differs from that one in more than
    its timing parameters (CoreSession.restore): time the whole emulation then."""
    session = model.session(emu.decoder(), emu.bounds, emu.last_call)
    if not session.restore(start):
        return None
    session.feed(emu.parts()[1], -1, access_logs)
    return session.finish().segment(len(emu.bounds) - 1)


def check_isa(emu: Emulation, cpu: GuestCpu) -> None:
    """Refuse (one IsaError) an executed instruction the CPU lacks, or a system instruction.
    Where the kernel assembles for that CPU, the error is the assembler's, with the source line."""
    check_records(emu.records(), cpu, emu.source, emu.machine, emu.assembler, emu.isa_cpu)


def check_records(records, cpu: GuestCpu, source: Path, machine: Machine, assembler: str | None,
                  isa_cpu: GuestCpu | None) -> None:
    """:func:`check_isa` for decoded records (a streamed run checks each chunk's new ones).
    `isa_cpu`: the CPU the kernel was assembled for (None: plain i686)."""
    from sim.guest.isa import IsaError, check_record

    for rec in records:
        try:
            check_record(rec, cpu, lambda: f"{source}: pc {machine.where(rec.pc)}")
        except IsaError:
            # GNU as, told the CPU, refuses the instruction with its source line (clang does not)
            from sim.guest.asm import assemble
            from sim.errors import AssemblerMissing

            built_for = isa_cpu.name if isa_cpu is not None else None
            for name in dict.fromkeys(n for n in (assembler, "gnu") if built_for != cpu.name or n == "gnu"):
                try:
                    assemble(source, name, cpu)
                except AssemblerMissing:
                    pass
            raise


def time_kernel(source: str | Path, entry: str, setup: Setup | None = None, cpu="pentium2-233",
                memory: str | None = None, repeat: int = 2, budget: int = 200_000_000,
                timeline_iterations: int = 0, assembler: str | None = None,
                progress: Callable[[int, int], None] | None = None) -> TimingResult:
    """Emulate and time in one step (see :func:`emulate` and :func:`time_emulation`); the kernel is
    assembled for the preset's instruction set. `cpu`: a preset name (or machine label), or a
    model from make_model (not yet run; `memory` is then its own). The preset is resolved once,
    here: the guest stages get its GuestCpu. The model times the trace as the emulator makes it
    (sim/timing/stream.py), unless a timeline window is asked for (it is chosen from the whole
    trace), the model cannot take a trace in chunks, or the kernel reads RDTSC (its answers need a
    first pass)."""
    model = make_model(cpu, memory) if isinstance(cpu, str) else cpu  # before emulating: an unknown preset fails fast
    target = GuestCpu.from_preset(model.preset)
    if timeline_iterations == 0:  # every family model takes a trace in chunks (FamilyModel.session)
        from sim.timing.stream import emulate_and_time

        machine, run = emulate_and_time(
            source, entry, setup, model, target, repeat, budget, assembler, progress,
            check=lambda m, records: check_records(records, target, Path(source), m, assembler, target))
        if run.rdtsc.size == 0:
            calls = [run.segment(k) for k in range(repeat)]
            return TimingResult(target.name, model.dram.name, entry, Path(source), repeat, calls, model, run, None)
    emu = emulate(source, entry, setup, repeat, budget, assembler, isa_cpu=target, progress=progress)
    return time_emulation(emu, model, timeline_iterations=timeline_iterations)
