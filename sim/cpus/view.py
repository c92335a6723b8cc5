"""A family's view: the words, rows and columns in which the reports show a run of its model.

:class:`FamilyView` is the family-neutral default, written for a family whose core fills the
contract's counters (sim/cpus/contract.py) and names them through a :class:`Vocabulary` (the P6
and the K6: decoders, ports or units, a window). A family with other words (the P5: two in-order
pipes, pairing) subclasses it in its own package (``sim/cpus/NAME/view.py``) and the registry
(sim/cpus/families.py) names the subclass, so the report modules ask the view and never the model
what a family looks like.

A view gives plain data (strings, rows, :class:`TableSpec`); sim/reports/views.py and
sim/reports/pipeline_html.py turn it into terminal tables and the pipeline page. It only reads a
run's records; it never times anything.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sim.cpus import contract as core  # the counter, per-instruction and timeline schemas
from sim.cpus.lowering import DEC_COMPLEX, DEC_MSROM, DEC_SIMPLE
from sim.cpus.vocabulary import GENERIC, STALL_KINDS, Vocabulary


@dataclass(frozen=True)
class Column:
    name: str
    justify: str = "left"
    no_wrap: bool | None = None   # None: rich's default
    overflow: str | None = None   # None: rich's default ("ellipsis")


@dataclass
class TableSpec:
    """A table as data: title, columns and rows of text (markup is escaped by the renderer).
    `compact`: the explain tables' light borders (the width goes to the cells)."""

    title: str
    columns: list[Column]
    rows: list[list[str]] = field(default_factory=list)
    compact: bool = True


# Stall counters of the summary: (counter, label, stall kind whose help the vocabulary gives).
SUMMARY_STALLS = (("stall_dependency", "dependency", "dependency"), ("stall_port", "port", "port"),
                  ("stall_decode", "decode", "decode"), ("stall_fetch", "fetch", None),
                  ("stall_mispredict", "branch", "mispredict"), ("stall_rob", "window", "window"),
                  ("stall_rs", "window (RS)", "window"), ("stall_store_buffer", "store buffer", None),
                  ("stall_partial_register", "partial", "partial"), ("stall_partial_flags", "partial flags", None),
                  ("stall_memory", "memory", "memory"), ("stall_store_forward", "forward", "store_forward"),
                  ("stall_register_read", "register read", None))


def blank_zero(x) -> str:
    """A table cell: the figure, or nothing for zero (so the eye finds the stalls)."""
    return f"{x:g}" if x else ""


def executed_statics(run, executions: int):
    """(id, per-static sums, executions, record, table match) of every static instruction the run
    executed, in address order; `executions` is the family's per-static column that counts them."""
    for sid in np.argsort([r.pc for r in run.program.records]):
        st = run.per_static[sid]
        n = int(st[executions])
        if n:
            yield sid, st, n, run.program.records[sid], run.program.matches[sid]


