"""P6 register read stalls (issue 36): the ROB-read stage reads at most two registers per clock from
the permanent register file, so a triplet of uops renamed together that reads 3 or 4 distinct
registers not modified recently costs a clock more, 5 or 6 two more (Agner Fog, The microarchitecture
of Intel, AMD and VIA CPUs, sec. 6.5 "ROB read"; PIIDM: at most 2 completed-register reads per
cycle). p6_machine.toml [rob.register_read]; sim/cpus/p6/core.py _register_reads.

Expected figures follow from that rule: a group of uops renamed together takes ceil(reads / 2)
clocks in the ROB-read stage, at least one. The loops are blocks (`retrosim loop` repeats them back
to back), so each block's uops are one triplet when the block is three uops."""

from __future__ import annotations

import math

import pytest

from sim.timing import loop

READ_PORTS = 2  # p6_machine.toml [rob.register_read] max_completed_register_reads_per_cycle


def timed(body: str, cpu: str = "pentium2-233") -> dict[str, float]:
    return loop.time_body(body, [cpu])[0].per_iteration


def clocks_for(distinct_reads: int) -> int:
    return max(1, math.ceil(distinct_reads / READ_PORTS))


def test_agner_example_6_4a_five_register_reads_cost_two_clocks():
    # MOV [EDI+ESI],EAX is two uops (store address reads EDI, ESI; store data reads EAX), MOV
    # EBX,[ESP+EBP] one (reads ESP, EBP; EBX is only written): one triplet reading five registers
    # that nothing writes, three clocks in ROB-read, two more than the one a triplet takes.
    t = timed("mov [edi+esi], eax\nmov ebx, [esp+ebp]\n")
    assert t["cycles"] == pytest.approx(clocks_for(5), abs=0.02)
    assert t["stall_register_read"] == pytest.approx(clocks_for(5) - 1, abs=0.02)


def test_agner_example_6_4b_two_registers_read_no_stall():
    # the same shape reading only EDI and ESI: no register read stall
    t = timed("mov [edi+esi], edi\nmov ebx, [edi+edi]\n")
    assert t["stall_register_read"] == 0
    assert t["cycles"] < clocks_for(5)


def test_a_register_written_in_the_previous_triplets_is_read_free():
    # Agner's example 6.5 rule: a register written in one triplet reads free in at least the next
    # three. Three ADDs each rewrite the register they read (as InstLatX64's throughput copies do):
    # every read is of a register written one triplet earlier, no stall, two ALU ports: 1.5 clocks.
    t = timed("add eax, eax\nadd ebx, ebx\nadd edx, edx\n")
    assert t["stall_register_read"] == 0
    assert t["cycles"] == pytest.approx(1.5, abs=0.02)


@pytest.mark.parametrize("cpu", ["pentium-pro-200", "pentium2-233", "celeron-300a", "pentium3-500"])
def test_instructions_that_only_read_their_registers_stall_as_instlat_measured(cpu):
    # InstLatX64 (PPro, PII Deschutes, Mendocino, PIII Katmai dumps): CMP/TEST r32,r32 T 0.67 and
    # CMP/TEST r1_32,r2_32 T 1.00, where SUB/AND/OR/XOR r32,r32 (the same port, but each copy
    # rewrites its register) measure 0.50. By the rule: copies that read three distinct registers
    # per triplet take 2 clocks per 3 copies, six distinct registers 3 clocks per 3 copies.
    same = timed("cmp eax, eax\ncmp ebx, ebx\ncmp edx, edx\n", cpu)
    pairs = timed("cmp eax, ebx\ncmp ecx, edx\ncmp esi, edi\n", cpu)
    assert same["cycles"] / 3 == pytest.approx(clocks_for(3) / 3, abs=0.01)
    assert pairs["cycles"] / 3 == pytest.approx(clocks_for(6) / 3, abs=0.01)


def test_fxch_reads_nothing_in_the_rule():
    # Agner: FXCH "neither reads nor writes any registers with regard to the rules for register
    # read stalls": two FXCHs on distinct stack registers never written (and a MOV that reads
    # nothing) cost no stall; counted as reads, ST(0), ST(1), ST(2) would make three
    t = timed("fxch st(1)\nfxch st(2)\nmov eax, 1\n")
    assert t["stall_register_read"] == 0


def test_rewritten_registers_stay_free_while_renaming_is_slow():
    # InstLatX64's throughput copies of PADDB mm,mm (T 0.50 on the PII dumps): eight copies, each
    # rewriting the register it reads, two per clock on the two MMX ALU ports. Each read is of a
    # register written eight uops (under three triplets) earlier: free by the rule, counted in
    # triplets. (Counted in clocks instead, a read 4 clocks after its writer would become a
    # permanent-file read once renaming slowed, and the copies would lock into 0.67.)
    body = "".join(f"paddb mm{k}, mm{k}\n" for k in range(8))
    t = timed(body)
    assert t["stall_register_read"] == 0
    assert t["cycles"] / 8 == pytest.approx(0.5, abs=0.01)
