"""The `retrosim` command line."""

from __future__ import annotations

import json
import math
import signal
import sys
import threading
from pathlib import Path

import click
import numpy as np
from rich import box
from rich.console import Console
from rich.markup import escape
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


def one_line(message: str) -> str:
    """A message as one literal line: control characters (newlines in a file name, terminal escape
    sequences) are shown escaped, never interpreted."""
    return "".join(c if c.isprintable() or c == "\t" else repr(c)[1:-1] for c in str(message))


def print_error(message: str) -> None:
    """The one way errors reach the user: `retrosim: error: ...` on stderr, printed literally
    (rich markup would eat `[...]` and crash on `[/]`, so no rich here)."""
    sys.stderr.write(f"retrosim: error: {one_line(message)}\n")
    sys.stderr.flush()


def say(message: str) -> None:
    """A status line on stderr, printed literally (paths and names may contain brackets)."""
    err_console.print(message, markup=False, highlight=False, soft_wrap=True)


def _terminate(signum, frame):
    # SIGTERM unwinds like Ctrl-C, so every `finally` removes its temporary file
    raise SystemExit(128 + signum)


class RetrosimGroup(click.Group):
    """Turn every RetrosimError into one clean line on stderr and exit status 2."""

    def invoke(self, ctx):
        if threading.current_thread() is threading.main_thread():  # signal handlers live in the main thread
            signal.signal(signal.SIGTERM, _terminate)
        try:
            return super().invoke(ctx)
        except RetrosimError as e:
            print_error(str(e))
            sys.exit(2)
        except MemoryError:
            print_error("out of host memory (a limit of the machine or of `ulimit -v`); "
                        "lower the workload (--budget, --repeat, the scene's size)")
            sys.exit(2)
        except BrokenPipeError:
            raise  # `retrosim ... | head`: click exits quietly
        except OSError as e:
            # a safety net: the checks above each writer should have named the problem first
            where = f"{e.filename}: " if getattr(e, "filename", None) else ""
            print_error(f"{where}{e.strerror or e}")
            sys.exit(2)


@click.group(cls=RetrosimGroup)
@click.version_option(package_name="retrosim")
def main():
    """Cycle-level timing of i686 kernels on late-1990s x86 CPUs."""


# -- argument parsing shared by run-kernel and trace -------------------------------------------
def _f32(text: str, what: str) -> np.float32:
    """A 32-bit float, refusing finite values that overflow it (1e40 would silently become inf)."""
    try:
        value = float(text)
    except ValueError:
        raise ArgumentError(f"{what}: not a number") from None
    with np.errstate(over="ignore"):
        single = np.float32(value)
    if math.isfinite(value) and not math.isfinite(single):
        raise ArgumentError(f"{what}: {value:g} is out of range for a 32-bit float (largest {np.finfo(np.float32).max:g})")
    return single


def _buffer(item: str, what: str, machine) -> tuple[np.ndarray, np.dtype, int]:
    """Check a buf:TYPE:COUNT[:FILL] item completely (sizes before allocating anything)."""
    parts = item.split(":")
    if len(parts) not in (3, 4) or parts[1] not in _DTYPES:
        raise ArgumentError(f"{what}: expected buf:TYPE:COUNT[:FILL], TYPE one of {', '.join(_DTYPES)}")
    dtype = np.dtype(_DTYPES[parts[1]])
    try:
        count = int(parts[2], 0)
    except ValueError:
        raise ArgumentError(f"{what}: COUNT must be a whole number") from None
    left = machine.arena.size - machine.arena.used
    if count < 0:
        raise ArgumentError(f"{what}: COUNT must not be negative")
    if count * dtype.itemsize > left:
        raise ArgumentError(f"{what}: {count:,} x {dtype.itemsize} bytes does not fit in the workload arena "
                            f"({left:,} of {machine.arena.size:,} bytes left)")
    fill = 0
    if len(parts) == 4:
        if dtype.kind == "f":
            if dtype == np.float32:
                fill = _f32(parts[3], what)
            else:
                try:
                    fill = float(parts[3])
                except ValueError:
                    raise ArgumentError(f"{what}: FILL must be a number") from None
        else:
            try:
                fill = int(parts[3], 0)
            except ValueError:
                raise ArgumentError(f"{what}: FILL must be a whole number for {parts[1]}") from None
            info = np.iinfo(dtype)
            if not info.min <= fill <= info.max:
                raise ArgumentError(f"{what}: FILL {fill} is out of range for {parts[1]} ({info.min}..{info.max})")
    return np.full(count, fill, dtype=dtype), dtype, count