class FamilyView:
    """The family-neutral view (what every method gives unless a family's view overrides it)."""

    vocabulary: Vocabulary = GENERIC

    # ---- `retrosim time` --------------------------------------------------------------------
    def summary_fields(self) -> dict:
        """Fields the family adds to `retrosim time --json` (after uops_per_cycle)."""
        return {}

    def summary_rows(self, s: dict, model) -> list[tuple[str, str, str]]:
        """(what, count, detail) rows of `retrosim time`, from :func:`sim.reports.views.summary`."""
        v = self.vocabulary
        ops = v.op + "s"
        rows = [("cycles", f"{s['cycles']:,}", f"{s['ipc']:.2f} instructions and {s['uops_per_cycle']:.2f} {ops} per cycle"),
                ("instructions", f"{s['instructions']:,}", ""),
                (ops, f"{s['uops']:,}", f"{s['msrom_uops']:,} {v.sequencer}")]
        used = [(name, s[f"decoder{k}"]) for k, name in enumerate(v.decoders) if name]
        rows.append(("decode", f"{s['decode_groups']:,}", f"{v.group}; " + ", ".join(f"{n} {c:,}" for n, c in used)))
        units = [(v.port_label(k), s[f"port{k}"]) for k in range(5)] + [(n, s[c]) for c, n in v.extra_units if c in s]
        rows.append((v.unit + "s", "", "  ".join(f"{n} {c:,}" for n, c in units)))
        rows.append(("branches", f"{s['branches']:,}", f"{s['mispredicts']:,} mispredicted "
                                                       f"(branch stall cycles: {s['stall_mispredict']:,}, see below)"))
        rows.append(("L1D", f"{s['l1d_loads'] + s['l1d_stores']:,}",
                     f"loads {s['l1d_loads']:,} ({s['l1d_load_misses']:,} miss), stores {s['l1d_stores']:,} "
                     f"({s['l1d_store_misses']:,} miss)"))
        preset = model.preset
        if preset.l2 is not None:
            where = str(preset.raw.get("l2", {}).get("location", ""))
            rows.append(("L2 (board)" if "motherboard" in where else "L2", f"{s['l2_accesses']:,}",
                         f"{s['l2_misses']:,} miss"))
        else:
            rows.append(("L2", "", "no L2 (L1 misses go to memory)"))
        if s.get("l3_accesses") or preset.board_cache:
            rows.append(("L3 (board)", f"{s.get('l3_accesses', 0):,}", f"{s.get('l3_misses', 0):,} miss"))
        rows += [("DRAM", f"{s['dram_fills']:,}", f"line fills, {s['dram_writebacks']:,} writebacks, "
                                                 f"{s['dram_cycles']:,} bus-busy core cycles; fills on an open DRAM "
                                                 f"page {s.get('dram_page_hits', 0):,}, page misses "
                                                 f"{s.get('dram_page_misses', 0):,}"),
                 ("data TLB", f"{s.get('dtlb_misses', 0):,}",
                  "misses (each a page walk: two page-table reads through the data caches)"),
                 ("L1I misses", f"{s['l1i_misses']:,}", "")]
        return rows

    def stall_labels(self, counters: dict) -> list[tuple[str, str]]:
        """(counter, label) of the stall kinds in `counters`, in the words `retrosim time` uses
        ("window (RS)" only when the reorder buffer's and the reservation station's are told apart)."""
        return [(k, "window (ROB)" if k == "stall_rob" and counters.get("stall_rs") else label)
                for k, label, _ in SUMMARY_STALLS if k in counters]

    # bottleneck words of the stall kinds whose summary label alone says too little
    stall_words = {"stall_dependency": "dependency chain",
                   "stall_partial_register": "partial-register stalls", "stall_memory": "memory: L1 misses",
                   "stall_store_forward": "store-to-load forwarding", "stall_store_buffer": "store buffer full",
                   "stall_fetch": "instruction fetch", "stall_mispredict": "branches: front-end restarts"}

    def resource_pressure(self, counters: dict) -> dict[str, float]:
        """Ops per port or unit (llvm-mca's resource pressure), from a run's counters: per
        iteration when `counters` are a loop's per-iteration figures. Every op that executes on a
        unit is counted on one, so the figures add up to the ops less those that need no unit."""
        v = self.vocabulary
        out = {v.port_label(k): counters.get(f"port{k}", 0) for k in range(5)}
        out.update({name: counters.get(c, 0) for c, name in v.extra_units})
        return out

    def counter_words(self, counters: dict) -> dict[str, str]:
        """The counters two runs of one family are compared by (`loop A.s B.s`: those that differ
        most are named), each in the family's words; only those in `counters`."""
        v = self.vocabulary
        words = {"instructions": "instructions", "uops": v.op + "s", "mispredicts": "mispredicts",
                 "l1d_load_misses": "L1D load misses", "l1d_store_misses": "L1D store misses"}
        words.update({f"port{k}": f"{v.unit} {v.port_label(k)}" for k in range(5)})
        words.update({c: f"{v.unit} {name}" for c, name in v.extra_units})
        words.update({k: f"{label} stall" for k, label in self.stall_labels(counters)})
        return {k: w for k, w in words.items() if k in counters}

    @property
    def pressure_heading(self) -> str:
        """What the resource-pressure figures count ("uops per port")."""
        return f"{self.vocabulary.op}s per {self.vocabulary.unit}"

    def bottleneck(self, counters: dict) -> str:
        """What held the run back most, in the family's words: a port or unit busy on (nearly) every
        cycle ("ports p0 saturated": the throughput bound, which no stall counter needs to show),
        else the stall kind with the most cycles, with the units it names, or "none". `counters`: a
        run's counters (a `time` summary or a loop's per-iteration figures)."""
        v = self.vocabulary
        cycles = counters.get("cycles", 0)
        use = [(n, name) for name, n in self.resource_pressure(counters).items()]
        full = [name for n, name in use if cycles and n >= 0.95 * cycles]
        if full:
            return f"{v.unit}s {'/'.join(full)} saturated"
        stalls = [(counters[k], k, label) for k, label in self.stall_labels(counters) if counters.get(k)]
        if not stalls:
            return "none"
        _, key, label = max(stalls, key=lambda s: (s[0], s[1]))
        if key == "stall_port":
            top = max(n for n, _ in use)
            busy = [name for n, name in use if top and n >= 0.9 * top]
            return f"{v.unit}s {'/'.join(busy)} saturated"
        if key == "stall_decode":
            return f"decode: {v.decoders[0] if v.decoders else 'decoders'} busy"
        if key in ("stall_rob", "stall_rs"):
            return f"window full: {v.window}"
        return self.stall_words.get(key, label)

    # ---- `retrosim explain` -------------------------------------------------------------------
    def explain_rows(self, result) -> list[dict]:
        """One row per static instruction executed in the last call, in address order, in the
        family's words (decoder marks, port or unit names)."""
        run, v = result.run, self.vocabulary
        rows = []
        for sid, st, n, rec, match in executed_statics(run, core.S_EXECUTIONS):
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

    def explain_tables(self, rows: list[dict]) -> list[list[TableSpec]]:
        """The per-instruction table's forms, widest first: the renderer prints the first that fits
        the terminal, else the last (three narrower tables keyed by the instruction)."""
        v = self.vocabulary
        ops = "uops" if v.op == "uop" else "ops"
        stalls = [(f"stall_{k}", title) for k, title in STALL_KINDS]
        shown = [(k, title) for k, title in stalls if any(r[k] for r in rows)]
        spec = {"pc": ("pc", "right"), "instruction": ("instruction", "left"), "runs": ("runs", "right"),
                "dec": ("dec", "left"), "ops": (ops, "right"), "units": (v.unit + "s", "left"),
                "i2r": ("iss->ret", "right"), "mispred": ("mispred", "right"), "row": ("table row", "left")}

        def build(parts: list[str], stall_cols, title: str) -> TableSpec:
            cols = []
            for p in parts:
                if p == "stalls":
                    cols += [Column(col, "right", no_wrap=True) for _, col in stall_cols]
                else:
                    name, justify = spec[p]
                    cols.append(Column(name, justify, no_wrap=p not in ("instruction", "units", "row"), overflow="fold"))
            out = []
            for r in rows:
                cells = []
                for p in parts:
                    if p == "stalls":
                        cells += [blank_zero(r[k]) for k, _ in stall_cols]
                    else:
                        cells.append({"pc": f"{r['pc']:#x}", "instruction": r["instruction"],
                                      "runs": f"{r['executions']:,}", "dec": r["decoder"], "ops": str(r["uops"]),
                                      "units": r["ports"], "i2r": f"{r['issue_to_retire']:g}",
                                      "mispred": blank_zero(r["mispredict_rate"]),
                                      "row": r["row"] + (" (est.)" if r["estimated"] else "")}[p])
                out.append(cells)
            return TableSpec(title, cols, out)

        head = "per instruction, last call"
        wide = build(["pc", "instruction", "runs", "dec", "ops", "units", "i2r", "stalls", "mispred", "row"], stalls,
                     head + " (stall columns: cycles per execution)")
        return [[wide],
                [build(["pc", "instruction", "runs", "dec", "ops", "units", "i2r"], [], head + ": decode and execution"),
                 build(["instruction", "stalls", "mispred"], shown,
                       "stall cycles per execution" + ("" if len(shown) == len(stalls) else
                                                       " (kinds with no stall left out)")),
                 build(["instruction", "row"], [], "instruction-table rows used")]]

    def loop_tables(self, rows: list[dict], cpu: str) -> list[list[TableSpec]]:
        """`retrosim loop`'s per-instruction table, narrowed to what a loop body needs (fits 80
        columns for short bodies); forms as :meth:`explain_tables`."""
        names = (("stall_dependency", "dep"), ("stall_port", "port"), ("stall_decode", "decode"),
                 ("stall_partial", "partial"), ("stall_memory", "mem"), ("stall_store_forward", "fwd"),
                 ("stall_window", "window"), ("mispredict_rate", "mispred"))
        cols = [Column(c, "right" if c in ("uops", "iss>ret") else "left")
                for c in ("instruction", "dec", "uops", "ports", "iss>ret", "stalls")]
        cells = [[r["instruction"], r["decoder"], str(r["uops"]), r["ports"], f"{r['issue_to_retire']:g}",
                  " ".join(f"{short} {r[k]:g}" for k, short in names if r[k])] for r in rows]
        return [[TableSpec(f"{cpu}: per instruction, cycles per execution (full table: --json)", cols, cells,
                           compact=False)]]

    # ---- the timeline -----------------------------------------------------------------------
    @property
    def timeline_legend(self) -> str:
        return self.vocabulary.timeline

    timeline_causes: tuple[str, ...] = core.CAUSES  # a timeline row's cause, by the core's index
    # after the legend of the stage letters: what a row's [cause] says ("" when the legend says it)
    timeline_cause_words = "; [cause]: what held the instruction back (the stall columns' words)"

    # ---- the pipeline page --------------------------------------------------------------------
    def page_words(self, timeline: list[dict], instructions: list[dict]) -> dict:
        """What the pipeline page draws in this family's words: each cause's meaning, the units and
        the op, each timeline row's lane (here: the decoder mark of its instruction), the explain
        table's columns ([heading, field of an explain row]) and the tooltip lines (a template of
        explain-row fields; {field|text}: text when the field is empty; a line with a `when` field
        is shown only when that field is set)."""
        v = self.vocabulary
        decoder = {r["pc"]: r["decoder"] for r in instructions}
        return {
            "causes": [[c, "" if c == "none" else v.stall_help.get(c, c)] for c in self.timeline_causes],
            "units": f"{v.unit}s " + ", ".join(v.port_label(k) for k in range(5)) + "".join(f", {n}" for _, n in v.extra_units),
            "op": v.op,
            "lanes": [decoder.get(r["pc"], "") for r in timeline],
            "show_units": True,
            "calm": "no stall",
            "causes_heading": "stall causes: ",
            "columns": [["instruction", "instruction"], ["dec", "decoder"], [v.op + "s", "uops"],
                        [f"{v.unit}s", "ports"], ["iss->ret", "issue_to_retire"], ["table row", "row"]],
            "tip": [["decoder {decoder} ({decoder_class}), {uops} " + v.op + "(s); {ports|no unit}", ""],
                    ["issue to retire {issue_to_retire} cycles per execution", ""]],
            "notes": [n for n in (v.decode_help, "; ".join(v.port_help), f"window: {v.window}") if n],
            "stalls": self.page_stalls(),
            "stalls_heading": "main stall (cycles per execution)",
        }

    def page_stalls(self) -> list[list[str]]:
        """[[field of an explain row, its stall in the family's words], ...]: the page marks each
        instruction with the biggest it pays (the first listed wins a tie)."""
        v = self.vocabulary
        words = {"dependency": "dependency: a source not ready", "port": f"{v.unit} busy",
                 "decode": "decode: the decoders were behind", "partial": "partial-register merge",
                 "memory": "memory: a miss beyond L1",
                 "store_forward": "store forwarding", "window": f"window full: {v.window}",
                 "mispredict": "branch restart"}
        return [[f"stall_{k}", words[k]] for k, _ in STALL_KINDS]
