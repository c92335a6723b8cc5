"""The claims' re-timings of the last call alone (sim.timing.kernel.resume_last_call): exact when
nothing changes, close to re-timing the whole emulation when a timing estimate changes, refused
when the machine differs in more than its timing."""

import pytest

from sim.cpus.build import make_model
from sim.memory.replay import AccessLogs
from sim.scenes import claims, raster
from sim.scenes.zbuffer.frames import draw_frames
from sim.scenes.geometry import GeometrySpec
from sim.timing.kernel import resume_last_call, time_emulation

MACHINES = [("pentium2-233", "edo"), ("k6-2-300", None), ("pentium-mmx-233", None)]


@pytest.fixture(scope="module")
def emulation():
    """Three frames of a Z-buffer scene (fp16z: BSR, SHRD, table reads, stores) whose buffers (300 KB)
    outgrow every modelled L2, so each call fills from DRAM."""
    geometry = GeometrySpec(generator="random", seed=5, triangles=24, depth_complexity=1.0).build(320, 240)
    spans = raster.rasterize(geometry, 320, 240)
    return draw_frames(spans, "fp16z", 320, 240, frames=3, colours=geometry.colour).emulation


def nominal(emulation, cpu, memory):
    logs = AccessLogs(keep=2)
    timed = time_emulation(emulation, make_model(cpu, memory), access_logs=logs, resumable=True)
    return timed, logs


@pytest.mark.parametrize("cpu, memory", MACHINES)
def test_the_last_call_resumed_on_the_same_machine_is_timed_exactly_as_in_the_whole_run(emulation, cpu, memory):
    timed, logs = nominal(emulation, cpu, memory)
    whole = time_emulation(emulation, make_model(cpu, memory))
    assert timed.calls == whole.calls  # fed in two parts, timed the same
    for access_logs in (logs, None):  # replaying the recorded cache results, and walking the caches
        resumed = resume_last_call(emulation, make_model(cpu, memory), timed.last_call_start, access_logs)
        assert resumed == whole.last


@pytest.mark.parametrize("cpu, memory", MACHINES)
def test_a_timing_estimate_re_timed_from_the_last_call_stays_close_to_the_whole_re_timing(emulation, cpu, memory):
    timed, logs = nominal(emulation, cpu, memory)
    resumed = claims.perturbed_timings(emulation, cpu, memory, timed.last, logs=logs, start=timed.last_call_start)
    whole = claims.perturbed_timings(emulation, cpu, memory, timed.last)
    assert resumed.keys() == whole.keys()
    moved = 0
    for p in claims.parameters(cpu, memory):
        for value in (p.low, p.high):
            a, b = resumed[(p.key, value)]["cycles"], whole[(p.key, value)]["cycles"]
            if p.structural:  # re-timed over the whole emulation either way
                assert resumed[(p.key, value)] == whole[(p.key, value)], p.key
            else:  # only what is in flight at the call boundary differs
                assert abs(a - b) <= max(64, b // 1000), (p.key, value, a, b)
            moved += b != timed.last["cycles"]
    assert moved >= 3  # the estimates do move this workload's cycles


def test_a_machine_of_other_caches_is_not_resumed_and_other_queues_and_pages_are(emulation):
    timed, logs = nominal(emulation, "pentium2-233", "edo")
    start = timed.last_call_start
    assert resume_last_call(emulation, make_model("pentium2-233", "edo", {"l2.size_kb": 128}), start, None) is None
    # another DRAM page geometry (its pages closed at the call's start), another uop queue size
    for change in ({"pages.page_bytes": 4096}, {"estimates.uop_queue": 12}, {"estimates.uop_queue": 4}):
        assert resume_last_call(emulation, make_model("pentium2-233", "edo", change), start, None) is not None
    k6 = {p.key: p for p in claims.parameters("k6-2-300")}
    assert k6["estimates.bht_history_bits"].structural
    assert not any(k6[key].structural for key in ("estimates.store_queue", "estimates.mispredict_restart",
                                                  "memory.overhead_bus_clocks"))


def test_a_resized_queue_keeps_the_cycles_of_the_entries_both_sizes_hold():
    from sim.cpus.session import resized_ring
    import numpy as np

    # events 0..9 with cycles 10, 20, ..., 100 in a ring of 4: slot count % 4 holds the oldest (event 6)
    count, ring = 10, np.zeros(4, np.int64)
    for e in range(count):
        ring[e % 4] = 10 * (e + 1)
    smaller, pos = resized_ring(ring, count % 4, count, 3)
    assert pos == 1 and [smaller[(pos + k) % 3] for k in range(3)] == [80, 90, 100]  # oldest first
    bigger, pos = resized_ring(ring, count % 4, count, 6)
    assert pos == 4 and [bigger[(pos + k) % 6] for k in range(6)] == [70, 70, 70, 80, 90, 100]
    ring = np.array([10, 20, 0, 0])  # two events so far: the other slots are not read yet
    few, pos = resized_ring(ring, 2, 2, 6)
    assert pos == 2 and list(few[:2]) == [10, 20]


def test_an_emulation_whose_first_call_is_short_is_re_timed_whole(emulation):
    """The sort scene's runs copy the keys, then sort them: the copy is short, and its writes may
    still be queued for the bus when the sort starts, so its re-timings run whole."""
    from sim.scenes.registry import load_scene
    from sim.scenes.sort.runner import emulate_case

    run = emulate_case(load_scene("scenes/sort.toml"), "merge-sbb", "uniform", 1024)
    assert not claims.resumes(run)
    assert claims.resumes(emulation)  # three frames: two before the last
