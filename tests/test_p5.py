"""P5 (Pentium / Pentium MMX) micro-benchmarks from sourced facts (docs/sources/p5.md):
expectations are the sources' clock counts and pairing rules, not the model's parameters."""

from __future__ import annotations

import pytest

from sim.timing.kernel import time_kernel

def loop_kernel(write_kernel, body: str, n: int = 200, pre: str = "", name: str = "k") -> float:
    """Cycles per iteration of `body` in a counted loop (ECX counter, dec/jnz pair), measured as
    the difference between 2n and n iterations (the loop overhead of the dec/jnz pair is 1 clock
    when it pairs, which the caller's expectation includes)."""
    src = write_kernel(f"""# @entry {name}(n, buf)
.globl {name}
{name}:
    push ebx
    push esi
    push edi
    push ebp
    mov ecx, [esp+20]
    mov esi, [esp+24]
    mov edi, esi
    xor eax, eax
    xor ebx, ebx
    xor edx, edx
    xor ebp, ebp
{pre}
    jmp 1f
.p2align 4, 0xCC
1:
{body}
    dec ecx
    jnz 1b
    pop ebp
    pop edi
    pop esi
    pop ebx
    ret
""", f"{name}.S")
    import numpy as np

    def setup(count):
        return lambda m: [count, m.arena.put(np.zeros(4096, np.uint8), align=4096)]

    c = [time_kernel(src, name, setup(k), cpu=CPU, repeat=2).last["cycles"] for k in (n, 2 * n)]
    return (c[1] - c[0]) / n


CPU = "pentium-133"


@pytest.fixture(autouse=True)
def _cpu():
    global CPU
    CPU = "pentium-133"
    yield


def test_simple_pairs_pair(write_kernel):
    # INTEL-PAIR: two simple independent instructions issue together; dec/jnz pair (flags exception)
    assert loop_kernel(write_kernel, "    add eax, 1\n    add ebx, 1\n    add edx, 1\n    add ebp, 1") == 3


def test_raw_breaks_a_pair(write_kernel):
    # INTEL-PAIR: a read-after-write between the two prevents pairing: 4 instructions, 4 clocks + dec/jnz
    assert loop_kernel(write_kernel, "    add eax, 1\n    add ebx, eax\n    add edx, ebx\n    add ebp, edx") == 5


def test_waw_breaks_a_pair(write_kernel):
    assert loop_kernel(write_kernel, "    mov eax, 1\n    mov eax, 2") == 3


def test_adc_pairs_only_in_u(write_kernel):
    # SCHMIT rule 3 / the article: ADC pairs in U only. ADC first: pairs with the next (1 clock);
    # after an ALU op it would need the V pipe (and reads its flags): it runs alone.
    u = loop_kernel(write_kernel, "    adc eax, 1\n    add ebx, 1", name="u")
    v = loop_kernel(write_kernel, "    add ebx, 1\n    adc eax, 1\n    add edx, 1", name="v")
    assert u == 2
    assert v == 3  # add alone, adc+add pair, dec/jnz


def test_agi(write_kernel):
    # AF9: an address register written in the preceding clock costs one clock
    agi = loop_kernel(write_kernel, "    add esi, 0\n    nop\n    mov eax, [esi]\n    nop", name="agi")
    far = loop_kernel(write_kernel, "    add esi, 0\n    nop\n    nop\n    nop\n    mov eax, [esi]\n    nop", name="far")
    assert agi == 4  # 2 pairs + AGI + dec/jnz
    assert far == 4  # 3 pairs + dec/jnz, no stall


def test_fxch_pairs_with_fp(write_kernel):
    # AF28.2 / AF-FXCH: FXCH after an FX-class instruction pairs and takes no clock
    pre = "    fldz\n    fldz"
    with_fxch = loop_kernel(write_kernel, "    fadd st(0), st(0)\n    fxch st(1)", pre=pre, name="fx")
    # FADD + FXCH: one clock as a pair; dec/jnz: one clock. Each FADD chain alternates between two
    # registers, so a FADD's input is 2 iterations = 4 clocks old, beyond the latency of 3
    assert with_fxch == 2
    alone = loop_kernel(write_kernel, "    fadd st(0), st(0)\n    nop\n    fxch st(1)\n    nop", pre=pre, name="fx2")
    # FADD alone (x87 pairs only with FXCH), NOP alone (FXCH pairs only after an FX instruction),
    # FXCH alone, NOP + DEC, JNZ alone
    assert alone == 5


