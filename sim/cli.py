"""The `retrosim` command line."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click
import numpy as np
from rich.console import Console
from rich.table import Table

from . import kernels as catalogue_mod
from .errors import ArgumentError, RetrosimError

console = Console()
err_console = Console(stderr=True)

_DTYPES = {"u8": np.uint8, "u16": np.uint16, "u32": np.uint32, "i8": np.int8, "i16": np.int16, "i32": np.int32,
           "f32": np.float32, "f64": np.float64}
_ARGS_HELP = ("comma-separated cdecl arguments: integers (12, -3, 0x1F), 32-bit floats (1.5f), or buffers "
              "allocated in the workload arena and passed by address: buf:TYPE:COUNT[:FILL] with TYPE one of "
              + ", ".join(_DTYPES))


class RetrosimGroup(click.Group):
    """Turn every RetrosimError into one clean line on stderr and exit status 2."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except RetrosimError as e:
            err_console.print(f"[bold red]retrosim: error:[/] {e}", highlight=False, soft_wrap=True)
            sys.exit(2)


@click.group(cls=RetrosimGroup)
@click.version_option(package_name="retrosim")
def main():
    """Cycle-level timing of i686 kernels on late-1990s x86 CPUs."""


# -- argument parsing shared by run-kernel and trace -------------------------------------------
def parse_args(text: str | None, machine) -> tuple[list, list[tuple[str, int, np.dtype, int]]]:
    """Parse --args; buffers are allocated in the machine's arena. Returns (values, buffers)."""
    values, buffers = [], []
    for i, item in enumerate(a.strip() for a in (text or "").split(",") if a.strip()):
        if item.startswith("buf:"):
            parts = item.split(":")
            if len(parts) not in (3, 4) or parts[1] not in _DTYPES:
                raise ArgumentError(f"--args item {i + 1} '{item}': expected buf:TYPE:COUNT[:FILL], "
                                    f"TYPE one of {', '.join(_DTYPES)}")
            dtype = np.dtype(_DTYPES[parts[1]])
            try:
                count = int(parts[2], 0)
                fill = (float(parts[3]) if dtype.kind == "f" else int(parts[3], 0)) if len(parts) == 4 else 0
            except ValueError:
                raise ArgumentError(f"--args item {i + 1} '{item}': COUNT and FILL must be numbers") from None
            address = machine.arena.put(np.full(count, fill, dtype=dtype))
            buffers.append((item, address, dtype, count))
            values.append(address)
        elif item.lower().endswith("f") and not item.lower().startswith("0x"):
            try:
                values.append(np.float32(float(item[:-1])))
            except ValueError:
                raise ArgumentError(f"--args item {i + 1} '{item}': not a float") from None
        else:
            try:
                values.append(int(item, 0))
            except ValueError:
                raise ArgumentError(f"--args item {i + 1} '{item}': not an integer, float (1.5f) or buf:TYPE:COUNT") from None
    return values, buffers


def _machine(source: str, assembler: str | None):
    from .emu import Machine

    return Machine.from_source(catalogue_mod.resolve(source), assembler=assembler)


def _entry(machine, entry: str | None) -> str:
    if entry:
        return entry
    # declared entry points first; a file without `# @entry` comments offers its global symbols
    candidates = list(machine.entries) or sorted(machine.image.global_symbols)
    if len(candidates) == 1:
        return candidates[0]
    names = ", ".join(candidates) or "the file defines no global symbol"
    raise ArgumentError(f"{machine.image.path}: choose an entry point with --entry ({names})")


def _buffer_summary(machine, buffers) -> list[dict]:
    out = []
    for spec, address, dtype, count in buffers:
        data = machine.arena.get(address, dtype, count)
        out.append({"arg": spec, "address": address, "first": data[:8].tolist(),
                    "sum": float(data.sum(dtype=np.float64)) if dtype.kind == "f" else int(data.astype(np.int64).sum())})
    return out


