"""A scene's last frame timed from a warm start (sim.timing.kernel time_emulation's `warm_start`):
the frames before it only warm what the machine learns in program order, and the last one starts
from an empty pipeline. A family that walks the warm-up without timing it (CoreSession.warm_chunk)
leaves exactly what timing it and draining leaves; the claims' re-timings resume from a warm start
exactly (but for another DRAM page geometry, whose pages start closed)."""

import numpy as np
import pytest

from sim.cpus.build import make_model
from sim.memory.hierarchy import OPEN_PAGE_BASE, STACK_BASE, TLB_CLOCK, TLB_STAMPS, CFG_TLB_SETS, CFG_TLB_WAYS
from sim.memory.replay import AccessLogs
from sim.guest.kernels import kernels_root
from sim.scenes import claims, raster
from sim.scenes.geometry import GeometrySpec
from sim.scenes.zbuffer.frames import draw_frames
from sim.timing.kernel import emulate, resume_last_call, time_emulation

WALKED = ["pentium2-233", "celeron-266", "k6-2-300", "k6-3-450"]  # families with a warm-up walk (P6, K6)


@pytest.fixture(scope="module")
def large():
    """Two frames of fp16z on a scene whose buffers (300 KB) outgrow every modelled L2."""
    geometry = GeometrySpec(generator="random", seed=5, triangles=24, depth_complexity=1.0).build(320, 240)
    spans = raster.rasterize(geometry, 320, 240)
    return draw_frames(spans, "fp16z", 320, 240, frames=2, colours=geometry.colour).emulation


@pytest.fixture(scope="module")
def frames():
    """Two frames of each Z-buffer variant of a small scene whose buffers outgrow the L1s."""
    geometry = GeometrySpec(generator="random", seed=5, triangles=12, depth_complexity=1.0).build(160, 120)
    spans = raster.rasterize(geometry, 160, 120)
    return {v: draw_frames(spans, v, 160, 120, frames=2, colours=geometry.colour).emulation
            for v in ("z32", "fp16z", "zf32")}


def rep_string(tmp_path, op):
    """Three calls of a REP string (ECX 300, 4-byte aligned, forward): microcode loops across calls."""
    src = tmp_path / "rep.S"
    src.write_text(f""".intel_syntax noprefix
.text
.globl k
k:
    push esi
    push edi
    mov esi, [esp + 12]
    lea edi, [esi + 4096]
    mov ecx, [esp + 16]
    cld
    {op}
    fld dword ptr [esi]
    fstp dword ptr [edi]
    pop edi
    pop esi
    ret
""")
    return emulate(src, "k", lambda m: [m.arena.put(np.arange(12288, dtype=np.uint8) % 7, align=4096), 300],
                   repeat=3, budget=100_000)


def learned(emulation, cpu, walk: bool):
    """(caches' contents, the core's state, the last call's counters) after the warm-up: walked
    (warm) or timed and drained."""
    model = make_model(cpu)
    session = model.session(emulation.decoder(), emulation.bounds, emulation.last_call)
    head, last = emulation.parts()
    if walk:
        session.warm(head, int(last.pc[0]))
    else:
        session.feed(head, int(last.pc[0]))
        session.drain()
    d, i = model.dside.contents(), model.iside.contents()
    state = [a.copy() for a in session.state]
    session.feed(last, -1)
    return d, i, state, session.finish().segment(len(emulation.bounds) - 1)


def tlb_order(work, config):
    """Each TLB set's ways from least to most recently used (service stamps a probe the P6's inline
    L1-hit path skips: the stamps' values differ, their order within a set does not)."""
    sets, ways = int(config[0, CFG_TLB_SETS]), int(config[0, CFG_TLB_WAYS])
    return [list(np.argsort(work[TLB_STAMPS + s * ways:TLB_STAMPS + (s + 1) * ways], kind="stable")) for s in range(sets)]


def assert_same_learned(a, b):
    (d1, i1, s1, c1), (d2, i2, s2, c2) = a, b
    for x, y in zip(d1[:3] + i1[:4], d2[:3] + i2[:4]):  # tags, stamps, dirty; the L1I whole
        np.testing.assert_array_equal(x, y)
    w1, w2 = d1[3], d2[3]
    np.testing.assert_array_equal(w1[:STACK_BASE], w2[:STACK_BASE])  # the LRU clock, the pages of the last fills
    np.testing.assert_array_equal(w1[OPEN_PAGE_BASE:TLB_CLOCK], w2[OPEN_PAGE_BASE:TLB_CLOCK])  # open DRAM rows
    np.testing.assert_array_equal(w1[TLB_CLOCK + 2:TLB_STAMPS], w2[TLB_CLOCK + 2:TLB_STAMPS])  # TLB pages
    assert tlb_order(w1, d1[4]) == tlb_order(w2, d2[4])
    for x, y in zip(s1, s2):
        np.testing.assert_array_equal(x, y)
    assert c1 == c2


