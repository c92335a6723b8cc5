"""Views of a timing run: summary, per-instruction table (explain), timeline. Views only read the
model's counters; they never change a simulation (the llvm-mca split). What a family looks like
(its rows, columns, words) is its FamilyView's (sim/cpus/view.py, sim/cpus/NAME/view.py); this
module asks the run's family view and renders what it gives."""

from __future__ import annotations

import io
import re
from typing import TYPE_CHECKING

import numpy as np
from rich import box
from rich.markup import escape
from rich.table import Table

from sim.cpus import contract as core  # the counter, per-instruction and timeline schemas
from sim.cpus import families
from sim.cpus.view import SUMMARY_STALLS, FamilyView, TableSpec
from sim.cpus.vocabulary import STALL_KINDS, Vocabulary

if TYPE_CHECKING:  # a view reads a timed run; it never times one
    from sim.timing.kernel import TimingResult

STALLS = ("stall_decode", "stall_fetch", "stall_mispredict", "stall_rob", "stall_rs", "stall_store_buffer",
          "stall_partial_register", "stall_partial_flags", "stall_dependency", "stall_port", "stall_memory",
          "stall_store_forward", "stall_register_read")


def summary(result: TimingResult) -> dict:
    """The last call's counters plus derived figures, as one flat dict (the JSON of `retrosim time`)."""
    c = dict(result.last)
    d = {"cpu": result.cpu, "memory": result.memory, "source": str(result.source), "entry": result.entry,
         "repeat": result.repeat, **c}
    d["ipc"] = round(c["instructions"] / c["cycles"], 4) if c["cycles"] else 0.0
    d["uops_per_cycle"] = round(c["uops"] / c["cycles"], 4) if c["cycles"] else 0.0
    d.update(family_view(result).summary_fields())
    d["l1d_misses"] = c["l1d_load_misses"] + c["l1d_store_misses"]
    d["l1d_hits"] = c["l1d_loads"] + c["l1d_stores"] - d["l1d_misses"]
    d["l2_hits"] = c["l2_accesses"] - c["l2_misses"]
    d["dram_cycles"] = c["dram_bus_cycles"]
    return d


def family_view(result: TimingResult) -> FamilyView:
    """The view of the run's family (sim/cpus/families.py: view)."""
    return families.view(result.model.family)


def _vocab(result: TimingResult) -> Vocabulary:
    return family_view(result).vocabulary


_OTHER_STALL_HELP = {"stall_fetch": "decoders idle for instruction bytes (L1I miss, branch-target miss)",
                     "stall_store_buffer": "waiting for a free store-buffer entry",
                     "stall_partial_flags": "reading flags after an instruction that writes only some of them",
                     "stall_rs": "waiting for a free reservation-station entry",
                     "stall_register_read": "renaming held: more than two reads per clock of registers not "
                                            "written recently (P6 permanent register file)"}


def summary_table(result: TimingResult) -> Table:
    """The last call's counters in the family's words: rows of (what, count, detail)."""
    s = summary(result)
    t = Table(title=escape(f"{result.source.name}:{result.entry} on {result.cpu} with {result.memory} "
                           f"(call {result.repeat} of {result.repeat})"), show_header=False, box=box.SIMPLE)
    t.add_column(style="bold", no_wrap=True)
    t.add_column(justify="right", no_wrap=True)
    t.add_column(overflow="fold")
    for row in family_view(result).summary_rows(s, result.model):
        t.add_row(*row)
    return t


def stall_labels(result: TimingResult, counters: dict) -> list[tuple[str, str]]:
    """(counter, label) of the stall kinds in `counters`, in the words `retrosim time` uses for the
    family: the P5's own (agi, prefix, write buffer, ...), else the summary's (window, branch, ...;
    "window (RS)" only when the reorder buffer's and the reservation station's are told apart)."""
    return family_view(result).stall_labels(counters)


def bottleneck(result: TimingResult, counters: dict) -> str:
    """What held the run back most, in its family's words ("ports p0/p1 saturated", "U/V pairing:
    2 of 4 alone", "write buffer full")."""
    return family_view(result).bottleneck(counters)