kernel_options = [
    click.argument("source"),
    click.option("--entry", "-e", help="entry point symbol (default: the only one the file declares)"),
    click.option("--args", "args_text", help=_ARGS_HELP),
    click.option("--budget", default=200_000_000, show_default=True, help="instruction budget (0 = unlimited)"),
    click.option("--assembler", type=click.Choice(["gnu", "zig"]), help="assembler back end (default: GNU as)"),
]


def with_kernel_options(fn):
    for option in reversed(kernel_options):
        fn = option(fn)
    return fn


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
    table = Table(title=f"kernels in {root}")
    table.add_column("file")
    table.add_column("entry point")
    for path, entries in cat.items():
        for i, e in enumerate(entries.values()):
            table.add_row(str(path.relative_to(root)) if i == 0 else "", e.signature())
        if not entries:
            table.add_row(str(path.relative_to(root)), "[dim](no @entry declared)[/]")
    console.print(table)


@main.command("run-kernel")
@with_kernel_options
@click.option("--json", "as_json", is_flag=True, help="print one JSON object")
def run_kernel_cmd(source, entry, args_text, budget, assembler, as_json):
    """Call a kernel once and print its results and instruction / memory-access counts."""
    m = _machine(source, assembler)
    entry = _entry(m, entry)
    values, buffers = parse_args(args_text, m)
    r = m.call(entry, *values, budget=budget, trace=True)
    t = r.trace
    report = {"entry": entry, "eax": r.eax, "edx": r.edx, "instructions": t.instructions,
              "distinct_pcs": int(np.unique(t.pc).size), "accesses": t.accesses, "reads": t.reads,
              "writes": t.writes, "bytes_read": int(t.mem_size[~t.mem_write].sum(dtype=np.int64)),
              "bytes_written": int(t.mem_size[t.mem_write].sum(dtype=np.int64)),
              "buffers": _buffer_summary(m, buffers)}
    if as_json:
        click.echo(json.dumps(report, indent=2))
        return
    table = Table(title=f"{Path(source).name}: {entry}", show_header=False)
    for key in ("eax", "edx"):
        table.add_row(key.upper(), f"{report[key]:#010x}  ({report[key]})")
    for key in ("instructions", "distinct_pcs", "accesses", "reads", "writes", "bytes_read", "bytes_written"):
        table.add_row(key.replace("_", " "), f"{report[key]:,}")
    for b in report["buffers"]:
        table.add_row(b["arg"], f"@{b['address']:#010x} first {b['first']} sum {b['sum']}")
    console.print(table)


@main.command("trace")
@with_kernel_options
@click.option("--out", "-o", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="output .npz (arrays pc, mem_addr, mem_size, mem_write, mem_insn)")
def trace_cmd(source, entry, args_text, budget, assembler, out):
    """Record a kernel's PC stream and data accesses to an .npz file for other simulators."""
    m = _machine(source, assembler)
    entry = _entry(m, entry)
    values, _ = parse_args(args_text, m)
    t = m.call(entry, *values, budget=budget, trace=True).trace
    if out.parent and not out.parent.exists():
        raise ArgumentError(f"--out {out}: directory {out.parent} does not exist")
    t.save(out)
    console.print(f"wrote {out}: {t.instructions:,} instructions, {t.accesses:,} data accesses "
                  f"({t.reads:,} reads, {t.writes:,} writes)")


def _cpu_choice(ctx, param, value):
    from .cpus import presets

    if value not in presets.available():
        raise click.BadParameter(f"unknown CPU preset '{value}' (choose one of: {', '.join(presets.available())})")
    return value


timing_options = [
    click.option("--cpu", "-c", default="pentium2-233", show_default=True, callback=_cpu_choice,
                 help="CPU preset (see `retrosim cpus`)"),
    click.option("--memory", "-m", help="memory preset (default: the CPU preset's)"),
    click.option("--repeat", "-n", default=2, show_default=True,
                 help="calls in one machine state; the last is reported (caches and predictors warm)"),
    click.option("--set", "sets", multiple=True, metavar="KEY=VALUE",
                 help="override a preset field (l2.size_kb=256, l2.size_kb=none, l2.latency_cycles=10, "
                      "write_allocate.mode=full, estimates.uop_queue=8, memory=sdram-pc100); repeatable"),
]


