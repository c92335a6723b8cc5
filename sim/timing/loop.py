"""Time a bare loop body or basic block, the way llvm-mca and uiCA take one.

The body's text becomes a program on the guest side: sim/guest/loop_body.py reads it (a loop or a
block), sim/guest/loop_program.py wraps, assembles and traces it and marks where the measured
iterations start. This module only times what it is handed, and imports no emulator.

Measurement: the body runs ``iterations`` times twice from the same registers (the first pass
warms caches and predictors). In the second pass the counters are cut where iteration
``iterations // 2`` and iteration ``iterations`` start; steady-state figures are the difference
divided by the iterations between (start-up cancels). The model is told that the body goes on
after the trace (to the next iteration's first instruction), so the last back-edge is taken and
nothing drains inside the window. Any family's model from :func:`sim.cpus.build.make_model` serves, as
for `retrosim time`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from sim.cpus.build import make_model
from sim.errors import ArgumentError
from sim.guest.cpu import GuestCpu
from sim.guest.decode import Decoder
from sim.guest.loop_body import parse_body
from sim.guest.loop_program import DEFAULT_ALIGN, DEFAULT_ITERATIONS, LoopRun, placement, run_on_cpus, x87_warnings
from sim.memory.hierarchy import write_allocate_full_when
from sim.timing.kernel import TimingResult

# --data: the caches' state when the measured pass starts. cold: what the warm-up pass left (reads
# allocate; a write allocates only if the preset's write policy does, so a P5 or a K6 without
# write allocation writes fresh memory through to the bus). warm: also every line the measured pass
# touches, read in, in address order, as far as it fits (llvm-mca's and uiCA's all-hits-L1 view).
# Cold is the default: it is what the chip does, and what every release has timed.
DATA_STATES = ("cold", "warm")
DEFAULT_DATA = "cold"


@dataclass
class LoopTiming:
    cpu: str                         # the preset, or the machine label with its overrides
    memory: str
    iterations: int                  # measured iterations (between the two cuts)
    per_iteration: dict[str, float]  # every counter divided by the measured iterations
    result: TimingResult = field(repr=False)  # for views.explain_rows / timeline_rows
    address: int = 0                 # where the body's first instruction was placed
    alignment: int = 0               # the largest power of two (up to ALIGN_SPAN) dividing it
    warnings: list[str] = field(default_factory=list)  # about the body's run (one line each)
    data: str = DEFAULT_DATA         # the caches' state at the measured pass (DATA_STATES)
    write_policy: str | None = None  # when the write policy decides the result: one line saying so

    @property
    def cycles_per_iteration(self) -> float:
        return self.per_iteration["cycles"]

    @property
    def uops_per_iteration(self) -> float:
        return self.per_iteration["uops"]


def time_run(run: LoopRun, cpu: str, memory: str | None = None, timeline_iterations: int = 3,
             data: str = DEFAULT_DATA) -> LoopTiming:
    """Time a traced body on one CPU (a preset or a machine label such as
    ``k6-233{write_allocate.mode=full}``; any family make_model knows), with the caches `data`
    (DATA_STATES) when the measured pass starts."""
    if data not in DATA_STATES:
        raise ArgumentError(f"--data {data}: choose {' or '.join(DATA_STATES)}")
    model = make_model(cpu, memory)
    span = min(256, run.iteration_length * max(0, timeline_iterations))
    core_run = _run_model(model, run, (run.cuts[1], span), data)
    calls = [core_run.segment(k) for k in range(len(run.cuts))]
    per = {k: round(v / run.measured, 4) for k, v in calls[-1].items()}
    result = TimingResult(cpu, model.dram.name, "loop", Path(run.body.name), 1, calls, model, core_run, run.trace)
    return LoopTiming(cpu, model.dram.name, run.measured, per, result, run.address, run.alignment,
                      x87_warnings(run), data, write_policy_line(model, cpu, per, data))


def _run_model(model, run: LoopRun, timeline: tuple[int, int], data: str = DEFAULT_DATA):
    """`model.run` on the loop's trace, except that the body does not end after the trace: it goes on
    to `run.next_pc` (the back-edge is taken). A run that ended there would take the last back-edge
    as falling through, a mispredict the loop never has, inside the measured window. With warm data
    the warm-up pass is fed first, then the lines of the measured pass are read into the caches
    (Hierarchy.prefill), then the measured pass is fed: the core's own state runs on unbroken."""
    decoder = Decoder(run.fetch)
    session_type = type(model.session(decoder, list(run.cuts), run.cuts[1]))
    session = session_type(model, decoder, list(run.cuts), timeline, run.cuts[1])
    if data == "warm":
        warm_end = run.cuts[0]
        session.feed(run.trace.head(warm_end), int(run.trace.pc[warm_end]))
        measured = run.trace.part(warm_end, run.trace.instructions)
        model.dside.prefill(measured.mem_addr, measured.mem_size)
        session.feed(measured, run.next_pc)
    else:
        session.feed(run.trace, run.next_pc)
    return session.finish()


