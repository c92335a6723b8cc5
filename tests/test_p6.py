"""P6 model micro-benchmarks with known answers. Each expectation names its source; a test fails
if the model stops charging what the sources say."""

import math

import numpy as np
import pytest

from sim.cpus import presets

from sim.cpus.build import make_model
from sim.timing.kernel import time_kernel

from conftest import KERNELS, RDTSC_KERNEL

PIPE = KERNELS / "micro" / "pipeline.S"
N = 400


def per_iteration(entry, *, n=N, cpu="pentium2-233", buf_words=64, extra=()):
    def setup(m):
        args = [n]
        if buf_words:
            args.append(m.arena.put(np.arange(buf_words, dtype=np.uint32)))
        return args + list(extra)

    r = time_kernel(PIPE, entry, setup, cpu=cpu, repeat=2)
    return r.last["cycles"] / n, r


@pytest.mark.table_check
def test_dependency_chain_runs_at_imul_latency():
    # IMUL r32,r32 latency 4 (sim/cpus/p6/p6.toml: Agner Fog sec. 29; InstLatX64 PII)
    cycles, r = per_iteration("imul_chain", buf_words=0)
    assert 8 * 4 - 0.5 <= cycles <= 8 * 4 + 1
    assert r.last["stall_dependency"] > 0


def test_independent_adds_run_at_two_per_cycle():
    # two ALU ports (p0, p1): 12 ADDs + DEC + JNZ (p1) per iteration = 14 ALU uops -> 7 cycles
    cycles, r = per_iteration("add_streams", buf_words=0)
    assert 7 <= cycles <= 7.2
    assert abs(r.last["port0"] - r.last["port1"]) <= N + 20


def test_run_of_two_uop_instructions_decodes_one_per_cycle():
    # 4-1-1: a 2-uop instruction only goes to decoder 0 (Pentium II Developer's Manual fig. 2-8)
    run, r1 = per_iteration("two_uop_run")
    inter, r2 = per_iteration("two_uop_interleaved")
    # 12 ADDs, one decode group each (DEC and JNZ join the last ADD's group in decoders 1 and 2:
    # IFETCH blocks start at an instruction boundary), plus the 1-cycle taken-branch bubble
    assert 12.9 <= run <= 13.2
    assert r1.last["decoder1"] + r1.last["decoder2"] <= 2 * N + 10  # only DEC/JNZ pair up
    assert inter <= 0.55 * run           # interleaving 1-uop instructions restores throughput
    # decoders 1 and 2 are busy (less than 4 per iteration where a group meets a 16-byte block end)
    assert r2.last["decoder1"] >= 4 * N and r2.last["decoder2"] >= 2.5 * N


@pytest.mark.parametrize("entry,per_iteration,expected,source", [
    ("loop_run", 1, 8, "AF29 LOOP short '2 1 8', the 8 read as reciprocal throughput"),
    ("emms_stream", 8, 5.67, "InstLat-PII EMMS T 5.67"),
    ("fmul_stream", 8, 2.0, "InstLat-PII FMUL T 2.00; GCC fmul issue latency 2"),
    ("div_stream", 4, 37, "AF29 DIV r32 throughput 1/37; GCC ppro_idiv issue latency 37"),
])
@pytest.mark.table_check
def test_measured_throughput_is_honoured(entry, per_iteration, expected, source):
    # independent instances run at the row's reciprocal throughput even where the ports would
    # allow more (kernels/micro/throughput.S; sim/cpus/lowering.py, "Throughput"). CMP r32,r32's
    # measured T 1.00 / 0.67 is the register read stall since issue 36 (tests/test_register_read_stall.py)
    n = N * 8 if entry == "loop_run" else N
    r = time_kernel(KERNELS / "micro" / "throughput.S", entry, lambda m: [n], cpu="pentium2-233", repeat=2)
    got = r.last["cycles"] / (n * per_iteration)
    assert expected - 0.1 <= got <= expected * 1.03 + 0.1, f"{entry}: {got:.2f}, {source} says {expected}"