def _overrides(sets) -> tuple[dict, str | None]:
    """--set KEY=VALUE items as (preset overrides, memory preset or None); checked by make_model."""
    from .cpus import parse_value

    out, memory = {}, None
    for item in sets:
        key, eq, value = item.partition("=")
        key = key.strip()
        if not eq or not key or not value.strip():
            raise ArgumentError(f"--set '{item}': expected KEY=VALUE (e.g. l2.size_kb=256)")
        if key == "memory":
            memory = value.strip()
        else:
            out[key] = parse_value(value)
    return out, memory


def _label(cpu: str, sets) -> tuple[str, str | None]:
    """(machine label, memory from --set) for a CPU preset and --set items, validated now."""
    from .cpus import load_dram, machine_label, make_model

    overrides, memory = _overrides(sets)
    label = machine_label(cpu, overrides)
    if memory is not None:
        load_dram(memory)
    make_model(label, memory)  # one clear error for an unknown key or an impossible value
    return label, memory


def with_timing_options(fn):
    for option in reversed(timing_options):
        fn = option(fn)
    return fn


def _time(source, entry, args_text, budget, assembler, cpu, memory, repeat, iterations=0, sets=()):
    from .emu import Machine
    from .timing import time_kernel

    cpu, set_memory = _label(cpu, sets)
    memory = memory or set_memory
    path = catalogue_mod.resolve(source)
    probe = Machine.from_source(path, assembler=assembler)  # resolve the entry and check --args once
    entry = _entry(probe, entry)
    parse_args(args_text, probe)
    result = time_kernel(path, entry, setup=lambda m: parse_args(args_text, m)[0], cpu=cpu, memory=memory,
                         repeat=repeat, budget=budget, timeline_iterations=iterations, assembler=assembler)
    result.cpu = cpu  # the machine label: the preset with its overrides
    return result


@main.command("time")
@with_kernel_options
@with_timing_options
@click.option("--json", "as_json", is_flag=True, help="print one JSON object")
def time_cmd(source, entry, args_text, budget, assembler, cpu, memory, repeat, sets, as_json):
    """Cycle counts of a kernel on a CPU model: cycles, uops, decode, ports, stalls, caches, DRAM."""
    from . import views

    result = _time(source, entry, args_text, budget, assembler, cpu, memory, repeat, sets=sets)
    if as_json:
        click.echo(json.dumps(views.summary(result), indent=2))
        return
    console.print(views.summary_table(result))


@main.command("explain")
@with_kernel_options
@with_timing_options
@click.option("--iterations", default=3, show_default=True, help="hot-loop iterations in the timeline")
@click.option("--json", "as_json", is_flag=True, help="print one JSON object (rows and timeline)")
def explain_cmd(source, entry, args_text, budget, assembler, cpu, memory, repeat, sets, iterations, as_json):
    """Per-instruction table of the last call (decoder, uops, ports, latency, stalls) and a timeline."""
    from . import views

    result = _time(source, entry, args_text, budget, assembler, cpu, memory, repeat, iterations, sets=sets)
    if as_json:
        click.echo(json.dumps({"summary": views.summary(result), "instructions": views.explain_rows(result),
                               "timeline": views.timeline_rows(result)}, indent=2))
        return
    console.print(views.summary_table(result))
    console.print(views.explain_table(result))
    text = views.timeline_text(result)
    if text:
        console.print(f"[bold]timeline[/]: {iterations} iterations of the hot loop, from the middle of the last call")
        console.print(text, markup=False, highlight=False, soft_wrap=True)


