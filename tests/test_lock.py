"""Issue 8: locked read-modify-writes and the SBB rows.

A LOCK-prefixed instruction, and XCHG with a memory operand (locked on every x86), cost the lock
(sim/cpus/locking.py, each machine table's [lock] section): a cache lock of fixed core clocks on the
P6, a bus lock in bus clocks on the P5 and K6. The expected figures are the InstLatX64 measurements
on presets whose core/bus ratio is the measured system's; the ratio tests check the kind of lock.
"""

from __future__ import annotations

import pytest

from sim.cpus.table import load_table
from sim.timing.kernel import time_kernel

PROLOGUE = "    push ebx\n    sub esp, 64\n    mov ebx, esp\n    mov eax, 1\n"
TAIL = "    add esp, 64\n    pop ebx\n    ret\n"


def per_insn(write_kernel, cpu: str, line: str, independent: bool = True) -> float:
    """Clocks per instruction of `line` repeated: the difference between 80 and 40 copies, so the
    call's own cost cancels. `{o}` in the line is an offset over eight dwords when independent."""
    cycles = []
    for n in (40, 80):
        body = "".join(f"    {line.format(o=4 * (i % 8) if independent else 0)}\n" for i in range(n))
        src = write_kernel(PROLOGUE + body, f"k{n}.S", entry="k", tail=TAIL)
        cycles.append(time_kernel(src, "k", cpu=cpu, repeat=2).last["cycles"])
    return (cycles[1] - cycles[0]) / 40


# (preset, measured LOCK ADD [m32],r32 T, measured XCHG r32,[m32] T, the dump): presets at the
# measured system's bus ratio (the P6's cache lock does not depend on it)
MEASURED = [
    ("pentium2-233", 21.0, 19.0, "InstLatX64 P2 Deschutes"),
    ("pentium-pro-200", 21.0, 19.0, "InstLatX64 P6 0617"),
    ("k6-233", 49.83, 49.83, "InstLatX64 K6 0562 (233.8 MHz, 3.5 x 66)"),
    ("pentium-90", 18.0, 15.0, "InstLatX64 P54C 0525 (100 MHz, 1.5 x 66; pentium-90 is 1.5 x 60)"),
]


@pytest.mark.parametrize("cpu,lock_add,xchg,dump", MEASURED)
@pytest.mark.table_check
def test_a_locked_rmw_costs_the_measured_lock(write_kernel, cpu, lock_add, xchg, dump):
    plain = per_insn(write_kernel, cpu, "add [ebx+{o}], eax")
    locked = per_insn(write_kernel, cpu, "lock add [ebx+{o}], eax")
    assert plain < 3  # the unlocked RMW: one to three clocks on every family
    assert locked == pytest.approx(lock_add, abs=1.0), dump
    assert locked - plain > 10  # the lock, not the ALU work, is the cost


@pytest.mark.parametrize("cpu,lock_add,xchg,dump", MEASURED)
@pytest.mark.table_check
def test_xchg_with_memory_costs_the_locked_figure(write_kernel, cpu, lock_add, xchg, dump):
    # XCHG with memory is locked with or without the prefix (Intel SDM vol. 2, XCHG)
    implicit = per_insn(write_kernel, cpu, "xchg [ebx+{o}], eax")
    explicit = per_insn(write_kernel, cpu, "lock xchg [ebx+{o}], eax")
    assert implicit == pytest.approx(xchg, abs=1.5), dump
    assert explicit >= implicit
    # XCHG between registers is not locked
    assert per_insn(write_kernel, cpu, "xchg eax, ecx") < 4


def test_every_lockable_rmw_pays_the_lock(write_kernel):
    # the lock is the cost whatever the operation (the P6's LOCK ADD figure as a floor)
    for line in ("lock or dword ptr [ebx+{o}], 1", "lock inc dword ptr [ebx+{o}]", "lock xadd [ebx+{o}], eax",
                 "lock cmpxchg [ebx+{o}], ecx", "lock bts dword ptr [ebx+{o}], 3", "lock sbb [ebx+{o}], eax"):
        assert per_insn(write_kernel, "pentium2-233", line) >= 20.5, line