@pytest.mark.parametrize("cpu", WALKED)
def test_a_walked_warm_up_leaves_what_a_timed_and_drained_one_leaves(frames, cpu):
    for emulation in frames.values():
        assert_same_learned(learned(emulation, cpu, walk=True), learned(emulation, cpu, walk=False))


@pytest.mark.parametrize("op", ["rep movsd", "rep stosd", "repe cmpsb", "rep lodsd"])
@pytest.mark.parametrize("cpu", ["pentium2-233", "k6-2-300"])
def test_a_walked_warm_up_of_rep_strings_and_x87_is_exact_too(tmp_path, cpu, op):
    emulation = rep_string(tmp_path, op)
    assert_same_learned(learned(emulation, cpu, walk=True), learned(emulation, cpu, walk=False))


@pytest.mark.parametrize("cpu", ["pentium2-233", "k6-2-300", "pentium-mmx-233"])
def test_drain_empties_the_pipeline_and_keeps_what_was_learned(frames, cpu):
    model = make_model(cpu)
    emulation = frames["fp16z"]
    session = model.session(emulation.decoder(), emulation.bounds, emulation.last_call)
    head, last = emulation.parts()
    session.feed(head, int(last.pc[0]))
    before = [a.copy() for a in session.state]
    session.drain()
    fresh = model.session(emulation.decoder(), emulation.bounds, emulation.last_call)
    fresh.indexed(head)  # the same statics: the same state shapes
    for k, (now, was, reset) in enumerate(zip(session.state, before, fresh.state)):
        if k == 0:
            continue
        np.testing.assert_array_equal(now, was if k in session.KEEP_ARRAYS else reset)
    for slot in range(session.state[0].size):
        assert session.state[0][slot] == (before[0][slot] if slot in session.KEEP_SLOTS else fresh.state[0][slot])
    # the predictors did learn the first frame
    assert any(not np.array_equal(before[k], fresh.state[k]) for k in session.KEEP_ARRAYS)


@pytest.mark.parametrize("cpu", ["pentium2-233", "k6-2-300", "pentium-mmx-233"])
def test_every_re_timing_from_a_warm_start_is_the_whole_re_timing(large, cpu):
    emulation = large
    logs = AccessLogs(keep=2)
    timed = time_emulation(emulation, make_model(cpu), access_logs=logs, resumable=True, warm_start=True)
    resumed = claims.perturbed_timings(emulation, cpu, None, timed.last, logs=logs, start=timed.last_call_start,
                                       warm_start=True)
    whole = claims.perturbed_timings(emulation, cpu, None, timed.last, warm_start=True)
    assert resumed.keys() == whole.keys()
    for (key, value), counters in whole.items():
        if key in claims.PAGE_GEOMETRY_KEYS:  # resumed with every DRAM page closed
            assert abs(resumed[(key, value)]["cycles"] - counters["cycles"]) <= 64, (key, value)
        else:
            assert resumed[(key, value)] == counters, (key, value)
    assert sum(c["cycles"] != timed.last["cycles"] for c in whole.values()) >= 3  # the estimates do move it


def test_a_warm_start_differs_from_the_timed_warm_up_by_what_was_in_flight_only(frames):
    """The last frame from an empty pipeline against the same frame after a timed one: the same
    misses and mispredicts; cycles within a few dozen (what was in flight at the boundary)."""
    for cpu in ("pentium2-233", "k6-2-300", "pentium-mmx-233"):
        emulation = frames["z32"]
        warm = time_emulation(emulation, make_model(cpu), warm_start=True).last
        timed = time_emulation(emulation, make_model(cpu)).last
        for name in ("mispredicts", "l1d_load_misses", "l1d_store_misses", "dram_fills", "instructions"):
            assert warm[name] == timed[name], (cpu, name)
        assert abs(warm["cycles"] - timed["cycles"]) <= 64, cpu


def test_a_kernel_reading_rdtsc_is_refused_a_warm_start(tmp_path):
    src = tmp_path / "t.S"
    src.write_text(".intel_syntax noprefix\n.text\n.globl k\nk:\n    rdtsc\n    ret\n")
    emulation = emulate(src, "k", lambda m: [], repeat=2, budget=1000)
    from sim.errors import RetrosimError
    with pytest.raises(RetrosimError, match="RDTSC"):
        time_emulation(emulation, make_model("pentium2-233"), warm_start=True)


def test_a_warm_start_with_a_timeline_is_refused(tmp_path):
    # the timeline would have to come from frames the warm start does not time
    src = tmp_path / "t.S"
    src.write_text(".intel_syntax noprefix\n.text\n.globl k\nk:\n    mov ecx, 50\n1:\n    dec ecx\n    jnz 1b\n    ret\n")
    emulation = emulate(src, "k", lambda m: [], repeat=2, budget=10000)
    with pytest.raises(ValueError, match="warm start has no timeline"):
        time_emulation(emulation, make_model("pentium2-233"), timeline_iterations=4, warm_start=True)
    assert time_emulation(emulation, make_model("pentium2-233"), timeline_iterations=4).last["cycles"] > 0
