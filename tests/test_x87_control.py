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
