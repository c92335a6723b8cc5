"""Commands on one kernel or loop body: kernels, run-kernel, trace, time, explain, loop, bench."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click
import numpy as np
from rich import box
from rich.markup import escape
from rich.table import Table

from sim.guest import kernels as catalogue_mod
from sim.errors import ArgumentError, RetrosimError
from sim.cli.app import (
    bounded, buffer_summary, choose_entry, console, cpu_choice, cpu_list, err_console, load_machine, main,
    memory_option, parse_args, resolve_machine, say, set_option, with_kernel_options, with_timing_options,
)


html_option = click.option("--html", "html_out", type=click.Path(), metavar="FILE",
                           help="also write the pipeline view: one self-contained HTML page (no network)")


def _check_html(given: str | None) -> Path | None:
    """--html FILE, checked before the work (a bad path fails at once); its folder is created."""
    if given is None:
        return None
    from sim.output import check_output_dir, check_output_file, file_path

    if given == "-":  # not a file named "-": standard output already holds the table or --json
        raise ArgumentError("--html -: the page is written to a file, not to standard output (which holds the "
                            "table or the --json document); give the file's name, e.g. --html view.html")
    path = file_path(given, "--html")
    check_output_dir(path.parent if str(path.parent) else Path("."), "--html", for_file=path)
    check_output_file(path, "--html")
    return path


# -- commands ------------------------------------------------------------------------------
@main.command("kernels")
@click.option("--json", "as_json", is_flag=True, help="print one JSON object")
def kernels_cmd(as_json: bool):
    """List kernel sources and the entry points they declare."""
    root = catalogue_mod.kernels_root()
    cat = catalogue_mod.catalogue(root)
    if as_json:
        click.echo(json.dumps({str(p.relative_to(root)): [e.signature() for e in entries.values()]
                               for p, entries in cat.items()}, indent=2))
        return
    table = Table(title=escape(f"kernels in {root}"), box=box.SIMPLE_HEAD, title_justify="left", show_lines=True,
                  caption="`# @entry` declarations: see kernels/README.md", caption_justify="left")
    table.add_column("file", no_wrap=True)
    table.add_column("entry point and what it returns", overflow="fold")
    for path, entries in cat.items():
        for i, e in enumerate(entries.values()):
            table.add_row(escape(str(path.relative_to(root))) if i == 0 else "", escape(e.signature()))
        if not entries:
            table.add_row(escape(str(path.relative_to(root))), "[dim](no @entry declared)[/]")
    console.print(table)


def _isa_cpu_choice(ctx, param, value):
    return None if value is None else cpu_choice(ctx, param, value)


_isa_cpu_option = click.option("--cpu", "-c", "isa_cpu", callback=_isa_cpu_choice,
                               help="assemble for this CPU preset's instruction set (default: plain i686)")


@main.command("run-kernel")
@with_kernel_options
@_isa_cpu_option
@click.option("--json", "as_json", is_flag=True, help="print one JSON object")
def run_kernel_cmd(source, entry, args_text, budget, assembler, isa_cpu, as_json):
    """Call a kernel once and print its results and instruction / memory-access counts."""
    m = load_machine(source, assembler, isa_cpu)
    entry = choose_entry(m, entry)
    values, buffers = parse_args(args_text, m)
    r = m.call(entry, *values, budget=budget, trace=True)
    t = r.trace
    report = {"entry": entry, "eax": r.eax, "edx": r.edx, "instructions": t.instructions,
              "distinct_pcs": int(np.unique(t.pc).size), "accesses": t.accesses, "reads": t.reads,
              "writes": t.writes, "bytes_read": int(t.mem_size[~t.mem_write].sum(dtype=np.int64)),
              "bytes_written": int(t.mem_size[t.mem_write].sum(dtype=np.int64)),
              "buffers": buffer_summary(m, buffers)}
    if as_json:
        click.echo(json.dumps(report, indent=2))
        return
    table = Table(title=f"{escape(Path(source).name)}: {escape(entry)}", show_header=False)
    for key in ("eax", "edx"):
        table.add_row(key.upper(), f"{report[key]:#010x}  ({report[key]})")
    for key in ("instructions", "distinct_pcs", "accesses", "reads", "writes", "bytes_read", "bytes_written"):
        table.add_row(key.replace("_", " "), f"{report[key]:,}")
    for b in report["buffers"]:
        table.add_row(escape(b["arg"]), escape(f"@{b['address']:#010x} first {b['first']} sum {b['sum']}"))
    console.print(table)


@main.command("trace")
@with_kernel_options
@_isa_cpu_option
@click.option("--out", "-o", type=click.Path(path_type=Path), required=True,
              help="output .npz (arrays pc, mem_addr, mem_size, mem_write, mem_insn)")
def trace_cmd(source, entry, args_text, budget, assembler, isa_cpu, out):
    """Record a kernel's PC stream and data accesses to an .npz file for other simulators."""
    from sim.output import check_output_file

    check_output_file(out, "--out")  # before the work: a bad path fails in a second, not after the run
    m = load_machine(source, assembler, isa_cpu)
    entry = choose_entry(m, entry)
    values, _ = parse_args(args_text, m)
    t = m.call(entry, *values, budget=budget, trace=True).trace
    t.save(out)
    console.print(f"wrote {out}: {t.instructions:,} instructions, {t.accesses:,} data accesses "
                  f"({t.reads:,} reads, {t.writes:,} writes)", markup=False, highlight=False)


