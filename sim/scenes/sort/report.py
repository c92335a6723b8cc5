"""Sort scene reports: claims, crossovers, Markdown, self-contained HTML, JSON, CSV, a plot of
cycles per key against size (PNG), the terminal summary and the baseline cases. How files are
written (atomically, deterministically) is sim.reports.render.

Claims (sim.scenes.sort.scene): faster/slower compare two variants' cycles per key on one
distribution at one size, on every covered machine, with the counters per key that differ and the
verdict's robustness to the model's estimated parameters (sim.scenes.claims: the runs were re-timed
with each at the ends of its range). "linear" compares each variant's marginal cost, the extra
cycles per extra key between consecutive sizes of the claim's range, (C(n2) - C(n1)) / (n2 - n1):
a cost a + b n gives the same b for every pair whatever its fixed part a, while an n log n cost's
marginal cost grows with log n (by half from 1 K to 64 K keys). It holds when the largest marginal
cost is at most 1 + tolerance times the smallest. "distribution-independent" compares each
variant's cycles per key over the claim's distributions at one size the same way (largest over
smallest). These two re-time nothing: their robustness is not measured.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

from sim.cpus.machine import MachineKey
from sim.reports.compare import differences
from sim.reports.render import FORMATS, md_table, png_bytes, wants_image, write_report_set
from sim.scenes.claims import holds, report_head, robustness_rows, robustness_text, verdict_text
from sim.scenes.kind import BASELINE_COUNTERS
from sim.scenes.sort import keys as K
from sim.scenes.sort.runner import SortResult
from sim.scenes.sort.scene import TIMED
from sim.scenes.sort.variants import VARIANTS

# counters per key that explain a faster/slower verdict (when present and different)
EXPLAIN_COUNTERS = ["instructions", "uops", "mispredicts", "stall_mispredict", "l1d_load_misses", "l1d_store_misses",
                    "l2_misses", "stall_memory", "stall_store_forward", "stall_partial_register"]
# each timing in the JSON report: a row of these columns (the CSV has every counter of every model)
TIMING_COLUMNS = ["variant", "distribution", "keys", "cpu", "memory", "cycles_per_key"]
JSON_COUNTERS = list(dict.fromkeys([*BASELINE_COUNTERS, "branches", "stall_mispredict", "l1d_loads", "l1d_stores",
                                    "l2_accesses", "stall_memory", "stall_store_forward"]))
MISS_COLUMNS = [("mispredicts", "mispredicts"), ("l1d_load_misses", "L1D load misses"),
                ("l1d_store_misses", "L1D store misses"), ("l2_misses", "L2 misses")]


def _label(key: str) -> str:
    return MachineKey.parse(key).display


def _family(key: str) -> str:
    from sim.cpus.machine import family_of

    return family_of(MachineKey.parse(key).label)


def _num(x: float | None, digits: int = 1) -> str:
    return "-" if x is None else f"{x:,.{digits}f}"


def sorts(result: SortResult) -> list[str]:
    return [v for v in result.scene.variants if VARIANTS[v].sorts]


# -- claims ----------------------------------------------------------------------------------------
def _robustness(result: SortResult, claim, a, b, key: str, verdict: bool) -> list[dict] | None:
    dist, size = claim.distributions[0], claim.sizes[0]
    return robustness_rows(claim, result.sensitivity.get((a, dist, size, key)),
                           result.sensitivity.get((b, dist, size, key)), key, verdict)


def _timed_claim(result: SortResult, claim, key: str) -> dict:
    a, b = claim.variants
    dist, size = claim.distributions[0], claim.sizes[0]
    ta, tb = result.timing(a, dist, size, key), result.timing(b, dist, size, key)
    ca, cb = ta.per_key("cycles"), tb.per_key("cycles")
    ratio = ca / cb if cb else float("inf")
    held = holds(claim, ratio)
    diffs = differences({n: ta.per_key(n) for n in EXPLAIN_COUNTERS if n in ta.counters},
                        {n: tb.per_key(n) for n in EXPLAIN_COUNTERS if n in tb.counters}, EXPLAIN_COUNTERS)
    rob = _robustness(result, claim, a, b, key, held)
    return {"cpu": key, "cycles_per_key": [round(ca, 4), round(cb, 4)], "ratio": round(ratio, 4), "holds": held,
            "explanation": diffs, "robustness": rob, "verdict": verdict_text(held, rob)}


def marginal_costs(result: SortResult, variant: str, dist: str, sizes, key: str) -> list[tuple[int, int, float]]:
    """(n1, n2, extra cycles per extra key) between consecutive sizes."""
    ns = sorted(sizes)
    out = []
    for n1, n2 in zip(ns, ns[1:]):
        c1, c2 = result.timing(variant, dist, n1, key), result.timing(variant, dist, n2, key)
        out.append((n1, n2, (c2.counters["cycles"] - c1.counters["cycles"]) / (n2 - n1)))
    return out


def _shape_claim(result: SortResult, claim, key: str) -> dict:
    per_variant = {}
    for v in claim.variants:
        if claim.expect == "linear":
            dist = claim.distributions[0]
            steps = marginal_costs(result, v, dist, claim.sizes, key)
            values = [m for _, _, m in steps]
            detail = {"marginal_cycles_per_key": [{"from": n1, "to": n2, "cycles": round(m, 3)} for n1, n2, m in steps],
                      "cycles_per_key": {n: round(result.cycles_per_key(v, dist, n, key), 3) for n in claim.sizes}}
            misses = {n: {c: round(result.timing(v, dist, n, key).per_key(c), 4) for c, _ in MISS_COLUMNS}
                      for n in (min(claim.sizes), max(claim.sizes))}
        else:
            size = claim.sizes[0]
            values = [result.cycles_per_key(v, d, size, key) for d in claim.distributions]
            detail = {"cycles_per_key": {d: round(c, 3) for d, c in zip(claim.distributions, values)}}
            misses = {d: {c: round(result.timing(v, d, size, key).per_key(c), 4) for c, _ in MISS_COLUMNS}
                      for d in claim.distributions}
        low, high = min(values), max(values)
        spread = high / low if low > 0 else float("inf")
        per_variant[v] = {"spread": round(spread, 4), "holds": spread <= 1 + claim.tolerance, **detail,
                          "counters_per_key": misses}
    held = all(p["holds"] for p in per_variant.values())
    return {"cpu": key, "variants": per_variant, "holds": held, "robustness": None,
            "verdict": "reproduced" if held else "not reproduced"}


def evaluate_claims(result: SortResult) -> list[dict]:
    """Each claim on every machine of the run it covers: verdict, the numbers and counters behind
    it, and (faster/slower) its robustness. A variant refused on a covered machine (CMOV on the P5
    or K6) is listed as not timed there."""
    out = []
    for claim in result.scene.claims:
        per_cpu, refused, missing = [], [], []
        for key in result.cpu_keys:
            if not claim.covers(MachineKey.parse(key).label, None, _family(key)):
                continue
            why = [result.refused[(v, key)] for v in claim.variants if (v, key) in result.refused]
            if why:
                refused.append({"cpu": key, "refusal": why[0]})
                continue
            per_cpu.append(_timed_claim(result, claim, key) if claim.expect in TIMED else _shape_claim(result, claim, key))
        for m in result.scene.machines:
            from sim.cpus.machine import family_of

            if m.label not in result.cpu_keys and claim.covers(m.preset, None, family_of(m.preset)):
                missing.append(m.label)
        verdicts = list(dict.fromkeys(e["verdict"] for e in per_cpu))
        if len(verdicts) == 1:
            overall = verdicts[0]
        elif per_cpu:  # which machines gave which verdict, by preset
            overall = "mixed: " + "; ".join(
                f"{v} on {', '.join(MachineKey.parse(e['cpu']).label for e in per_cpu if e['verdict'] == v)}"
                for v in verdicts)
        else:
            overall = "not checked"
        out.append({"text": claim.text, "expect": claim.expect, "variants": list(claim.variants),
                    "covers": claim.describe_coverage(), "distributions": list(claim.distributions),
                    "sizes": list(claim.sizes), "tolerance": claim.tolerance, "verdict": overall,
                    "per_cpu": per_cpu, "refused": refused, "not_checked": missing})
    return out


def claim_sentence(c: dict) -> str:
    """The Markdown lines of one evaluated claim."""
    if c["expect"] in TIMED:
        a, b = c["variants"]
        what = (f"{a} {c['expect']} than {b} on {c['distributions'][0]} keys at {c['sizes'][0]:,} keys"
                + (f" (margin {c['tolerance']:.0%})" if c["tolerance"] else ""))
    elif c["expect"] == "linear":
        what = (f"{', '.join(c['variants'])}: extra cycles per extra key between consecutive sizes "
                f"{min(c['sizes']):,} to {max(c['sizes']):,} on {c['distributions'][0]} keys, largest at most "
                f"{1 + c['tolerance']:.2f} x the smallest")
    else:
        what = (f"{', '.join(c['variants'])}: cycles per key over {', '.join(c['distributions'])} keys at "
                f"{c['sizes'][0]:,} keys, largest at most {1 + c['tolerance']:.2f} x the smallest")
    lines = [f"- {c['text']} — **{c['verdict']}**. Checked: {what}, on {c['covers']}."]
    for e in c["per_cpu"]:
        if c["expect"] in TIMED:
            a, b = c["variants"]
            more = ", ".join(f"{'+' if d > 0 else ''}{d:g} {n.replace('_', ' ')}" for n, d in e["explanation"].items())
            lines.append(f"  - {_label(e['cpu'])}: **{e['verdict']}** — {a} {e['cycles_per_key'][0]:.1f} vs {b} "
                         f"{e['cycles_per_key'][1]:.1f} cycles/key, ratio {e['ratio']:.3f}; per key, {a} minus {b}: "
                         f"{more or 'no counter differs'}.{robustness_text(e['robustness'])}")
        else:
            parts = []
            for v, p in e["variants"].items():
                if c["expect"] == "linear":
                    steps = ", ".join(f"{s['cycles']:.1f}" for s in p["marginal_cycles_per_key"])
                    lo, hi = min(c["sizes"]), max(c["sizes"])
                    ml, mh = p["counters_per_key"][lo], p["counters_per_key"][hi]
                    parts.append(f"{v} marginal cycles/key {steps} (spread {p['spread']:.2f}); per key at {lo:,} and "
                                 f"{hi:,} keys: L1D load misses {ml['l1d_load_misses']:g} and {mh['l1d_load_misses']:g}, "
                                 f"L1D store misses {ml['l1d_store_misses']:g} and {mh['l1d_store_misses']:g}, "
                                 f"L2 misses {ml['l2_misses']:g} and {mh['l2_misses']:g}, mispredicts "
                                 f"{ml['mispredicts']:g} and {mh['mispredicts']:g}")
                else:
                    cpk = ", ".join(f"{d} {x:.1f}" for d, x in p["cycles_per_key"].items())
                    mp = [m["mispredicts"] for m in p["counters_per_key"].values()]
                    parts.append(f"{v} cycles/key {cpk} (spread {p['spread']:.2f}; mispredicts per key "
                                 f"{min(mp):g} to {max(mp):g})")
            lines.append(f"  - {_label(e['cpu'])}: **{e['verdict']}** — " + "; ".join(parts) + ".")
    for r in c["refused"]:
        lines.append(f"  - {_label(r['cpu'])}: not timed: `{r['refusal']}`")
    for k in c["not_checked"]:
        lines.append(f"  - {_label(k)}: not checked (CPU not in this run).")
    return "\n".join(lines)


# -- crossovers ------------------------------------------------------------------------------------
def crossovers(result: SortResult) -> list[dict]:
    """For each radix variant, CPU and sweep distribution: the smallest sweep size from which the
    radix sort is faster than every comparison sort run at that size, at that size and every larger
    one (None: it never stays ahead)."""
    s = result.scene
    radix = [v for v in s.variants if VARIANTS[v].kind == "radix"]
    comparison = [v for v in s.variants if VARIANTS[v].kind == "comparison"]
    out = []
    for r in radix:
        for key in result.cpu_keys:
            for dist in s.sweep_distributions:
                rows = []
                for n in sorted(s.sizes):
                    mine = result.cycles_per_key(r, dist, n, key)
                    rivals = {v: result.cycles_per_key(v, dist, n, key) for v in comparison}
                    rivals = {v: c for v, c in rivals.items() if c is not None}
                    if mine is None or not rivals:
                        continue
                    best = min(rivals, key=lambda v: (rivals[v], v))
                    rows.append((n, mine < rivals[best], best, rivals[best], mine))
                start = None
                for n, wins, *_ in reversed(rows):
                    if not wins:
                        break
                    start = n
                out.append({"radix": r, "cpu": key, "distribution": dist, "from_size": start,
                            "smallest_size": rows[0][0] if rows else None,
                            "per_size": [{"size": n, "radix": round(mine, 2), "best_comparison": best,
                                          "comparison": round(c, 2), "radix_wins": wins}
                                         for n, wins, best, c, mine in rows]})
    return out


def _crossover_text(x: dict) -> str:
    if x["from_size"] is None:
        return "never (up to the largest size)"
    if x["from_size"] == x["smallest_size"]:
        return f"at every size (from {x['from_size']:,})"
    below = max(p["size"] for p in x["per_size"] if p["size"] < x["from_size"])
    return f"from {x['from_size']:,} (not at {below:,})"


# -- tables ------------------------------------------------------------------------------------------
def table_rows(result: SortResult, key: str) -> tuple[list[str], list[list[str]]]:
    s = result.scene
    header = ["variant"] + list(s.distributions)
    rows = []
    for v in s.variants:
        if (v, key) in result.refused:
            continue
        rows.append([v] + [_num(result.cycles_per_key(v, d, s.table_size, key)) for d in s.distributions])
    return header, rows


def counter_rows(result: SortResult, dist: str, size: int) -> tuple[list[str], list[list[str]]]:
    s = result.scene
    header = ["variant", "CPU"] + [t for _, t in MISS_COLUMNS]
    rows = []
    for v in s.variants:
        for key in result.cpu_keys:
            t = result.timing(v, dist, size, key)
            if t is None:
                continue
            rows.append([v, _label(key)] + [_num(t.per_key(c), 3) for c, _ in MISS_COLUMNS])
    return header, rows


def sweep_rows(result: SortResult, dist: str, key: str) -> tuple[list[str], list[list[str]]]:
    s = result.scene
    sizes = sorted(s.sizes)
    header = ["variant"] + [f"{n:,}" for n in sizes]
    rows = []
    for v in s.variants:
        if (v, key) in result.refused:
            continue
        rows.append([v] + [_num(result.cycles_per_key(v, dist, n, key)) for n in sizes])
    return header, rows


# -- documents ---------------------------------------------------------------------------------------
def findings(result: SortResult) -> list[str]:
    """Plain statements computed from the results."""
    s, out = result.scene, []
    out.append(f"Every run's output was checked against Python's sorted() (clamp variants: against min(max(key, lo), "
               f"hi)): {len(result.checked)} runs, all correct.")
    for key in result.cpu_keys:
        timed = [v for v in s.variants if (v, key) not in result.refused and VARIANTS[v].sorts]
        best = {}
        for d in s.distributions:
            vals = {v: result.cycles_per_key(v, d, s.table_size, key) for v in timed}
            best[d] = min(vals, key=lambda v: (vals[v], v))
        out.append(f"{_label(key)}: fastest sort at {s.table_size:,} keys: "
                   + ", ".join(f"{d} {v} ({result.cycles_per_key(v, d, s.table_size, key):.1f} cycles/key)"
                               for d, v in best.items()) + ".")
    if {"radix8", "radix11"} <= set(s.variants):
        dist = s.sweep_distributions[0]
        for n in sorted({s.table_size, max(s.sizes)}):
            parts = []
            for key in result.cpu_keys:
                a, b = result.timing("radix8", dist, n, key), result.timing("radix11", dist, n, key)
                if a is None or b is None:
                    continue
                miss = lambda t: t.per_key("l1d_load_misses") + t.per_key("l1d_store_misses")
                parts.append(f"{_label(key)} {b.per_key('cycles'):.1f} against {a.per_key('cycles'):.1f} cycles, "
                             f"{miss(b):.2f} against {miss(a):.2f} L1D misses")
            if parts:
                out.append(f"radix11 against radix8 per key at {n:,} {dist} keys: " + "; ".join(parts) + ".")
    return out


def _zbuffer_text(result: SortResult) -> list[str]:
    z = result.zbuffer
    if not z:
        return []
    return [f"The `zbuffer` keys are the 16-bit float (fp16z) depth codes of the `{z['scene']}` scene's frame: "
            f"{z['triangles']:,} triangles, {z['spans']:,} spans, {z['pixels']:,} pixel visits in draw order with "
            f"{z['distinct_codes']:,} distinct codes; a run of n keys takes n of them evenly spaced over the visits "
            "(sim/scenes/sort/keys.py). The code is monotone in depth, so the keys sort as unsigned integers.", ""]


def to_markdown(result: SortResult, png_name: str | None) -> str:
    s = result.scene
    parts = report_head(s, evaluate_claims(result), _label, findings(result)[:2]) + ["Variants (`kernels/sort/`):", ""]
    parts += [f"- `{v}` (`{VARIANTS[v].file}`, `{VARIANTS[v].entry}`): {VARIANTS[v].label}" for v in s.variants] + [""]
    parts += [f"Key distributions (16-bit unsigned keys, seed {s.seed}):", ""]
    parts += [f"- `{d}`: {K.DISTRIBUTIONS[d]}" for d in dict.fromkeys(s.distributions + s.sweep_distributions)] + [""]
    parts += _zbuffer_text(result)
    parts += [f"The clamp variants clamp each key into [{s.clamp[0]}, {s.clamp[1]}]: on uniform keys a quarter lies "
              "below and a quarter above (each branch of `clamp-branchy` goes either way at random)." if s.clamp == (16384, 49152)
              else f"The clamp variants clamp each key into [{s.clamp[0]}, {s.clamp[1]}].", ""]
    parts += ["How a run is timed: the keys are copied into the buffer the variant works on by a first call "
              "(`sort_load`, not counted), as the code that produced them would have written them, then the variant's "
              "call is timed alone (caches warm with what the copy left; branch predictors start cold). Cycles per key "
              "are that call's cycles over its keys. Every run's output is checked against Python's `sorted()`.", ""]
    if s.limits:
        parts += ["## Sizes and limits", "", s.limits.strip(), ""]
    if result.refused:
        parts += ["## Not timed", "", "CMOV is a P6 instruction; the P5 and the K6 family lack it. These variants are "
                  "refused on those CPUs with the usual error and not timed there:", ""]
        parts += [f"- `{v}` on {_label(k)}: `{msg}`" for (v, k), msg in result.refused.items()] + [""]
    if result.timings:
        parts += [f"## Cycles per key at {s.table_size:,} keys, by distribution", ""]
        for key in result.cpu_keys:
            parts += [f"### {_label(key)}", "", md_table(*table_rows(result, key)), ""]
        for dist in s.distributions[:1]:
            parts += [f"## Mispredicts and cache misses per key ({dist} keys, {s.table_size:,} keys)", "",
                      "The models' counters over the timed call, per key: mispredicted branches, L1 data cache load "
                      "and store misses (a store miss allocates a line on the P6, and on a K6 whose preset sets write "
                      "allocation (the K6-2 300's does); the P5 never allocates on a store, so each store to a line not "
                      "in L1 counts), and misses of the L2 (the P5's and the K6-2's L2 is the board cache).", "",
                      md_table(*counter_rows(result, dist, s.table_size)), ""]
        for dist in s.sweep_distributions:
            parts += [f"## Cycles per key against size ({dist} keys)", ""]
            for key in result.cpu_keys:
                parts += [f"### {_label(key)}", "", md_table(*sweep_rows(result, dist, key)), ""]
            big = max(s.sizes)
            parts += [f"Mispredicts and cache misses per key at {big:,} {dist} keys:", "",
                      md_table(*counter_rows(result, dist, big)), ""]
        if png_name:
            parts += ["## Plot", "", f"![cycles per key against size]({png_name})", ""]
        xs = crossovers(result)
        if xs:
            parts += ["## Where radix sort starts to win", "",
                      "The smallest size from which each radix sort is faster than every comparison sort run at that "
                      "size (insertion sort, quicksort and the merge sorts within their size limits), and stays faster at "
                      "every larger size of the sweep.", ""]
            header = ["radix", "CPU"] + [f"{d} keys" for d in s.sweep_distributions]
            rows = []
            for r in dict.fromkeys(x["radix"] for x in xs):
                for key in result.cpu_keys:
                    cells = [_crossover_text(next(x for x in xs if (x["radix"], x["cpu"], x["distribution"]) == (r, key, d)))
                             for d in s.sweep_distributions]
                    rows.append([r, _label(key)] + cells)
            parts += [md_table(header, rows), ""]
    claims = evaluate_claims(result)
    if claims:
        parts += ["## The essays' claims, checked", "",
                  "Faster/slower claims state their margin; their runs were re-timed with each estimated model parameter "
                  "at the ends of its plausible range (sim/scenes/claims.py), and a verdict that changes is reported as "
                  "depending on it. The linear and distribution-independent claims re-time nothing (their robustness is "
                  "not measured). Verdicts are as the models give them.", ""]
        parts += [claim_sentence(c) for c in claims] + [""]
    parts += ["## Findings", ""] + [f"- {f}" for f in findings(result)] + [""]
    parts += ["## Notes", "",
              "- 16-bit keys need two passes with 8-bit digits and still two with 11-bit digits: `radix11` saves no pass "
              "here, it only trades a 1 KB histogram for an 8 KB one (and 32 entries for the high 5 bits). 8 KB is the "
              "whole L1 data cache of the first Pentiums (P54C; the Pentium MMX's and the P6's are 16 KB, the K6-2's "
              "32 KB): while the first pass scatters, the histogram competes with the keys it reads and the buffer it "
              "writes, and clearing it and summing its 2,048 counts costs the same for 256 keys as for 64 K. The "
              "findings above give each CPU's misses. With 32-bit keys 11-bit digits would need 3 passes instead of 4.",
              "- The merge sorts run from runs of one key up (no insertion-sorted start), so their loop-end branches "
              "mispredict often in the first passes whatever the select is made of; the SBB and CMOV merges remove "
              "only the select's branch.",
              "- Every kernel loads its keys with MOVZX, which the P5 does not pair and spends 3 clocks on "
              "(sim/cpus/p5/p5.toml); the P5's figures include it at every key load, in every variant.", ""]
    return "\n".join(parts).rstrip() + "\n"


def to_json(result: SortResult) -> dict:
    s = result.scene
    return {
        "scene": s.name, "kind": s.kind, "description": s.description, "seed": s.seed,
        "distributions": {d: K.DISTRIBUTIONS[d] for d in dict.fromkeys(s.distributions + s.sweep_distributions)},
        "table_size": s.table_size, "sizes": list(s.sizes), "sweep_distributions": list(s.sweep_distributions),
        "clamp": list(s.clamp), "max_size": dict(s.max_size), "limits": s.limits, "zbuffer": result.zbuffer,
        "variants": {v: {"file": VARIANTS[v].file, "entry": VARIANTS[v].entry, "kind": VARIANTS[v].kind,
                         "label": VARIANTS[v].label} for v in s.variants},
        "refused": [{"variant": v, "cpu": k, "message": m} for (v, k), m in result.refused.items()],
        "checked_runs": len(result.checked),
        "timings": {"columns": TIMING_COLUMNS + JSON_COUNTERS,
                    "rows": [[t.variant, t.distribution, t.size, t.cpu, t.memory, round(t.per_key("cycles"), 4)]
                             + [t.counters.get(c) for c in JSON_COUNTERS] for t in result.timings]},
        "crossovers": crossovers(result),
        "claims": evaluate_claims(result),
        "findings": findings(result),
    }


def json_text(result: SortResult) -> str:
    """The JSON report, indented, with each timing row on one line (a thousand rows stay readable)."""
    doc = to_json(result)
    timings = doc.pop("timings")
    rows = ",\n".join("      " + json.dumps(r) for r in timings["rows"])
    return (json.dumps(doc, indent=2)[:-2] + f',\n  "timings": {{\n    "columns": {json.dumps(timings["columns"])},\n'
            f'    "rows": [\n{rows}\n    ]\n  }}\n}}\n')


def to_csv(result: SortResult) -> str:
    buf = io.StringIO()
    counters = list(dict.fromkeys(c for t in result.timings for c in t.counters))
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["scene", "variant", "distribution", "keys", "cpu", "memory", "cycles_per_key"] + counters)
    for t in result.timings:
        w.writerow([result.scene.name, t.variant, t.distribution, t.size, t.cpu, t.memory, f"{t.per_key('cycles'):.4f}"]
                   + [t.counters.get(c, "") for c in counters])
    return buf.getvalue()


def figure(result: SortResult):
    """Cycles per key (log) against keys (log 2), one panel per CPU (columns) and sweep
    distribution (rows), one line per sort variant (the same colour and marker in every panel)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = result.scene
    keys = result.cpu_keys
    variants = sorts(result)
    palette = plt.get_cmap("tab10")
    markers = "osD^vP*Xh<>"
    nrow, ncol = len(s.sweep_distributions), len(keys)
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.2 * ncol + 0.6, 2.9 * nrow + 1.0), dpi=100, sharex=True,
                             sharey=True, layout="constrained", squeeze=False)
    sizes = sorted(s.sizes)
    for r, dist in enumerate(s.sweep_distributions):
        for c, key in enumerate(keys):
            ax = axes[r][c]
            for i, v in enumerate(variants):
                pts = [(n, result.cycles_per_key(v, dist, n, key)) for n in sizes]
                pts = [(n, y) for n, y in pts if y is not None]
                if not pts:
                    continue
                ax.plot([n for n, _ in pts], [y for _, y in pts], marker=markers[i % len(markers)], markersize=3.5,
                        linewidth=1.2, color=palette(i % palette.N), label=v)
            ax.set_xscale("log", base=2)
            ax.set_yscale("log")
            ax.grid(True, which="both", color="0.9", linewidth=0.6)
            ax.set_title(f"{_label(key)} [{_family(key).upper()}]\n{dist} keys", fontsize=8)
            if r == nrow - 1:
                ax.set_xlabel("keys", fontsize=8)
            if c == 0:
                ax.set_ylabel("cycles per key", fontsize=8)
            ax.tick_params(labelsize=7)
    found = {}
    for row in axes:
        for ax in row:
            for h, lab in zip(*ax.get_legend_handles_labels()):
                found.setdefault(lab, h)
    labels = [v for v in variants if v in found]  # the variants' order, whichever panel drew each first
    handles = [found[v] for v in labels]
    fig.legend(handles, labels, fontsize=8, loc="outside lower center", ncol=min(7, len(labels)), frameon=False)
    fig.suptitle(f"{s.name}: cycles per key against the number of keys (fewer is faster)", fontsize=10)
    return fig