def test_fdiv_overlaps_integer_code(write_kernel):
    # AF28.2: FDIV 39 clocks, 38 of them overlap later integer instructions: a loop with one FDIV
    # and 20 pairs of integer work costs max(39 x87 clocks, integer clocks), not their sum
    pre = "    fld1\n    fld1"
    ints = "\n".join("    add eax, 1\n    add ebx, 1" for _ in range(20))
    c = loop_kernel(write_kernel, "    fdiv st(0), st(1)\n" + ints, pre=pre, name="fdiv", n=50)
    assert 39 <= c < 39 + 21


def test_prefix_costs_a_clock_on_p54c(write_kernel):
    # VTUNE Prefix_Pen: a prefixed instruction takes one additional clock on the Pentium; the P55C
    # with its instruction FIFO full pays nothing and pairs 66h-prefixed instructions in V
    global CPU
    body = "    add ax, 1\n    add bx, 1"
    p54 = loop_kernel(write_kernel, body, name="p54")
    CPU = "pentium-mmx-166"
    p55 = loop_kernel(write_kernel, body, name="p55")
    # P54C: 1 prefix clock + ADD AX alone (ADD BX is prefixed: not in V); 1 prefix clock + ADD BX with
    # DEC in V; JNZ alone
    assert p54 == 5
    assert p55 == 2  # P55C: ADD AX + ADD BX pair, DEC + JNZ pair


def test_misaligned_access(write_kernel):
    # AF-ALIGN: a misaligned dword access costs 3 clocks
    aligned = loop_kernel(write_kernel, "    mov eax, [esi+4]\n    nop", name="al")
    mis = loop_kernel(write_kernel, "    mov eax, [esi+2]\n    nop", name="mis")
    assert mis - aligned == 3


def test_write_miss_burst_fills_the_write_buffers(write_kernel):
    # policies.toml [p5.l1d]: no allocation on a write miss, so stores to lines never read go to the
    # write buffers (2 on the P54C); a burst of 4 such stores per iteration is bus bound: each costs
    # the bus write (82439TX single write 3 bus clocks = 6 core clocks at 2x)
    body = "\n".join(f"    mov [edi+{64 * k}], eax\n    nop" for k in range(4)) + "\n    add edi, 4"
    c = loop_kernel(write_kernel, body, n=100, name="wb")
    assert c >= 4 * 6
    hits = loop_kernel(write_kernel, "\n".join(f"    mov eax, [edi+{64 * k}]\n    mov [edi+{64 * k}], eax"
                                           for k in range(4)) + "\n    add edi, 4", n=100, name="hit")
    assert hits < c / 2  # the same stores to lines that were read (cached) do not touch the bus


def test_p54c_refuses_mmx(write_kernel):
    from sim.errors import RetrosimError

    src = write_kernel("# @entry m()\n.globl m\nm:\n    .byte 0x0f, 0xef, 0xc0\n    .byte 0x0f, 0x77\n    ret\n", "m.S")
    with pytest.raises(RetrosimError, match="MMX"):
        time_kernel(src, "m", cpu="pentium-133", repeat=1)
    assert time_kernel(src, "m", cpu="pentium-mmx-233", repeat=1).last["instructions"] == 3


def test_rdtsc_is_answered_by_the_model(write_kernel):
    src = write_kernel("""# @entry r()
.globl r
r:
    push ebx
    rdtsc
    mov ebx, eax
    mov ecx, 100
    jmp 1f
.p2align 4, 0xCC
1:
    dec ecx
    jnz 1b
    rdtsc
    sub eax, ebx
    pop ebx
    ret
""", "r.S")
    res = time_kernel(src, "r", cpu="pentium-133", repeat=2)
    assert res.run.rdtsc.size == 4
    delta = int(res.run.rdtsc[3] - res.run.rdtsc[2])
    assert 100 <= delta <= 100 + 30  # dec/jnz pairs: 1 clock per iteration, plus RDTSC and the mov


