"""The P6 core's rooms (sim.cpus.p6.core rooms) and what they prove (P6Model.repeats): a model
whose parameters differ from the nominal's only where the nominal run kept room for the change
times the trace exactly as the nominal run did, so the claims' robustness pass may reuse the
nominal counters instead of re-timing (sim.scenes.claims.perturbed_timings)."""

import numpy as np
import pytest

import sim.cpus.p6.core as core
from sim.cpus.build import make_model
from sim.guest.kernels import kernels_root
from sim.scenes import claims
from sim.timing.bench import SPAN_KERNEL, span_workload
from sim.timing.kernel import emulate, time_emulation

CPU = "pentium2-233"
TRACKED = {"estimates.forward_latency": core.P_FWD_LAT, "estimates.static_redirect": core.P_STATIC_REDIRECT}

# a store, then a load of it that the next store's data waits for: the forwarding latency is on
# the loop's critical path, so it has no room
FORWARD_CHAIN = """.intel_syntax noprefix
.text
.globl k
k:
    mov ecx, [esp+4]
    xor eax, eax
    sub esp, 4
1:  mov [esp], eax
    mov eax, [esp]
    add eax, 1
    dec ecx
    jnz 1b
    add esp, 4
    ret
"""


def _span(pixels=2048):
    zinit, (z, dz, colour) = span_workload(pixels)
    setup = lambda m: [m.arena.put(zinit), m.arena.put(np.zeros(pixels, np.uint16)), pixels, z, dz, colour]
    return emulate(kernels_root() / SPAN_KERNEL, "fp16z_span", setup, repeat=2, budget=0)


def _chain(tmp_path, n=400):
    path = tmp_path / "k.S"
    path.write_text(FORWARD_CHAIN)
    return emulate(path, "k", lambda m: [n], repeat=2)


def _timed(emu, overrides=None, **kw):
    return time_emulation(emu, make_model(CPU, None, overrides), resumable=True, **kw)


def _ends():
    return [(p.key, value) for p in claims.parameters(CPU) if p.key in TRACKED for value in (p.low, p.high)
            if value != p.nominal]


@pytest.mark.parametrize("warm_start", [False, True])
def test_a_change_within_its_room_times_the_trace_as_the_nominal_run(warm_start):
    emu = _span()
    nominal = _timed(emu, rooms=True, warm_start=warm_start)
    assert set(nominal.run.rooms) == set(TRACKED.values())
    repeated = 0
    for key, value in _ends():
        other = make_model(CPU, None, {key: value})
        if nominal.model.repeats(nominal.run, other):
            repeated += 1
            assert _timed(emu, {key: value}, warm_start=warm_start).calls == nominal.calls, (key, value)
    assert repeated > 0  # the span loop forwards no store: any forwarding latency times it the same


def test_a_forward_on_the_critical_path_has_no_room_and_its_latency_moves_the_run(tmp_path):
    emu = _chain(tmp_path)
    nominal = _timed(emu, rooms=True)
    down, up = nominal.run.rooms[core.P_FWD_LAT]
    assert up < 0 and down < 0
    assert nominal.last["store_forwards"] > 0
    for value in (3, 5):
        other = make_model(CPU, None, {"estimates.forward_latency": value})
        assert not nominal.model.repeats(nominal.run, other)
        assert _timed(emu, {"estimates.forward_latency": value}).last["cycles"] != nominal.last["cycles"]


def test_rooms_are_kept_only_when_asked_and_nothing_is_proved_without_them(tmp_path):
    emu = _chain(tmp_path)
    plain = _timed(emu)
    assert plain.run.rooms is None
    forward = make_model(CPU, None, {"estimates.forward_latency": 5})
    assert not plain.model.repeats(plain.run, forward)
    assert plain.model.repeats(plain.run, make_model(CPU))  # the same machine: no room needed
    kept = _timed(emu, rooms=True)
    assert kept.calls == plain.calls  # keeping rooms (the core's other version) changes no count


def test_a_model_differing_beyond_the_rooms_is_never_taken_for_a_repeat():
    emu = _span()
    nominal = _timed(emu, rooms=True)
    for key in ("estimates.mispredict_restart", "estimates.l2_bus_full_speed", "pages.page_bytes"):
        p = next(p for p in claims.parameters(CPU) if p.key == key)
        other = make_model(CPU, None, {key: p.high if p.high != p.nominal else p.low})
        assert not nominal.model.repeats(nominal.run, other), key
    assert not nominal.model.repeats(nominal.run, make_model("celeron-300a"))


def test_the_robustness_pass_gives_the_same_counters_with_and_without_the_rooms():
    emu = _span()
    timed = _timed(emu, rooms=True, warm_start=True)
    args = (emu, CPU, None, timed.last)
    kw = dict(start=timed.last_call_start, warm_start=True)
    assert claims.perturbed_timings(*args, timed=timed, **kw) == claims.perturbed_timings(*args, **kw)


@pytest.mark.parametrize("cpu, key", [("k6-233", "estimates.mispredict_restart"),
                                      ("pentium-mmx-233", "estimates.tlb_walk_clocks")])
def test_a_family_without_rooms_repeats_only_the_same_machine(cpu, key):
    from sim.guest.decode import Decoder
    from sim.guest.trace import Trace

    model = make_model(cpu)
    run = model.run(Trace.empty(), Decoder(lambda address, n: b""), [0])
    assert run.rooms is None
    assert model.repeats(run, make_model(cpu))
    p = next(p for p in claims.parameters(cpu) if p.key == key)
    assert not model.repeats(run, make_model(cpu, None, {key: p.high}))
    assert not model.repeats(run, make_model(cpu, "sdram-pc100"))
