"""Commands about the models themselves: cpus, validate, conformance."""

from __future__ import annotations

import json
from pathlib import Path

import click
from rich import box
from rich.table import Table

from sim.errors import ArgumentError
from sim.cli.app import REPORTS_DIR, console, err_console, main


@main.command("cpus")
@click.option("--json", "as_json", is_flag=True, help="print one JSON object")
def cpus_cmd(as_json):
    """List CPU and memory presets with their caches, clocks and default memory."""
    from sim.cpus import presets
    from sim.cpus.overrides import load_dram, memory_presets

    cpus = [presets.load(n) for n in presets.available()]
    if as_json:
        click.echo(json.dumps({"cpus": {c.name: {"family": c.family, "core_mhz": c.core_mhz, "fsb_mhz": c.fsb_mhz,
                                                 "l1i": c.l1i.describe(), "l1d": c.l1d.describe(),
                                                 "l2": c.l2.describe() if c.l2 else None,
                                                 "board_cache": c.board_cache.describe() if c.board_cache else None,
                                                 "write_allocate": write_allocate_mode(c),
                                                 "memory": c.memory} for c in cpus},
                               "memory": {m: load_dram(m).describe() for m in memory_presets()}}, indent=2))
        return
    for t in _cpu_tables(cpus, console.width):
        console.print(t)
    m = Table(title="memory presets (sources in sim/memory/presets/*.toml)", box=box.SIMPLE_HEAD,
              title_justify="left", pad_edge=False)
    for col in ("preset", "type", "burst (bus clocks)"):
        m.add_column(col, no_wrap=True)
    for name in memory_presets():
        d = load_dram(name)
        m.add_row(name, d.kind, "-".join(str(x) for x in d.burst))
    console.print(m)


def write_allocate_mode(preset) -> str:
    """The L1 data cache's write allocation, in the words of the `write_allocate.mode` override:
    "full", "page+sector only" or "none" (a loop writing fresh memory waits on the write buffer on
    all but "full": `retrosim loop --data`)."""
    return preset.data_caches()[0].write_allocate_mode


def _write_allocate_caption(cpus, modes: dict, full: bool) -> str:
    """What the presets' write allocation means for a loop, and (compact table) which presets lack it."""
    lacking = {}
    for c in cpus:
        mode = modes[c.name]
        if mode != "full":
            lacking.setdefault(mode, []).append(c.name)
    where = "" if full else " (" + "; ".join(f"{mode}: {', '.join(names)}" for mode, names in lacking.items()) + ")"
    return ("write alloc.: does the L1D allocate a line on a write miss" + where + "; where it does not, a loop "
            "writing fresh memory waits on the write buffer: see retrosim loop --data")


def _cpu_tables(cpus, width: int) -> list:
    """The presets in one wide table (every cache in full) when `width` holds it, else a compact one:
    sizes only, with the latencies and clock ratios one `--json` away."""
    from sim.reports.views import natural_width

    modes = {c.name: write_allocate_mode(c) for c in cpus}  # once per preset, for both tables

    def level(c) -> str:
        return ("board " if c.on_board else "") + f"{c.size_kb}"

    def caches(c, full: bool) -> str:
        if c.l2 is None:
            return "no L2"
        text = c.l2.describe() if full else level(c.l2)
        if not full and c.l2.speed_ratio != 1.0:
            text += f" at {c.l2.speed_ratio:g}x"
        if c.board_cache:
            text += " + " + (f"board {c.board_cache.describe()}" if full else
                             level(c.board_cache))
        return text

    def build(full: bool) -> Table:
        t = Table(title="CPU presets (sources in sim/cpus/presets/*.toml)", box=box.SIMPLE_HEAD, title_justify="left",
                  pad_edge=False,
                  caption=("L1: size, ways, line, load-to-use clocks; L2 'x clock': its clock over the core's"
                           if full else "MHz: core and bus clocks; L1: instruction + data; 'board': the motherboard cache; 'at 0.5x': L2 at half the core clock; "
                           "ways and latencies with --json or a wider terminal")
                  + "\n" + _write_allocate_caption(cpus, modes, full), caption_justify="left")
        cols = (["preset", "family", "MHz", "bus MHz", "L1I", "L1D", "L2", "write alloc.", "memory"] if full else
                ["preset", "family", "MHz", "bus", "L1 KB", "L2 KB", "memory"])
        for col in cols:
            t.add_column(col, no_wrap=True, justify="right" if col in ("MHz", "bus", "bus MHz") else "left")
        for c in cpus:
            l1 = [c.l1i.describe(), c.l1d.describe()] if full else [f"{c.l1i.size_kb}+{c.l1d.size_kb}"]
            # truncated, as the parts are sold: 266.67 MHz is a Celeron 266 on a 66 MHz bus
            t.add_row(c.name, c.family.upper(), f"{int(c.core_mhz)}", f"{int(c.fsb_mhz)}", *l1, caches(c, full),
                      *([modes[c.name]] if full else []), c.memory)
        return t

    wide = build(True)
    return [wide] if natural_width(wide) <= width else [build(False)]


