"""Dependent chains of multi-uop instructions take their measured latency on each family.

Each kernel of kernels/micro/chains.S (and cmov.S) runs 8 instances of one instruction per iteration, each
reading the previous one's result; cycles / (8 n) is the instruction's latency (the loop counter
is off the chain). The expected figures are measurements (InstLatX64 dumps, quoted in the rows of
sim/cpus/p6/p6.toml and k6.toml) or, where a row has only a published delay, Agner Fog's table
plus the measured L1 load latency; each case names its source. Short keys as in the tables:
InstLat-PII = InstLatX64 GenuineIntel0000651 (Pentium II); IL-all = the same figure in the K6, K6-2
and K6-III dumps (AuthenticAMD0000562, 0000580, 0000591); AF29 = Agner Fog, "How to optimize for
the Pentium family", sec. 29.1.
"""

import numpy as np
import pytest

from sim.timing.kernel import emulate, time_emulation

from conftest import KERNELS

CHAINS = KERNELS / "micro" / "chains.S"
CMOV = KERNELS / "micro" / "cmov.S"  # apart: CMOV does not assemble for the CPUs that lack it
N = 200
SLACK = 0.25  # per instance: the loop's counter and branch, amortised over 8 instances

# entry -> (P6 latency, its source) on pentium2-233
P6 = {
    "bsr_chain": (2, "InstLat-PII BSR r32,r32 L 2.0; InstLat-Mendocino L 2.0"),
    "mul_chain": (5, "InstLat-PII MUL r32 L 5.0"),
    "imul1_chain": (5, "InstLat-PII IMUL r32 L 5.0"),
    "imul_chain": (4, "InstLat-PII IMUL r32,r32 L 4.0; AF29 delay 4"),
    "imul_imm_chain": (4, "InstLat-PII IMUL r32,r32,imm8 L 4.0"),
    "imul_mem_chain": (7, "AF29 MUL IMUL (r),m delay 4 + InstLat-PII MOV r32,[m32] L 3.0"),
    "cmov_chain": (2, "InstLat-PII CMOVNZ r32,r32 L 2.0; InstLat-PPro L 2.0"),
    "add_mem_chain": (4, "InstLat-PII ADD r32,[m32] L 4 (load 3 + add 1)"),
    "shld_chain": (2, "InstLat-PII SHLD r32,r32,imm8 L 2.0"),
    "shrd_chain": (2, "InstLat-PII SHRD r32,r32,imm8 L 2.0; InstLat-Mendocino the same"),
    "shrd_cl_chain": (2, "InstLat-PII SHRD r32,r32,cl L 2.0"),
    "xchg_chain": (1.8, "InstLat-PII XCHG r1_32,r2_32 L 1.8"),
    "adc_chain": (2, "InstLat-PII ADC r32,r32 L 2.0; InstLat-PPro L 2.0"),
    "sbb_chain": (2, "InstLat-PII SBB r1_32,r2_32 L 2.0"),
}

# entry -> (K6 latency, its source) on every K6 generation
K6 = {
    "bsr_chain": (10, "IL-all BSR r32,r32 L 10.0"),
    "mul_chain": (3, "IL-all MUL r32 L 3.0"),
    "imul1_chain": (3, "IL-all IMUL r32 L 3.0"),
    "imul_chain": (3, "IL-all IMUL r32,r32 L 3.0"),
    "imul_imm_chain": (3, "IL-all IMUL r32,r32,imm8 L 3.0"),
    "imul_mem_chain": (5, "IL-all IMUL r32,r32 L 3.0 + IL-all MOV r32,[m32] L 2.0"),
    "add_mem_chain": (3, "IL-all ADD r32,[m32] L 3.0"),
    "shld_chain": (2, "IL-all SHLD r32,r32,imm8 L 2.0"),
    "shrd_chain": (2, "IL-all SHRD r32,r32,imm8 L 2.0"),
    "shrd_cl_chain": (2, "IL-all SHRD r32,r32,cl L 2.0"),
    "xchg_chain": (2, "IL-all XCHG r1_32,r2_32 L 2.0"),
    "adc_chain": (2, "IL-all ADC r32,r32 L 2.0"),
    "sbb_chain": (2, "IL-all SBB r1_32,r2_32 L 2.0"),
}


def per_instance(entry, cpus, per_iteration=8):
    def setup(m):
        return [N, m.arena.put(np.zeros(16, np.uint32))]

    emu = emulate(CMOV if entry == "cmov_chain" else CHAINS, entry, setup, repeat=2)
    return {cpu: time_emulation(emu, cpu).last["cycles"] / (N * per_iteration) for cpu in cpus}


@pytest.mark.parametrize("entry", sorted(P6))
def test_p6_chain_takes_the_measured_latency(entry):
    expected, source = P6[entry]
    got = per_instance(entry, ["pentium2-233"])["pentium2-233"]
    assert expected - SLACK <= got <= expected + SLACK, f"{entry}: {got:.2f} cycles, {source} says {expected}"


@pytest.mark.parametrize("entry", sorted(K6))
def test_k6_chain_takes_the_measured_latency(entry):
    expected, source = K6[entry]
    for cpu, got in per_instance(entry, ["k6-233", "k6-2-300", "k6-3-450"]).items():
        assert expected - SLACK <= got <= expected + SLACK, f"{entry} on {cpu}: {got:.2f} cycles, {source} says {expected}"


def test_an_instruction_inside_a_chain_adds_its_latency():
    # IMUL r32,r32 then BSR r32,r32 on one register: the latencies add (P6 4 + 2, InstLat-PII;
    # K6 3 + 10, IL-all). Before the uops of one instruction were chained on the P6, the BSRs
    # made the IMUL chain faster than IMULs alone.
    got = per_instance("imul_bsr_mix", ["pentium2-233", "k6-233"], per_iteration=4)
    assert 6 - SLACK <= got["pentium2-233"] <= 6 + SLACK
    assert 13 - SLACK <= got["k6-233"] <= 13 + SLACK
    imul_alone = per_instance("imul_chain", ["pentium2-233"])["pentium2-233"]
    assert got["pentium2-233"] > imul_alone