def test_cli_explain_shows_pipes_and_why_an_instruction_ran_alone(write_kernel):
    from click.testing import CliRunner

    from sim.cli import main

    src = write_kernel("""# @entry e(n)
.globl e
e:
    mov ecx, [esp+4]
    jmp 1f
.p2align 4, 0xCC
1:
    add eax, 1
    add edx, eax
    dec ecx
    jnz 1b
    ret
""", "e.S")
    r = CliRunner().invoke(main, ["explain", str(src), "--cpu", "pentium-133", "--args", "50", "--json"])
    assert r.exit_code == 0, r.output
    import json

    rows = {row["instruction"]: row for row in json.loads(r.output)["instructions"]}
    assert "RAW" in rows["add eax, 1"]["alone_because"] and "eax" in rows["add eax, 1"]["alone_because"]
    jnz = next(row for name, row in rows.items() if name.startswith("jne"))
    # ADD EAX alone (RAW), ADD EDX + DEC pair, so JNZ reaches the U pipe, where a branch cannot take a
    # partner (INTEL-PAIR: branches pair only as the second instruction): it runs alone
    assert rows["dec ecx"]["v_pipe"] == 50
    assert jnz["u_pipe"] == 50 and "V-pipe-only" in jnz["alone_because"]
    r = CliRunner().invoke(main, ["cpus"])
    assert all(name in r.output for name in ("pentium-90", "pentium-133", "pentium-166", "pentium-mmx-166",
                                             "pentium-mmx-233", "fpm-430fx", "edo-430hx", "sdram-430tx"))


def test_bank_conflict_on_the_p54c_only(write_kernel):
    # VTUNE Bank_Conflict: two paired accesses 32 bytes apart hit the same 4-byte bank: one clock
    global CPU
    same = loop_kernel(write_kernel, "    mov eax, [esi]\n    mov ebx, [esi+32]", name="bank")
    other = loop_kernel(write_kernel, "    mov eax, [esi]\n    mov ebx, [esi+4]", name="nobank")
    assert other == 2  # pair + dec/jnz
    assert same == other + 1
    CPU = "pentium-mmx-233"
    assert loop_kernel(write_kernel, "    mov eax, [esi]\n    mov ebx, [esi+32]", name="bank55") == 2


def test_esp_agi_exceptions(write_kernel):
    # AF9: PUSH/POP/CALL change ESP without an AGI for the next stack instruction (POP EAX / POP ESI
    # pair, no stall); ADD ESP then POP is an AGI
    pops = loop_kernel(write_kernel, "    push eax\n    push ebx\n    pop eax\n    pop ebx", name="pops")
    agi = loop_kernel(write_kernel, "    push eax\n    push eax\n    add esp, 4\n    nop\n    pop eax\n    nop", name="espagi")
    assert pops == 3  # push/push pair, pop/pop pair, dec/jnz
    assert agi == 5   # push/push, add+nop, AGI, pop+nop, dec/jnz


def test_mispredicted_branch_in_v_costs_4_clocks_on_the_p54c(write_kernel):
    # UW-CSEP548 / p5_machine.toml: a correctly predicted branch costs nothing, a mispredicted one 3
    # (U) or 4 (V) clocks. JZ pairs with AND in V. Taken: 3 clocks per iteration, not taken: 4; a
    # branch alternating between the two is mispredicted on every not-taken turn by 2-bit counters.
    def body(op):
        return f"    mov eax, ecx\n    nop\n    {op}\n    jz 2f\n    nop\n2:"

    taken = loop_kernel(write_kernel, body("and eax, 0"), name="taken")
    never = loop_kernel(write_kernel, body("or eax, 1"), name="never")
    alternating = loop_kernel(write_kernel, body("and eax, 1"), name="alt")
    assert (taken, never) == (3, 4)
    assert alternating == (taken + never) / 2 + 4 / 2


