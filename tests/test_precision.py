"""x87 precision control: the trace knows the control word at every instruction, and FDIV/FSQRT
take the time of the precision in force on every family (P5, P6, K6)."""

import numpy as np
import pytest

from sim.cpus import presets
from sim.cpus.table import InstructionTable
from sim.guest.emu import Machine
from sim.errors import RetrosimError
from sim.timing.kernel import emulate, time_emulation
from sim.guest.trace import Trace, precision_of

from conftest import KERNELS

KERNEL = KERNELS / "micro" / "x87_precision.S"
CW = {24: 0x007F, 53: 0x027F, 64: 0x037F}
ALL = presets.available()
FAMILY = {name: presets.load(name).family for name in ALL}

# Published divide figures (cycles) by precision 24 / 53 / 64 bits, with the reciprocal throughput
# where a family's dependent chain is bound by it:
# P5: AF28.2 note p, FDIV 19 / 33 / 39 (latency = issue, no overlap between dependent divides);
# P6: AF29n note h and InstLatX64 Pentium II, FDIV latency 18 / 32 / 38 (throughput 17 / 31 / 37);
# K6: InstLatX64 K6, K6-2, K6-III, FDIV32/64/80 st(i),st latency 20 / 34 / 40, reciprocal
#     throughput 21 / 35 / 41 (the unit is not pipelined: a dependent chain runs at the throughput).
CHAIN_STEP = {"p5": (19, 33, 39), "p6": (18, 32, 38), "k6": (21, 35, 41)}


def _trace_words(kernel_call):
    m = Machine.from_source(KERNEL)
    native = kernel_call(m, True)
    m.reset_fpu()
    python = kernel_call(m, "python")
    return native, python


def test_control_word_known_at_every_instruction_native_equals_python():
    """The native trace reads FPCW only after the instructions that write it; the Python trace reads
    it before every instruction. Both give the same word at every instruction."""
    def call(m, how):
        cws = m.arena.put(np.array([CW[24], CW[53], CW[64]], np.uint16))
        return m.call("cw_cycle", cws, 7, trace=how).trace

    native, python = _trace_words(call)
    assert np.array_equal(native.pc, python.pc)
    every = np.arange(native.instructions)
    assert np.array_equal(native.control_word_at(every), python.control_word_at(every))
    # the FNINIT word on entry, the caller's word restored before RET
    assert native.control_word_at([0])[0] == CW[64] and native.control_word_at([every[-1]])[0] == CW[64]
    assert set(native.cw_value.tolist()) == set(CW.values())


def test_back_to_back_writers_and_fninit_are_followed(tmp_path):
    src = tmp_path / "w.S"
    src.write_text(""".intel_syntax noprefix
.text
# @entry writers(words) -> EAX = 0
.globl writers
writers:
    mov eax, [esp+4]
    fldcw [eax]
    fldcw [eax+2]
    fninit
    fldcw [eax]
    sub esp, 108
    fnsave [esp]
    fldcw [eax+2]
    frstor [esp]
    add esp, 108
    fninit
    xor eax, eax
    ret
""")
    m = Machine.from_source(src)
    words = m.arena.put(np.array([CW[24], CW[53]], np.uint16))
    t = m.call("writers", words, trace=True).trace
    got = t.control_word_at(np.arange(t.instructions)).tolist()
    #      mov   fldcw  fldcw  fninit fldcw  sub    fnsave fldcw  frstor add    fninit xor    ret
    want = [CW[64], CW[64], CW[24], CW[53], CW[64], CW[24], CW[24], CW[64], CW[53], CW[24], CW[24], CW[64], CW[64]]
    assert got == want


def test_trace_survives_refills_and_save_load(tmp_path):
    m = Machine.from_source(KERNEL)
    m._tracer = None
    from sim.guest.trace import NativeTracer

    m._tracer = NativeTracer(m.uc, instruction_capacity=64, access_capacity=64, control_word_pcs=m.control_word_pcs(),
                             control_word_capacity=4)  # forces many chunk refills and control-word stops
    cws = m.arena.put(np.array([CW[24], CW[53], CW[64]], np.uint16))
    t = m.call("cw_cycle", cws, 50, trace=True).trace
    m.reset_fpu()
    m._tracer = None
    ref = m.call("cw_cycle", cws, 50, trace=True).trace
    every = np.arange(ref.instructions)
    assert np.array_equal(t.pc, ref.pc)
    assert np.array_equal(t.control_word_at(every), ref.control_word_at(every))
    t.save(tmp_path / "t.npz")
    back = Trace.load(tmp_path / "t.npz")
    assert np.array_equal(back.control_word_at(every), ref.control_word_at(every))
    # a trace saved before control words existed reads as the FNINIT state
    np.savez(tmp_path / "old.npz", pc=t.pc, mem_addr=t.mem_addr, mem_size=t.mem_size, mem_write=t.mem_write,
             mem_insn=t.mem_insn)
    old = Trace.load(tmp_path / "old.npz")
    assert set(old.control_word_at(every).tolist()) == {CW[64]}
    # the head of a trace keeps the words of its instructions
    assert np.array_equal(t.head(40).control_word_at(np.arange(40)), ref.control_word_at(np.arange(40)))