def write_policy_line(model, cpu: str, per: dict[str, float], data: str) -> str | None:
    """One line when the preset's write policy decides the result: stores in the measured
    iterations miss the L1 data cache and the L1 does not allocate every write miss (some families'
    never does; others' per their preset's write_allocate mode), so each goes to the bus and the loop
    waits on the write buffer. None otherwise (no such store, or warm data). Where the family's L1
    can be set to allocate every write miss (sim/memory/policies.toml), the line says how."""
    from sim.memory.cache import ALLOC_ALWAYS

    misses = per.get("l1d_store_misses", 0)
    if data == "warm" or not misses or model.dside.geometries[0].allocate_id == ALLOC_ALWAYS:
        return None
    what = model.dside.geometries[0].write_miss_words
    full = write_allocate_full_when(model.family)
    return (f"{cpu}: the write policy decides this result: {misses:g} store(s) per iteration miss L1 and go to the "
            f"bus (its L1 data cache {what}); --data warm times them as L1 hits"
            + (f"; --set write_allocate.mode=full makes write misses allocate ({full})" if full else ""))


def time_body(text: str, cpus: list[str], name: str = "<stdin>", syntax: str | None = None,
              iterations: int = DEFAULT_ITERATIONS, regs: dict[str, int] | None = None,
              assembler: str | None = None, timeline_iterations: int = 3, memory: str | None = None,
              align: int = DEFAULT_ALIGN, offset: int = 0, data: str = DEFAULT_DATA) -> list[LoopTiming]:
    """Time the body on every CPU in `cpus` (presets or machine labels); a CPU without an
    instruction the body uses is an error."""
    timings, _ = time_body_where_possible(text, cpus, name, syntax, iterations, regs, assembler,
                                          timeline_iterations, memory, align, offset, skip=False, data=data)
    return timings


def time_body_where_possible(text: str, cpus: list[str], name: str = "<stdin>", syntax: str | None = None,
                             iterations: int = DEFAULT_ITERATIONS, regs: dict[str, int] | None = None,
                             assembler: str | None = None, timeline_iterations: int = 3,
                             memory: str | None = None, align: int = DEFAULT_ALIGN, offset: int = 0,
                             skip: bool = True, data: str = DEFAULT_DATA) -> tuple[list[LoopTiming], dict[str, list[str]]]:
    """Time the body on the CPUs in `cpus` that have every instruction it uses; return the timings
    and the others by what they lack ({"MMX": [cpu, ...]}). With no CPU able to run it (or
    `skip` false and one CPU unable), the first refusal is the error."""
    from sim.cpus import presets
    from sim.cpus.overrides import split_label

    placement(align, offset)  # a bad --align / --offset (or --data) fails before any emulation
    if data not in DATA_STATES:
        raise ArgumentError(f"--data {data}: choose {' or '.join(DATA_STATES)}")
    if not cpus:
        raise ArgumentError("no CPU to time the body on")
    bases = {}
    for c in cpus:  # an unknown preset fails before any emulation
        base, _ = split_label(c)
        if base not in presets.available():
            raise ArgumentError(f"unknown CPU preset '{base}' (choose one of: {', '.join(presets.available())})")
        bases[c] = base
    targets = {c: GuestCpu.from_preset(presets.load(bases[c])) for c in cpus}  # each preset read once
    body = parse_body(text, name, syntax, targets[cpus[0]])
    runs, missing = run_on_cpus(body, cpus, targets, iterations, regs, assembler, align, offset, skip)
    return [time_run(run, c, memory, timeline_iterations=timeline_iterations, data=data) for c, run in runs], missing