def _time(source, entry, args_text, budget, assembler, cpu, memory, repeat, iterations=0, sets=()):
    from sim.cpus.build import make_model
    from sim.guest.cpu import GuestCpu
    from sim.guest.emu import Machine
    from sim.timing.kernel import time_kernel

    # the preset is resolved and the model built once, here; the model is not run until time_kernel
    machine = resolve_machine(cpu, sets, memory)
    label, model = machine.label, make_model(machine)
    path = catalogue_mod.resolve(source)
    probe = Machine.from_source(path, assembler=assembler, cpu=GuestCpu.from_preset(model.preset))
    entry = choose_entry(probe, entry)  # resolve the entry and check --args once
    parse_args(args_text, probe)
    if repeat < 20:
        result = time_kernel(path, entry, setup=lambda m: parse_args(args_text, m)[0], cpu=model,
                             repeat=repeat, budget=budget, timeline_iterations=iterations, assembler=assembler)
    else:
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        # many calls: show where the emulation is (stderr, so --json stays clean)
        with Progress(TextColumn("{task.description}", markup=False), BarColumn(),
                      TextColumn("{task.completed}/{task.total}"), TimeElapsedColumn(), console=err_console,
                      transient=True) as bar:
            task = bar.add_task(f"emulating {entry} x {repeat:,}", total=repeat)
            result = time_kernel(path, entry, setup=lambda m: parse_args(args_text, m)[0], cpu=model,
                                 repeat=repeat, budget=budget, timeline_iterations=iterations, assembler=assembler,
                                 progress=lambda done, total: bar.update(task, completed=done))
    result.cpu = label  # the machine label: the preset with its overrides
    return result


@main.command("time")
@with_kernel_options
@with_timing_options
@click.option("--json", "as_json", is_flag=True, help="print one JSON object")
def time_cmd(source, entry, args_text, budget, assembler, cpu, memory, repeat, sets, as_json):
    """Cycle counts of a kernel on a CPU model: cycles, uops, decode, ports, stalls, caches, DRAM."""
    from sim.reports import registry

    result = _time(source, entry, args_text, budget, assembler, cpu, memory, repeat, sets=sets)
    if as_json:  # one view (the summary): its part is the whole document
        click.echo(json.dumps({k: v for part in registry.document(result, "time").values() for k, v in part.items()},
                              indent=2))
        return
    _print_views(registry.text(result, registry.TextContext("time", console.width)))


def _print_lines(lines) -> None:
    for line in lines:  # literal text (rows hold [esi]), wrapped at the terminal's width
        console.print(line, markup=False, highlight=False)


def _print_views(items) -> None:
    """Print the registered views' text items (sim/reports/registry.py)."""
    from sim.reports import registry

    for item, how in items:
        if how == registry.RICH:
            console.print(item)
        elif how == registry.LINES:  # literal text (rows hold [esi]), wrapped at the terminal's width
            console.print(item, markup=False, highlight=False)
        else:  # a chart: literal, never wrapped
            console.print(item, markup=False, highlight=False, soft_wrap=True)


