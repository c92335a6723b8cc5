"""P6 port binding: a uop that may use port 0 or port 1 is bound to one of them when it enters the
reservation station, to the port with fewer uops bound and not yet dispatched, and then waits for
that port (Intel patent US 5,689,674, abstract; sim/cpus/p6/p6_machine.toml [port_binding];
docs/sources/p6.md "Port choice for p01 uops"). Ties go to estimates.p01_tie_port (no source).

Every expected figure below is derived by hand from that rule and from sourced machine facts: IMUL
r32,r32 one port-0 uop of latency 4 (p6.toml: AF29, InstLat-PII), ADD r32,imm one p01 uop of
latency 1, a 20-entry RS and a 40-entry ROB (p6_machine.toml). The old rule (a p01 uop takes the
lowest-numbered port free in the cycle it becomes ready) gives other figures, named in each test."""

from __future__ import annotations

import pytest

from sim.timing import loop


def timed(body: str, cpu: str = "pentium2-233", iterations: int = 100) -> dict[str, float]:
    return loop.time_body(body, [cpu], iterations=iterations)[0].per_iteration


IMUL_THEN_ADD = "imul ecx, ecx\nadd eax, ecx\n"


def test_an_add_bound_to_port_1_lets_the_multiply_chain_run_at_its_latency():
    # IMUL ECX,ECX is a chain of latency 4 (port 0); each ADD reads the IMUL's result, so the ADD
    # and the next IMUL become ready in the same cycle, the ADD the older. Allocation runs ahead
    # until the RS is full, so when an ADD is allocated the uops waiting in the RS are the IMULs
    # of the iterations not yet dispatched and the ADDs of the same iterations plus the one whose
    # IMUL has just left: as many ADDs as IMULs. Port 0's count is (waiting IMULs) + (ADDs bound
    # to port 0), port 1's the ADDs bound to port 1: they differ by twice the ADDs on port 0, so
    # with every earlier ADD on port 1 the counts tie. With ties to port 1, every ADD is bound to
    # port 1: the ADD and the next IMUL dispatch together, 4 clocks per iteration, one uop per port.
    # (The old rule gave 5: the ready ADD took port 0, the lowest free, and the IMUL waited a clock.)
    t = timed(IMUL_THEN_ADD, "pentium2-233{estimates.p01_tie_port=1}")
    assert t["cycles"] == pytest.approx(4.0, abs=0.02)
    assert t["port0"] == pytest.approx(1.0, abs=0.02)
    assert t["port1"] == pytest.approx(1.0, abs=0.02)


def test_a_tie_to_port_0_costs_a_clock_once_per_reservation_station_window():
    # The same loop with ties to port 0 (the estimate's default): an ADD allocated when no waiting
    # ADD is on port 0 (counts tie) is bound to port 0; it is ready in the same cycle as the next
    # IMUL and, being older, takes port 0: that IMUL waits a clock. The ADDs allocated after it see
    # it in port 0's count and go to port 1, until it dispatches, about ten iterations later (the
    # 20-entry RS holds the IMUL and ADD of about ten iterations). One clock lost per ten
    # iterations: about 4.1 clocks per iteration, and 1.1 uops on port 0.
    # (The old rule gave 5.0, with both uops on port 0.)
    t = timed(IMUL_THEN_ADD)
    assert t["cycles"] == pytest.approx(4.1, abs=0.025)
    assert t["port0"] == pytest.approx(1.1, abs=0.025)
    assert t["port1"] == pytest.approx(0.9, abs=0.025)


@pytest.mark.parametrize("cpu", ["pentium2-233", "pentium2-233{estimates.p01_tie_port=1}"])
def test_adds_beside_a_waiting_multiply_chain_are_all_bound_to_port_1(cpu):
    # Three independent ADDs beside the IMUL chain: the ADDs run as soon as they are allocated,
    # the IMULs wait (4 clocks each), so the ROB fills with ten iterations (40 entries, 4 uops
    # each) and about ten IMULs wait in the RS when an ADD is allocated, against at most the two
    # ADDs allocated just before it: port 0's count is always the larger (no tie), every ADD is
    # bound to port 1. Port 1: 3 uops per iteration, port 0: the IMUL; 4 clocks (the chain).
    # (The old rule put the ADDs on port 0 whenever it was free: 3 on port 0, 1 on port 1.)
    t = timed("imul ecx, ecx\nadd eax, 1\nadd ebx, 1\nadd edx, 1\n", cpu)
    assert t["cycles"] == pytest.approx(4.0, abs=0.02)
    assert t["port0"] == pytest.approx(1.0, abs=0.02)
    assert t["port1"] == pytest.approx(3.0, abs=0.02)


def test_independent_adds_are_spread_evenly():
    # Four independent ADD chains (latency 1) and nothing else: the two ports are the limit,
    # 2 clocks per iteration; binding to the port with fewer waiting uops keeps the counts equal,
    # two ADDs per port per iteration.
    t = timed("add eax, 1\nadd ebx, 1\nadd edx, 1\nadd ebp, 1\n")
    assert t["cycles"] == pytest.approx(2.0, abs=0.02)
    assert t["port0"] == pytest.approx(2.0, abs=0.05)
    assert t["port1"] == pytest.approx(2.0, abs=0.05)
