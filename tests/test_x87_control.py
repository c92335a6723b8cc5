"""Issue 20 item 3: loading the x87 control word costs what the sources say, in every family.

A 24-bit FDIV chain (FDIV ST,ST(1) repeated on one stack value) with and without an FLDCW of the same
control word before every FDIV. Without it the loop runs at the FDIV's 24-bit latency; with it:
- P6: the control word is not renamed (Intel, IA-32 Intel Architecture Optimization Reference Manual
  248966, "Floating-point Modes": "On the Pentium III processor, the FLDCW instruction is an
  expensive operation"): FLDCW waits for the FDIV before it and the next FDIV waits for FLDCW, so
  nothing of the FLDCW's latency after its load (86Box fldcw_op 10, less the 3-clock L1 load: 7)
  overlaps the divide;
- P5: FLDCW is 8 clocks, not pairable, and waits for the FPU (Agner Fog, "How to optimize for the
  Pentium family", sec. 28.2: FLDCW m16 8 clocks, np, no overlap);
- K6: FLDCW is a vector-decoded 8-clock FPU op (86Box codegen_timing_k6.c D9 /5; no AMD figure found).
"""

from __future__ import annotations

import pytest

from sim.timing.kernel import time_kernel

KERNEL = """.intel_syntax noprefix
.text
# @entry with_fldcw(n)
.globl with_fldcw
with_fldcw:
    mov ecx, dword ptr [esp+4]
    fninit
    fldcw word ptr [cw24]
    fld1
    fld1
1:
    fldcw word ptr [cw24]
    fdiv st(0), st(1)
    dec ecx
    jnz 1b
    fstp st(0)
    fstp st(0)
    ret
# @entry without_fldcw(n)
.globl without_fldcw
without_fldcw:
    mov ecx, dword ptr [esp+4]
    fninit
    fldcw word ptr [cw24]
    fld1
    fld1
1:
    nop
    fdiv st(0), st(1)
    dec ecx
    jnz 1b
    fstp st(0)
    fstp st(0)
    ret
.data
cw24: .short 0x007F   # every exception masked, 24-bit precision, round to nearest
"""


def per_iteration(src, entry: str, cpu: str) -> float:
    a = time_kernel(src, entry, lambda m: [200], cpu=cpu).last["cycles"]
    b = time_kernel(src, entry, lambda m: [400], cpu=cpu).last["cycles"]
    return (b - a) / 200


@pytest.fixture(scope="module")
def kernel(tmp_path_factory):
    path = tmp_path_factory.mktemp("x87") / "x87_control.S"
    path.write_text(KERNEL)
    return path


# FDIV at 24-bit precision (latency) and what an FLDCW before each one adds, per the sources above
CASES = {
    "pentium2-233": (18, 7),   # InstLat-PII / AF29n h: FDIV 18 at 24 bits; FLDCW 10 - 3 (load)
    "pentium3-500": (18, 7),
    "pentium-90": (19, 8),     # AF28.2: FDIV 19/33/39; FLDCW 8
    "k6-2-300": (None, 8),     # 86Box: FLDCW 8
    "k6-233": (None, 8),
}


@pytest.mark.parametrize("cpu", list(CASES))
def test_loading_the_control_word_before_each_divide_costs_its_sourced_clocks(kernel, cpu):
    fdiv, fldcw = CASES[cpu]
    without = per_iteration(kernel, "without_fldcw", cpu)
    with_ = per_iteration(kernel, "with_fldcw", cpu)
    if fdiv is not None:
        assert without == pytest.approx(fdiv, abs=0.5)
    assert with_ - without == pytest.approx(fldcw, abs=0.5)


# ---- issue 36: the x87 stack carries the dependencies the control word's rule relies on ----------
# The rule (sim/cpus/lowering.py fpcw_sources, P6 only): FLDCW waits for every older x87 instruction
# and every later one that rounds waits for it. In the issue's loop the FDIVP's result is discarded
# by FSTP ST(0) (or FFREE ST(0) + FINCSTP, or FFREEP ST(0)); the next FLDCW must still wait for the
# divide. Expected figures are the sum of the table rows' latencies along that chain, taken from the
# model's own table (not from a run): the FLDCW's compute after its load, an FLD1, the second FLD1
# a clock later (both rows are port-0 only and wait for the same FLDCW), the FDIVP at 24 bits (the
# loop's control word is the zero word at [ESI]: precision control 00), then the discarding
# instruction's chain to the next FLDCW. Before issue 36, the loop ran at the FDIVP's throughput.

ISSUE_LOOP = """top:
    fldcw [esi]
    fld1
    fld1
    fdivp st(1), st
    {discard}
    dec ecx
    jnz top
"""


def row_latency(table, mnemonic: str, signature: str, precision: int | None = None) -> int:
    match = table.lookup(mnemonic, signature)
    if precision is not None:
        match = match.at_precision(precision)
    row = match.row
    return int(row.latency) if row.latency is not None else row.uops  # lowering: 1 per compute uop


@pytest.mark.parametrize("cpu", ["pentium2-233", "pentium3-500"])
@pytest.mark.parametrize("discard", ["fstp st(0)", "ffreep st(0)", "ffree st(0)\n    fincstp"])
def test_fldcw_waits_for_a_divide_whose_result_was_discarded(cpu, discard):
    from sim.cpus.build import make_model
    from sim.timing import loop
    model = make_model(cpu)
    table = model.table
    chain = (row_latency(table, "fldcw", "m16") - model.l1_latency + row_latency(table, "fld1", "") + 1
             + row_latency(table, "fdivp", "sti,st", precision=0))
    if discard == "fstp st(0)":  # FSTP ST(0) reads the quotient: the next FLDCW waits for it too
        chain += row_latency(table, "fstp", "sti")
    cycles = loop.time_body(ISSUE_LOOP.format(discard=discard), [cpu])[0].cycles_per_iteration
    assert cycles == pytest.approx(chain, abs=0.05)