EXPLAIN_HELP = """Per-instruction table of the last call (decoder, uops, ports, latency,
stalls) and a timeline.

\b
Columns, in each family's names (P6: ports p0-p4, decoders D0/D1/D2 and
MS; K6: units X/Y/load/store/branch, short S1/S2, long L and vector V
decode); the legend under the tables spells them out for the CPU asked:
  runs       executions in the last call
  dec        the decoder that took the instruction
  uops/ops   uops (K6: RISC86 ops) per execution
  ports      per execution on each port (K6: units)
  iss->ret   average cycles from the first uop issuing to retirement
  stalls     cycles per execution an op waited: dep (an operand),
             port (a busy unit), decode (the decoders), partial (a
             partial-register merge), mem (memory beyond L1), fwd
             (store-to-load forwarding), window (room in the reorder
             buffer or reservation station; K6: the scheduler), branch
             (the front end after a branch)
  mispred    mispredictions per execution; P6's branch stall also counts
             every taken branch's fetch bubble, so it can be large with
             few mispredictions
  table row  the instruction-table row used; (est.) = estimated figures
Narrow terminals get the table in three parts keyed by the instruction."""


@main.command("explain", help=EXPLAIN_HELP)
@with_kernel_options
@with_timing_options
@click.option("--iterations", default=3, show_default=True, callback=bounded(0, 1000), help="hot-loop iterations in the timeline")
@click.option("--json", "as_json", is_flag=True, help="print one JSON object (rows and timeline)")
@html_option
def explain_cmd(source, entry, args_text, budget, assembler, cpu, memory, repeat, sets, iterations, as_json, html_out):
    from sim.reports import registry

    html_out = _check_html(html_out)
    result = _time(source, entry, args_text, budget, assembler, cpu, memory, repeat, iterations, sets=sets)
    doc = registry.document(result, "explain")
    if html_out is not None:
        from sim.output import atomic_write
        from sim.reports import pipeline_html

        atomic_write(html_out, pipeline_html.page(pipeline_html.explain_data(doc, result)).encode(), "--html")
        if not as_json:  # where the page went (not with --json: its stdout is one document)
            say(f"wrote {html_out} (open it in a browser)")
    if as_json:
        click.echo(json.dumps(doc, indent=2))
        return
    _print_views(registry.text(result, registry.TextContext("explain", console.width, iterations=iterations)))



def loop_sections(text, name, cpus, memory, sets, syntax, iterations, regs, align, offset, timeline, assembler,
                  warn=lambda w: None, data=None) -> list[dict]:
    """Time a loop body, or each region of a whole compiler output (sim/guest/body_source.py), as
    `retrosim loop` does: one section per region ({"region": Region or None, "doc": its --json
    document, "timings": its timings}). Shared by `loop` and `serve`; `warn` receives each warning line
    (syntax first, then the run's)."""
    from sim.guest import body_source

    regions = body_source.regions(text, name, syntax)
    if regions is None:
        doc, timings = _loop_document(text, name, cpus, memory, sets, syntax, iterations, regs, align, offset,
                                      timeline, assembler, warn, data=data)
        return [{"region": None, "doc": doc, "timings": timings}]
    for warning in body_source.syntax_of(text, syntax)[1]:
        warn(warning)
    out = []
    for region in regions:
        doc, timings = _loop_document(region.text, name, cpus, memory, sets, syntax, iterations, regs, align,
                                      offset, timeline, assembler, warn, syntax_warned=True, data=data)
        doc = {"region": region.name, "lines": [region.first, region.last], "notes": region.notes, **doc}
        out.append({"region": region, "doc": doc, "timings": timings})
    return out


def loop_document(text, name, cpus, memory, sets, syntax, iterations, regs, align, offset, timeline, assembler,
                  warn=lambda w: None, data=None):
    """The --json document of `retrosim loop` (a whole output's: {"source", "regions": [one document per
    region]}), and the sections (:func:`loop_sections`)."""
    sections = loop_sections(text, name, cpus, memory, sets, syntax, iterations, regs, align, offset, timeline,
                             assembler, warn, data)
    if sections[0]["region"] is None:
        return sections[0]["doc"], sections
    return {"source": name, "data": sections[0]["doc"]["data"], "regions": [s["doc"] for s in sections]}, sections