# ICG (docs/sources/p5.md), the Pentium's REP string timings: (clocks with ECX = 0, start-up, clocks per
# element), n elements costing start-up + n x per element ("REP MOVS 6, 13+n", "REP STOS 6, 9+3n", ...)
REP_COSTS = {"rep movsd": (6, 13, 1), "rep stosd": (6, 9, 3), "rep lodsd": (7, 7, 3), "repe cmpsd": (7, 9, 4),
             "repe scasd": (7, 9, 4), "repne cmpsd": (7, 8, 4), "repne scasd": (7, 9, 4)}


def rep_kernel(write_kernel, op: str, dst_offset: int = 512, cpu: str = "pentium-133"):
    """cycles(n) of one call running `op` over n dwords of a zeroed, L1-resident buffer: every call
    first reads the whole buffer (the P5 allocates lines on reads only), so no element misses.
    REPE runs on equal zeros; REPNE SCASD looks for EAX = 1, REPNE CMPSD compares zeros with ones."""
    import numpy as np

    src = write_kernel(f"""# @entry r(p, n)
.globl r
r:
    push esi
    push edi
    mov esi, [esp+12]
    xor edx, edx
1:
    mov eax, [esi+edx]
    add edx, 32
    cmp edx, 2048
    jne 1b
    mov ecx, [esp+16]
    lea edi, [esi+{dst_offset}]
    mov eax, {1 if op == "repne scasd" else 0}
    cld
    {op}
    pop edi
    pop esi
    ret
""", f"rep{dst_offset}.S")
    buf = np.zeros(2048, np.uint8)
    if op == "repne cmpsd":
        buf[dst_offset:dst_offset + 1024] = 1
    return lambda n: time_kernel(src, "r", lambda m: [m.arena.put(buf, align=4096), n], cpu=cpu,
                                 repeat=2).last["cycles"]


@pytest.mark.parametrize("op", sorted(REP_COSTS))
@pytest.mark.parametrize("cpu", ["pentium-133", "pentium-mmx-233"])
@pytest.mark.table_check
def test_rep_string_cost_is_start_up_plus_n_elements(write_kernel, op, cpu):
    # the same kernel with ECX = 0, 1, 2, 10, 100: everything but the REP instruction is the same, so the
    # differences are the source's figures (the trace holds one execution per element)
    zero, startup, per = REP_COSTS[op]
    cycles = rep_kernel(write_kernel, op, cpu=cpu)
    c = {n: cycles(n) for n in (0, 1, 2, 10, 100)}
    assert c[1] - c[0] == startup + per - zero
    assert [c[n] - c[1] for n in (2, 10, 100)] == [(n - 1) * per for n in (2, 10, 100)]


def test_rep_movs_bank_conflict_costs_a_clock_per_element_on_the_p54c(write_kernel):
    # AF 26.3: REP MOVS reads the next element while it writes this one; when ESI + 4 - EDI is a
    # multiple of 32 the two hit one bank (bits 2-4) and each element takes a clock more (P54C)
    apart = rep_kernel(write_kernel, "rep movsd", dst_offset=512)
    clash = rep_kernel(write_kernel, "rep movsd", dst_offset=36)
    per = REP_COSTS["rep movsd"][2]
    assert apart(50) - apart(10) == 40 * per
    assert clash(50) - clash(10) == 40 * (per + 1)


def test_rep_string_elements_that_miss_wait_for_memory(write_kernel):
    # each element's accesses go through the memory model: REP STOSD to lines not in L1 (the P5 does
    # not allocate on a write miss) takes write buffers and the bus, so it costs more than the
    # source's per-element clocks once the two write buffers are full
    import numpy as np

    src = write_kernel("# @entry f(p, n)\n.globl f\nf:\n    push edi\n    mov edi, [esp+8]\n    mov ecx, [esp+12]\n"
                   "    xor eax, eax\n    cld\n    rep stosd\n    pop edi\n    ret\n", "fill.S")

    def run(n):
        return time_kernel(src, "f", lambda m: [m.arena.put(np.zeros(4096, np.uint8), align=4096), n],
                           cpu="pentium-133", repeat=2).last

    small, big = run(10), run(110)
    assert big["bus_writes"] - small["bus_writes"] == 100
    assert big["cycles"] - small["cycles"] > 100 * REP_COSTS["rep stosd"][2]
    assert big["stall_write_buffer"] > small["stall_write_buffer"]