def test_partial_register_stall_costs_about_five_cycles():
    # MOV AL,[m] then reading EAX waits for the partial write to retire: +5 measured on PPro/PII
    # (p6_machine.toml [partial_register_stall], InstLatX64 dependency chains)
    stalled, r = per_iteration("partial_stall")
    clean, _ = per_iteration("partial_avoided")
    assert 4.5 <= stalled - clean <= 5.5
    assert r.last["stall_partial_register"] >= 4 * N


def test_store_forwarding_failure_costs_more_than_success():
    # same address and size forwards (~5 cycle round trip, measured); a larger load after a smaller
    # store waits for the store to reach L1 (Intel optimization manual, 'large and small load stalls')
    ok, r_ok = per_iteration("forward_ok")
    fail, r_fail = per_iteration("forward_fail")
    assert 4.5 <= ok <= 5.5
    assert fail >= ok + 3
    assert r_ok.last["store_forwards"] >= N and r_fail.last["store_forwards"] == 0
    assert r_fail.last["stall_store_forward"] > 0


def chase_setup(bytes_, seed=5):
    line = 32
    lines = bytes_ // line

    def setup(m):
        base = m.arena.alloc(bytes_, align=4096)
        order = np.random.default_rng(seed).permutation(lines)
        nxt = np.empty(lines, np.uint32)
        nxt[order] = base + line * np.roll(order, -1)  # a single random cycle through every line
        words = np.zeros(bytes_ // 4, np.uint32)
        words[::line // 4] = nxt
        m.uc.mem_write(base, words.tobytes())
        return [bytes_ // line // 8, base + line * int(order[0])]

    return setup


@pytest.mark.parametrize("cpu", ["pentium2-233", "celeron-300a"])
def test_l1_miss_l2_hit_costs_the_l2_latency(cpu):
    p = presets.load(cpu)
    size = 4 * p.l1d.size_bytes  # misses L1, fits L2
    r = time_kernel(KERNELS / "micro" / "memory.S", "chase", chase_setup(size), cpu=cpu, repeat=2)
    loads = r.last["l1d_loads"]
    assert r.last["l1d_load_misses"] >= 0.95 * loads and r.last["l2_misses"] == 0
    per_load = r.last["cycles"] / loads
    assert p.l2.latency_cycles - 0.5 <= per_load <= p.l2.latency_cycles + 1


def test_l2_miss_sends_the_bus_request_after_the_tag_check():
    # p6_machine.toml [caches.l2_miss_path] (Intel patent US 5,345,576): the tag RAM's miss signal
    # starts the front-side bus request, so an L2 miss costs less than the L2's data latency plus the
    # memory lead-off: L1 + the tag check (backside clocks / the L2's speed) + the lead-off.
    cpu = "pentium2-233"
    p, model = presets.load(cpu), make_model(cpu)
    size = 4 * p.l2.size_bytes
    r = time_kernel(KERNELS / "micro" / "memory.S", "chase", chase_setup(size), cpu=cpu, repeat=1)
    loads = r.last["l1d_loads"]
    assert r.last["l2_misses"] >= 0.9 * loads
    per_load = r.last["cycles"] / loads
    detect = math.ceil(model.estimates["l2_miss_detect_bsb_clocks"] / p.l2.speed_ratio)
    expected = p.l1d.latency_cycles + detect + model.dram.lead_off
    assert expected - 0.5 <= per_load <= expected + 2
    assert per_load < p.l2.latency_cycles + model.dram.lead_off - 10
    # a slower tag answer delays every miss by the difference
    slow = time_kernel(KERNELS / "micro" / "memory.S", "chase", chase_setup(size), repeat=1,
                       cpu=make_model(cpu, overrides={"estimates.l2_miss_detect_bsb_clocks": 4}))
    assert 3 <= slow.last["cycles"] / loads - per_load <= 5
    # SDRAM's shorter lead-off makes the same chase faster than EDO
    fast = time_kernel(KERNELS / "micro" / "memory.S", "chase", chase_setup(size), cpu=cpu, memory="sdram-pc100",
                       repeat=1)
    assert fast.last["cycles"] < r.last["cycles"]


def test_no_l2_celeron_goes_straight_to_dram():
    size = 64 * 1024
    slow = time_kernel(KERNELS / "micro" / "memory.S", "chase", chase_setup(size), cpu="celeron-266", repeat=2)
    fast = time_kernel(KERNELS / "micro" / "memory.S", "chase", chase_setup(size), cpu="celeron-300a", repeat=2)
    assert slow.last["l2_accesses"] == 0 and slow.last["dram_fills"] > 0
    assert slow.last["cycles"] > 2 * fast.last["cycles"]


def test_deterministic():
    a = per_iteration("two_uop_interleaved")[1]
    b = per_iteration("two_uop_interleaved")[1]
    assert a.calls == b.calls
    np.testing.assert_array_equal(a.run.per_static, b.run.per_static)


def test_every_timing_row_names_a_source():
    from sim.cpus.table import load_table

    for family in ("p6", "k6"):
        table = load_table(family)
        for row in table.rows.values():
            assert row.source.strip(), f"{family}: {row.key} has no source"


ROW = """[[insn]]
mnemonic = "add"
signature = "r32,r32"
uops = 1
ports = ["p01"]
latency = 1
source = "AF29"
"""


@pytest.mark.parametrize("extra,message", [
    ("latency_by_precision = { single = 18 }\n", "unknown field 'latency_by_precision'"),
    ("units = [\"int-xy\"]\n", "unknown field 'units'"),  # a K6 field in a P6 table
])
def test_table_loader_refuses_fields_no_model_reads(tmp_path, extra, message):
    from sim.cpus.table import InstructionTable
    from sim.errors import RetrosimError

    path = tmp_path / "p6.toml"
    path.write_text(ROW + extra)
    with pytest.raises(RetrosimError, match=message) as e:
        InstructionTable(path)
    assert "p6.toml" in str(e.value) and "row 1 (add r32,r32)" in str(e.value)
    path.write_text(ROW)
    assert InstructionTable(path).lookup("add", "r32,r32").row.latency == 1


def test_too_many_register_operands_is_an_error_naming_the_instruction(monkeypatch):
    # the cores track MAX_OPS sources and destinations per instruction; more is refused, not truncated
    from sim.cpus import lowering
    from sim.cpus.p6.lowering import P6Limits, uops_rule
    from sim.cpus.table import load_table
    from sim.guest.decode import decode_one

    rec = decode_one(bytes.fromhex("01c8"), 0x400000)  # add eax, ecx: 2 sources + flags
    assert lowering.lower([rec], load_table("p6"), uops_for=uops_rule(P6Limits())).s_nsrc[0] == 2
    monkeypatch.setattr(lowering, "MAX_OPS", 1)
    with pytest.raises(lowering.LoweringError, match=r"pc 0x00400000 \(add eax, ecx\)"):
        lowering.lower([rec], load_table("p6"), uops_for=uops_rule(P6Limits()))


def test_rdtsc_returns_simulated_cycles(write_kernel):
    src = write_kernel(RDTSC_KERNEL, "tsc.S")
    r = time_kernel(src, "timed", lambda m: [200], cpu="pentium2-233", repeat=1)
    measured = r.run.rdtsc[1] - r.run.rdtsc[0]
    # 200 IMULs at latency 4, plus the loop-exit mispredict, the RDTSC microcode and, from a cold
    # machine, a code line fetched from memory (~70-95 clocks with the calibrated DRAM latency),
    # behind the cold stack page's data-TLB walk: the PUSH commits after the first RDTSC and its
    # walk reads the directory and table entries from memory first (two more fills, ~2 x 95)
    assert 4 * 200 <= measured <= 4 * 200 + 120 + 2 * 95
    # the kernel itself computed the same difference from the values RDTSC returned in the replay
    from sim.guest.emu import Machine

    answers = iter(int(c) for c in r.run.rdtsc)
    assert Machine.from_source(src, rdtsc=lambda ev: next(answers)).call("timed", 200).eax == measured


def _loop_kernel(write_kernel, body: str, setup: str = ""):
    """A kernel `k(n)` running `body` n times (with DEC/JNZ)."""
    return write_kernel(".globl k\n.p2align 4\nk:\n    push ebx\n    push esi\n    push edi\n"
                        f"    mov ecx, [esp+16]\n{setup}\n    jmp 1f\n.p2align 4\n1:\n{body}\n    dec ecx\n    jnz 1b\n"
                        "    pop edi\n    pop esi\n    pop ebx\n    ret\n")


def _cycles_per_iteration(src, n=200, cpu="pentium2-233"):
    return time_kernel(src, "k", lambda m: [n], cpu=cpu, repeat=2).last["cycles"] / n


def test_six_byte_instructions_decode_two_per_cycle(write_kernel):
    # 16-byte IFETCH blocks start at an instruction boundary (Agner Fog, PPro/PII/PIII instruction
    # fetch): two 6-byte ADD r32,imm32 per block, one block per cycle. InstLat-PII ADD r32,imm32
    # T 0.50. With blocks aligned to 16 bytes a 6-byte instruction straddles every third boundary.
    body = "\n".join(f"    add {r}, 0x12345" for r in ("eax", "ebx", "edx", "esi", "edi", "eax") * 4)
    per_add = _cycles_per_iteration(_loop_kernel(write_kernel, body)) / 24
    assert 0.5 <= per_add <= 0.55


def test_fxch_is_renamed_and_does_not_wait_for_its_operands(write_kernel):
    # FXCH is done in the register renamer (AF29n note f): two FSQRT chains alternated with FXCH
    # overlap, so each FSQRT costs its throughput (68, InstLat-PII FSQRT80 T 68.08), not its
    # latency (69), and not latency + 1 for an FXCH waiting for the root
    setup = "    fld1\n    fld1"
    alternating = _cycles_per_iteration(_loop_kernel(write_kernel, "    fsqrt\n    fxch st(1)\n" * 4, setup), n=50) / 4
    assert 67.5 <= alternating <= 68.5
    chained = _cycles_per_iteration(_loop_kernel(write_kernel, "    fsqrt\n" * 4, setup), n=50) / 4
    assert 68.5 <= chained <= 69.5


def test_pushad_popad_are_split_into_their_stores_and_loads(write_kernel):
    # AF29: PUSHA(D) = 2 p01 + 8 store-address + 8 store-data uops, POPA(D) = 2 p01 + 8 loads
    r = time_kernel(_loop_kernel(write_kernel, "    pushad\n    popad"), "k", lambda m: [100], cpu="pentium2-233", repeat=2)
    c = r.last
    assert c["port2"] >= 8 * 100 and c["port3"] >= 8 * 100 and c["port4"] >= 8 * 100
    assert 28 * 100 <= c["uops"] - 2 * 100 <= 28 * 100 + 30  # DEC, JNZ: 1 uop each; the call's own few


# -- partial flags stalls (Agner Fog, PPro/PII/PIII "partial flags stalls") ----------------------------
def _flag_stalls(tmp_path, body: str) -> int:
    from sim.timing.kernel import time_kernel

    src = tmp_path / "flags.S"
    src.write_text(".intel_syntax noprefix\n.text\n.globl k\nk:\n    push edi\n    mov edi, esp\n    sub edi, 64\n"
                   "    cld\n" + body * 8 + "    pop edi\n    ret\n")
    return time_kernel(src, "k", cpu="pentium2-233", repeat=2).last["stall_partial_flags"]


def test_reading_only_df_after_a_full_status_write_does_not_stall(tmp_path):
    # NEG writes all six status flags: Agner lists NEG followed by PUSHF(D) (which reads DF too) as no stall
    assert _flag_stalls(tmp_path, "    neg eax\n    stosd\n    sub edi, 4\n") == 0


def test_reading_unmodified_flags_after_a_partial_write_stalls(tmp_path):
    # Agner: CMP / INC / JC stalls (JC reads CF, which INC leaves); CLD / SETZ stalls as well
    assert _flag_stalls(tmp_path, "    cmp eax, ebx\n    inc ecx\n    setc al\n") > 0
    assert _flag_stalls(tmp_path, "    cmp eax, ebx\n    cld\n    setz al\n") > 0