def page_section(sections) -> tuple[dict, list]:
    """The document and timings the pipeline page draws: the body's, or a whole output's first region
    (a warning names the others)."""
    first = sections[0]
    doc = dict(first["doc"])
    if first["region"] is not None:
        r = first["region"]
        others = [f"{s['region'].name} ({s['region'].lines})" for s in sections[1:]]
        doc["warnings"] = [f"region {r.name} ({r.lines}) shown" + (f"; not shown: {', '.join(others)}" if others else "")
                           ] + r.notes + doc["warnings"]
    return doc, first["timings"]


def _loop_document(text, name, cpus, memory, sets, syntax, iterations, regs, align, offset, timeline, assembler,
                   warn, syntax_warned=False, data=None):
    """One body's document and timings."""
    from sim.cpus.overrides import load_dram
    from sim.guest import loop_body, loop_program
    from sim.timing import loop
    from sim.reports import registry, views

    loop_program.placement(align, offset)
    if memory:
        load_dram(memory)
    try:  # a forced --syntax that contradicts the body: said before the assembler's complaints
        syntax_warnings = [] if syntax_warned else loop_body.parse_body(text, name, syntax).warnings
    except RetrosimError:
        syntax_warnings = []  # refused below, with the CPU named
    for warning in syntax_warnings:
        warn(warning)
    labels = []
    for cpu in cpu_list(cpus):  # --set applies to every CPU, as `time --set` does to its one
        machine = resolve_machine(cpu, sets)  # checked here; the loop times each label once
        labels.append(machine.label)
        memory = memory or machine.memory_named
    timings, not_timed = loop.time_body_where_possible(text, list(dict.fromkeys(labels)), name, syntax, iterations,
                                                       loop_program.parse_regs(regs), assembler, timeline, memory, align,
                                                       offset, data=data or loop.DEFAULT_DATA)
    warnings = list(dict.fromkeys(w for t in timings for w in t.warnings))
    for warning in warnings:
        warn(warning)
    warnings = syntax_warnings + warnings
    doc = {"source": name, "data": data or loop.DEFAULT_DATA,
           "registers": {k: f"{v:#010x}" for k, v in loop_program.parse_regs(regs).items()},
           "placement": _placement(timings, align, offset),
           "not_timed": not_timed,
           "warnings": warnings,
           "results": [{"cpu": t.cpu, "memory": t.memory,
                        "cycles_per_iteration": t.cycles_per_iteration,
                        "uops_per_iteration": t.uops_per_iteration,
                        "instructions_per_iteration": t.per_iteration["instructions"],
                        "measured_iterations": t.iterations, "per_iteration": t.per_iteration,
                        "write_policy": t.write_policy,
                        "bottleneck": views.bottleneck(t.result, t.per_iteration),
                        "resource_pressure": views.resource_pressure(t.result, t.per_iteration),
                        **registry.document(t.result, "loop")} for t in timings]}
    return doc, timings


LOOP_HELP = """Time a bare loop body or basic block (FILE, or - for standard input): steady-state
cycles per iteration. Two files (A.s B.s) are timed alike and compared per CPU.

\b
Output, most read first:
  summary    one line per CPU: cycles, instructions and uops per
             iteration, IPC, the bottleneck in the family's words
  pressure   uops (K6: RISC86 ops; P5: instructions) per port, unit or
             pipe per iteration, per family
  detail     the per-instruction table and a timeline with its legend:
             the first CPU's, or every CPU's with --detail
A/B (two files): per CPU each one's cycles per iteration, the ratio A/B,
the faster one and the counters that differ most, then each file's
summary (--detail: each file's detail on every CPU too)."""


@main.command("loop", help=LOOP_HELP)
@click.argument("sources", nargs=-1, required=True, metavar="FILE [B_FILE]")
@click.option("--cpu", "-c", "cpus", multiple=True,
              help="CPU preset or machine label (k6-233{write_allocate.mode=full}); repeat or separate with "
                   "commas for several, `all` for every preset [default: pentium2-233]")
