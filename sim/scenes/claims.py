"""Claims checked as widely as they are stated, and how robust each verdict is to the model's estimates.

A scene's ``[[claims]]`` (:class:`Claim`) name the machines their words cover. :func:`evaluate`
checks each claim on every covered machine of the run (holds / does not hold, with the counters
that explain the difference) and lists the covered machines of the scene that the run left out.

Robustness. Some model parameters have no sourced figure: the estimates of the family models (each
family's machine table [estimates], read through sim/cpus/families.py, with its plausible range and
mechanism counter), the cache latencies a preset marks ``latency_estimated`` and the board's DRAM
overhead (``[memory] overhead_bus_clocks``, calibrated on one measured system or carried over from
another), each with a range here; and the page-mode figures a memory preset marks estimated
(``[pages] estimated``, with their ranges and reasons in ``[pages.ranges]``), as ``pages.FIELD``.
While a variant's emulation is alive the runner re-times the same trace (no re-emulation) with each
parameter set to either end of its range, one at a time (:func:`perturbed_timings`). No parameter but
the page geometry (``pages.open_pages``, ``pages.page_bytes``) changes what the data caches' walk
decides, so those re-timings read the caches' results back instead of walking them
(sim/memory/replay.py); the page geometry decides which fills are page hits, so a re-timing with
another geometry walks the caches itself (the geometry is part of the cache configuration a
replay log is keyed by, so it could not replay the nominal log anyway).

A re-timing times the last call only (the one the claims compare), from the machine state the
nominal timing left at its start (sim.timing.kernel.resume_last_call). The caches, TLB, DRAM pages
and branch predictors hold then what they would with any value of a timing parameter (each is
updated in program order, never by the clock); what differs is what is in flight at the call
boundary (queues, buses, port reservations).

- A Z-buffer scene's frames are timed from a warm start (`warm_start`: the frames before the last
  only warm the machine, and the last starts from an empty pipeline), so nothing is in flight and
  a re-timing that resumes times exactly what re-timing the whole emulation does
  (tests/test_warm_start.py), but for another DRAM page geometry: its re-timing starts the call
  with every page closed (which rows its warm-up would have left open is not known; the caches
  hold the same lines whatever the geometry), so at most one access per bank differs. Warming up
  again with the geometry instead made the article scene's P6 re-timings a quarter slower. An
  estimate that changes what the machine learns from call to call (``structural``: a predictor
  table's indexing) is re-timed over the whole emulation.
- Other emulations (the sort scene: a key copy, then the sort) are timed whole, and their
  re-timings resume only where the calls before the last are at least as long as it
  (:func:`resumes`): a short first call may leave much in flight (the key copy leaves its writes
  queued for the bus: resuming there moved ratios by up to 7e-4), so the sort scene is re-timed
  whole. Where one resumes, a page geometry's re-timing starts with every DRAM page closed too, and a
  queue of another size (a uop queue, a store queue) with the cycles of the nominal's last entries
  (sim.cpus.session.resized_ring); measured against re-timing the whole emulation, off by at most
  18 of 14.8 million cycles (tests/test_claims_resume.py bounds it on a smaller frame).

A parameter whose mechanism never fires in a variant (no
store forward, no MSROM uop, no DRAM fill, ...) cannot change its timing and is not re-run. A claim
whose verdict on a machine differs at either end of a range from the nominal verdict is reported as
"depends on <parameter>", never as reproduced. Only the ends are timed: between them the verdict is
assumed not to flip twice (the cycle ratio moves monotonically with each of these parameters).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from sim.cpus.machine import MachineKey
from sim.reports.compare import differences
from sim.memory import dram

# Estimated cache latencies (preset ``latency_estimated = true``): +-30 % of the estimate, the
# spread between the proxies they were derived from (full-speed 13 vs half-speed 23 on the P6).
CACHE_SPREAD = 0.30
# Board DRAM overhead: a figure carried over from another system (``overhead_estimated``) ranges from
# a fast 133 MHz P6 platform's ~9 bus clocks (MemLat-Coppermine: 86 - 13 = 73 clocks / 5.5) to the
# measured Covington's 18.5 + 1 (its page-miss overhead, calibrated on InstLatX64's linear 1 KB walk
# as it ran: issue 24, docs/sources/memory.md; 15.5 + 1 before); a figure calibrated on this CPU's
# own measurement +-2 bus clocks (about the 10 % calibration tolerance).
OVERHEAD_CARRIED = (9.0, 19.5)
OVERHEAD_MEASURED = 2.0

# A preset parameter's mechanism fires only when this counter is non-zero (a family estimate names
# its own: machine table [estimates.NAME] mechanism).
MECHANISM = {"memory.overhead_bus_clocks": "dram_fills", "l2.latency_cycles": "l1d_load_misses",
             "l3.latency_cycles": "l3_accesses", "pages.hit_saving_bus_clocks": "dram_page_hits",
             "pages.write_saving_bus_clocks": "dram_writebacks",
             # the geometry decides which fills are page hits: any DRAM fill may become one
             "pages.open_pages": "dram_fills", "pages.page_bytes": "dram_fills"}
PAGE_GEOMETRY_KEYS = tuple(f"pages.{f}" for f in dram.PAGE_GEOMETRY)


@dataclass(frozen=True)
class Param:
    key: str
    nominal: float
    low: float
    high: float
    why: str
    mechanism: str | None = None  # the counter that must be non-zero for it to matter (None: always)
    structural: bool = False  # it changes what the machine learns, not only when: re-timed whole (perturbed_timings)

    def describe(self) -> str:
        return f"{self.key} {_n(self.low)}..{_n(self.high)} (model {_n(self.nominal)})"


def _n(x: float) -> str:
    return f"{x:g}"


def parameters(cpu: str, memory: str | None = None) -> list[Param]:
    """The estimated parameters of a CPU preset on a memory preset (`memory`, or the CPU preset's
    default) and their plausible ranges."""
    from sim.cpus import families
    from sim.cpus.overrides import load_dram, load_preset, overridable

    preset = load_preset(cpu)
    values = overridable(cpu, memory)
    estimates = families.FAMILIES[preset.family].estimates.values() if preset.family in families.FAMILIES else ()
    out = [Param(e.key, values[e.key], e.low, e.high, e.range_reason, None if e.mechanism == families.ALWAYS else e.mechanism,
                 e.structural)
           for e in estimates if e.key in values and e.applies_to(preset)]  # applies_to: e.g. no on-die L2, never read
    for level, cache in (("l2", preset.l2), ("l3", preset.board_cache)):
        if cache is not None and cache.estimated and f"{level}.latency_cycles" in values:
            v = values[f"{level}.latency_cycles"]
            out.append(Param(f"{level}.latency_cycles", v, max(1, round(v * (1 - CACHE_SPREAD))),
                             round(v * (1 + CACHE_SPREAD)), f"estimated {level.upper()} latency +-30 %",
                             MECHANISM[f"{level}.latency_cycles"]))
    if "memory.overhead_bus_clocks" in values:
        v = float(values["memory.overhead_bus_clocks"])
        if preset.overhead_estimated:
            lo, hi, why = min(v, OVERHEAD_CARRIED[0]), max(v, OVERHEAD_CARRIED[1]), "board overhead carried over from another system"
        else:
            lo, hi, why = max(0.0, v - OVERHEAD_MEASURED), v + OVERHEAD_MEASURED, "board overhead calibrated on this CPU: +-2 bus clocks"
        if isinstance(values["memory.overhead_bus_clocks"], int):  # a whole-number field (the P5 presets'):
            lo, hi = math.floor(lo), math.ceil(hi)                   # its range's ends widened to whole clocks
        out.append(Param("memory.overhead_bus_clocks", v, lo, hi, why, MECHANISM["memory.overhead_bus_clocks"]))
    pages = load_dram(memory or preset.memory).pages
    # the savings first: the geometry's re-timings walk the caches (see perturbed_timings)
    for field in sorted(pages.ranges if pages else (), key=lambda f: f in dram.PAGE_GEOMETRY):
        low, high, why = pages.ranges[field]
        key = f"pages.{field}"
        out.append(Param(key, values[key], low, high, f"estimated page figure ({pages.chipset}): {why}", MECHANISM[key]))
    return out


def exercised(param: Param, counters: dict) -> bool:
    name = param.mechanism
    return name is None or counters.get(name, 1) != 0


def perturbed_timings(emulation, cpu: str, memory: str, nominal: dict, logs=None, start=None, what: str = "",
                      warm_start: bool = False, timed=None) -> dict:
    """{(param key, value): counters of the last call} with each parameter at each end of its range;
    parameters whose mechanism does not fire reuse the nominal counters (their timing cannot move),
    and so do those the nominal timing `timed` (a sim.timing.kernel TimingResult, if given) shows
    would time the same (its model's `repeats`: the same machine, or within the P6 core's rooms).
    `logs`: the sim.memory.replay.AccessLogs the nominal timing recorded into, if it did. `start`:
    the machine state the nominal timing left at the last call's start (sim.timing.kernel
    resume_last_call), if it kept it: a re-timing then times the last call only, where the
    machine allows. `warm_start`: the nominal timing was a warm start (sim.timing.kernel
    time_emulation), and so is a re-timing of the whole emulation. Each re-timing is reported as a
    machine run (sim.scenes.progress), named `what` and its number."""
    from sim.cpus.build import make_model
    from sim.memory.replay import AccessLogs
    from sim.parallel import report
    from sim.scenes.progress import machine_run
    from sim.timing.kernel import resume_last_call, time_emulation

    out = {}
    # no parameter here but the page geometry changes what the data caches' walk decides: one walk
    # of them serves every other run; a geometry re-timing walks them without a log (its own
    # recording would only evict the nominal one, which the log store keys by the geometry anyway)
    logs = AccessLogs(keep=2) if logs is None else logs
    ends = []  # (parameter, value, its model or None: not re-timed)
    for p in parameters(cpu, memory):
        for value in (p.low, p.high):
            model = make_model(cpu, memory, {p.key: value}) if value != p.nominal and exercised(p, nominal) else None
            if model is not None and timed is not None and timed.model.repeats(timed.run, model):
                model = None
            ends.append((p, value, model))
    runs = sum(model is not None for _, _, model in ends)
    # which re-timings run is known only now, from the nominal counters: the runs a progress display
    # counts grow by them
    report(more=runs)
    n = 0
    for p, value, model in ends:
        if model is None:
            out[(p.key, value)] = nominal
            continue
        n += 1
        replay = None if p.key in PAGE_GEOMETRY_KEYS else logs
        with machine_run(f"{what}: re-timing {n} of {runs}"):
            counters = None if p.structural or start is None else resume_last_call(emulation, model, start, replay)
            if counters is None:  # the whole emulation (structural, or a machine restore refuses)
                counters = time_emulation(emulation, model, access_logs=replay, resumable=start is not None,
                                          warm_start=warm_start).last  # fed as the nominal was: its logs replay
        out[(p.key, value)] = counters
    return out


def resumes(emulation) -> bool:
    """Whether the re-timings of `emulation` time its last call alone (perturbed_timings): where the
    calls before it are at least as long (a Z-buffer scene's first frame), which halves them. Where
    they are short (the sort scene's key copy), the whole emulation is re-timed: resuming would save
    little, and the state in flight after a short call can be far from drained (a copy's writes still
    queued for the bus)."""
    return 2 * emulation.last_call >= emulation.trace.instructions


def timed_with_robustness(emulation, model, key: str, robust: bool, what: str,
                          warm_start: bool = False) -> tuple[dict, dict | None]:
    """Counters of the last call of `emulation` on `model` (machine `key`), and the claims' robustness
    re-timings (:func:`perturbed_timings`) when `robust`: a pool's task of the kinds whose claims are
    re-timed (a pure function of its arguments: the same in any process); reported as `what`.
    `warm_start`: the calls before the last only warm the machine (sim.timing.kernel
    time_emulation); a re-timing then resumes from the nominal's start and is exact (but for a page
    geometry's: :func:`perturbed_timings`)."""
    from sim.memory.replay import AccessLogs
    from sim.scenes.progress import timed_run

    # the re-timings replay this timing's cache results (when resumable, one log for the calls before
    # the last and one for the last: sim.timing.kernel Emulation.parts)
    logs = AccessLogs(keep=2) if robust else None
    timed = timed_run(what, emulation, model, access_logs=logs, warm_start=warm_start,
                      resumable=robust and (warm_start or resumes(emulation)), rooms=robust)
    if not robust:
        return timed.last, None
    machine = MachineKey.parse(key)
    return timed.last, perturbed_timings(emulation, machine.label, machine.memory, timed.last, logs=logs,
                                         start=timed.last_call_start, what=what, warm_start=warm_start,
                                         timed=timed)


# -- what a claim names --------------------------------------------------------------------------

@dataclass(frozen=True)
class Claim:
    """A published claim a scene's report checks: `variants` (of run.variants) and what is expected
    of them (`expect`, within `tolerance`), on every machine its words cover. The Z-buffer kind's
    claims are these (variants[0] is similar to / faster / slower than variants[1]); a kind whose
    claims say more adds its fields in a subclass (texture: a measured quantity; snap: workloads;
    sort: distributions and sizes).

    Coverage: ``cpus`` (``preset`` = that preset with any memory, or ``preset:memory``) and
    ``families`` (every preset of those CPU families), narrowed by ``memories`` when given. The
    report checks the claim on each covered machine of the run and names the covered machines of
    the scene that the run left out ("not checked (CPU not in this run)")."""

    text: str
    variants: tuple[str, ...]
    expect: str
    tolerance: float | None = 0.0
    cpus: tuple[str, ...] = ()
    families: tuple[str, ...] = ()
    memories: tuple[str, ...] = ()

    def covers(self, preset: str, memory: str | None, family: str) -> bool:
        """Whether the claim's words cover `preset` (a machine label: with overrides it is still
        that preset) on `memory` of CPU family `family`."""
        if self.memories and memory not in self.memories:
            return False
        preset = MachineKey(preset).preset
        return family in self.families or preset in self.cpus or f"{preset}:{memory}" in self.cpus

    def describe_coverage(self) -> str:
        parts = list(self.cpus) + [f"every {f.upper()} preset" for f in self.families]
        text = ", ".join(parts)
        return text + (f" (memory {', '.join(self.memories)})" if self.memories else "")


def unrun(cpus, families, memories, machines) -> list[str]:
    """What a claim names that the scene does not run, so that its verdict would silently skip it:
    each ``cpus`` entry (a preset, or ``preset:memory``) and each family that no machine of the
    scene (``machines``: objects with .preset and .memory) matches, within ``memories`` when the
    claim narrows them. The loaders refuse such a claim (sim.scenes.schema.Validator.require_cover)."""
    from sim.cpus.machine import family_of

    ran = [(MachineKey(m.preset).preset, m.memory, family_of(m.preset)) for m in machines  # overrides aside
           if not memories or m.memory in memories]
    out = []
    for entry in cpus:
        preset, _, memory = entry.partition(":")
        if not any(p == preset and (not memory or mem == memory) for p, mem, _ in ran):
            out.append(entry)
    out += [f"every {f.upper()} preset" for f in families if not any(fam == f for _, _, fam in ran)]
    return out


# -- verdicts ------------------------------------------------------------------------------------

def holds(claim, ratio: float) -> bool:
    return {"similar": abs(ratio - 1) <= claim.tolerance, "faster": ratio < 1 - claim.tolerance,
            "slower": ratio > 1 + claim.tolerance}[claim.expect]


def covered(claim, result) -> tuple[list[str], list[str]]:
    """(machine keys of the run the claim covers, covered machines of the scene not in the run)."""
    from sim.cpus.machine import family_of

    keys = {k: MachineKey.parse(k) for k in result.cpu_keys}
    run = [k for k, m in keys.items() if claim.covers(m.label, m.memory, family_of(k))]
    scene = [m.label for m in result.scene.run.cpus if claim.covers(m.preset, m.memory, family_of(m.preset))]
    explicit = [c for c in claim.cpus if ":" in c and c not in scene]  # named but not in the scene
    return run, [k for k in scene + explicit if k not in run]


def evaluate(result, explain_counters: list[str]) -> list[dict]:
    """Every claim on every covered machine: verdict, cycles per pixel, the counters that differ,
    and the verdict's robustness to the estimated parameters (when the run measured it)."""
    out = []
    for claim in result.scene.claims:
        a_name, b_name = claim.variants
        checked, missing = covered(claim, result)
        per_cpu = []
        for key in checked:
            a, b = result.timing(a_name, key), result.timing(b_name, key)
            ca, cb = a.per_pixel("cycles"), b.per_pixel("cycles")
            ratio = ca / cb if cb else float("inf")
            verdict = holds(claim, ratio)
            diffs = differences({n: a.per_pixel(n) for n in explain_counters if n in a.counters},
                                {n: b.per_pixel(n) for n in explain_counters if n in b.counters}, explain_counters)
            entry = {"cpu": key, "cycles_per_pixel": [round(ca, 4), round(cb, 4)], "ratio": round(ratio, 4),
                     "holds": verdict, "explanation": diffs}
            entry["robustness"] = _robustness(claim, result, key, a, b, verdict)
            entry["verdict"] = verdict_text(verdict, entry["robustness"])
            per_cpu.append(entry)
        verdicts = {e["verdict"] for e in per_cpu}
        overall = verdicts.pop() if len(verdicts) == 1 else "mixed (see each machine)" if per_cpu else "not checked"
        out.append({"text": claim.text, "covers": claim.describe_coverage(), "variants": list(claim.variants),
                    "expect": claim.expect, "tolerance": claim.tolerance,
                    "holds": bool(per_cpu) and all(e["holds"] for e in per_cpu), "verdict": overall,
                    "per_cpu": per_cpu, "not_checked": missing})
    return out


def _robustness(claim, result, key, a, b, verdict) -> list[dict] | None:
    return robustness_rows(claim, result.sensitivity.get((a.variant, key)), result.sensitivity.get((b.variant, key)),
                           key, verdict)


def robustness_rows(claim, pa: dict | None, pb: dict | None, key: str, verdict: bool) -> list[dict] | None:
    """A faster/slower/similar claim's ratio at both ends of each estimated parameter's range on
    machine `key`: `pa`/`pb` map (parameter, value) to the two variants' counters there (None: not
    re-timed). Shared by every scene kind with such claims."""
    if pa is None or pb is None:
        return None
    rows = []
    machine = MachineKey.parse(key)
    for p in parameters(machine.label, machine.memory or None):
        ends = {}
        for end, value in (("low", p.low), ("high", p.high)):
            ca, cb = pa[(p.key, value)], pb[(p.key, value)]
            r = (ca["cycles"] / cb["cycles"]) if cb["cycles"] else float("inf")
            ends[end] = (value, round(r, 4), holds(claim, r))
        same = all(h == verdict for _, _, h in ends.values())
        rows.append({"parameter": p.key, "model": p.nominal, "low": ends["low"][0], "high": ends["high"][0],
                     "ratio_low": ends["low"][1], "ratio_high": ends["high"][1], "same_verdict": same,
                     "why": p.why})
    return rows


def robustness_text(rob: list[dict] | None) -> str:
    """` Robustness: ...` after a machine's verdict: the parameters whose range flips it, with the
    ratio at each end, then those it survives; "" when nothing was re-timed."""
    if not rob:
        return ""
    flips = [r for r in rob if not r["same_verdict"]]
    stable = [r for r in rob if r["same_verdict"]]
    parts = []
    if flips:
        parts.append("verdict flips with " + "; ".join(
            f"{r['parameter']} (ratio {r['ratio_low']:.3f} at {_n(r['low'])}, {r['ratio_high']:.3f} at "
            f"{_n(r['high'])}; model {_n(r['model'])})" for r in flips))
    if stable:
        parts.append("same verdict over " + ", ".join(
            f"{r['parameter']} {_n(r['low'])}..{_n(r['high'])}" for r in stable))
    return " Robustness: " + "; ".join(parts) + "."


def verdict_text(verdict: bool, robustness: list[dict] | None) -> str:
    flips = [r["parameter"] for r in robustness or [] if not r["same_verdict"]]
    if flips:
        return "depends on " + ", ".join(flips)
    return "reproduced" if verdict else "not reproduced"


def sentence(c: dict, cpu_label, counter_label=lambda n: n.replace("_", " ")) -> str:
    """The Markdown lines of one evaluated claim."""
    a, b = c["variants"]
    word = {"similar": "about the same as", "faster": "faster than", "slower": "slower than"}[c["expect"]]
    lines = [f"- {c['text']} — **{c['verdict']}**. Claim: {a} {word} {b} (tolerance {c['tolerance']:.0%}) on "
             f"{c['covers']}."]
    for e in c["per_cpu"]:
        more = ", ".join(f"{'+' if d > 0 else ''}{d:g} {counter_label(n)}" for n, d in e["explanation"].items())
        line = (f"  - {cpu_label(e['cpu'])}: **{e['verdict']}** — {a} {e['cycles_per_pixel'][0]:.2f} vs {b} "
                f"{e['cycles_per_pixel'][1]:.2f} cycles/pixel, ratio {e['ratio']:.3f}; per pixel, {a} minus {b}: "
                f"{more or 'no counter differs'}.")
        lines.append(line + robustness_text(e.get("robustness")))
    for k in c["not_checked"]:
        lines.append(f"  - {cpu_label(k)}: not checked (CPU not in this run).")
    return "\n".join(lines)


# -- the verdict summary a scene report opens with ----------------------------------------------

def _entry_verdict(e: dict) -> str:
    return e.get("verdict") or ("reproduced" if e.get("held", e.get("holds")) else "not reproduced")


def _measure(e: dict) -> tuple[str, float] | None:
    """The number a machine's verdict rests on: the cycle ratio of a faster/slower/similar claim, the
    measured quantity of a figure claim, the largest spread of a shape claim."""
    if e.get("ratio") is not None:
        return "ratio", e["ratio"]
    if e.get("measured") is not None:
        return "measured", e["measured"]
    if e.get("variants"):
        return "spread", max(p["spread"] for p in e["variants"].values())
    return None


def _overall(c: dict) -> str:
    """A claim's verdict without the detail the summary gives per machine ("mixed: ...", "(see ...)")."""
    return c["verdict"].split(" (")[0].split(":")[0]


def verdict_summary(claims: list[dict], cpu_label, reading: list[str]) -> list[str]:
    """The Markdown lines a scene report opens with, shared by every scene kind: one line per
    evaluated claim (its verdict, the machines grouped by their verdict, the range of the number the
    verdicts rest on, the estimates a verdict depends on), then `reading`, a few sentences on the
    numbers. The detail follows in the report's own sections."""
    if not claims and not reading:
        return []
    lines = ["## Verdicts" if claims else "## In short", ""]  # a scene without claims: the reading alone
    for c in claims:
        per = c.get("per_cpu")
        if per is None:  # a claim about results, not timings: the same on every machine
            lines.append(f"- **{c['verdict']}** — {c['text']} (independent of the machine)")
            continue
        groups: dict[str, list[str]] = {}
        for e in per:
            groups.setdefault(_entry_verdict(e), []).append(cpu_label(e["cpu"]))
        if len(groups) == 1:
            where = "on " + ", ".join(next(iter(groups.values())))
        else:
            where = "; ".join(f"{v} on {', '.join(ms)}" for v, ms in groups.items()) or "no machine of this run"
        measures = [m for m in map(_measure, per) if m is not None]
        span = ""
        if measures:
            lo, hi = min(x for _, x in measures), max(x for _, x in measures)
            name = measures[0][0]
            if name == "ratio" and len(c.get("variants") or ()) == 2:
                name = "cycles {0}/{1}".format(*c["variants"])
            span = f"; {name} {lo:.3f}" + (f"..{hi:.3f}" if hi != lo else "")
        estimates = list(dict.fromkeys(r["parameter"] for e in per for r in e.get("robustness") or []
                                       if not r["same_verdict"]))
        depends = f"; depends on {', '.join(estimates)}" if estimates else ""
        unchecked = len(c.get("not_checked") or ()) + len(c.get("refused") or ())
        skipped = f"; {unchecked} covered machine(s) not timed" if unchecked else ""
        lines.append(f"- **{_overall(c)}** — {c['text']} — {where}{span}{depends}{skipped}.")
    counts: dict[str, int] = {}
    for c in claims:
        key = "depends on an estimate" if _overall(c).startswith("depends on") else _overall(c)
        counts[key] = counts.get(key, 0) + 1
    if claims:
        lines += ["", f"{len(claims)} claim(s): " + ", ".join(f"{n} {v}" for v, n in counts.items()) + "."]
    for sentence in reading:
        lines += ([] if lines[-1] == "" else [""]) + [sentence]
    return lines + [""]


def report_head(scene, claims: list[dict], cpu_label, reading: list[str]) -> list[str]:
    """The Markdown lines every scene report opens with, whatever its kind: the scene's name, the
    verdict summary (:func:`verdict_summary`), its description and what generated the report."""
    return ([f"# {scene.name}", ""] + verdict_summary(claims, cpu_label, reading)
            + [scene.description.strip(), "",
               f"Generated by `retrosim report {scene.name}` from `scenes/{scene.name}.toml`; do not edit.", ""])