def stall_table(result: TimingResult) -> Table:
    """Stall cycles of the last call by kind, each with what it counts in this family."""
    s, v = summary(result), _vocab(result)
    t = Table(title="stall cycles by kind (they overlap: they do not add up to the cycle count)",
              box=box.SIMPLE, show_header=True)
    t.add_column("kind", no_wrap=True)
    t.add_column("cycles", justify="right", no_wrap=True)
    t.add_column("what it counts", overflow="fold")
    for counter, label, kind in SUMMARY_STALLS:
        if s.get(counter):
            what = v.stall_help.get(kind, "") if kind else _OTHER_STALL_HELP.get(counter, "")
            if counter == "stall_rob":
                what = v.stall_help.get("window", "") if not s.get("stall_rs") else "waiting for a free reorder-buffer entry"
            if counter == "stall_rs":
                what = _OTHER_STALL_HELP["stall_rs"]
            t.add_row(label, f"{s[counter]:,}", what)
    if not t.row_count:
        t.add_row("none", "0", "")
    return t


def mispredict_note(result: TimingResult) -> str:
    return _vocab(result).mispredict_note


def explain_rows(result: TimingResult) -> list[dict]:
    """One row per static instruction executed in the last call, in address order, in the family's
    words (decoder marks, port or unit names)."""
    return family_view(result).explain_rows(result)


# -- what the figures rest on: estimated rows, behaviour the model does not implement --------------
# A note sentence naming behaviour the model leaves out (the tables' own words: "Start-up cost not
# modelled separately.", "Not modelled: a power-of-2 divisor L 9 ...", "transition cost not modelled").
_NOT_MODELLED = re.compile(r"not (?:modell?ed|enforced|implemented|reproduced)", re.IGNORECASE)
_SENTENCE = re.compile(r"(?<=[.!?])\s+(?=[A-Z(])")


def row_limits(row) -> list[str]:
    """Why a table row's figures are not what the model runs, from the row itself: the `unreproduced`
    field (a sourced explanation of a rate the model does not reproduce) and every sentence of its
    note that names behaviour not modelled."""
    out = []
    if row.extra.get("unreproduced"):
        out.append(str(row.extra["unreproduced"]))
    out += [t.strip() for t in _SENTENCE.split(row.note or "") if _NOT_MODELLED.search(t)]
    return list(dict.fromkeys(out))


def caveats(result: TimingResult) -> dict:
    """What the run's figures rest on, over the instructions the per-instruction table covers (the
    last call; a loop's measured iterations): how many executions used a row marked estimated in
    the family's instruction table, and the rows whose behaviour the model does not implement (:func:`row_limits`)."""
    run = result.run
    rows = explain_rows(result)
    matches = {(rec.pc, m.describe()): m for rec, m in zip(run.program.records, run.program.matches)}
    total = sum(r["executions"] for r in rows)
    estimated: dict[str, int] = {}
    limits: dict[str, dict] = {}
    for r in rows:
        if r["estimated"]:
            estimated[r["row"]] = estimated.get(r["row"], 0) + r["executions"]
        match = matches.get((r["pc"], r["row"]))
        why = row_limits(match.row) if match is not None else []
        if why:
            entry = limits.setdefault(match.row.key, {"row": match.row.key, "instructions": [], "executions": 0,
                                                      "why": why})
            entry["instructions"].append(r["instruction"])
            entry["executions"] += r["executions"]
    est = sum(estimated.values())
    return {"instructions": total, "estimated_instructions": est,
            "estimated_share": round(est / total, 4) if total else 0.0,
            "estimated_rows": [{"row": k, "executions": n} for k, n in
                               sorted(estimated.items(), key=lambda kv: (-kv[1], kv[0]))],
            "not_modelled": sorted(limits.values(), key=lambda e: (-e["executions"], e["row"]))}


def caveat_lines(result: TimingResult, c: dict | None = None) -> list[str]:
    """One or two short lines for the summary (the rows and reasons: explain, --json)."""
    c = c or caveats(result)
    n, est = c["instructions"], c["estimated_instructions"]
    rows = len(c["estimated_rows"])
    lines = [f"estimated rows: {est:,} of {n:,} executed instructions ({100 * est / n if n else 0:.0f} %)"
             + (f" use {rows} table row{'s' if rows > 1 else ''} marked estimated" if est else "")]
    if c["not_modelled"]:
        lines.append(not_modelled_line(c))
    return lines


def not_modelled_line(c: dict) -> str:
    return "relies on behaviour not modelled: " + "; ".join(
        f"{e['row']} ({e['executions']:,} executions)" for e in c["not_modelled"]) + " (why: explain, --json)"


def caveat_details(result: TimingResult, c: dict | None = None) -> list[str]:
    """The not-modelled rows with their reasons, for explain's legend."""
    c = c or caveats(result)
    return [f"not modelled, {e['row']} ({', '.join(e['instructions'])}): {' '.join(e['why'])}" for e in c["not_modelled"]]


