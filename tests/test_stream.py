"""A run timed in chunks (a streamed emulation, sim/timing/stream.py) reports exactly what the whole trace does."""

import numpy as np
import pytest

from sim.cpus.build import make_model
from sim.errors import GuestFault
from sim.guest.isa import IsaError
from sim.guest.kernels import kernels_root
from sim.timing.kernel import emulate, hot_loop_window, time_emulation, time_kernel

MICRO = kernels_root() / "micro"
ZBUF = kernels_root() / "zbuffer"
CWS = np.array([0x007F, 0x027F, 0x037F], np.uint16)  # 24-, 53- and 64-bit precision


def _span_setup(n=3000):
    rng = np.random.default_rng(7)
    zinit = rng.integers(0, 1 << 16, n).astype(np.uint16)

    def setup(m):
        return [m.arena.put(zinit), m.arena.put(np.zeros(n, np.uint16)), n, 0x28000000, 0x9000, 0x7BEF]
    return setup


def _chunked(model, emu, sizes, timeline=(0, 0)):
    """The emulation's trace fed to a session in parts of the given sizes (cycled)."""
    trace = emu.trace
    family_session = type(model.session(emu.decoder(), emu.bounds))  # the family's session class
    session = family_session(model, emu.decoder(), emu.bounds, timeline, emu.last_call)
    cuts, at, k = [0], 0, 0
    while at < trace.instructions:
        at = min(trace.instructions, at + sizes[k % len(sizes)])
        cuts.append(at)
        k += 1
    for a, b in zip(cuts, cuts[1:]):
        session.feed(trace.part(a, b), int(trace.pc[b]) if b < trace.instructions else -1)
    return session.finish()


def _same(a, b):
    assert np.array_equal(a.counters, b.counters)
    assert np.array_equal(a.per_static, b.per_static)
    assert np.array_equal(a.timeline, b.timeline)
    assert np.array_equal(a.rdtsc, b.rdtsc)
    assert a.total_cycles == b.total_cycles
    assert [(r.pc, r.mnemonic) for r in a.program.records] == [(r.pc, r.mnemonic) for r in b.program.records]
    assert np.array_equal(a.program.u_lat, b.program.u_lat)


@pytest.mark.parametrize("cpu", ["pentium2-233", "celeron-266", "pentium-mmx-233", "pentium-133", "k6-233", "k6-2-300",
                                 "k6-3-450"])
@pytest.mark.parametrize("sizes", [[1], [2], [7, 1000, 3], [4096]])
def test_a_trace_fed_in_chunks_times_as_the_whole_trace(cpu, sizes):
    emu = emulate(ZBUF / "fp16z.S", "fp16z_span", _span_setup(), repeat=2)
    model = make_model(cpu)
    tl = hot_loop_window(emu.trace.pc, emu.last_call, 8)
    whole = model.run(emu.trace, emu.decoder(), emu.bounds, tl, emu.last_call)
    assert whole.counters[-1, 0] > 0 and whole.timeline[:, 6].all()
    _same(_chunked(model, emu, sizes, tl), whole)


@pytest.mark.parametrize("cpu", ["pentium-mmx-233", "pentium-133"])
@pytest.mark.parametrize("sizes", [[1], [3], [5, 2]])
def test_p5_pairs_across_chunk_boundaries_as_in_the_whole_trace(cpu, sizes):
    # the P5 pairs an instruction with the next one (U and V pipes): cut between the two, the
    # pair must still form, REP string elements still follow their first, branches still resolve
    from sim.cpus.p5.core import C_PAIRS

    emu = emulate(ZBUF / "z16.S", "z16_span", _span_setup(), repeat=2)
    model = make_model(cpu)
    whole = model.run(emu.trace, emu.decoder(), emu.bounds, (0, emu.trace.instructions), emu.last_call)
    assert whole.counters[:, C_PAIRS].sum() > 0
    chunked = _chunked(model, emu, sizes, (0, emu.trace.instructions))
    _same(chunked, whole)
    assert chunked.static.arrays[1].tolist() == whole.static.arrays[1].tolist()  # pairing classes


@pytest.mark.parametrize("cpu", ["pentium-mmx-233", "pentium-133"])
@pytest.mark.parametrize("sizes", [[1], [2], [3, 1]])
def test_p5_rep_strings_and_x87_pairs_cut_anywhere_time_as_whole(tmp_path, cpu, sizes):
    # a REP MOVS element knows it is a later one by the PC before it, and the P54C's bank clash by
    # the previous element's store; FLD/FXCH pairs and a store miss's write buffers span the cuts
    src = tmp_path / "mix.S"
    src.write_text(".intel_syntax noprefix\n.text\n.globl k\nk:\n    push esi\n    push edi\n"
                   "    mov esi, [esp+12]\n    lea edi, [esi+36]\n    mov ecx, 40\n    cld\n    rep movsd\n"
                   "    mov esi, [esp+12]\n    mov edx, 6\n    fldz\n1:  fld dword ptr [esi]\n    fxch st(1)\n"
                   "    faddp st(1), st(0)\n    mov [esi+4096+8*edx], eax\n    add esi, 4\n"
                   "    dec edx\n    jnz 1b\n    fstp st(0)\n    pop edi\n    pop esi\n    ret\n")
    buf = np.zeros(16384, np.uint8)
    emu = emulate(src, "k", lambda m: [m.arena.put(buf, align=4096)], repeat=2)
    model = make_model(cpu)
    whole = model.run(emu.trace, emu.decoder(), emu.bounds, (0, emu.trace.instructions), emu.last_call)
    assert whole.segment()["pairs"] > 0 and whole.segment()["bus_writes"] > 0
    _same(_chunked(model, emu, sizes, (0, emu.trace.instructions)), whole)


