"""REP string instructions on the P6 and K6 (issue 20 item 1): per-element clocks of an L1-resident
REP MOVSD / REP STOSD, measured as the difference between a run of n elements and one of none, so
the call's own instructions cancel. Each expected figure names its source (docs/sources/p6.md and
k6.md, "REP strings"); the tolerance covers the first element's decode and the rounding of the
loop's fractional rate to whole cycles."""

import numpy as np
import pytest

from sim.timing.kernel import time_kernel

# ESI = p + soff, EDI = p + 4096 + doff (ECX dwords); back = 1 copies downwards (DF = 1) from the
# same last element
KERNEL = """.intel_syntax noprefix
.text
.globl k
k:
    push esi
    push edi
    mov esi, [esp+12]
    lea edi, [esi+4096]
    add edi, [esp+24]
    add esi, [esp+20]
    mov ecx, [esp+16]
    cmp dword ptr [esp+28], 0
    je 1f
    lea eax, [ecx*4-4]
    add esi, eax
    add edi, eax
    std
1:
    {op}
    cld
    pop edi
    pop esi
    ret
"""


def per_element(tmp_path, cpu, op, n, soff=0, doff=0, back=0):
    """Clocks per element of `op` over n dwords, the buffers in L1 (the last of three calls)."""
    src = tmp_path / f"{op.replace(' ', '_')}.S"
    src.write_text(KERNEL.format(op=op))

    def cycles(count):
        setup = lambda m: [m.arena.put(np.zeros(12288, np.uint8), align=4096), count, soff, doff, back]
        return time_kernel(src, "k", setup, cpu=cpu, repeat=3).last["cycles"]

    return (cycles(n) - cycles(0)) / n


# P6 fast strings: InstLat-PII (Pentium II Deschutes) REP MOVSD 9.03 B/c = 0.44 clk per dword and
# REP STOSD 5.62 B/c = 0.71, in L1; start-up AF26.3 (Agner Fog, "How to optimize for the Pentium
# family", sec. 26.3: about 215 + 2n uops for REP MOVSD, 185 + 1.5n for REP STOSD in fast mode, the
# constant at 3 uops per clock: 72 and 62 clocks). 256 dwords: 0.44 + 72/256 and 0.71 + 62/256.
@pytest.mark.parametrize("op, rate, startup", [("rep movsd", 0.44, 72), ("rep stosd", 0.71, 62)])
def test_p6_fast_strings_move_a_kilobyte_in_under_a_clock_per_dword(tmp_path, op, rate, startup):
    got = per_element(tmp_path, "pentium2-233", op, 256)
    assert got == pytest.approx(rate + startup / 256, abs=0.05)
    assert got <= 1.0


# AF29 (Agner Fog's P6 table): REP MOVS ca. 6n uops, REP STOS ca. 5n: 2 and 1.67 clocks per element
# at 3 uops per clock when the fast-string conditions fail (IASDM3 8.2.4 / AF26.3: ECX >= 64, ESI
# and EDI aligned by 8, forward, EDI - ESI >= 32)
@pytest.mark.parametrize("op, slow", [("rep movsd", 2.0), ("rep stosd", 1.67)])
@pytest.mark.parametrize("case", ["count 63", "edi misaligned", "backward"])
def test_p6_strings_without_fast_mode_run_the_microcode_loop(tmp_path, op, slow, case):
    n, doff, back = {"count 63": (63, 0, 0), "edi misaligned": (256, 4, 0), "backward": (256, 0, 1)}[case]
    assert per_element(tmp_path, "pentium2-233", op, n, doff=doff, back=back) == pytest.approx(slow, abs=0.1)


def test_p6_rep_movsd_source_alignment_and_distance_matter_rep_stosd_has_no_source(tmp_path):
    # REP MOVS needs ESI aligned by 8 too (IASDM3 8.2.4: "EDI and ESI must be 8-byte aligned for the
    # Pentium III"); REP STOS reads nothing, so ESI does not count
    assert per_element(tmp_path, "pentium2-233", "rep movsd", 256, soff=4) == pytest.approx(2.0, abs=0.1)
    assert per_element(tmp_path, "pentium2-233", "rep stosd", 256, soff=4) == pytest.approx(0.71 + 62 / 256, abs=0.05)


def test_p6_fast_strings_start_at_64_elements(tmp_path):
    # the 64-element run pays the fast start-up (AF26.3, 72 clocks) and 0.44 per element; the
    # 63-element run none of it but 2 clocks per element (AF29): ECX = 64 is faster in total
    fast = per_element(tmp_path, "pentium2-233", "rep movsd", 64) * 64
    slow = per_element(tmp_path, "pentium2-233", "rep movsd", 63) * 63
    assert fast == pytest.approx(72 + 64 * 0.44, abs=4)
    assert slow == pytest.approx(63 * 2.0, abs=4)


# K6: IL-K62 (InstLatX64 K6-2 dump) REP MOVSD 5.13 B/c = 0.78 clk per dword, REP STOSD 3.19 B/c =
# 1.25; the K6 (model 6) takes the K6-2 core figure (its own dump, 0.22 B/c, was measured on a board
# without write allocation, which the memory model charges itself)
@pytest.mark.parametrize("cpu", ["k6-2-300", "k6-233{write_allocate.mode=full}"])
@pytest.mark.parametrize("op, rate", [("rep movsd", 0.78), ("rep stosd", 1.25)])
def test_k6_rep_strings_run_at_the_measured_core_rate(tmp_path, cpu, op, rate):
    assert per_element(tmp_path, cpu, op, 256) == pytest.approx(rate, abs=0.05)


@pytest.mark.parametrize("case", [(16, 0, 0), (256, 4, 0), (256, 0, 1)])
def test_k6_rep_movsd_rate_does_not_depend_on_count_alignment_or_direction(tmp_path, case):
    # no K6 source gives a start-up, a misalignment or a DF = 1 cost for REP MOVS (docs/sources/k6.md):
    # the measured per-element rate holds for small, misaligned and backward copies alike
    n, doff, back = case
    assert per_element(tmp_path, "k6-2-300", "rep movsd", n, doff=doff, back=back) == pytest.approx(0.78, abs=0.08)


def test_k6_233_without_write_allocation_pays_the_bus_per_store(tmp_path):
    # the same copy to lines not in L1: on the k6-233 board (no write allocation) every store is a
    # bus write (the memory model, k6-233.toml [write_allocate]), far above the core's 0.78
    src = tmp_path / "miss.S"
    src.write_text(".intel_syntax noprefix\n.text\n.globl k\nk:\n    push esi\n    push edi\n"
                   "    mov esi, [esp+12]\n    lea edi, [esi+65536]\n    mov ecx, [esp+16]\n    cld\n"
                   "    rep movsd\n    pop edi\n    pop esi\n    ret\n")

    def run(n):
        setup = lambda m: [m.arena.put(np.zeros(131072, np.uint8), align=4096), n]
        return time_kernel(src, "k", setup, cpu="k6-233", repeat=1).last

    small, big = run(16), run(1040)
    assert big["bus_writes"] - small["bus_writes"] >= 1000
    assert (big["cycles"] - small["cycles"]) / 1024 > 5