def test_the_p6_locks_its_cache_the_p5_and_k6_their_bus(write_kernel):
    # P6: the same core clocks at bus ratio 3 (Pentium Pro 200) and 5 (Pentium III 500); the
    # Socket 7 parts lock the bus, so the cost in core clocks grows with the ratio
    p6 = [per_insn(write_kernel, cpu, "lock add [ebx+{o}], eax") for cpu in ("pentium-pro-200", "pentium3-500")]
    assert p6[0] == pytest.approx(p6[1], abs=0.5)
    p5 = [per_insn(write_kernel, cpu, "lock add [ebx+{o}], eax") for cpu in ("pentium-90", "pentium-166")]
    assert p5[1] > p5[0] * 1.4  # ratio 1.5 -> 2.5
    k6 = [per_insn(write_kernel, cpu, "xchg [ebx+{o}], eax") for cpu in ("k6-2-300", "k6-3-450")]
    assert k6[1] > k6[0]


@pytest.mark.table_check
def test_a_dependent_lock_add_chain_runs_at_the_measured_latency(write_kernel):
    # InstLatX64 Deschutes LOCK ADD [m32],r32 L 21.0: a chain through one address waits for the lock
    assert per_insn(write_kernel, "pentium2-233", "lock add [ebx], eax", independent=False) == pytest.approx(21, abs=1)


# -- SBB is timed as ADC (Agner Fog's P6 uop list gives one line for ADC and SBB; 86Box decodes both
# as vector ops on the K6; InstLatX64 measures SBB r,r = ADC r,r on every CPU here) ----------------
@pytest.mark.parametrize("family", ["p6", "k6", "p5"])
@pytest.mark.parametrize("sig", ["r32,m32", "m32,r32"])
def test_sbb_memory_rows_are_the_adc_rows(family, sig):
    table = load_table(family)
    sbb, adc = table.lookup("sbb", sig).row, table.lookup("adc", sig).row
    def timing(row):
        return (row.uops, row.ports, row.decoder, row.latency, row.throughput,
                *(row.extra.get(f) for f in ("units", "cycles", "pairing")))
    assert timing(sbb) == timing(adc)
    assert "as the add" not in sbb.source


@pytest.mark.parametrize("cpu", ["pentium2-233", "k6-2-300"])
def test_sbb_times_as_adc(write_kernel, cpu):
    for form in ("{m} eax, [ebx+{{o}}]", "{m} [ebx+{{o}}], eax"):
        sbb, adc = (per_insn(write_kernel, cpu, form.format(m=m)) for m in ("sbb", "adc"))
        assert sbb == pytest.approx(adc, abs=0.05)
    # and not as ADD: the P6 dependent chain SBB EAX,[m] is load 3 + SBB 2 (InstLat SBB r,r L 2)
    chain = {m: per_insn(write_kernel, "pentium2-233", f"{m} eax, [ebx]", independent=False) for m in ("sbb", "add")}
    assert chain["sbb"] > chain["add"]


@pytest.mark.table_check
def test_p6_bound_takes_agners_line_for_both_sizes():
    table = load_table("p6")
    r32, r16 = table.rows[("bound", "r32,m64")], table.rows[("bound", "r16,m32")]
    assert r32.uops == r16.uops == 15 and r32.ports == r16.ports


def test_no_dead_m32_movhps_movlps_rows():
    # MOVHPS/MOVLPS move 64 bits: the decoder asks for m64, and only m64 rows exist
    rows = load_table("p6").rows
    for m in ("movhps", "movlps"):
        assert (m, "xmm,m32") not in rows and (m, "m32,xmm") not in rows
        assert (m, "xmm,m64") in rows and (m, "m64,xmm") in rows
