"""Two runs of the same job compared, family-neutral: the cycle ratio, which one wins, and the
counters that differ (the biggest first). The scene claims (sim/scenes/claims.py, the sort report)
explain a verdict with it, and `retrosim loop A.s B.s` names what differs per CPU."""

from __future__ import annotations

import math
from typing import Iterable, Mapping


def differences(a: Mapping[str, float], b: Mapping[str, float], counters: Iterable[str],
                at_least: float = 0.005, digits: int = 3) -> dict[str, float]:
    """{counter: a - b} of `counters` present in both runs whose figures differ by `at_least` or
    more, rounded to `digits`, in the order of `counters`."""
    return {n: round(a[n] - b[n], digits) for n in counters if n in a and n in b and abs(a[n] - b[n]) >= at_least}


def largest(diffs: Mapping[str, float], n: int) -> list[tuple[str, float]]:
    """The `n` differences of largest size, biggest first (ties by name, so the order is stable)."""
    return sorted(diffs.items(), key=lambda kv: (-abs(kv[1]), kv[0]))[:n]


def ratio(a: float, b: float) -> float:
    """a / b, infinite when b is 0 (a run with no cycles)."""
    return a / b if b else math.inf


def faster(a: float, b: float) -> str:
    """Which of two cycle counts wins: "A", "B" or "same"."""
    return "same" if a == b else "A" if a < b else "B"


def loop_pair(timings_a, timings_b, n: int = 4) -> list[dict]:
    """`retrosim loop A.s B.s` on each CPU both were timed on (sim.timing.loop.LoopTiming lists):
    each one's cycles per iteration, the ratio A/B, which is faster and the `n` counters that differ
    most per iteration (A minus B), named in the family's words."""
    from sim.cpus import families

    by_cpu = {t.cpu: t for t in timings_b}
    out = []
    for ta in timings_a:
        tb = by_cpu.get(ta.cpu)
        if tb is None:
            continue
        words = families.view(ta.result.model.family).counter_words(ta.per_iteration)
        ca, cb = ta.cycles_per_iteration, tb.cycles_per_iteration
        diffs = largest(differences(ta.per_iteration, tb.per_iteration, words), n)
        out.append({"cpu": ta.cpu, "cycles_per_iteration": [ca, cb], "ratio": round(ratio(ca, cb), 4) if cb else None,
                    "faster": faster(ca, cb),
                    "differences": [{"counter": k, "words": words[k], "a_minus_b": d} for k, d in diffs]})
    return out
