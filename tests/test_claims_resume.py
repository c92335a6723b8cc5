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


def test_a_machine_of_another_shape_or_cache_geometry_is_not_resumed(emulation):
    timed, logs = nominal(emulation, "pentium2-233", "edo")
    start = timed.last_call_start
    bigger_queue = make_model("pentium2-233", "edo", {"estimates.uop_queue": 12})
    smaller_l2 = make_model("pentium2-233", "edo", {"l2.size_kb": 128})
    assert resume_last_call(emulation, bigger_queue, start, logs) is None
    assert resume_last_call(emulation, smaller_l2, start, None) is None
    # another DRAM page geometry is resumed, with its pages closed at the call's start
    other_pages = make_model("pentium2-233", "edo", {"pages.page_bytes": 4096})
    assert resume_last_call(emulation, other_pages, start, None) is not None
    k6 = {p.key: p for p in claims.parameters("k6-2-300")}
    assert k6["estimates.bht_history_bits"].structural and k6["estimates.store_queue"].structural
    assert not k6["estimates.mispredict_restart"].structural and not k6["memory.overhead_bus_clocks"].structural


def test_an_emulation_whose_first_call_is_short_is_re_timed_whole(emulation):
    """The sort scene's runs copy the keys, then sort them: the copy is short, and its writes may
    still be queued for the bus when the sort starts, so its re-timings run whole."""
    from sim.scenes.registry import load_scene
    from sim.scenes.sort.runner import emulate_case

    run = emulate_case(load_scene("scenes/sort.toml"), "merge-sbb", "uniform", 1024)
    assert not claims.resumes(run)
    assert claims.resumes(emulation)  # three frames: two before the last