@main.command("cpus")
@click.option("--json", "as_json", is_flag=True, help="print one JSON object")
def cpus_cmd(as_json):
    """List CPU and memory presets with their caches, clocks and default memory."""
    from .cpus import load_dram, memory_presets, presets

    cpus = [presets.load(n) for n in presets.available()]
    if as_json:
        click.echo(json.dumps({"cpus": {c.name: {"family": c.family, "core_mhz": c.core_mhz, "fsb_mhz": c.fsb_mhz,
                                                 "l1i": c.l1i.describe(), "l1d": c.l1d.describe(),
                                                 "l2": c.l2.describe() if c.l2 else None,
                                                 "board_cache": c.board_cache.describe() if c.board_cache else None,
                                                 "memory": c.memory} for c in cpus},
                               "memory": {m: load_dram(m).describe() for m in memory_presets()}}, indent=2))
        return
    t = Table(title="CPU presets (sources in sim/cpus/presets/*.toml)")
    for col in ("preset", "family", "MHz", "FSB", "L1I", "L1D", "L2", "memory"):
        t.add_column(col, no_wrap=col in ("preset", "memory"))
    for c in cpus:
        t.add_row(c.name, c.family, f"{c.core_mhz:g}", f"{c.fsb_mhz:g}", c.l1i.describe(), c.l1d.describe(),
                  (c.l2.describe() if c.l2 else "none") + (f" + board {c.board_cache.describe()}" if c.board_cache else ""),
                  c.memory)
    console.print(t)
    m = Table(title="memory presets (sources in sim/cpus/presets/memory/*.toml)")
    for col in ("preset", "type", "burst (bus clocks)"):
        m.add_column(col)
    for name in memory_presets():
        d = load_dram(name)
        m.add_row(name, d.kind, "-".join(str(x) for x in d.burst))
    console.print(m)


REPORTS_DIR = Path(__file__).resolve().parent.parent / "reports"
SCENES_DIR = Path(__file__).resolve().parent.parent / "scenes"


def _scenes(names) -> list:
    from .scene import load_scene

    if not names:
        paths = sorted(SCENES_DIR.glob("*.toml"))
    else:
        paths = []
        for n in names:
            p = Path(n)
            p = p if p.suffix == ".toml" and p.is_file() else SCENES_DIR / f"{n}.toml"
            if not p.is_file():
                known = ", ".join(sorted(q.stem for q in SCENES_DIR.glob("*.toml")))
                raise ArgumentError(f"no scene '{n}' (shipped scenes: {known})")
            paths.append(p)
    return [load_scene(p) for p in paths]


def _run_scenes(scenes, cpus, jobs: int | None = None) -> list:
    """Run scenes with a progress bar per scene (on stderr, so --json output stays clean)."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from .parallel import check_jobs
    from .runner import run_scene

    jobs = check_jobs(jobs)
    results = []
    with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                  TimeElapsedColumn(), console=err_console, transient=False) as bar:
        for scene in scenes:
            steps = len(scene.variants) * (1 + len(list(cpus) or scene.cpus))
            task = bar.add_task(scene.name, total=steps)

            def progress(msg, task=task):
                bar.update(task, advance=1, description=msg[:70])

            results.append(run_scene(scene, list(cpus) or None, progress, jobs=jobs))
            bar.update(task, completed=steps, description=f"{scene.name}: done")
    return results


def _summary_table(results) -> Table:
    t = Table(title="cycles per pixel (last frame) and pixels with wrong visibility")
    t.add_column("scene")
    t.add_column("variant")
    keys = list(dict.fromkeys(k for r in results for k in r.cpu_keys))
    for k in keys:
        t.add_column(k.replace(":", "\n"), justify="right")
    t.add_column("wrong visibility", justify="right")
    for r in results:
        for i, v in enumerate(r.scene.variants):
            cells = []
            for k in keys:
                try:
                    cells.append(f"{r.timing(v, k).per_pixel('cycles'):.2f}")
                except KeyError:
                    cells.append("")
            vis = r.accuracy[v].visibility
            t.add_row(r.scene.name if i == 0 else "", v, *cells,
                      f"{vis['fraction']:.3%}" if vis else "-")
    return t


_JOBS_OPTION = click.option("--jobs", "-j", type=int, default=None,
                            help="worker processes (default: every core); results are the same for any N")


def _with_sets(chosen, cpus, sets) -> list[str]:
    """--cpu entries (or every scene's machines) with the --set overrides applied to each."""
    if not sets:
        return list(cpus)
    out = []
    for spec in (list(cpus) or [c for s in chosen for c in s.cpus]):
        cpu, _, memory = spec.partition(":")
        label, set_memory = _label(cpu, sets)
        memory = set_memory or memory
        out.append(f"{label}:{memory}" if memory else label)
    return list(dict.fromkeys(out))


@main.command("report")
@click.argument("scenes", nargs=-1)
@click.option("--cpu", "cpus", multiple=True, help="run on these presets instead of the scene's (preset[:memory])")
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE", help="override a preset field of every CPU run, as in `time --set`; repeatable")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=REPORTS_DIR, show_default=True,
              help="directory for the Markdown, HTML, JSON, CSV and PNG reports")