@main.command("validate")
@click.option("--family", "fams", multiple=True, help="only these families (default: every validation/*.toml)")
@click.option("--out", type=click.Path(path_type=Path), default=REPORTS_DIR / "validation.md",
              show_default=True, help="Markdown report to write")
@click.option("--check", is_flag=True, help="write nothing; fail if the committed report differs from a fresh one")
def validate_cmd(fams, out, check):
    """Time published loop timings (validation/*.toml) and write reports/validation.md."""
    import time as _time

    from sim import output
    from sim.reports.validation import markdown
    from sim.studies import validation

    start = _time.perf_counter()
    if not check:  # before the work: a device, pipe, folder or missing folder fails at once
        output.check_output_file(out, "--out")
    results = [validation.run_family(f) for f in validation.families(only=list(fams) or None)]
    text = markdown(results)
    if check:
        # a regular file of sane size only: a FIFO would block, a huge file is not the committed report
        committed = out.read_text() if out.is_file() and out.stat().st_size <= 16 << 20 else ""
        strip = lambda t: "\n".join(x for x in t.splitlines() if not x.startswith("Run time:"))  # noqa: E731
        if strip(committed) != strip(text):
            err_console.print(f"stale report: {out} (regenerate with `retrosim validate`)")
            raise SystemExit(1)
    else:
        output.atomic_write(out, text.encode(), "--out")
        err_console.print(f"wrote {out}")
    t = Table(title=f"validation against published timings ({_time.perf_counter() - start:.1f} s)")
    for col in ("family", "preset", "cases", "MAPE", "within 1 cycle", "harness errors"):
        t.add_column(col, justify="left" if col in ("family", "preset") else "right")
    for fr in results:
        t.add_row(fr.family.family, fr.family.cpu, str(len(fr.timed)), f"{fr.mape():.1f} %", f"{fr.within_one():.0%}",
                  str(len(fr.results) - len(fr.timed)))
    console.print(t)


@main.command("conformance")
@click.option("--out", type=click.Path(path_type=Path), default=REPORTS_DIR / "conformance.md",
              show_default=True, help="where to write the report")
@click.option("--family", "families", multiple=True, help="only these families (those with a conformance preset: p6, k6)")
def conformance_cmd(out, families):
    """Run every table row's generated latency/throughput benchmark through the model on each preset
    of its family and write the comparison with the row's sourced figures (about 90 s of CPU time)."""
    from sim.studies.conformance import FAMILY_ISA, write_report

    unknown = [f for f in families if f not in FAMILY_ISA]
    if unknown:
        raise ArgumentError(f"--family: no conformance run for '{unknown[0]}' (choose from: {', '.join(FAMILY_ISA)})")
    results, seconds = write_report(out, tuple(families) or tuple(FAMILY_ISA))
    for fam, (rows, _) in results.items():
        src = [r for r in rows if r.checked and not r.row.estimated]
        console.print(f"{fam}: {len(rows)} rows, {sum(r.checked for r in rows)} benchmarked, "
                      f"{sum(r.ok for r in src)}/{len(src)} sourced rows reproduced")
    console.print(f"wrote {out} in {seconds:.0f} s")

