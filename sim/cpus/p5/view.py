"""The P5's view: two in-order pipes (U and V) and pairing, its own stall counters (AGI, prefix,
x87, write buffer, ...) and, per instruction, the pipe it ran in and why it ran alone. The
reports show a P5 run in these words (sim/cpus/view.py says what a view gives)."""

from __future__ import annotations

from sim.cpus.lowering import GPRS
from sim.cpus.p5 import core
from sim.cpus.view import Column, FamilyView, TableSpec, blank_zero as _z, executed_statics


class P5View(FamilyView):
    pipe_names = ("U", "V")
    # the stall counters `time` and `loop` list for a P5 run, in its own words (not the P6 aliases)
    stall_counters = ("stall_agi", "stall_prefix", "stall_fpu", "stall_memory", "stall_misaligned", "stall_bank",
                      "stall_write_buffer", "stall_fetch", "stall_mispredict")
    # bottleneck words of the stall counters whose label alone says too little
    stall_words = {"stall_write_buffer": "write buffer full", "stall_agi": "AGI: an address register written "
                   "the clock before", "stall_bank": "cache bank conflicts between the U and V pipes"}
    reasons = core.REASONS
    # timeline words: a row's cause is why its instruction ran alone ("none" when it paired)
    # short forms of core.REASONS, so a timeline line fits 80 columns (the long forms are in the
    # "alone because" column)
    timeline_causes = ("none",) + tuple("alone: " + r for r in (
        "NP", "PV class in U", "next's class", "RAW", "WAW", "flags", "disp+imm", "prefix", "first run",
        "x87, no FXCH", "MMX unit", "MMX mem in U", "branch"))
    timeline_legend = ("D the previous group left the pipe, R issue (after AGI, prefix, x87 waits), E execute, "
                       "C done; in-order U/V pipes; [alone: ...] why it did not pair (in full under 'alone because')")
    timeline_cause_words = ""  # the legend says what [alone: ...] means
    explain_columns = (("pc", "right"), ("instruction", "left"), ("runs", "right"), ("class", "left"),
                       ("U", "right"), ("V", "right"), ("clk", "right"), ("agi", "right"), ("pfx", "right"),
                       ("fpu", "right"), ("mem", "right"), ("mis", "right"), ("bank", "right"), ("wbuf", "right"),
                       ("mispred", "right"), ("alone because", "left"), ("table row", "left"))

    def summary_fields(self) -> dict:
        return {"pipes": list(self.pipe_names)}

    def summary_rows(self, s: dict, model) -> list[tuple[str, str, str]]:
        """(label, value, detail) rows of `retrosim time` for a P5 run."""
        stalls = [(k, s[k]) for k in self.stall_counters if s[k]]
        alone = sorted(((s[f"alone_{j}"], name) for j, name in enumerate(core.REASONS) if j and s[f"alone_{j}"]),
                       reverse=True)
        return [
            ("cycles", f"{s['cycles']:,}", f"IPC {s['ipc']:.2f}"),
            ("instructions", f"{s['instructions']:,}", f"{s['pairs']:,} U/V pairs, {s['alone']:,} alone"),
            ("pipes", "", f"U {s['u_pipe']:,}  V {s['v_pipe']:,}"),
            ("ran alone because", "", "; ".join(f"{name} {v:,}" for v, name in alone) or "-"),
            ("branches", f"{s['branches']:,}", f"{s['mispredicts']:,} mispredicted"),
            ("L1D", f"{s['l1d_loads'] + s['l1d_stores']:,}",
             f"loads {s['l1d_loads']:,} ({s['l1d_load_misses']:,} miss), stores {s['l1d_stores']:,} "
             f"({s['l1d_store_misses']:,} miss, no allocation: {s['bus_writes']:,} bus writes)"),
            ("L2 (board)", f"{s['l2_accesses']:,}", f"{s['l2_misses']:,} miss"),
            ("DRAM", f"{s['dram_fills']:,}", f"line fills, {s['dram_writebacks']:,} writebacks, "
                                             f"{s['dram_bus_cycles']:,} bus-busy core cycles; fills on an open DRAM page "
                                             f"{s.get('dram_page_hits', 0):,}, page misses {s.get('dram_page_misses', 0):,}"),
            ("data TLB", f"{s.get('dtlb_misses', 0):,}", "misses (each a page walk: two page-table reads through the data caches)"),
            ("L1I misses", f"{s['l1i_misses']:,}", ""),
            ("stall cycles", "", "  ".join(f"{k[6:].replace('_', ' ')} {v:,}" for k, v in stalls) or "none"),
        ]

    def stall_labels(self, counters: dict) -> list[tuple[str, str]]:
        return [(k, k[6:].replace("_", " ")) for k in self.stall_counters if k in counters]

    def resource_pressure(self, counters: dict) -> dict[str, float]:
        """Instructions per pipe: every instruction issues in U or V."""
        return {"U": counters.get("u_pipe", 0), "V": counters.get("v_pipe", 0)}

    pressure_heading = "instructions per pipe"

    def counter_words(self, counters: dict) -> dict[str, str]:
        """Every family's, with pipes and pairing for ports and ops (a P5 instruction is its op)."""
        words = {k: w for k, w in super().counter_words(counters).items() if k != "uops" and not k.startswith("port")}
        words.update({"pairs": "U/V pairs", "alone": "instructions alone", "u_pipe": "U pipe", "v_pipe": "V pipe",
                      "bus_writes": "bus writes"})
        return {k: w for k, w in words.items() if k in counters}

    def bottleneck(self, counters: dict) -> str:
        """Pairing when more instructions ran alone than any stall kind cost cycles ("U/V pairing:
        2 of 4 alone"), else the stall kind with the most cycles ("write buffer full")."""
        stalls = [(counters[k], k) for k in self.stall_counters if counters.get(k)]
        alone, n = counters.get("alone", 0), counters.get("instructions", 0)
        top = max(stalls, default=(0, ""))
        if alone and alone >= top[0]:
            return f"U/V pairing: {alone:g} of {n:g} alone"
        if not top[0]:
            # nothing alone, no stall: the instructions' own clocks (a load-op's 2, ...) set the pace
            groups = counters.get("pairs", 0) + alone
            extra = counters.get("cycles", 0) - groups
            return f"all paired; multi-clock instructions +{extra:g}" if groups and extra > 0 \
                else "all paired, a pair per clock" if groups else "none"
        return self.stall_words.get(top[1], top[1][6:].replace("_", " "))

    def explain_rows(self, result) -> list[dict]:
        """One row per static instruction of the last call, in address order: the pipe it ran in,
        clocks per execution of the groups it started, stalls, and why it ran alone."""
        run = result.run
        rows = []
        for sid, v, n, rec, match in executed_statics(run, core.S_EXEC):
            per = lambda key: round(float(v[key]) / n, 2)  # noqa: E731
            why = []
            for j in range(1, core.NR):
                c = int(v[core.S_REASON0 + j])
                if c:
                    text = core.REASONS[j]
                    if j in (core.R_RAW, core.R_WAW):
                        reg = int(v[core.S_REASON_REG])
                        text += f": {GPRS[reg]}" if 0 <= reg < 8 else ""
                    why.append(f"{text} ({c:,})")
            alone = int(sum(v[core.S_REASON0 + j] for j in range(1, core.NR)))
            rows.append({
                "pc": rec.pc, "instruction": f"{rec.mnemonic} {rec.op_str}".strip(), "executions": n,
                "class": run.static.classes[sid] if run.static else "", "u_pipe": int(v[core.S_U]),
                "v_pipe": int(v[core.S_V]), "paired_as_u": int(v[core.S_PAIRED_U]), "alone": alone,
                "group_cycles": per(core.S_CYCLES), "stall_agi": per(core.S_AGI), "stall_prefix": per(core.S_PREFIX),
                "stall_fpu": per(core.S_FPU), "stall_memory": per(core.S_MEMORY),
                "stall_misaligned": per(core.S_MISALIGNED), "stall_bank": per(core.S_BANK),
                "stall_write_buffer": per(core.S_WB), "mispredict_rate": per(core.S_MISPREDICTS),
                "l1d_miss_rate": per(core.S_L1D_MISSES), "alone_because": "; ".join(why),
                "row": match.describe(), "source": match.row.source, "estimated": match.row.estimated,
            })
        return rows

    def explain_cells(self, r: dict) -> list[str]:
        return [f"{r['pc']:#x}", r["instruction"], f"{r['executions']:,}", r["class"], f"{r['u_pipe']:,}",
                f"{r['v_pipe']:,}", _z(r["group_cycles"]), _z(r["stall_agi"]), _z(r["stall_prefix"]), _z(r["stall_fpu"]),
                _z(r["stall_memory"]), _z(r["stall_misaligned"]), _z(r["stall_bank"]), _z(r["stall_write_buffer"]),
                _z(r["mispredict_rate"]), r["alone_because"], r["row"] + (" (est.)" if r["estimated"] else "")]

    def explain_tables(self, rows: list[dict]) -> list[list[TableSpec]]:
        """One table when it fits, else three keyed by the instruction: pipes, stall columns,
        reasons and table rows."""
        cols = [Column(name, justify, no_wrap=name not in ("instruction", "alone because", "table row"),
                       overflow="fold") for name, justify in self.explain_columns]
        cells = [self.explain_cells(r) for r in rows]

        def build(idx: list[int], title: str) -> TableSpec:
            return TableSpec(title, [cols[i] for i in idx], [[c[i] for i in idx] for c in cells])

        names = [c.name for c in cols]
        instr = [names.index("instruction")]
        text = [i for i, name in enumerate(names) if name in ("alone because", "table row")]
        rest = [i for i in range(7, len(cols)) if i not in text]
        return [[build(list(range(len(cols))), "per instruction, last call (stall columns: cycles per execution)")],
                [build(list(range(7)), "per instruction, last call: pipes"),  # no stall column here
                 build(instr + rest, "stall cycles per execution"),
                 build(instr + text, "why it ran alone, and the table row used")]]

    def loop_tables(self, rows: list[dict], cpu: str) -> list[list[TableSpec]]:
        """The explain tables (a P5 loop body needs its pipes and reasons), each naming the CPU and
        the measured iterations."""
        forms = self.explain_tables(rows)
        for form in forms:
            for part in form:
                part.title = f"{cpu}: {part.title.replace('last call', 'measured iterations')}"
        return forms

    def page_words(self, timeline: list[dict], instructions: list[dict]) -> dict:
        return {
            "causes": [[c, "paired in the U/V pipes" if i == 0 else f"ran alone in the U pipe: {self.reasons[i]}"
                        if i < len(self.reasons) else c] for i, c in enumerate(self.timeline_causes)],
            "units": "U/V pipes",
            "op": "instruction",
            "lanes": lanes(timeline),
            "show_units": False,
            "calm": "paired",
            "causes_heading": "why it ran alone: ",
            "columns": [["instruction", "instruction"], ["class", "class"], ["U", "u_pipe"], ["V", "v_pipe"],
                        ["clk", "group_cycles"], ["alone because", "alone_because"], ["table row", "row"]],
            "tip": [["class {class}; U pipe {u_pipe}, V pipe {v_pipe}; clocks per group {group_cycles}", ""],
                    ["ran alone because: {alone_because}", "alone_because"]],
            "notes": ["In-order U and V pipes: two instructions issued in one clock paired (the first in U, "
                      "the second in V); one issued alone ran in U, and its colour says why it did not pair."],
            "stalls": self.page_stalls(),
            "stalls_heading": "main stall (clocks per execution)",
        }

    def page_stalls(self) -> list[list[str]]:
        """The P5's stall columns of an explain row in its words (a pair's bank conflict and AGI are
        the pair's first instruction's; a store's wait for the write buffer is the store's)."""
        own = {"stall_prefix": "prefix decode", "stall_fpu": "x87 wait", "stall_memory": "memory: a miss beyond L1",
               "stall_misaligned": "misaligned access", **self.stall_words}
        return [[k, own.get(k, k[6:].replace("_", " "))] for k in self.stall_counters
                if k not in ("stall_fetch", "stall_mispredict")]  # counted per run, not per instruction


def lanes(rows: list[dict]) -> list[str]:
    """The pipe of each timeline row, as the P5 core records a group: the two instructions of a
    pair share their issue clock (and are the only rows with cause 'none'), the first in U, the
    second in V; an instruction issued alone runs in U."""
    out = [""] * len(rows)
    i = 0
    while i < len(rows):
        r = rows[i]
        if r["cause"] != "none":
            out[i] = "U"
        elif i + 1 < len(rows) and rows[i + 1]["cause"] == "none" and rows[i + 1]["alloc"] == r["alloc"]:
            out[i], out[i + 1] = "U", "V"
            i += 1
        else:  # the other half of the pair is outside the recorded window
            out[i] = "V" if i == 0 else "U"
        i += 1
    return out