@_JOBS_OPTION
def report_cmd(scenes, cpus, sets, out, jobs):
    """Run scenes (default: every shipped scene) and write their reports; print a summary."""
    from .report import write_reports

    chosen = _scenes(scenes)
    cpus = _with_sets(chosen, cpus, sets)
    results = _run_scenes(chosen, cpus, jobs)
    for r in results:
        paths = write_reports(r, out)
        err_console.print(f"wrote {', '.join(str(p) for p in paths)}")
    if not scenes and not cpus and not sets:  # the default set also regenerates the conversion report
        err_console.print("[dim]conversion report: timing kernels/convert/loops.S ...[/]")
        err_console.print(f"wrote {_write_conversion_report(out)}")
    console.print(_summary_table(results))


def _write_conversion_report(out: Path) -> Path:
    from .microreport import conversion_markdown, conversion_results
    from .report import atomic_write

    path = Path(out) / "conversion.md"
    atomic_write(path, conversion_markdown(conversion_results()).encode())
    return path


@main.command("check")
@click.argument("scenes", nargs=-1)
@click.option("--update", is_flag=True, help="re-record the baselines of the scenes run (say why in the commit)")
@click.option("--reports/--no-reports", "check_reports", default=False,
              help="also check that the committed Markdown/JSON/CSV reports are up to date")
@_JOBS_OPTION
def check_cmd(scenes, update, check_reports, jobs):
    """Re-run scenes and compare exact cycle counts with reports/baselines.json."""
    from . import baseline
    from .report import write_reports

    chosen = _scenes(scenes)
    results = _run_scenes(chosen, (), jobs)
    if update:
        baseline.save(baseline.update(baseline.load(), results))
        console.print(f"re-recorded {len(results)} scene(s) in {baseline.BASELINE_FILE}")
        return
    drifts = baseline.compare(baseline.load(), results)
    stale = []
    if check_reports:
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            fresh = [p for r in results for p in write_reports(r, Path(tmp), formats=("md", "json", "csv"))]
            if not scenes:
                fresh.append(_write_conversion_report(Path(tmp)))
            for path in fresh:
                committed = REPORTS_DIR / path.name
                if not committed.is_file() or committed.read_bytes() != path.read_bytes():
                    stale.append(committed)
    if drifts:
        t = Table(title=f"{len(drifts)} counter(s) differ from reports/baselines.json")
        for col in ("scene", "case", "counter", "old", "new", "delta", "percent"):
            t.add_column(col, justify="right" if col in ("old", "new", "delta", "percent") else "left")
        for d in drifts:
            t.add_row(d.scene, d.case, d.counter, "-" if d.old is None else f"{d.old:,}",
                      "-" if d.new is None else f"{d.new:,}", "-" if d.delta is None else f"{d.delta:+,}",
                      "-" if d.percent is None else f"{d.percent:+.2f}%")
        console.print(t)
    for p in stale:
        err_console.print(f"stale report: {p} (regenerate with `retrosim report`)")
    if drifts or stale:
        raise SystemExit(1)
    console.print(f"{sum(len(baseline.entries(r)) for r in results)} case(s) in {len(results)} scene(s) "
                  "match the baselines" + (" and the committed reports" if check_reports else ""))


