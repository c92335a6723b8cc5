"""Issue 36: every x87 instruction that reads or writes the register stack carries its dependency.

The decoder names a popping instruction's destination before the pop (FADDP ST(1),ST writes st1,
FSTP ST(i) writes st(i)) and a pushing one's after the push (sim/guest/decode.py); the cores map
destinations through TOP after the instruction, so the lowering restates a popping destination
in that frame (sim/cpus/lowering.py after_pop). Before issue 36 it did not: a popped result landed
one slot off, and the next reader of ST(0) did not wait for it.

Each loop below carries one value from iteration to iteration through the instruction under test.
The expected cycles per iteration follow from the models' dependency rule (a uop starts when its
sources are ready, a result is ready its row's latency later): the sum of the table rows' latencies
along the chain, read from the model's own table, except where a row's throughput bounds the loop
(said at the case). The loops start with the x87 stack as `retrosim loop` leaves it (empty, FNINIT
control word, 64-bit precision): Unicorn does not fault on an empty slot, and the timing models
only follow the slots' ready times.
"""

from __future__ import annotations

import pytest

from sim.cpus.build import make_model
from sim.timing import loop


def latency(cpu: str, mnemonic: str, signature: str) -> float:
    row = make_model(cpu).table.lookup(mnemonic, signature).row
    return row.latency


def cycles(body: str, cpu: str) -> float:
    return loop.time_body(body, [cpu])[0].cycles_per_iteration


# (body, the chain through it as (mnemonic, signature) rows)
POPPING_ARITHMETIC = {
    m: (f"fld st(0)\n{m} st(1), st\n", [("fld", "sti"), (m, "sti,st")])
    for m in ("faddp", "fsubp", "fmulp", "fdivrp")
}
CHAINS = {
    **POPPING_ARITHMETIC,
    # FSTP ST(1) pops the square into the slot the FLD copied from: the next FLD reads it
    "fstp st(1)": ("fld st(0)\nfmul st(0), st(0)\nfstp st(1)\n", [("fld", "sti"), ("fmul", "st,sti"), ("fstp", "sti")]),
    # FST ST(1) copies the sum to ST(1), which the next FADD reads
    "fst st(1)": ("fadd st(0), st(1)\nfst st(1)\n", [("fadd", "st,sti"), ("fst", "sti")]),
    # FPATAN and FYL2X pop and leave their result in the new ST(0)
    "fpatan": ("fld st(0)\nfpatan\n", [("fld", "sti"), ("fpatan", "")]),
    "fyl2x": ("fld st(0)\nfyl2x\n", [("fld", "sti"), ("fyl2x", "")]),
}


@pytest.mark.parametrize("name", list(CHAINS))
def test_a_value_carried_through_the_stack_waits_for_its_producer_on_the_p6(name):
    body, rows = CHAINS[name]
    expected = sum(latency("pentium2-233", m, s) for m, s in rows)
    assert cycles(body, "pentium2-233") == pytest.approx(expected, abs=0.05)


@pytest.mark.parametrize("name", list(POPPING_ARITHMETIC) + ["fstp st(1)"])
def test_a_value_carried_through_the_stack_waits_for_its_producer_on_the_p5(name):
    # the P5's FPU pipeline: a dependent x87 instruction waits for its source's latency
    body, rows = CHAINS[name]
    expected = sum(latency("pentium-mmx-233", m, s) for m, s in rows)
    assert cycles(body, "pentium-mmx-233") == pytest.approx(expected, abs=0.05)


def test_fxch_swaps_the_ready_times_of_two_independent_chains_on_the_p6():
    # FMUL ST,ST squares ST(0); FXCH ST(1) brings the other value up: two chains of FMULs
    # alternate, each FMUL waits for the one two iterations back. The loop runs at half the
    # FMUL's latency, or at the FMUL's throughput if that is larger. FXCH itself costs nothing
    # (renamed: AF29n note f). If FXCH did not swap the slots' ready times the FMULs would form
    # one chain, a full latency per iteration.
    t = make_model("pentium2-233").table.lookup("fmul", "st,sti").row
    expected = max(t.latency / 2, t.throughput)
    assert cycles("fmul st(0), st(0)\nfxch st(1)\n", "pentium2-233") == pytest.approx(expected, abs=0.05)