@memory_option
@set_option
@click.option("--syntax", type=click.Choice(["intel", "att"]), help="source syntax (default: detected; Intel if unsure)")
@click.option("--iterations", "-n", default=100, show_default=True,
              help="iterations per pass; counters are taken between iteration N/2 and N of the second pass")
@click.option("--reg", "regs", multiple=True, metavar="R=V", help="register start value, e.g. --reg ecx=1000")
@click.option("--align", "align", default=64, show_default=True, metavar="N",
              help="place the body's first instruction at a multiple of N bytes (1, 2, 4, ..., 64) and of no "
                   "larger power of two, as a function's loop may be: 16 gives 16 bytes past a 64-byte boundary")
@click.option("--offset", "offset", default=0, show_default=True, metavar="K",
              help="then K bytes further (0 <= K < N): --align 16 --offset 3 starts the body 19 bytes past a "
                   "64-byte boundary")
@click.option("--data", "data", type=click.Choice(["cold", "warm"]), default="cold", show_default=True,
              help="the data caches when the measured pass starts. cold: as the warm-up pass left them (reads "
                   "allocate; writes only where the CPU's write policy allocates: not on a P5, nor on a K6 preset "
                   "without write allocation). warm: also every line the measured pass touches read in first, as "
                   "far as it fits (every access an L1 hit when the working set fits, as llvm-mca and uiCA assume)")
@click.option("--timeline", "timeline", default=3, show_default=True, callback=bounded(0, 1000),
              help="iterations shown in the timeline")
@click.option("--detail", is_flag=True, help="the per-instruction table and timeline of every CPU (default: the first's)")
@click.option("--brief", is_flag=True, help="only the summary table")
@click.option("--assembler", type=click.Choice(["gnu", "zig"]), help="assembler back end (default: GNU as)")
@click.option("--json", "as_json", is_flag=True, help="print one JSON object")
@html_option
def loop_cmd(sources, cpus, memory, sets, syntax, iterations, regs, align, offset, data, timeline, detail, brief,
             assembler, as_json, html_out):
    from sim.guest import loop_body

    if len(sources) > 2:
        raise ArgumentError(f"loop: {len(sources)} files given; give one body, or two (A.s B.s) to compare")
    if "-" in sources and len(sources) == 2:
        raise ArgumentError("loop A.s B.s: compare two files (standard input, '-', holds one body)")
    html_out = _check_html(html_out)
    if html_out is not None and len(sources) == 2:
        raise ArgumentError("--html draws one body: give one file, not two")
    warn = lambda w: click.echo(f"retrosim: warning: {w}", err=True)  # noqa: E731
    runs = []
    for source in sources:
        text, name = loop_body.read_body(source, sys.stdin.buffer)
        doc, sections = loop_document(text, name, cpus, memory, sets, syntax, iterations, regs, align, offset,
                                      timeline, assembler, warn=warn, data=data)
        runs.append((text, name, doc, sections))
    if len(runs) == 2:
        _loop_ab(runs, iterations, timeline, align, offset, detail, brief, as_json)
        return
    text, name, doc, sections = runs[0]
    if html_out is not None:
        from sim.output import atomic_write
        from sim.reports import pipeline_html

        page_doc, page_timings = page_section(sections)
        atomic_write(html_out, pipeline_html.page(pipeline_html.loop_data(page_doc, page_timings, text)).encode(),
                     "--html")
        if not as_json:  # where the page went (not with --json: its stdout is one document)
            say(f"wrote {html_out} (open it in a browser)")
    if as_json:
        click.echo(json.dumps(doc, indent=2))
        return
    for section in sections:
        _print_region_head(section, name)
        _print_loop_section(section["doc"], section["timings"], name, iterations, timeline, align, offset,
                            "summary" if brief else "all" if detail else "first")


def _print_region_head(section, name) -> None:
    region = section["region"]
    if region is not None:  # a whole output: each region under its name and the lines it took
        console.print(f"[bold]region {escape(region.name)}[/]: {escape(name)} {region.lines}")
        _print_lines(region.notes)


