"""Two runs of the same job compared, family-neutral: the cycle ratio, which one wins, and the
counters that differ (the biggest first). The scene claims (sim/scenes/claims.py, the sort report)
explain a verdict with it, and `retrosim loop A.s B.s` names what differs per CPU."""

from __future__ import annotations

import math
from typing import Iterable, Mapping

from sim.errors import ArgumentError


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


def loop_comparison(name_a: str, sections_a: list[dict], name_b: str, sections_b: list[dict]) -> list[dict]:
    """`retrosim loop A.s B.s` and the web app's second body: the sections of A and B paired (the
    one body each, or a whole output's regions in order when both have as many), each pair as
    {"a": its label, "b": its label, "per_cpu": :func:`loop_pair`}. Sections are the ones
    sim.cli.kernel_cmds.loop_document gives; regions that do not pair up are one ArgumentError."""
    if len(sections_a) != len(sections_b):
        count = lambda s: f"{len(s)} region{'s' if len(s) > 1 else ''}" if s[0]["region"] else "one body"  # noqa: E731
        raise ArgumentError(f"loop A.s B.s: {name_a} holds {count(sections_a)} and {name_b} {count(sections_b)}: they "
                            "do not pair up; cut each to one region (# LLVM-MCA-BEGIN name / # LLVM-MCA-END) or one "
                            "body")
    label = lambda s, name: f"{name} {s['region'].name}" if s["region"] is not None else name  # noqa: E731
    return [{"a": label(sa, name_a), "b": label(sb, name_b), "per_cpu": loop_pair(sa["timings"], sb["timings"])}
            for sa, sb in zip(sections_a, sections_b)]


AB_NOTE = ("differs most: the per-iteration counters of the two in the family's words, largest difference first; "
           "stall cycles overlap, so the stall that differs most need not be the one that costs the cycles")
