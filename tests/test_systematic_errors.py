"""Sourced figures behind the issue-20 item-6 fixes (systematic errors on held-out loops).

Each test asserts a figure a source states (the citation is in the test), timed as a block with the
loop harness: a dependent chain gives the latency, independent copies the throughput. None of these
figures is a held-out loop timing."""

from __future__ import annotations

import pytest

from sim.timing import loop


def cycles(body: str, cpu: str, iterations: int = 40) -> float:
    return loop.time_body(body, [cpu], iterations=iterations)[0].cycles_per_iteration


# -- P5: 32-bit MUL/IMUL take 9 clocks ------------------------------------------------------------
# InstLatX64 GenuineIntel0000525_P54C_InstLatX86.txt (P54C 100 MHz) and
# GenuineIntel0000543_P55C_InstLatX86.txt (P55C 200 MHz): MUL r32 and IMUL r32 (EAX and EDX
# results), IMUL r32,r32 and IMUL r32,r32,imm: L 9.0 T 9.00; MUL/IMUL r8 and r16: 11.
# Agner Fog's Pentium list (1997 edition, sec. 20): 32-bit MUL/IMUL 9 clocks, not pairable.

@pytest.mark.parametrize("cpu", ["pentium-133", "pentium-mmx-166"])
@pytest.mark.parametrize("insn, clocks", [("mul ebx", 9), ("imul ebx", 9), ("imul eax, eax, 10", 9), ("mul bl", 11)])
def test_p5_multiply_clocks(cpu, insn, clocks):
    assert cycles(insn, cpu) == pytest.approx(clocks, abs=0.05)


@pytest.mark.parametrize("insn, clocks", [("imul eax, ebx", 9), ("mul bx", 11)])
def test_p5_prefixed_multiply_clocks_on_the_p55c(insn, clocks):
    # 0F (IMUL r,r) and 66 (MUL r16): no decode clock on the P55C with its FIFO full (p5_machine.toml)
    assert cycles(insn, "pentium-mmx-166") == pytest.approx(clocks, abs=0.05)


def test_p5_independent_multiplies_do_not_overlap():
    # T = L = 9 (IL-P5): the multiplier is not pipelined, independent multiplies still take 9 each
    assert cycles("mul ebx\nmul ecx\nmul ebp", "pentium-133") == pytest.approx(27, abs=0.1)