def _loop_ab(runs, iterations, timeline, align, offset, detail, brief, as_json) -> None:
    """`loop A.s B.s`: per CPU both figures, the ratio, the faster and what differs most; then each
    side's summary (and with --detail its detail)."""
    from sim.reports import compare

    (_, name_a, doc_a, sections_a), (_, name_b, doc_b, sections_b) = runs
    comparison = compare.loop_comparison(name_a, sections_a, name_b, sections_b)
    pairs = list(zip(sections_a, sections_b))
    if as_json:
        click.echo(json.dumps({"a": doc_a, "b": doc_b, "comparison": comparison}, indent=2))
        return
    for c in comparison:
        table = Table(title=escape(f"A/B, cycles per iteration: A = {c['a']}, B = {c['b']}"))
        for col in ("cpu", "A", "B", "A/B", "faster", "differs most per iteration (A minus B)"):
            table.add_column(col, justify="left" if col in ("cpu", "faster", "differs most per iteration (A minus B)")
                             else "right", overflow="fold")
        for e in c["per_cpu"]:
            ca, cb = e["cycles_per_iteration"]
            table.add_row(escape(e["cpu"]), f"{ca:.2f}", f"{cb:.2f}", f"{e['ratio']:.3f}",
                          {"A": "A", "B": "B", "same": "neither"}[e["faster"]],
                          escape(", ".join(f"{d['words']} {d['a_minus_b']:+g}" for d in e["differences"]) or "none"))
        console.print(table)
        _print_lines([compare.AB_NOTE])
    depth = "all" if detail else "summary"
    for (sa, sb), c in zip(pairs, comparison):
        for side, section, name in (("A", sa, name_a), ("B", sb, name_b)):
            console.print(f"[bold]{side}[/]: {escape(c[side.lower()])}")
            _print_loop_section(section["doc"], section["timings"], name, iterations, timeline, align, offset,
                                "summary" if brief else depth)


def _print_loop_section(doc, timings, name, iterations, timeline, align, offset, depth) -> None:
    """The text output of one body (or region), most read first: the summary table and the lines under
    it, the resource pressure, then the per-instruction tables and timeline of the first CPU (`depth`
    "first"), of every CPU ("all") or of none ("summary": the summary table alone)."""
    from sim.guest import loop_program
    from sim.reports import registry, views

    not_timed = doc["not_timed"]
    console.print(views.loop_summary_table(
        f"{name}: steady state per iteration (iterations {iterations // 2}..{iterations})", timings, console.width))
    limits = {t.cpu: views.caveats(t.result) for t in timings}
    place = _placement(timings, align, offset)
    lines = [f"body at {place['address']} ({place['alignment']}-byte aligned, {place['past_boundary']} past a "
             f"{loop_program.ALIGN_SPAN}-byte boundary: --align {align} --offset {offset}); est.: executed instructions "
             "timed with estimated table rows", DATA_LINES[doc["data"]]]
    lines += [t.write_policy for t in timings if t.write_policy]
    lines += [f"not timed (no {what}): {', '.join(cpus_)}" for what, cpus_ in not_timed.items()]
    lines += [f"{cpu}: {views.not_modelled_line(c)}" for cpu, c in limits.items() if c["not_modelled"]]
    _print_lines(lines)
    if depth == "summary":
        return
    for heading, table in views.pressure_tables(timings):
        console.print(f"[bold]{escape(heading)}[/]")
        console.print(table)
    shown = timings if depth == "all" else timings[:1]
    for t in shown:
        _print_views(registry.text(t.result, registry.TextContext("loop", console.width, t.cpu, timeline)))
    if len(timings) > len(shown):
        _print_lines([f"per-instruction detail of {shown[0].cpu} only; --detail shows every CPU's"])


# the caches' state, said under every loop table (sim.timing.loop.DATA_STATES)
DATA_LINES = {"cold": "data: cold (caches as the warm-up pass left them; writes allocate only where the CPU's write "
                      "policy does; --data warm reads every line in first)",
              "warm": "data: warm (every line the measured pass touches read into the caches first, as far as it "
                      "fits)"}


def _placement(timings, align: int, offset: int) -> dict:
    from sim.guest import loop_program

    address = timings[0].address
    return {"address": f"{address:#010x}", "align": align, "offset": offset,
            "alignment": timings[0].alignment, "past_boundary": address % loop_program.ALIGN_SPAN}


