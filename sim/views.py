"""Views of a timing run: summary, per-instruction table (explain), timeline. Views only read the
model's counters; they never change a simulation (the llvm-mca split)."""

from __future__ import annotations

import numpy as np
from rich.markup import escape  # file names are shown literally, brackets included
from rich.table import Table

from .cpus import p6_core as core
from .cpus.lowering import DEC_COMPLEX, DEC_MSROM, DEC_SIMPLE
from .timing import TimingResult

STALLS = ("stall_decode", "stall_fetch", "stall_mispredict", "stall_rob", "stall_rs", "stall_store_buffer",
          "stall_partial_register", "stall_partial_flags", "stall_dependency", "stall_port", "stall_memory",
          "stall_store_forward")


def summary(result: TimingResult) -> dict:
    """The last call's counters plus derived figures, as one flat dict (the JSON of `retrosim time`)."""
    c = dict(result.last)
    d = {"cpu": result.cpu, "memory": result.memory, "source": str(result.source), "entry": result.entry,
         "repeat": result.repeat, **c}
    d["ipc"] = round(c["instructions"] / c["cycles"], 4) if c["cycles"] else 0.0
    d["uops_per_cycle"] = round(c["uops"] / c["cycles"], 4) if c["cycles"] else 0.0
    d["l1d_misses"] = c["l1d_load_misses"] + c["l1d_store_misses"]
    d["l1d_hits"] = c["l1d_loads"] + c["l1d_stores"] - d["l1d_misses"]
    d["l2_hits"] = c["l2_accesses"] - c["l2_misses"]
    d["dram_cycles"] = c["dram_bus_cycles"]
    return d


def summary_table(result: TimingResult) -> Table:
    s = summary(result)
    t = Table(title=f"{escape(result.source.name)}:{result.entry} on {result.cpu} with {result.memory} "
                    f"(call {result.repeat} of {result.repeat})", show_header=False)
    t.add_column(style="bold")
    t.add_column(justify="right")
    t.add_column()
    t.add_row("cycles", f"{s['cycles']:,}", f"IPC {s['ipc']:.2f}, {s['uops_per_cycle']:.2f} uops/cycle")
    t.add_row("instructions", f"{s['instructions']:,}", "")
    t.add_row("uops", f"{s['uops']:,}", f"{s['msrom_uops']:,} from the microcode sequencer")
    t.add_row("decode groups", f"{s['decode_groups']:,}",
              f"decoder 0/1/2: {s['decoder0']:,} / {s['decoder1']:,} / {s['decoder2']:,}")
    t.add_row("port uops", "", "  ".join(f"p{p} {s[f'port{p}']:,}" for p in range(5)))
    t.add_row("branches", f"{s['branches']:,}", f"{s['mispredicts']:,} mispredicted")
    t.add_row("L1D", f"{s['l1d_loads'] + s['l1d_stores']:,}",
              f"loads {s['l1d_loads']:,} ({s['l1d_load_misses']:,} miss), stores {s['l1d_stores']:,} "
              f"({s['l1d_store_misses']:,} miss)")
    t.add_row("L2", f"{s['l2_accesses']:,}", f"{s['l2_misses']:,} miss")
    t.add_row("DRAM", f"{s['dram_fills']:,}", f"line fills, {s['dram_writebacks']:,} writebacks, "
                                             f"{s['dram_cycles']:,} bus-busy core cycles")
    t.add_row("L1I misses", f"{s['l1i_misses']:,}", "")
    stalls = [(k, s[k]) for k in STALLS if s[k]]
    t.add_row("stall cycles", "", "  ".join(f"{k[6:].replace('_', ' ')} {v:,}" for k, v in stalls) or "none")
    return t