def test_precision_field_decoding():
    assert precision_of([0x007F, 0x027F, 0x037F, 0x017F, 0x0C7F]).tolist() == [0, 1, 2, 2, 0]


def _chain(bits: int, n: int):
    return emulate(KERNEL, "fdiv_chain", lambda m: [CW[bits], n], repeat=2)


@pytest.fixture(scope="module")
def chains():
    return {(bits, n): _chain(bits, n) for bits in (24, 53, 64) for n in (32, 64)}


@pytest.mark.parametrize("cpu", ALL)
@pytest.mark.table_check
def test_24_bit_divides_are_faster_on_every_preset(chains, cpu):
    """Chains of 4 * 32 and 4 * 64 dependent divides at each precision: the difference between
    the two lengths is 128 divides in steady state, and each takes the sources' figure for the
    precision in force, on every preset of every family."""
    cycles = {key: time_emulation(emu, cpu).last["cycles"] for key, emu in chains.items()}
    per_divide = tuple((cycles[bits, 64] - cycles[bits, 32]) / 128 for bits in (24, 53, 64))
    assert per_divide[0] < per_divide[1] < per_divide[2]
    assert per_divide == CHAIN_STEP[FAMILY[cpu]]


@pytest.mark.parametrize("cpu", ["pentium-133", "pentium2-233", "k6-2-300"])
def test_precision_changed_mid_run_times_each_divide_at_its_own_precision(cpu):
    """One static FDIV runs at 24, 53 and 64 bits in turn (FLDCW from an array each iteration):
    the model times it as three statics, each with its precision's figures and its own count."""
    n = 30
    emu = emulate(KERNEL, "cw_cycle", lambda m: [m.arena.put(np.array([CW[24], CW[53], CW[64]], np.uint16)), n],
                  repeat=1)
    result = time_emulation(emu, cpu)
    program, counts = result.run.program, {}
    for s, (rec, match) in enumerate(zip(program.records, program.matches)):
        if rec.mnemonic == "fdiv":
            counts[match.precision] = counts.get(match.precision, 0) + int(result.run.per_static[s][0])
            figure = match.row.extra["cycles"] if FAMILY[cpu] == "p5" else match.row.latency
            assert figure == {"p5": (19, 33, 39), "p6": (18, 32, 38), "k6": (20, 34, 40)}[FAMILY[cpu]][match.precision]
            assert match.describe().endswith(("@24-bit", "@53-bit", "@64-bit"))
    assert counts == {0: n // 3, 1: n // 3, 2: n // 3}


@pytest.mark.table_check
def test_k6_fsqrt_throughput_by_model_and_precision():
    """IL-K6/IL-K62: FSQRT T 23/38/43; IL-K63 (K6-III): T = L = 21/36/41."""
    from sim.cpus.k6.model import K6Rules
    from sim.cpus.record import machine_table
    from sim.cpus.table import load_table

    row = load_table("k6").lookup("fsqrt", "").row
    for key, want in (("k6-2", (23, 38, 43)), ("k6-3", (21, 36, 41))):
        rules = K6Rules(key, machine_table("k6"))
        assert tuple(rules.field(row.at_precision(p), "throughput") for p in range(3)) == want
        assert tuple(rules.field(row.at_precision(p), "latency") for p in range(3)) == (21, 36, 41)


@pytest.mark.parametrize("fields,message", [
    ("precision_latency = [18, 32]\n", "must list three numbers"),
    ("precision_latency = [18, 32, 37]\n", "differs from latency = 38"),
    ("precision_latency = [18, 32, 38]\nprecision_speed = [1, 2, 3]\n", "unknown field 'precision_speed'"),
])
def test_table_loader_checks_precision_fields(tmp_path, fields, message):
    path = tmp_path / "p6.toml"
    path.write_text('[[insn]]\nmnemonic = "fdiv"\nsignature = "st,st"\nuops = 1\nports = ["p0"]\nlatency = 38\n'
                    f'throughput = 37\n{fields}source = "test"\n')
    with pytest.raises(RetrosimError, match=message):
        InstructionTable(path, "p6")


@pytest.mark.table_check
def test_fsqrt_follows_precision_where_the_sources_say_so():
    """P6 (InstLatX64 Pentium II) and K6 (InstLatX64) FSQRT depend on precision; the P5's does not
    (AF28.2 gives 70 clocks, one figure)."""
    from sim.cpus.table import load_table

    assert load_table("p6").lookup("fsqrt", "").row.at_precision(0).latency == 29
    assert load_table("k6").lookup("fsqrt", "").row.at_precision(0).latency == 21
    assert not load_table("p5").lookup("fsqrt", "").row.precision_dependent