@main.command("bench")
@click.option("--pixels", default=1 << 20, show_default=True, callback=bounded(1, 1 << 22, " (the Python-hook mode keeps every instruction as Python objects, about 1 GB per million pixels)"), help="pixels in the Z-buffer span workload")
@click.option("--json", "as_json", is_flag=True, help="print one JSON object with the figures")
@click.option("--check", "check_speed", is_flag=True,
              help="the models' speed check: each model alone (P6, K6, P5) against the native trace's rate in "
                   "this process, compared with benchmarks/model_speed.json; exit 1 when a ratio is more than "
                   "15 % below its recorded figure")
@click.option("--count", "count", is_flag=True,
              help="the models' instruction count: host instructions per guest instruction of each model alone, "
                   "counted by valgrind for a generic x86-64 CPU (repeatable whatever the load), compared with "
                   "benchmarks/model_count.json; exit 1 when one grows more than 5 % (sim/timing/speedcount.py)")
@click.option("--record", is_flag=True, help="measure the models' speed ratios (with --count: their instruction "
                                             "counts) and write benchmarks/model_speed.json (model_count.json)")
@click.option("--rounds", default=3, show_default=True, callback=bounded(1, 50),
              help="--check/--record: interleaved rounds, the best of which is kept (per placement of each core)")
@click.option("--placements", default=4, show_default=True, callback=bounded(1, 16),
              help="--check/--record: copies of each core, each compiled at its own address; a model's figure "
                   "is their mean (one placement varies by about a fifth: sim/timing/speedcheck.py)")
def bench_cmd(pixels: int, as_json: bool, check_speed: bool, count: bool, record: bool, rounds: int,
              placements: int):
    """Emulation speed: Unicorn bare, with Python hooks, with the native trace (same workload).
    With --check or --record: the models' speed ratios (sim/timing/speedcheck.py); with --count:
    their instruction counts (sim/timing/speedcount.py)."""
    from sim.timing.bench import run_bench

    if count:
        if check_speed:
            raise ArgumentError("--check and --count: choose one (--count checks the counts)")
        _count_check(record, as_json)
        return
    if check_speed or record:
        _speed_check(check_speed, record, rounds, placements, as_json)
        return
    result = run_bench(pixels, progress=None if as_json else console)
    if as_json:
        click.echo(json.dumps(result, indent=2))
        return
    table = Table(title=f"retrosim bench: fp16z_span over {pixels:,} pixels, "
                        f"{result['instructions']:,} guest instructions, {result['cores']} core(s)")
    table.add_column("mode")
    table.add_column("seconds", justify="right")
    table.add_column("guest instr/s", justify="right")
    table.add_column("vs bare", justify="right")
    for mode, key in (("Unicorn, no hooks", "unicorn_bare"), ("Python hooks (code + memory)", "python_hook"),
                      ("native trace (numba cfuncs)", "native_trace"),
                      ("end to end, streamed: trace + P6 model (pentium2-233)", "end_to_end"),
                      ("P6 model alone on the trace (pentium2-233)", "model_only"),
                      ("end to end, streamed: trace + K6 model (k6-233)", "k6_end_to_end"),
                      ("end to end, streamed: trace + P5 model (pentium-mmx-233)", "p5_end_to_end"),
                      ("K6 model alone on the trace (k6-233)", "k6_model_only"),
                      ("P5 model alone on the trace (pentium-mmx-233)", "p5_model_only")):
        ips = result[f"{key}_ips"]
        table.add_row(mode, f"{result[f'{key}_seconds']:.3f}", f"{ips / 1e6:,.1f} M",
                      f"{result['unicorn_bare_ips'] / ips:,.1f}x slower" if key != "unicorn_bare" else "1x")
    console.print(table)
    console.print(f"native trace vs Python hooks: [bold]{result['native_vs_python']:.1f}x[/] faster (target >= 15x); "
                  f"native trace vs bare Unicorn: [bold]{result['bare_vs_native']:.1f}x[/] slower (target <= 10x); "
                  f"end to end: [bold]{result['end_to_end_ips'] / 1e6:.1f} M[/] instructions/s, "
                  f"{result['end_to_end_vs_native']:.2f} of the native trace's rate (target >= 0.5), "
                  f"{result['bare_vs_end_to_end']:.1f}x slower than bare Unicorn; each model alone against the native "
                  f"trace (target >= 0.8): P6 [bold]{result['model_only_vs_native']:.2f}[/], "
                  f"K6 [bold]{result['k6_model_only_vs_native']:.2f}[/], P5 [bold]{result['p5_model_only_vs_native']:.2f}[/]")