@main.command("sweep")
@click.argument("spec", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="output path without suffix (default: the spec's path without .toml); writes .parquet, "
                   ".csv, .md and a PNG per swept parameter")
@click.option("--scheduler", default="local", show_default=True,
              help="'local' (an embedded Dask LocalCluster on 127.0.0.1), 'serial' (this process), or the "
                   "address of a running Dask scheduler (tcp://HOST:PORT)")
@click.option("--retry-failed", is_flag=True, help="recompute points whose row in the output records an error")
@_JOBS_OPTION
def sweep_cmd(spec, out, scheduler, retry_failed, jobs):
    """Run a design-space sweep (scenes or kernels x CPUs x memories x overrides) into one table."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from .parallel import check_jobs
    from .sweep import load_spec, run_sweep

    if scheduler not in ("local", "serial") and not scheduler.startswith(("tcp://", "tls://", "inproc://")):
        raise ArgumentError(f"--scheduler '{scheduler}': expected local, serial or tcp://HOST:PORT")
    parsed = load_spec(spec)
    base = out or spec.with_suffix("")
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=err_console) as bar:
        task = bar.add_task(f"sweep {spec.name}", total=None)
        result = run_sweep(parsed, base, scheduler, check_jobs(jobs), retry_failed=retry_failed,
                           progress=lambda n, total: bar.update(task, completed=n, total=total))
    for path in result.files:
        err_console.print(f"wrote {path}")
    console.print(f"{len(result.rows)} point(s): {result.computed} computed now, "
                  f"{len(result.rows) - result.computed} from {base.with_suffix('.parquet')}, {result.failed} failed")


@main.command("bench")
@click.option("--pixels", default=1 << 20, show_default=True, help="pixels in the Z-buffer span workload")
@click.option("--json", "as_json", is_flag=True, help="print one JSON object with the figures")
def bench_cmd(pixels: int, as_json: bool):
    """Emulation speed: Unicorn bare, with Python hooks, with the native trace (same workload)."""
    from .bench import run_bench

    result = run_bench(pixels, progress=None if as_json else console)
    if as_json:
        click.echo(json.dumps(result, indent=2))
        return
    table = Table(title=f"retrosim bench: fp16z_span over {pixels:,} pixels, "
                        f"{result['instructions']:,} guest instructions")
    table.add_column("mode")
    table.add_column("seconds", justify="right")
    table.add_column("guest instr/s", justify="right")
    table.add_column("vs bare", justify="right")
    for mode, key in (("Unicorn, no hooks", "unicorn_bare"), ("Python hooks (code + memory)", "python_hook"),
                      ("native trace (numba cfuncs)", "native_trace"),
                      ("end to end: trace + P6 model (pentium2-233)", "end_to_end"),
                      ("end to end: trace + K6 model (k6-233)", "k6_end_to_end")):
        ips = result[f"{key}_ips"]
        table.add_row(mode, f"{result[f'{key}_seconds']:.3f}", f"{ips / 1e6:,.1f} M",
                      f"{result['unicorn_bare_ips'] / ips:,.1f}x slower" if key != "unicorn_bare" else "1x")
    console.print(table)
    console.print(f"native trace vs Python hooks: [bold]{result['native_vs_python']:.1f}x[/] faster (target >= 15x); "
                  f"native trace vs bare Unicorn: [bold]{result['bare_vs_native']:.1f}x[/] slower (target <= 10x); "
                  f"end to end: [bold]{result['end_to_end_ips'] / 1e6:.1f} M[/] instructions/s (target >= 10 M), "
                  f"{result['bare_vs_end_to_end']:.1f}x slower than bare Unicorn")


if __name__ == "__main__":
    main()