def parse_args(text: str | None, machine) -> tuple[list, list[tuple[str, int, np.dtype, int]]]:
    """Parse --args; buffers are allocated in the machine's arena. Returns (values, buffers)."""
    values, buffers = [], []
    for i, item in enumerate(a.strip() for a in (text or "").split(",") if a.strip()):
        what = f"--args item {i + 1} '{item}'"
        if item.startswith("buf:"):
            data, dtype, count = _buffer(item, what, machine)
            address = machine.arena.put(data)
            buffers.append((item, address, dtype, count))
            values.append(address)
        elif item.lower().endswith("f") and not item.lower().startswith(("0x", "-0x")):
            values.append(_f32(item[:-1], what))
        else:
            try:
                value = int(item, 0)
            except ValueError:
                raise ArgumentError(f"{what}: not an integer, float (1.5f) or buf:TYPE:COUNT") from None
            if not -(1 << 31) <= value < (1 << 32):
                raise ArgumentError(f"{what}: does not fit in a 32-bit stack slot")
            values.append(value)
    return values, buffers


def _machine(source: str, assembler: str | None, cpu: str | None = None):
    from .emu import Machine

    return Machine.from_source(catalogue_mod.resolve(source), assembler=assembler, cpu=cpu)


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


def _set_syntax(ctx, param, value):
    """--syntax applies to every source the command assembles (set for each invocation, None too)."""
    from . import asm

    asm._syntax.set(value)
    return value


def _bounded(low: int, high: int | None = None, note: str = ""):
    """An option callback refusing integers outside [low, high] with one line naming the option."""
    def check(ctx, param, value):
        if value is None:
            return value
        name = max(param.opts, key=len)  # the long spelling: --repeat, not -n
        if value < low or (high is not None and value > high):
            bound = f"at least {low:,}" if high is None else f"between {low:,} and {high:,}"
            raise ArgumentError(f"{name} {value}: must be {bound}{note}")
        return value
    return check


MAX_REPEAT = 10_000  # every call's trace is kept for the model; see also RETROSIM_TRACE_MB

