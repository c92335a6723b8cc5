"""Views of a timing run: summary, per-instruction table (explain), timeline. Views only read the
model's counters; they never change a simulation (the llvm-mca split)."""

from __future__ import annotations

import io
import re

import numpy as np
from rich import box
from rich.markup import escape
from rich.table import Table

from sim.cpus import contract as core  # the counter, per-instruction and timeline schemas
from sim.cpus import vocabulary
from sim.cpus.vocabulary import STALL_KINDS, Vocabulary
from sim.cpus.lowering import DEC_COMPLEX, DEC_MSROM, DEC_SIMPLE
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
    if hasattr(result.model, "summary_rows"):  # a family with its own vocabulary (the P5's pipes)
        d["pipes"] = list(result.model.pipe_names)
    d["l1d_misses"] = c["l1d_load_misses"] + c["l1d_store_misses"]
    d["l1d_hits"] = c["l1d_loads"] + c["l1d_stores"] - d["l1d_misses"]
    d["l2_hits"] = c["l2_accesses"] - c["l2_misses"]
    d["dram_cycles"] = c["dram_bus_cycles"]
    return d


def _vocab(result: TimingResult) -> Vocabulary:
    return vocabulary.of(result.model)


def _has_l2(result: TimingResult) -> bool:
    return getattr(getattr(result.model, "preset", None), "l2", True) is not None


# Stall counters of the summary: (counter, label); the help comes from the family's vocabulary.
_SUMMARY_STALLS = (("stall_dependency", "dependency", "dependency"), ("stall_port", "port", "port"),
                   ("stall_decode", "decode", "decode"), ("stall_fetch", "fetch", None),
                   ("stall_mispredict", "branch", "mispredict"), ("stall_rob", "window", "window"),
                   ("stall_rs", "window (RS)", "window"), ("stall_store_buffer", "store buffer", None),
                   ("stall_partial_register", "partial", "partial"), ("stall_partial_flags", "partial flags", None),
                   ("stall_memory", "memory", "memory"), ("stall_store_forward", "forward", "store_forward"),
                   ("stall_register_read", "register read", None))
_OTHER_STALL_HELP = {"stall_fetch": "decoders idle for instruction bytes (L1I miss, branch-target miss)",
                     "stall_store_buffer": "waiting for a free store-buffer entry",
                     "stall_partial_flags": "reading flags after an instruction that writes only some of them",
                     "stall_rs": "waiting for a free reservation-station entry",
                     "stall_register_read": "renaming held: more than two reads per clock of registers not "
                                            "written recently (P6 permanent register file)"}


def summary_table(result: TimingResult) -> Table:
    """The last call's counters in the family's words: rows of (what, count, detail)."""
    s, v = summary(result), _vocab(result)
    t = Table(title=escape(f"{result.source.name}:{result.entry} on {result.cpu} with {result.memory} "
                           f"(call {result.repeat} of {result.repeat})"), show_header=False, box=box.SIMPLE)
    t.add_column(style="bold", no_wrap=True)
    t.add_column(justify="right", no_wrap=True)
    t.add_column(overflow="fold")
    if hasattr(result.model, "summary_rows"):  # the model names its own pipes and counters (P5)
        for row in result.model.summary_rows(s):
            t.add_row(*row)
        return t
    ops = v.op + "s"
    t.add_row("cycles", f"{s['cycles']:,}", f"{s['ipc']:.2f} instructions and {s['uops_per_cycle']:.2f} {ops} per cycle")
    t.add_row("instructions", f"{s['instructions']:,}", "")
    t.add_row(ops, f"{s['uops']:,}", f"{s['msrom_uops']:,} {v.sequencer}")
    used = [(name, s[f"decoder{k}"]) for k, name in enumerate(v.decoders) if name]
    t.add_row("decode", f"{s['decode_groups']:,}", f"{v.group}; " + ", ".join(f"{n} {c:,}" for n, c in used))
    units = [(v.port_label(k), s[f"port{k}"]) for k in range(5)] + [(n, s[c]) for c, n in v.extra_units if c in s]
    t.add_row(v.unit + "s", "", "  ".join(f"{n} {c:,}" for n, c in units))
    t.add_row("branches", f"{s['branches']:,}", f"{s['mispredicts']:,} mispredicted "
                                                f"(branch stall cycles: {s['stall_mispredict']:,}, see below)")
    t.add_row("L1D", f"{s['l1d_loads'] + s['l1d_stores']:,}",
              f"loads {s['l1d_loads']:,} ({s['l1d_load_misses']:,} miss), stores {s['l1d_stores']:,} "
              f"({s['l1d_store_misses']:,} miss)")
    if _has_l2(result):
        where = str(getattr(result.model.preset, "raw", {}).get("l2", {}).get("location", ""))
        t.add_row("L2 (board)" if "motherboard" in where else "L2", f"{s['l2_accesses']:,}", f"{s['l2_misses']:,} miss")
    else:
        t.add_row("L2", "", "no L2 (L1 misses go to memory)")
    if s.get("l3_accesses") or getattr(getattr(result.model, "preset", None), "board_cache", None):
        t.add_row("L3 (board)", f"{s.get('l3_accesses', 0):,}", f"{s.get('l3_misses', 0):,} miss")
    t.add_row("DRAM", f"{s['dram_fills']:,}", f"line fills, {s['dram_writebacks']:,} writebacks, "
                                             f"{s['dram_cycles']:,} bus-busy core cycles; fills on an open DRAM page "
                                             f"{s.get('dram_page_hits', 0):,}, page misses {s.get('dram_page_misses', 0):,}")
    t.add_row("data TLB", f"{s.get('dtlb_misses', 0):,}", "misses (each a page walk: two page-table reads through the data caches)")
    t.add_row("L1I misses", f"{s['l1i_misses']:,}", "")
    return t