def render(spec: TableSpec) -> Table:
    """A family view's table as a terminal table (its text escaped: '[ebx]' is not markup)."""
    if spec.compact:  # light borders: the width goes to the cells, not to box drawing
        t = Table(title=escape(spec.title), box=box.SIMPLE_HEAD, pad_edge=False, title_justify="left")
    else:
        t = Table(title=escape(spec.title))
    for c in spec.columns:
        opts = {k: v for k, v in (("no_wrap", c.no_wrap), ("overflow", c.overflow)) if v is not None}
        t.add_column(c.name, justify=c.justify, **opts)
    for row in spec.rows:
        t.add_row(*(escape(str(cell)) for cell in row))
    return t


def fitting(forms: list[list[TableSpec]], width: int) -> list[Table]:
    """The first form whose tables all fit `width` columns, else the last form."""
    for form in forms[:-1]:
        tables = [render(spec) for spec in form]
        if all(natural_width(t) <= width for t in tables):
            return tables
    return [render(spec) for spec in forms[-1]]


def explain_tables(result: TimingResult, width: int) -> list[Table]:
    """The per-instruction table: one table when `width` columns hold it, else the family's
    narrower ones (each keyed by the instruction)."""
    return fitting(family_view(result).explain_tables(explain_rows(result)), width)


def loop_tables(result: TimingResult, cpu: str, width: int) -> list[Table]:
    """`retrosim loop`'s per-instruction table(s) of one CPU, in its family's form."""
    return fitting(family_view(result).loop_tables(explain_rows(result), cpu), width)


def explain_table(result: TimingResult) -> Table:
    """The one-table form (any width); see explain_tables for the form that fits a terminal."""
    return explain_tables(result, 10_000)[0]


def natural_width(table: Table) -> int:
    from rich.console import Console

    probe = Console(width=10_000, file=io.StringIO())
    return probe.measure(table).maximum


def explain_legend(result: TimingResult) -> list[str]:
    """What every column and mark of the per-instruction table and the timeline means, in this
    family's words (printed under the tables; also in `retrosim explain --help`)."""
    v = _vocab(result)
    ops = "uops" if v.op == "uop" else "ops"
    units = v.unit + "s"
    table = result.model.family
    rows = explain_rows(result)
    kinds = [k for k, _ in STALL_KINDS if any(r.get(f"stall_{k}") for r in rows)]
    lines = [f"runs: executions in the last call. dec: {v.decode_help}.",
             f"{ops}: {v.op}s per execution. {units}: {v.op}s per execution on each ({'; '.join(v.port_help)}).",
             "iss->ret: average cycles from the instruction's first " + v.op + " issuing to its retirement.",
             "stall columns, cycles per execution: " + "; ".join(f"{col} = {v.stall_help.get(k, '')}"
                                                                  for k, col in STALL_KINDS if k in kinds) + ".",
             "mispred: mispredictions per execution. " + (v.mispredict_note + "." if v.mispredict_note else ""),
             f"table row: the row of sim/cpus/{table}/{table}.toml used (a -> b: looked up as a, found as b); "
             "(est.): that row's figures are estimates, not measurements (its source is in --json).",
             f"timeline: {timeline_key(result)}; [cause]: what held the instruction back, a wait to issue before a wait to enter the window (names as in the stall columns)."]
    return lines


def timeline_key(result: TimingResult, causes: bool = False) -> str:
    """What the timeline's letters mean in the family's words; `causes`: also what a [cause] says."""
    view = family_view(result)
    return view.timeline_legend + (view.timeline_cause_words if causes else "")


def timeline_rows(result: TimingResult) -> list[dict]:
    run = result.run
    causes = family_view(result).timeline_causes  # the family's own words
    out = []
    for row in run.timeline:
        sid = int(row[1])
        rec = run.program.records[sid]
        out.append({"insn": int(row[0]), "pc": rec.pc, "instruction": f"{rec.mnemonic} {rec.op_str}".strip(),
                    **{name: int(row[k]) for k, name in enumerate(core.T_NAMES) if k >= 2 and name != "cause"},
                    "cause": causes[int(row[7])]})
    return out