@pytest.mark.parametrize("cpu", ["pentium2-233", "pentium-mmx-233", "pentium-133", "k6-233"])
@pytest.mark.parametrize("sizes", [[9], [1]])
def test_precision_variants_met_early_are_reported_in_whole_trace_order(cpu, sizes):
    # the first chunks run FDIV at 24, 53 and 64 bits before the loop's reset path and the epilogue
    # first appear: the chunked run numbers those statics differently until it finishes
    emu = emulate(MICRO / "x87_precision.S", "cw_cycle", lambda m: [m.arena.put(CWS), 12], repeat=1)
    model = make_model(cpu)
    tl = (0, emu.trace.instructions)
    whole = model.run(emu.trace, emu.decoder(), emu.bounds, tl, 0)
    assert len(whole.program.records) > len({r.pc for r in whole.program.records})  # variants exist
    chunked = _chunked(model, emu, sizes, tl)
    _same(chunked, whole)


@pytest.mark.parametrize("cpu", ["pentium2-233", "pentium-mmx-233", "k6-2-300"])
def test_time_kernel_streams_and_matches_the_classic_path(cpu):
    setup = _span_setup(20000)
    streamed = time_kernel(ZBUF / "fp16z.S", "fp16z_span", setup, cpu=cpu, repeat=3)
    assert streamed.trace is None  # the trace was never held whole
    emu = emulate(ZBUF / "fp16z.S", "fp16z_span", setup, repeat=3, isa_cpu=cpu)
    classic = time_emulation(emu, cpu)
    assert streamed.calls == classic.calls
    assert np.array_equal(streamed.run.per_static, classic.run.per_static)


def test_a_kernel_reading_rdtsc_is_timed_with_its_answers():
    from sim.studies import texture_loops as texture

    streamed = time_kernel(kernels_root() / texture.FDIV_KERNEL, "timesnap", None, cpu="pentium2-233", repeat=2)
    emu = emulate(kernels_root() / texture.FDIV_KERNEL, "timesnap", None, repeat=2, isa_cpu="pentium2-233")
    classic = time_emulation(emu, "pentium2-233")
    assert streamed.run.rdtsc.size > 0
    assert np.array_equal(streamed.run.rdtsc, classic.run.rdtsc) and streamed.calls == classic.calls


@pytest.mark.parametrize("cut", ["before the first", "every instruction", "mixed"])
def test_p5_rdtsc_answers_survive_any_cut(cut):
    # PUSH EDX; RDTSC: the PUSH, first run, waits for its successor's static (held back), and
    # the RDTSC after it is timed with it: later RDTSCs of that chunk still get their own answers
    from sim.studies import texture_loops as texture

    emu = emulate(kernels_root() / texture.FDIV_KERNEL, "timesnap", None, repeat=2)
    model = make_model("pentium-mmx-233")
    whole = model.run(emu.trace, emu.decoder(), emu.bounds, (0, 0), emu.last_call)
    assert whole.rdtsc.size == 4
    records, index = emu.decoder().decode_trace(emu.trace.pc)
    first = int(np.flatnonzero(np.isin(index, [s for s, r in enumerate(records) if r.mnemonic == "rdtsc"]))[0])
    sizes = {"before the first": [first, 1000], "every instruction": [1], "mixed": [3, 1]}[cut]
    _same(_chunked(model, emu, sizes), whole)


def test_a_fault_in_a_streamed_run_is_reported_and_leaves_no_thread(tmp_path):
    import threading

    src = tmp_path / "bad.S"
    src.write_text(".intel_syntax noprefix\n.text\n.globl k\nk:\n    mov ecx, 300000\n1:  dec ecx\n    jnz 1b\n"
                   "    mov eax, dword ptr [0x10]\n    ret\n")
    with pytest.raises(GuestFault, match="bad.S"):
        time_kernel(src, "k", None, cpu="pentium2-233", repeat=1)
    assert not [t for t in threading.enumerate() if t.name == "retrosim-model"]


def test_a_system_instruction_stops_a_streamed_run(tmp_path):
    src = tmp_path / "sys.S"
    src.write_text(".intel_syntax noprefix\n.text\n.globl k\nk:\n    mov ecx, 2500000\n1:  dec ecx\n    jnz 1b\n"
                   "    cli\n    ret\n")
    with pytest.raises(IsaError, match="cli"):
        time_kernel(src, "k", None, cpu="pentium2-233", repeat=1)