def stall_labels(result: TimingResult, counters: dict) -> list[tuple[str, str]]:
    """(counter, label) of the stall kinds in `counters`, in the words `retrosim time` uses for the
    family: the P5's own (agi, prefix, write buffer, ...), else the summary's (window, branch, ...;
    "window (RS)" only when the reorder buffer's and the reservation station's are told apart)."""
    own = getattr(result.model, "stall_counters", None)
    if own:
        return [(k, k[6:].replace("_", " ")) for k in own if k in counters]
    return [(k, "window (ROB)" if k == "stall_rob" and counters.get("stall_rs") else label)
            for k, label, _ in _SUMMARY_STALLS if k in counters]


def stall_table(result: TimingResult) -> Table:
    """Stall cycles of the last call by kind, each with what it counts in this family."""
    s, v = summary(result), _vocab(result)
    t = Table(title="stall cycles by kind (they overlap: they do not add up to the cycle count)",
              box=box.SIMPLE, show_header=True)
    t.add_column("kind", no_wrap=True)
    t.add_column("cycles", justify="right", no_wrap=True)
    t.add_column("what it counts", overflow="fold")
    for counter, label, kind in _SUMMARY_STALLS:
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
    if hasattr(result.model, "explain_rows"):  # a family with rows of its own (the P5: pipes, pairing)
        return result.model.explain_rows(result)
    run, v = result.run, _vocab(result)
    rows = []
    for sid in np.argsort([r.pc for r in run.program.records]):
        st = run.per_static[sid]
        n = int(st[core.S_EXECUTIONS])
        if n == 0:
            continue
        rec = run.program.records[sid]
        match = run.program.matches[sid]
        dec = int(run.program.s_dec[sid])
        cls = {DEC_SIMPLE: 0, DEC_COMPLEX: 1, DEC_MSROM: 2}[dec]
        slots = [int(st[core.S_DECODER0 + k]) for k in range(3)]
        decoder = v.class_marks[cls] or "/".join(v.slot_marks[k] for k in range(3) if slots[k] and v.slot_marks[k]) or "-"
        per = lambda key: round(float(st[key]) / n, 2)  # noqa: E731
        rows.append({
            "pc": rec.pc, "instruction": f"{rec.mnemonic} {rec.op_str}".strip(), "executions": n,
            "decoder": decoder, "decoder_class": v.classes[cls],
            "uops": int(run.program.s_nuops[sid]),
            "ports": " ".join(f"{v.port_label(p)}:{per(core.S_PORT0 + p):g}" for p in range(5)
                              if st[core.S_PORT0 + p]),
            "issue_to_retire": per(core.S_ISSUE_TO_RETIRE),
            "stall_dependency": per(core.S_STALL_DEPENDENCY), "stall_port": per(core.S_STALL_PORT),
            "stall_decode": per(core.S_STALL_DECODE), "stall_partial": per(core.S_STALL_PARTIAL),
            "stall_memory": per(core.S_STALL_MEMORY), "stall_store_forward": per(core.S_STALL_STORE_FORWARD),
            "stall_window": per(core.S_STALL_WINDOW), "stall_mispredict": per(core.S_STALL_MISPREDICT),
            "mispredict_rate": per(core.S_MISPREDICTS), "l1d_miss_rate": per(core.S_L1D_MISSES),
            "row": match.describe(), "source": match.row.source, "estimated": match.row.estimated,
        })
    return rows


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
    sim/cpus/tables/, and the rows whose behaviour the model does not implement (:func:`row_limits`)."""
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


def _table(title: str | None = None) -> Table:
    # light borders: the width goes to the cells, not to box drawing
    return Table(title=title, box=box.SIMPLE_HEAD, pad_edge=False, title_justify="left")


def explain_tables(result: TimingResult, width: int) -> list[Table]:
    """The per-instruction table: one table when `width` columns hold it, else three narrower ones
    (decode and execution; stall cycles; the instruction-table rows), each keyed by the instruction."""
    v = _vocab(result)
    rows = explain_rows(result)
    model = result.model
    if hasattr(model, "explain_cells"):  # a family with its own columns (the P5: pipes, pairing)
        return _model_explain_tables(model, rows, width)
    z = lambda x: f"{x:g}" if x else ""  # noqa: E731
    ops = "uops" if v.op == "uop" else "ops"
    units = v.unit + "s"
    stalls = [(f"stall_{k}", title) for k, title in STALL_KINDS]
    shown = [(k, title) for k, title in stalls if any(r[k] for r in rows)]
    row_text = lambda r: escape(r["row"] + (" (est.)" if r["estimated"] else ""))  # noqa: E731

    def build(parts: list[str], stall_cols, title: str) -> Table:
        t = _table(title)
        spec = {"pc": ("pc", "right"), "instruction": ("instruction", "left"), "runs": ("runs", "right"),
                "dec": ("dec", "left"), "ops": (ops, "right"), "units": (units, "left"),
                "i2r": ("iss->ret", "right"), "mispred": ("mispred", "right"), "row": ("table row", "left")}
        for p in parts:
            if p == "stalls":
                for _, col in stall_cols:
                    t.add_column(col, justify="right", no_wrap=True)
            else:
                name, justify = spec[p]
                t.add_column(name, justify=justify, overflow="fold",
                             no_wrap=p not in ("instruction", "units", "row"))
        for r in rows:
            cells = []
            for p in parts:
                if p == "stalls":
                    cells += [z(r[k]) for k, _ in stall_cols]
                else:
                    cells.append({"pc": f"{r['pc']:#x}", "instruction": escape(r["instruction"]),
                                  "runs": f"{r['executions']:,}", "dec": r["decoder"], "ops": str(r["uops"]),
                                  "units": r["ports"], "i2r": f"{r['issue_to_retire']:g}",
                                  "mispred": z(r["mispredict_rate"]), "row": row_text(r)}[p])
            t.add_row(*cells)
        return t

    head = "per instruction, last call"
    wide = build(["pc", "instruction", "runs", "dec", "ops", "units", "i2r", "stalls", "mispred", "row"], stalls,
                 head + " (stall columns: cycles per execution)")
    if natural_width(wide) <= width:
        return [wide]
    return [build(["pc", "instruction", "runs", "dec", "ops", "units", "i2r"], [], head + ": decode and execution"),
            build(["instruction", "stalls", "mispred"], shown,
                  "stall cycles per execution" + ("" if len(shown) == len(stalls) else
                                                  " (kinds with no stall left out)")),
            build(["instruction", "row"], [], "instruction-table rows used")]


def _model_explain_tables(model, rows: list[dict], width: int) -> list[Table]:
    """A family's own columns (model.explain_columns / explain_cells): one table when it fits, else
    three keyed by the instruction: pipes, stall columns, reasons and table rows."""
    cols = list(model.explain_columns)
    cells = [[escape(c) for c in model.explain_cells(r)] for r in rows]  # '[ebx]' is not markup

    def build(idx: list[int], title: str) -> Table:
        t = _table(title)
        for i in idx:
            name, justify = cols[i]
            t.add_column(name, justify=justify, overflow="fold",
                         no_wrap=name not in ("instruction", "alone because", "table row"))
        for c in cells:
            t.add_row(*(c[i] for i in idx))
        return t

    head = "per instruction, last call (stall columns: cycles per execution)"
    wide = build(list(range(len(cols))), head)
    if natural_width(wide) <= width:
        return [wide]
    instr = [i for i, (name, _) in enumerate(cols) if name == "instruction"]
    text = [i for i, (name, _) in enumerate(cols) if name in ("alone because", "table row")]
    rest = [i for i in range(7, len(cols)) if i not in text]
    return [build(list(range(min(7, len(cols)))), "per instruction, last call: pipes"),  # no stall column here
            build(instr + rest, "stall cycles per execution"),
            build(instr + text, "why it ran alone, and the table row used")]


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
    table = getattr(result.model, "family", v.family) or "the family's"
    rows = explain_rows(result)
    kinds = [k for k, _ in STALL_KINDS if any(r.get(f"stall_{k}") for r in rows)]
    lines = [f"runs: executions in the last call. dec: {v.decode_help}.",
             f"{ops}: {v.op}s per execution. {units}: {v.op}s per execution on each ({'; '.join(v.port_help)}).",
             "iss->ret: average cycles from the instruction's first " + v.op + " issuing to its retirement.",
             "stall columns, cycles per execution: " + "; ".join(f"{col} = {v.stall_help.get(k, '')}"
                                                                  for k, col in STALL_KINDS if k in kinds) + ".",
             "mispred: mispredictions per execution. " + (v.mispredict_note + "." if v.mispredict_note else ""),
             f"table row: the row of sim/cpus/tables/{table}.toml used (a -> b: looked up as a, found as b); "
             "(est.): that row's figures are estimates, not measurements (its source is in --json).",
             f"timeline: {timeline_key(result)}; [cause]: what held the instruction back, a wait to issue before a wait to enter the window (names as in the stall columns)."]
    return lines


def timeline_key(result: TimingResult) -> str:
    return getattr(result.model, "timeline_legend", None) or _vocab(result).timeline


def timeline_rows(result: TimingResult) -> list[dict]:
    run = result.run
    causes = getattr(result.model, "timeline_causes", core.CAUSES)  # the model's own words, if it has them
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