kernel_options = [
    click.argument("source"),
    click.option("--entry", "-e", help="entry point symbol (default: the only one the file declares)"),
    click.option("--args", "args_text", help=_ARGS_HELP),
    click.option("--budget", default=200_000_000, show_default=True, callback=_bounded(0),
                 help="instruction budget (0 = unlimited; traces are still bounded by RETROSIM_TRACE_MB)"),
    click.option("--assembler", type=click.Choice(["gnu", "zig"]), help="assembler back end (default: GNU as)"),
    click.option("--syntax", type=click.Choice(["intel", "att"]), expose_value=False, callback=_set_syntax,
                 help="syntax of a source without .intel_syntax/.att_syntax (default: detected from % register "
                      "prefixes or PTR/[reg], else AT&T as GNU as)"),
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
    return None if value is None else _cpu_choice(ctx, param, value)


_isa_cpu_option = click.option("--cpu", "-c", "isa_cpu", callback=_isa_cpu_choice,
                               help="assemble for this CPU preset's instruction set (default: plain i686)")


@main.command("run-kernel")
@with_kernel_options
@_isa_cpu_option
@click.option("--json", "as_json", is_flag=True, help="print one JSON object")
def run_kernel_cmd(source, entry, args_text, budget, assembler, isa_cpu, as_json):
    """Call a kernel once and print its results and instruction / memory-access counts."""
    m = _machine(source, assembler, isa_cpu)
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
    from .output import check_output_file

    check_output_file(out, "--out")  # before the work: a bad path fails in a second, not after the run
    m = _machine(source, assembler, isa_cpu)
    entry = _entry(m, entry)
    values, _ = parse_args(args_text, m)
    t = m.call(entry, *values, budget=budget, trace=True).trace
    t.save(out)
    console.print(f"wrote {out}: {t.instructions:,} instructions, {t.accesses:,} data accesses "
                  f"({t.reads:,} reads, {t.writes:,} writes)", markup=False, highlight=False)


def _cpu_choice(ctx, param, value):
    from .cpus import presets

    if value not in presets.available():
        raise click.BadParameter(f"unknown CPU preset '{value}' (choose one of: {', '.join(presets.available())})")
    return value


timing_options = [
    click.option("--cpu", "-c", default="pentium2-233", show_default=True, callback=_cpu_choice,
                 help="CPU preset (see `retrosim cpus`)"),
    click.option("--memory", "-m", help="memory preset (default: the CPU preset's)"),
    click.option("--repeat", "-n", default=2, show_default=True, callback=_bounded(1, MAX_REPEAT),
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
    probe = Machine.from_source(path, assembler=assembler, cpu=cpu)  # resolve the entry and check --args once
    entry = _entry(probe, entry)
    parse_args(args_text, probe)
    if repeat < 20:
        result = time_kernel(path, entry, setup=lambda m: parse_args(args_text, m)[0], cpu=cpu, memory=memory,
                             repeat=repeat, budget=budget, timeline_iterations=iterations, assembler=assembler)
    else:
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        # many calls: show where the emulation is (stderr, so --json stays clean)
        with Progress(TextColumn("{task.description}", markup=False), BarColumn(),
                      TextColumn("{task.completed}/{task.total}"), TimeElapsedColumn(), console=err_console,
                      transient=True) as bar:
            task = bar.add_task(f"emulating {entry} x {repeat:,}", total=repeat)
            result = time_kernel(path, entry, setup=lambda m: parse_args(args_text, m)[0], cpu=cpu, memory=memory,
                                 repeat=repeat, budget=budget, timeline_iterations=iterations, assembler=assembler,
                                 progress=lambda done, total: bar.update(task, completed=done))
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
    console.print(views.stall_table(result))


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
@click.option("--iterations", default=3, show_default=True, callback=_bounded(0, 1000), help="hot-loop iterations in the timeline")
@click.option("--json", "as_json", is_flag=True, help="print one JSON object (rows and timeline)")
def explain_cmd(source, entry, args_text, budget, assembler, cpu, memory, repeat, sets, iterations, as_json):
    from . import views

    result = _time(source, entry, args_text, budget, assembler, cpu, memory, repeat, iterations, sets=sets)
    if as_json:
        click.echo(json.dumps({"summary": views.summary(result), "instructions": views.explain_rows(result),
                               "timeline": views.timeline_rows(result)}, indent=2))
        return
    console.print(views.summary_table(result))
    console.print(views.stall_table(result))
    for table in views.explain_tables(result, console.width):
        console.print(table)
    for line in views.explain_legend(result):
        console.print(line, markup=False, highlight=False)
    text = views.timeline_text(result, columns=console.width)
    if text:
        console.print(f"[bold]timeline[/]: {iterations} iterations of the hot loop, from the middle of the last call")
        console.print(text, markup=False, highlight=False, soft_wrap=True)


def _cpu_list(values) -> list[str]:
    """--cpu may repeat, take comma-separated presets, or `all` (every preset)."""
    from .cpus import presets

    names = [n.strip() for v in values for n in v.split(",") if n.strip()] or ["pentium2-233"]
    if "all" in names:
        return presets.available()
    for n in names:
        if n not in presets.available():
            raise ArgumentError(f"unknown CPU preset '{n}' (choose one of: {', '.join(presets.available())}, or all)")
    return list(dict.fromkeys(names))


def _loop_explain_table(t) -> Table:
    """The explain table, narrowed to what a loop body needs (fits 80 columns for short bodies)."""
    from rich.markup import escape

    from . import views

    table = Table(title=f"{t.cpu}: per instruction, cycles per execution (full table: --json)")
    for col in ("instruction", "dec", "uops", "ports", "iss>ret", "stalls"):
        table.add_column(col, justify="right" if col in ("uops", "iss>ret") else "left")
    names = (("stall_dependency", "dep"), ("stall_port", "port"), ("stall_decode", "decode"),
             ("stall_partial", "partial"), ("stall_memory", "mem"), ("stall_store_forward", "fwd"),
             ("stall_window", "window"), ("mispredict_rate", "mispred"))
    for r in views.explain_rows(t.result):
        table.add_row(escape(r["instruction"]), r["decoder"], str(r["uops"]), r["ports"], f"{r['issue_to_retire']:g}",
                      " ".join(f"{short} {r[k]:g}" for k, short in names if r[k]))
    return table


@main.command("loop")
@click.argument("source")
@click.option("--cpu", "-c", "cpus", multiple=True,
              help="CPU preset; repeat or separate with commas for several, `all` for every preset [default: pentium2-233]")
@click.option("--syntax", type=click.Choice(["intel", "att"]), help="source syntax (default: detected; Intel if unsure)")
@click.option("--iterations", "-n", default=100, show_default=True,
              help="iterations per pass; counters are taken between iteration N/2 and N of the second pass")
@click.option("--reg", "regs", multiple=True, metavar="R=V", help="register start value, e.g. --reg ecx=1000")
@click.option("--timeline", "timeline", default=3, show_default=True, help="iterations shown in the timeline")
@click.option("--brief", is_flag=True, help="only the table of cycles per iteration")
@click.option("--assembler", type=click.Choice(["gnu", "zig"]), help="assembler back end (default: GNU as)")
@click.option("--json", "as_json", is_flag=True, help="print one JSON object")
def loop_cmd(source, cpus, syntax, iterations, regs, timeline, brief, assembler, as_json):
    """Time a bare loop body or basic block (FILE, or - for standard input): steady-state cycles per iteration."""
    from . import loop, views

    if source == "-":
        text, name = sys.stdin.read(), "<stdin>"
    else:
        path = Path(source)
        if not path.is_file():
            raise ArgumentError(f"{source}: no such file")
        text, name = path.read_text(errors="replace"), source
    timings = loop.time_body(text, _cpu_list(cpus), name, syntax, iterations, loop.parse_regs(regs), assembler,
                             timeline)
    if as_json:
        click.echo(json.dumps({"source": name, "registers": {k: f"{v:#010x}" for k, v in loop.parse_regs(regs).items()},
                               "results": [{"cpu": t.cpu, "memory": t.memory,
                                            "cycles_per_iteration": t.cycles_per_iteration,
                                            "uops_per_iteration": t.uops_per_iteration,
                                            "instructions_per_iteration": t.per_iteration["instructions"],
                                            "measured_iterations": t.iterations, "per_iteration": t.per_iteration,
                                            "instructions": views.explain_rows(t.result),
                                            "timeline": views.timeline_rows(t.result)} for t in timings]}, indent=2))
        return
    if not brief:
        for t in timings:
            if hasattr(t.result.model, "explain_cells"):  # a family with columns of its own (P5)
                for part in views.explain_tables(t.result, console.width):
                    console.print(part)
            else:
                console.print(_loop_explain_table(t))
            text_tl = views.timeline_text(t.result)
            if text_tl:
                console.print(f"[bold]timeline[/] on {t.cpu}: {timeline} iterations from the middle of the measured pass")
                console.print(text_tl, markup=False, highlight=False, soft_wrap=True)
    table = Table(title=f"{escape(name)}: steady state per iteration (iterations {iterations // 2}..{iterations})")
    for col in ("cpu", "cycles", "instr", "uops", "IPC", "main stalls (cycles)"):
        table.add_column(col, justify="left" if col in ("cpu", "main stalls (cycles)") else "right")
    for t in timings:
        p = t.per_iteration
        stalls = sorted(((p[k], k[6:].replace("_", " ")) for k in views.STALLS if p.get(k)), reverse=True)[:3]
        table.add_row(t.cpu, f"{t.cycles_per_iteration:.2f}", f"{p['instructions']:g}", f"{t.uops_per_iteration:g}",
                      f"{p['instructions'] / t.cycles_per_iteration:.2f}" if t.cycles_per_iteration else "-",
                      ", ".join(f"{what} {v:g}" for v, what in stalls) or "none")
    console.print(table)


@main.command("texture-loops")
@click.option("--cpu", "cpus", multiple=True, callback=lambda c, p, v: [_cpu_choice(c, p, x) for x in v],
              help="CPU preset (repeatable; default: every preset)")
@click.option("--out", default=None, type=click.Path(path_type=Path), help="Markdown file to write")
def texture_loops_cmd(cpus, out):
    """Cycles per pixel of the texture-mapping article's span loops on every preset (reports/texture-loops.md)."""
    from . import texture

    out = out or REPORTS_DIR / "texture-loops.md"
    texture.write_report(out, list(cpus) or None)  # also part of `retrosim report` and `check --reports`
    console.print(f"wrote {out}")


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
    for t in _cpu_tables(cpus, console.width):
        console.print(t)
    m = Table(title="memory presets (sources in sim/cpus/presets/memory/*.toml)", box=box.SIMPLE_HEAD,
              title_justify="left", pad_edge=False)
    for col in ("preset", "type", "burst (bus clocks)"):
        m.add_column(col, no_wrap=True)
    for name in memory_presets():
        d = load_dram(name)
        m.add_row(name, d.kind, "-".join(str(x) for x in d.burst))
    console.print(m)


def _cpu_tables(cpus, width: int) -> list:
    """The presets in one wide table (every cache in full) when `width` holds it, else a compact one:
    sizes only, with the latencies and clock ratios one `--json` away."""
    from .views import _natural_width

    def level(c, section: dict | None) -> str:
        return ("board " if "motherboard" in str((section or {}).get("location", "")) else "") + f"{c.size_kb}"

    def caches(c, full: bool) -> str:
        if c.l2 is None:
            return "no L2"
        raw = c.raw
        text = c.l2.describe() if full else level(c.l2, raw.get("l2"))
        if not full and c.l2.speed_ratio != 1.0:
            text += f" at {c.l2.speed_ratio:g}x"
        if c.board_cache:
            text += " + " + (f"board {c.board_cache.describe()}" if full else
                             level(c.board_cache, raw.get("l3") or raw.get("board_cache")))
        return text

    def build(full: bool) -> Table:
        t = Table(title="CPU presets (sources in sim/cpus/presets/*.toml)", box=box.SIMPLE_HEAD, title_justify="left",
                  pad_edge=False,
                  caption=("L1: size, ways, line, load-to-use clocks; L2 'x clock': its clock over the core's"
                           if full else "MHz: core and bus clocks; L1: instruction + data; 'board': the motherboard cache; 'at 0.5x': L2 at half the core clock; "
                           "ways and latencies with --json or a wider terminal"), caption_justify="left")
        cols = (["preset", "family", "MHz", "bus MHz", "L1I", "L1D", "L2", "memory"] if full else
                ["preset", "family", "MHz", "bus", "L1 KB", "L2 KB", "memory"])
        for col in cols:
            t.add_column(col, no_wrap=True, justify="right" if col in ("MHz", "bus", "bus MHz") else "left")
        for c in cpus:
            l1 = [c.l1i.describe(), c.l1d.describe()] if full else [f"{c.l1i.size_kb}+{c.l1d.size_kb}"]
            # truncated, as the parts are sold: 266.67 MHz is a Celeron 266 on a 66 MHz bus
            t.add_row(c.name, c.family.upper(), f"{int(c.core_mhz)}", f"{int(c.fsb_mhz)}", *l1, caches(c, full),
                      c.memory)
        return t

    wide = build(True)
    return [wide] if _natural_width(wide) <= width else [build(False)]


REPORTS_DIR = Path(__file__).resolve().parent.parent / "reports"
SCENES_DIR = Path(__file__).resolve().parent.parent / "scenes"


def _scene_paths(names) -> list[Path]:
    if not names:
        return sorted(SCENES_DIR.glob("*.toml"))
    paths = []
    for n in names:
        p = Path(n)
        p = p if p.suffix == ".toml" and p.exists() else SCENES_DIR / f"{n}.toml"
        if not p.exists():  # anything else that exists (a device, a pipe) is refused by load_scene
            known = ", ".join(sorted(q.stem for q in SCENES_DIR.glob("*.toml")))
            raise ArgumentError(f"no scene '{n}' (shipped scenes: {known})")
        paths.append(p)
    return paths


def _scenes(names) -> list:
    from .scene import load_scene

    return [load_scene(p) for p in _scene_paths(names)]


def _run_scenes(scenes, cpus, on_result=None, jobs: int | None = None) -> tuple[list, list[str]]:
    """Run scenes (Scene objects, or paths loaded one by one) with a progress bar per scene (on
    stderr, so --json output stays clean), timing on `jobs` worker processes. With `on_result`, each
    result is handed over as soon as its scene finishes and a failing scene does not stop the others:
    returns (results, failures). Without it the first failure is raised."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from .parallel import check_jobs
    from .runner import run_scene
    from .scene import load_scene

    jobs = check_jobs(jobs)
    results, failures = [], []
    with Progress(TextColumn("{task.description}", markup=False), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                  TimeElapsedColumn(), console=err_console, transient=False) as bar:
        for item in scenes:
            try:
                scene = load_scene(item) if isinstance(item, Path) else item
                steps = len(scene.variants) * (1 + len(list(cpus) or scene.cpus))
                task = bar.add_task(scene.name, total=steps)

                def progress(msg, task=task):
                    bar.update(task, advance=1, description=msg[:70])

                result = run_scene(scene, list(cpus) or None, progress, jobs=jobs)
                bar.update(task, completed=steps, description=f"{scene.name}: done")
                if result.pixels == 0:
                    bar.console.print(f"{scene.name}: the scene draws no pixels (degenerate, collinear, off-screen or "
                                      "sub-pixel triangles): every metric counts 0 covered pixels",
                                      markup=False, highlight=False, soft_wrap=True)
                if on_result is not None:
                    on_result(result)
            except RetrosimError as e:
                if on_result is None:
                    raise
                failures.append(one_line(str(e)))
                if item is not scenes[-1]:  # say it now when other scenes still run; the last line repeats it
                    bar.console.print(f"retrosim: error: {one_line(str(e))}", markup=False, highlight=False,
                                      soft_wrap=True)
                continue
            results.append(result)
    return results, failures


PARTIAL_DIR = REPORTS_DIR.parent / "build" / "reports"


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
@click.option("--cpu", "cpus", multiple=True, help="run on these presets instead of the scene's (preset[:memory]); "
              "without --out the reports then go to build/reports/, never over the committed ones")
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE",
              help="override a preset field of every CPU run, as in `time --set`; repeatable (like --cpu, "
                   "writes to build/reports/ without --out)")
@click.option("--out", type=click.Path(path_type=Path), default=None,
              help="directory for the Markdown, HTML, JSON, CSV and PNG reports [default: reports/, or "
                   "build/reports/ for a run restricted with --cpu or changed with --set]")
@_JOBS_OPTION
def report_cmd(scenes, cpus, sets, out, jobs):
    """Run scenes (default: every shipped scene) and write their reports; print a summary."""
    from .output import check_output_dir
    from .report import summary_tables, write_reports

    if out is None:
        # reports/ holds the committed reports, which CI compares with fresh ones: a run with other
        # CPUs would silently replace them with different content
        out = PARTIAL_DIR if cpus or sets else REPORTS_DIR
        if cpus or sets:
            say(f"--cpu/--set change the reports' content: writing to {out}/ (not over the committed reports in "
                f"{REPORTS_DIR}/; choose a directory with --out)")
            out.mkdir(parents=True, exist_ok=True)
    check_output_dir(out, "--out")  # before the work: a read-only or impossible folder fails at once
    paths = _scene_paths(scenes)
    if sets:
        from .scene import load_scene

        paths = [load_scene(p) for p in paths]
        cpus = _with_sets(paths, cpus, sets)

    def write(result):  # each scene's reports as soon as it finishes: a later failure keeps them
        say(f"wrote {', '.join(str(p) for p in write_reports(result, out))}")

    results, failures = _run_scenes(paths, cpus, on_result=write, jobs=jobs)
    if not scenes and not cpus and not sets and not failures:  # the default set also regenerates the conversion report
        err_console.print("[dim]conversion report: timing kernels/convert/loops.S ...[/]")
        say(f"wrote {_write_conversion_report(out)}")
        say(f"wrote {_write_texture_report(out)}")
    for part in summary_tables(results):
        console.print(part, highlight=False)
    if len(paths) == 1 and failures:
        raise RetrosimError(failures[0])
    if failures:
        raise RetrosimError(f"{len(failures)} of {len(paths)} scene(s) failed, the others' reports are written: "
                            + "; ".join(failures))


def _write_texture_report(out: Path) -> Path:
    from . import texture

    return texture.write_report(Path(out) / "texture-loops.md")


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
    baseline.load()  # a damaged baselines file fails before the work, not after it
    results, _ = _run_scenes(chosen, (), jobs=jobs)
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
                fresh.append(_write_texture_report(Path(tmp)))
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
        say(f"stale report: {p} (regenerate with `retrosim report`)")
    if drifts or stale:
        raise SystemExit(1)
    console.print(f"{sum(len(baseline.entries(r)) for r in results)} case(s) in {len(results)} scene(s) "
                  "match the baselines" + (" and the committed reports" if check_reports else ""))


@main.command("validate")
@click.option("--family", "fams", multiple=True, help="only these families (default: every validation/*.toml)")
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), default=REPORTS_DIR / "validation.md",
              show_default=True, help="Markdown report to write")
@click.option("--check", is_flag=True, help="write nothing; fail if the committed report differs from a fresh one")
def validate_cmd(fams, out, check):
    """Time published loop timings (validation/*.toml) and write reports/validation.md."""
    import time as _time

    from . import validation
    from .report import atomic_write

    start = _time.perf_counter()
    results = [validation.run_family(f) for f in validation.families(only=list(fams) or None)]
    text = validation.markdown(results)
    if check:
        committed = out.read_text() if out.is_file() else ""
        strip = lambda t: "\n".join(x for x in t.splitlines() if not x.startswith("Run time:"))  # noqa: E731
        if strip(committed) != strip(text):
            err_console.print(f"stale report: {out} (regenerate with `retrosim validate`)")
            raise SystemExit(1)
    else:
        if not out.parent.is_dir():
            raise ArgumentError(f"--out {out}: directory {out.parent} does not exist")
        atomic_write(out, text.encode())
        err_console.print(f"wrote {out}")
    t = Table(title=f"validation against published timings ({_time.perf_counter() - start:.1f} s)")
    for col in ("family", "preset", "cases", "MAPE", "within 1 cycle", "harness errors"):
        t.add_column(col, justify="left" if col in ("family", "preset") else "right")
    for fr in results:
        t.add_row(fr.family.family, fr.family.cpu, str(len(fr.timed)), f"{fr.mape():.1f} %", f"{fr.within_one():.0%}",
                  str(len(fr.results) - len(fr.timed)))
    console.print(t)


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
@click.option("--pixels", default=1 << 20, show_default=True, callback=_bounded(1, 1 << 22, " (the Python-hook mode keeps every instruction as Python objects, about 1 GB per million pixels)"), help="pixels in the Z-buffer span workload")
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
                      ("P6 model alone on the trace (pentium2-233)", "model_only"),
                      ("end to end: trace + K6 model (k6-233)", "k6_end_to_end"),
                      ("end to end: trace + P5 model (pentium-mmx-233)", "p5_end_to_end")):
        ips = result[f"{key}_ips"]
        table.add_row(mode, f"{result[f'{key}_seconds']:.3f}", f"{ips / 1e6:,.1f} M",
                      f"{result['unicorn_bare_ips'] / ips:,.1f}x slower" if key != "unicorn_bare" else "1x")
    console.print(table)
    console.print(f"native trace vs Python hooks: [bold]{result['native_vs_python']:.1f}x[/] faster (target >= 15x); "
                  f"native trace vs bare Unicorn: [bold]{result['bare_vs_native']:.1f}x[/] slower (target <= 10x); "
                  f"end to end: [bold]{result['end_to_end_ips'] / 1e6:.1f} M[/] instructions/s, "
                  f"{result['end_to_end_vs_native']:.2f} of the native trace's rate (target >= 0.5), "
                  f"{result['bare_vs_end_to_end']:.1f}x slower than bare Unicorn")


@main.command("conformance")
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), default=REPORTS_DIR / "conformance.md",
              show_default=True, help="where to write the report")
@click.option("--family", "families", multiple=True, type=click.Choice(["p6", "k6"]), help="only these families")
def conformance_cmd(out, families):
    """Run every table row's generated latency/throughput benchmark through the model on each preset
    of its family and write the comparison with the row's sourced figures (about 90 s of CPU time)."""
    from .conformance import write_report

    results, seconds = write_report(out, tuple(families) or ("p6", "k6"))
    for fam, (rows, _) in results.items():
        src = [r for r in rows if r.checked and not r.row.estimated]
        console.print(f"{fam}: {len(rows)} rows, {sum(r.checked for r in rows)} benchmarked, "
                      f"{sum(r.ok for r in src)}/{len(src)} sourced rows reproduced")
    console.print(f"wrote {out} in {seconds:.0f} s")


if __name__ == "__main__":
    main()