def test_fadd_issues_every_clock_fmul_every_other(write_kernel):
    # AF28.2: FADD 3 clocks of which 2 overlap later x87 instructions (one FADD per clock);
    # FMUL cannot start in the clock after another FMUL (note n; GCC pentium.md: FMUL's first two
    # cycles are not pipelined). Three independent operations per iteration, plus DEC/JNZ.
    pre = "    fld1\n    fld1\n    fld1\n    fld1"
    fadd = loop_kernel(write_kernel, "    fadd st(1), st\n    fadd st(2), st\n    fadd st(3), st", pre=pre, name="fadd")
    fmul = loop_kernel(write_kernel, "    fmul st(1), st\n    fmul st(2), st\n    fmul st(3), st", pre=pre, name="fmul")
    assert fadd == 3 + 1
    assert fmul == 2 * 3  # the DEC/JNZ pair fits in the gap after the last FMUL


@pytest.mark.parametrize("cpu", ("pentium-133", "pentium-mmx-233"))
def test_a_pair_touching_one_dword_is_imperfect(write_kernel, cpu):
    # AF97-PAIR sec. 10.2 (PPlain and PMMX): the two instructions of a pair cannot access the same
    # DWORD at the same time: MOV AL,[ESI] / MOV BL,[ESI+1] takes 2 clocks, MOV AL,[ESI+3] /
    # MOV BL,[ESI+4] (either side of a dword boundary) 1; the rule names no direction, so two byte
    # stores into one dword too (the line is loaded first: the P5 does not allocate on a write miss)
    global CPU
    CPU = cpu
    assert loop_kernel(write_kernel, "    mov al, [esi]\n    mov bl, [esi+1]", name="same") == 2 + 1
    assert loop_kernel(write_kernel, "    mov al, [esi+3]\n    mov bl, [esi+4]", name="across") == 1 + 1
    pre = "    mov edx, [esi]"
    assert loop_kernel(write_kernel, "    mov [esi], al\n    mov [esi+1], bl", pre=pre, name="wsame") == 2 + 1
    assert loop_kernel(write_kernel, "    mov [esi+3], al\n    mov [esi+4], bl", pre=pre, name="wacross") == 1 + 1


@pytest.mark.parametrize("body, clocks", [
    ("    add [esi], eax\n    add [esi+8], ebx", 5),   # read/modify/write, read/modify/write (sec. 11)
    ("    add [esi], eax\n    add ebx, [esi+8]", 4),   # read/modify/write, read/modify
    ("    add ebx, [esi+8]\n    add [esi], eax", 3),   # read/modify, read/modify/write: no extra clock
    ("    add [esi], eax\n    mov ebx, [esi+8]", 3),   # read/modify/write, MOV: no extra clock
    ("    add ebx, [esi+8]\n    add edx, [esi+16]", 2),  # read/modify, read/modify: no extra clock
])
def test_read_modify_write_pairs_take_agners_table(write_kernel, body, clocks):
    # AF97-PAIR sec. 10.4: a read/modify/write instruction paired with a read/modify or
    # read/modify/write one is an imperfect pair; the pair's clocks by the kinds of the first and
    # second instruction (accesses in different dwords and banks here); plus the DEC/JNZ pair
    assert loop_kernel(write_kernel, body, name="rmw") == clocks + 1


def test_fst_to_memory_needs_its_value_a_clock_early(write_kernel):
    # AF97-FP sec. 15: FST(P) m takes 2 clocks but needs its operand one clock before, so right after
    # the FLD that loads it (1 clock) it stalls a clock, which an instruction in between hides; an FSTP
    # to a register is not a store and does not wait (AF28.2: FLD and FSTP st(i) 1 clock each)
    direct = loop_kernel(write_kernel, "    fld dword ptr [esi]\n    fstp dword ptr [esi+8]", name="fstm")
    hidden = loop_kernel(write_kernel, "    fld dword ptr [esi]\n    nop\n    fstp dword ptr [esi+8]", name="fstnop")
    register = loop_kernel(write_kernel, "    fld dword ptr [esi]\n    fstp st(1)", pre="    fldz", name="fstr")
    assert direct == 1 + 1 + 2 + 1
    assert hidden == direct
    assert register == 1 + 1 + 1