def png(result: SortResult) -> bytes | None:
    if not result.timings or len(result.scene.sizes) < 2:
        return None
    return png_bytes(figure(result))


def write_reports(result: SortResult, out_dir: Path, formats: tuple[str, ...] = FORMATS) -> list[Path]:
    name = result.scene.name
    image = png(result) if wants_image(formats) else None
    # the Markdown names its plot whichever formats are written: `check --reports` writes no PNG
    # and must produce the same Markdown as `report`
    md = to_markdown(result, f"{name}.png" if result.timings else None)
    return write_report_set(out_dir, name, md, image, json_text(result), to_csv(result), formats)


def baseline_entries(result: SortResult) -> dict[str, dict[str, int]]:
    """The recorded cycle counts: one case per run (variant/distribution/keys) and machine."""
    return {f"{t.variant}/{t.distribution}/{t.size}@{t.key}": {c: int(t.counters[c]) for c in BASELINE_COUNTERS}
            for t in result.timings}


def summary_tables(result: SortResult) -> list:
    """The terminal summary: cycles per key on the first distribution at table_size (a column per
    CPU), where each radix sort starts to win, and how many claims held."""
    from rich import box
    from rich.markup import escape
    from rich.padding import Padding
    from rich.table import Table
    from rich.text import Text

    s = result.scene
    dist = s.distributions[0]
    presets = [MachineKey.parse(k).label for k in result.cpu_keys]
    if len(set(presets)) < len(presets):  # one preset with two memories: name the memory too
        presets = list(result.cpu_keys)
    presets = [p.rpartition("-")[0] + "-\n" + p.rpartition("-")[2] if "-" in p else p for p in presets]  # 80 columns
    t = Table(title=f"{escape(s.name)}: cycles per key, {s.table_size:,} {dist} keys", title_justify="left",
              box=box.SIMPLE_HEAD, pad_edge=False)
    t.add_column("variant", no_wrap=True)
    for p in presets:
        t.add_column(escape(p), justify="right")
    for v in s.variants:
        t.add_row(v, *[("refused" if (v, key) in result.refused else _num(result.cycles_per_key(v, dist, s.table_size, key)))
                       for key in result.cpu_keys])
    out = [t]
    xs = crossovers(result)
    if xs:
        c = Table(title="keys from which radix sort beats every comparison sort", title_justify="left",
                  box=box.SIMPLE_HEAD, pad_edge=False)
        c.add_column("radix, keys", no_wrap=True)
        for p in presets:
            c.add_column(escape(p), justify="right")
        for r in dict.fromkeys(x["radix"] for x in xs):
            for d in s.sweep_distributions:
                cells = []
                for key in result.cpu_keys:
                    x = next(x for x in xs if (x["radix"], x["cpu"], x["distribution"]) == (r, key, d))
                    cells.append("never" if x["from_size"] is None else f"{x['from_size']:,}")
                c.add_row(f"{r}, {d}", *cells)
        out.append(c)
    claims = evaluate_claims(result)
    if claims:
        held = sum(1 for c in claims if c["verdict"] == "reproduced")
        out.append(Padding(Text(f"claims: {held} of {len(claims)} reproduced"), (0, 0, 0, 1)))
        # "claim. — verdict", as the Markdown report has it (a claim is a sentence: "claim.: verdict" misreads)
        out += [Padding(Text(f"- {c['text']} — {c['verdict']}"), (0, 0, 0, 3)) for c in claims if c["verdict"] != "reproduced"]
    return out