def explain_rows(result: TimingResult) -> list[dict]:
    """One row per static instruction executed in the last call, in address order."""
    run = result.run
    rows = []
    for sid in np.argsort([r.pc for r in run.program.records]):
        v = run.per_static[sid]
        n = int(v[core.S_EXECUTIONS])
        if n == 0:
            continue
        rec = run.program.records[sid]
        match = run.program.matches[sid]
        dec = int(run.program.s_dec[sid])
        slots = [int(v[core.S_DECODER0 + k]) for k in range(3)]
        decoder = "MS" if dec == DEC_MSROM else "/".join(f"D{k}" for k in range(3) if slots[k]) or "-"
        per = lambda key: round(float(v[key]) / n, 2)  # noqa: E731
        rows.append({
            "pc": rec.pc, "instruction": f"{rec.mnemonic} {rec.op_str}".strip(), "executions": n,
            "decoder": decoder, "decoder_class": {DEC_SIMPLE: "simple", DEC_COMPLEX: "complex",
                                                  DEC_MSROM: "msrom"}[dec],
            "uops": int(run.program.s_nuops[sid]),
            "ports": " ".join(f"p{p}:{per(core.S_PORT0 + p):g}" for p in range(5) if v[core.S_PORT0 + p]),
            "issue_to_retire": per(core.S_ISSUE_TO_RETIRE),
            "stall_dependency": per(core.S_STALL_DEPENDENCY), "stall_port": per(core.S_STALL_PORT),
            "stall_decode": per(core.S_STALL_DECODE), "stall_partial": per(core.S_STALL_PARTIAL),
            "stall_memory": per(core.S_STALL_MEMORY), "stall_store_forward": per(core.S_STALL_STORE_FORWARD),
            "stall_window": per(core.S_STALL_WINDOW), "mispredict_rate": per(core.S_MISPREDICTS),
            "l1d_miss_rate": per(core.S_L1D_MISSES),
            "row": match.describe(), "source": match.row.source, "estimated": match.row.estimated,
        })
    return rows


def explain_table(result: TimingResult) -> Table:
    t = Table(title=f"{escape(result.source.name)}:{result.entry} on {result.cpu}: per instruction, last call "
                    "(stall columns are cycles per execution)")
    cols = [("pc", "right"), ("instruction", "left"), ("runs", "right"), ("dec", "left"), ("uops", "right"),
            ("ports", "left"), ("iss->ret", "right"), ("dep", "right"), ("port", "right"), ("decode", "right"),
            ("partial", "right"), ("mem", "right"), ("fwd", "right"), ("window", "right"), ("mispred", "right"),
            ("table row", "left")]
    for name, justify in cols:
        t.add_column(name, justify=justify)
    z = lambda x: f"{x:g}" if x else ""  # noqa: E731
    for r in explain_rows(result):
        t.add_row(f"{r['pc']:#x}", r["instruction"], f"{r['executions']:,}", r["decoder"], str(r["uops"]), r["ports"],
                  f"{r['issue_to_retire']:g}", z(r["stall_dependency"]), z(r["stall_port"]), z(r["stall_decode"]),
                  z(r["stall_partial"]), z(r["stall_memory"]), z(r["stall_store_forward"]), z(r["stall_window"]),
                  z(r["mispredict_rate"]), r["row"] + (" (est.)" if r["estimated"] else ""))
    return t


def timeline_rows(result: TimingResult) -> list[dict]:
    run = result.run
    out = []
    for row in run.timeline:
        sid = int(row[1])
        rec = run.program.records[sid]
        out.append({"insn": int(row[0]), "pc": rec.pc, "instruction": f"{rec.mnemonic} {rec.op_str}".strip(),
                    **{name: int(row[k]) for k, name in enumerate(core.T_NAMES) if k >= 2 and name != "cause"},
                    "cause": core.CAUSES[int(row[7])]})
    return out


def timeline_text(result: TimingResult, width: int = 72) -> str:
    """llvm-mca style: D decode, R rename, = waiting, E executing, - done, C retire."""
    rows = timeline_rows(result)
    if not rows:
        return ""
    base = min(r["decode"] for r in rows)
    lines = [f"cycle 0 = {base}; D decode, R rename, = wait in RS, E execute, - done, C retire"]
    for r in rows:
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
        cause = "" if r["cause"] == "none" else f"  [{r['cause']}]"
        lines.append(f"{''.join(cells).rstrip():<{width}} {r['instruction']}{cause}")
    return "\n".join(lines)
