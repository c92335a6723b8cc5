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


# -- P54C: a multi-clock instruction hides the next prefixes' decode clocks -----------------------
# Agner Fog, Pentium manual (1997 edition, Fujinami's translation), sec. 13: on the PPlain an
# instruction taking N clocks to execute hides the decode delay of N-1 prefixes of the next two
# instructions or pairs. InstLatX64 P54C dump (GenuineIntel0000525): chains of 0F-prefixed
# multi-clock instructions measure what the P55C measures (MOVZX r32,r8 3, SHLD r32,r32,imm8 4,
# BSF r32,r32 6, IMUL r32,r32 9), one-clock ones one clock more (BSWAP r32 2, MOV r16,r16 2).

@pytest.mark.parametrize("insn, clocks", [("movzx eax, al", 3), ("shld eax, ebx, 3", 4), ("bsf eax, eax", 6),
                                          ("imul eax, ebx", 9), ("bswap eax", 2), ("mov ax, bx", 2)])
def test_p54c_prefix_decode_hides_behind_multi_clock_instructions(insn, clocks):
    assert cycles(insn, "pentium-133") == pytest.approx(clocks, abs=0.05)


def test_p54c_prefix_after_one_clock_instructions_still_costs_a_clock():
    # AF97 sec. 13: two one-clock instructions (a pair) cast no shadow: the 0F prefix of MOVZX costs
    # its clock; after a 2-clock CLD it does not (Agner's CLD / REP MOVSD example, the same rule)
    plain = cycles("add ebx, 1\nadd ecx, 1\nbswap eax", "pentium-133")
    shadowed = cycles("cld\nbswap eax", "pentium-133")
    assert plain == pytest.approx(1 + 2, abs=0.05)   # the pair, then BSWAP's prefix and execute clocks
    assert shadowed == pytest.approx(2 + 1, abs=0.05)  # CLD 2 clocks, BSWAP 1: its prefix is hidden


# -- P6: the multiply's uop flow ------------------------------------------------------------------
# Intel, "Optimizations for Intel's 32-Bit Processors" v2.2 (1995), App. D "P6 Processor Instruction
# Timing Information": MUL/IMUL rm8 is one port-0 uop (AX = mul(AL, r8), latency 4); MUL/IMUL rm32 is
# the multiply (port 0, latency 4), then EAX (port 0 or 1) and EDX (port 0), one clock each.
# Intel 242816 (Intel Architecture Optimization Manual, 1997) Table 2-3: integer multiplication
# latency 4, throughput 1/cycle (pipelined). InstLatX64 PII: MUL r8 L 4, MUL r32 L 5 (EAX and EDX).

@pytest.mark.table_check
@pytest.mark.parametrize("insn, clocks", [("mul bl", 4), ("imul bl", 4), ("mul ebx", 5), ("imul ebx", 5)])
def test_p6_multiply_latency(insn, clocks):
    assert cycles(insn, "pentium2-233") == pytest.approx(clocks, abs=0.05)


@pytest.mark.parametrize("cpu", ["pentium2-233", "pentium3-500"])
def test_p6_independent_byte_multiplies_pipeline(cpu):
    # four MUL r8 whose AL each comes from a fresh MOV: one port-0 uop each on a pipelined
    # multiplier, so port 0 gives one multiply per clock (the model held the multiplier 4 clocks
    # per MUL r8, InstLat's T 4.00, which is the chain through AL/AX, and took 16)
    body = "mov al, cl\nmul bl\n" * 4
    assert cycles(body, cpu) == pytest.approx(4, abs=0.3)


@pytest.mark.parametrize("cpu", ["pentium-pro-200", "pentium2-233", "pentium3-500"])
def test_p6_partial_flags_stall_costs_about_four_clocks(cpu):
    # Agner Fog, The microarchitecture of Intel, AMD and VIA CPUs, sec. 6.8 "Partial flags stalls"
    # (PPro/P2/P3): reading a flag INC/DEC left unmodified (CF) stalls, "approximately 4 clocks".
    # The model's wait (the writers' retirement plus estimates.partial_extra, set from the measured
    # +5 of the partial-register stall) is not given this figure.
    stalled = cycles("inc ecx\nadc edx, 0", cpu)
    clean = cycles("add ecx, 1\nadc edx, 0", cpu)
    assert stalled - clean == pytest.approx(4, abs=1)