def _count_check(record: bool, as_json: bool) -> None:
    from sim.timing import speedcount

    say = None if as_json or not console.is_terminal else (lambda m: console.print(f"[dim]{escape(m)} ...[/]"))
    baseline = None if record else speedcount.load(speedcount.BASELINE_FILE)
    result = speedcount.measure(pixels=baseline["pixels"] if baseline else speedcount.PIXELS, progress=say)
    failed = [] if record else speedcount.regressions(result, baseline)
    if record:
        speedcount.record(result)
    if as_json:
        click.echo(json.dumps({**result, "baseline": baseline and baseline["host_per_guest"], "regressions": failed},
                              indent=2))
    else:
        table = Table(title=f"model instruction count: fp16z_span, {result['instructions']:,} guest instructions, "
                            "host instructions per guest instruction (valgrind, generic x86-64)")
        for col in ("model alone", "host/guest", "recorded", "change"):
            table.add_column(col, justify="left" if col == "model alone" else "right")
        for cpu, v in result["models"].items():
            want = baseline["host_per_guest"].get(cpu) if baseline else None
            table.add_row(cpu, f"{v['host_per_guest']:,.1f}", "-" if want is None else f"{want:,.1f}",
                          "-" if want is None else f"{v['host_per_guest'] / want - 1:+.1%}")
        console.print(table)
        if baseline and baseline["versions"] != result["versions"]:
            console.print(f"[yellow]recorded with {baseline['versions']}, measured with {result['versions']}: "
                          "other versions compile other code[/]")
        if record:
            console.print(f"wrote {speedcount.BASELINE_FILE}")
    _exit_on_regressions(failed, "instruction-count regression")


def _speed_check(check_speed: bool, record: bool, rounds: int, placements: int, as_json: bool) -> None:
    from sim.timing import speedcheck

    if check_speed and record:
        raise ArgumentError("--check and --record: choose one")
    say = None if as_json or not console.is_terminal else (lambda m: console.print(f"[dim]{escape(m)} ...[/]"))
    if record:
        result = speedcheck.measure(rounds=rounds, placements=placements, progress=say)
        speedcheck.record(result)
        failed, baseline = [], None
    else:
        baseline = speedcheck.load(speedcheck.BASELINE_FILE)
        result, failed = speedcheck.check(baseline, rounds=rounds, placements=placements, progress=say)
    if as_json:
        click.echo(json.dumps({**result, "baseline": baseline and baseline["ratios"], "regressions": failed}, indent=2))
    else:
        table = Table(title=f"model speed: fp16z_span, {result['instructions']:,} guest instructions, mean of "
                            f"{result.get('placements', 1)} placement(s) of each core, each the best of {result['rounds']} "
                            f"rounds (CPU time); native trace {result['native_ips'] / 1e6:.1f} M/s")
        for col in ("model alone", "instr/s", "placements", "vs native", "recorded"):
            table.add_column(col, justify="left" if col == "model alone" else "right")
        for cpu, v in result["models"].items():
            want = baseline["ratios"].get(cpu) if baseline else None
            spread = v.get("placements") or [v["ips"]]
            table.add_row(cpu, f"{v['ips'] / 1e6:.1f} M", f"{min(spread) / 1e6:.1f}-{max(spread) / 1e6:.1f} M",
                          f"{v['ratio']:.3f}", "-" if want is None else f"{want:.3f}")
        console.print(table)
        if record:
            console.print(f"wrote {speedcheck.BASELINE_FILE}")
    _exit_on_regressions(failed, "speed regression")


def _exit_on_regressions(failed: list[str], what: str) -> None:
    """One line per regression on standard error, then exit 1; nothing when there is none."""
    if failed:
        for line in failed:
            click.echo(f"{what}: {line}", err=True)
        sys.exit(1)