def timeline_text(result: TimingResult, width: int = 72, columns: int | None = None) -> str:
    """llvm-mca style: D decode, R rename (K6: enter the scheduler), = waiting, E executing, - done,
    C retire. `columns`: the terminal width; the chart narrows so that every line fits it."""
    rows = timeline_rows(result)
    if not rows:
        return ""
    labels = [r["instruction"] + ("" if r["cause"] == "none" else f"  [{r['cause']}]") for r in rows]
    if columns:
        width = max(16, min(120, columns - 1 - max(map(len, labels))))
    base = min(r["decode"] for r in rows)
    lines = [f"cycle 0 = {base}"]
    for r, label in zip(rows, labels):
        cells = [" "] * width

        def put(c, ch):
            if 0 <= c - base < width:
                cells[c - base] = ch
        for c in range(r["alloc"] + 1, r["dispatch"]):
            put(c, "=")
        for c in range(r["dispatch"], r["complete"]):
            put(c, "E")
        for c in range(r["complete"], r["retire"]):
            put(c, "-")
        put(r["decode"], "D")
        put(r["alloc"], "R")
        put(r["retire"], "C")
        lines.append(f"{''.join(cells).rstrip():<{width}} {label}")
    return "\n".join(lines)


# -- retrosim loop: the summary first, then resource pressure, then the detail -----------------------
# under every loop's per-instruction table: the stall columns are charged per instruction
STALL_OVERLAP_NOTE = ("stall cycles are charged to each instruction that waited, and they overlap (two "
                      "instructions wait in the same cycle): they may add up to more than the cycles per iteration")


def resource_pressure(result: TimingResult, counters: dict) -> dict[str, float]:
    """Ops per port or unit in the family's words (llvm-mca's resource pressure), from `counters`
    (a loop's per-iteration figures: then per iteration): {unit name: figure}."""
    return {name: round(float(n), 4) for name, n in family_view(result).resource_pressure(counters).items()}


def loop_summary_table(title: str, timings, width: int = 10_000) -> Table:
    """One line per CPU: cycles, instructions and uops per iteration, IPC, the share timed with
    estimated rows, the bottleneck in the family's words and the biggest stall kinds (left out when
    the table would not fit `width` columns: the bottleneck names the biggest)."""
    cols = ("cpu", "cycles", "instr", "uops", "IPC", "est.", "bottleneck", "main stalls (cycles)")
    rows = []
    for t in timings:
        p = t.per_iteration
        stalls = sorted(((p[k], label) for k, label in stall_labels(t.result, p) if p[k]),
                        key=lambda x: -x[0])[:3]  # the family's words, as `retrosim time` names them
        rows.append((escape(t.cpu), f"{t.cycles_per_iteration:.2f}", f"{p['instructions']:g}",
                     f"{t.uops_per_iteration:g}",
                     f"{p['instructions'] / t.cycles_per_iteration:.2f}" if t.cycles_per_iteration else "-",
                     f"{100 * caveats(t.result)['estimated_share']:.0f}%", escape(bottleneck(t.result, p)),
                     ", ".join(f"{what} {v:g}" for v, what in stalls) or "none"))
    # a preset's name whole; a longer machine label (k6-233{write_allocate.mode=full}) folds
    name_width = min(20, max((len(t.cpu) for t in timings), default=3))

    def build(n: int) -> Table:
        table = Table(title=escape(title))
        for col in cols[:n]:
            table.add_column(col, justify="left" if col in ("cpu", "bottleneck", "main stalls (cycles)") else "right",
                             overflow="fold", min_width=name_width if col == "cpu" else None)
        for row in rows:
            table.add_row(*row[:n])
        return table

    full = build(len(cols))
    return full if natural_width(full) <= width else build(len(cols) - 1)


def pressure_tables(timings) -> list[tuple[str, Table]]:
    """Resource pressure per iteration: one table per family (its ports, units or pipes as columns),
    one row per CPU of that family, then the ops that ran on no unit (an FXCH the P6 renames away,
    ...) when there are any, and the total (the ops per iteration), each after its heading line (a
    title would wrap at the narrow table's width)."""
    groups: dict[str, list] = {}
    for t in timings:
        groups.setdefault(t.result.model.family, []).append(t)
    out = []
    for ts in groups.values():
        view = family_view(ts[0].result)
        rows = [(t.cpu, resource_pressure(t.result, t.per_iteration), t.uops_per_iteration) for t in ts]
        units = list(rows[0][1])
        rest = [round(ops - sum(p.values()), 4) for _, p, ops in rows]
        table = Table(box=box.SIMPLE_HEAD)
        table.add_column("cpu", overflow="fold")
        for u in units + (["no unit"] if any(rest) else []) + ["total"]:
            table.add_column(escape(u), justify="right", no_wrap=True)
        for (cpu, pressure, ops), r in zip(rows, rest):
            table.add_row(escape(cpu), *(f"{pressure[u]:g}" for u in units), *([f"{r:g}"] if any(rest) else []),
                          f"{ops:g}")
        out.append((f"resource pressure: {view.pressure_heading}, per iteration", table))
    return out
