"""The `retrosim` command group and what its commands share: error printing, kernel and timing
options, CPU choices, where reports and scenes live (`--args` parsing is sim.guest.args)."""

from __future__ import annotations

import signal
import sys
import threading
from pathlib import Path

import click
import numpy as np
from rich.console import Console

from sim.guest import kernels as catalogue_mod
from sim.guest.args import ARGS_HELP, parse_args  # noqa: F401  (parse_args: shared by the kernel commands)
from sim.errors import ArgumentError, RetrosimError

console = Console()
err_console = Console(stderr=True)

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


def load_machine(source: str, assembler: str | None, cpu: str | None = None):
    """A machine holding the kernel `source`, assembled for the CPU preset `cpu` (None: plain
    i686). The preset is read here, once; the guest stages get its GuestCpu."""
    from sim.guest.emu import Machine
    from sim.timing.kernel import guest_cpu

    return Machine.from_source(catalogue_mod.resolve(source), assembler=assembler, cpu=guest_cpu(cpu))


def choose_entry(machine, entry: str | None) -> str:
    if entry:
        return entry
    # declared entry points first; a file without `# @entry` comments offers its global symbols
    candidates = list(machine.entries) or sorted(machine.image.global_symbols)
    if len(candidates) == 1:
        return candidates[0]
    names = ", ".join(candidates) or "the file defines no global symbol"
    raise ArgumentError(f"{machine.image.path}: choose an entry point with --entry ({names})")


def buffer_summary(machine, buffers) -> list[dict]:
    out = []
    for spec, address, dtype, count in buffers:
        data = machine.arena.get(address, dtype, count)
        out.append({"arg": spec, "address": address, "first": data[:8].tolist(),
                    "sum": float(data.sum(dtype=np.float64)) if dtype.kind == "f" else int(data.astype(np.int64).sum())})
    return out


def _set_syntax(ctx, param, value):
    """--syntax applies to every source the command assembles (set for each invocation, None too)."""
    from sim.guest import asm

    asm.use_syntax(value)
    return value


def bounded(low: int, high: int | None = None, note: str = ""):
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
    click.option("--args", "args_text", help=ARGS_HELP),
    click.option("--budget", default=200_000_000, show_default=True, callback=bounded(0),
                 help="instruction budget (0 = unlimited; traces are still bounded by RETROSIM_TRACE_MB)"),
    click.option("--assembler", type=click.Choice(["gnu", "zig"]), help="assembler back end (default: GNU as)"),
    click.option("--syntax", type=click.Choice(["intel", "att"]), expose_value=False, callback=_set_syntax,
                 help="syntax of a source without .intel_syntax/.att_syntax (default: detected: % register "
                      "prefixes mean AT&T, PTR or bare register names Intel; if both or neither, AT&T as GNU as)"),
]


def with_kernel_options(fn):
    for option in reversed(kernel_options):
        fn = option(fn)
    return fn


def cpu_choice(ctx, param, value):
    from sim.cpus import presets

    if value not in presets.available():
        raise click.BadParameter(f"unknown CPU preset '{value}' (choose one of: {', '.join(presets.available())})")
    return value


memory_option = click.option("--memory", "-m", help="memory preset (default: the CPU preset's)")
set_option = click.option("--set", "sets", multiple=True, metavar="KEY=VALUE",
                          help="override a preset field (l2.size_kb=256, l2.size_kb=none, l2.latency_cycles=10, "
                               "write_allocate.mode=full, estimates.uop_queue=8, memory=sdram-pc100); repeatable")
timing_options = [
    click.option("--cpu", "-c", default="pentium2-233", show_default=True, callback=cpu_choice,
                 help="CPU preset (see `retrosim cpus`)"),
    memory_option,
    click.option("--repeat", "-n", default=2, show_default=True, callback=bounded(1, MAX_REPEAT),
                 help="calls in one machine state; the last is reported (caches and predictors warm)"),
    set_option,
]


def _overrides(sets) -> tuple[dict, str | None]:
    """--set KEY=VALUE items as (preset overrides, memory preset or None); checked by make_model."""
    from sim.cpus.overrides import parse_value

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


def resolve_machine(cpu: str, sets, memory: str | None = None):
    """The resolved machine (sim.cpus.machine.Machine) of a CPU preset, --set items and --memory
    (which wins over a --set memory=...), validated now: the commands pass it down (its `label`,
    `memory_named`; sim.cpus.build.make_model(machine) is its timing model)."""
    from sim.cpus.machine import resolve
    from sim.cpus.overrides import load_dram

    overrides, set_memory = _overrides(sets)
    if set_memory is not None:
        load_dram(set_memory)
    return resolve(cpu, overrides, memory or set_memory)  # one clear error for an unknown key or an impossible value


def with_timing_options(fn):
    for option in reversed(timing_options):
        fn = option(fn)
    return fn


def _split_cpus(value: str) -> list[str]:
    """Comma-separated CPUs; a comma inside a label's braces (pentium2-233{l2.size_kb=256,...}) is its own."""
    out, depth, start = [], 0, 0
    for i, ch in enumerate(value + ","):
        depth += {"{": 1, "}": -1}.get(ch, 0)
        if ch == "," and depth <= 0:
            out.append(value[start:i].strip())
            start = i + 1
    return [n for n in out if n]


def cpu_list(values) -> list[str]:
    """--cpu may repeat, take comma-separated presets or machine labels (k6-233{write_allocate.mode=full}),
    or `all` (every preset)."""
    from sim.cpus import presets
    from sim.cpus.machine import MachineKey

    names = [n for v in values for n in _split_cpus(v)]
    if values and not names:  # `--cpu ,,,` or `--cpu ''`: a mistake, not a request for the default
        raise ArgumentError(f"--cpu {','.join(values)!r}: names no CPU")
    names = names or ["pentium2-233"]
    if "all" in names:
        return presets.available()
    for n in names:
        preset = MachineKey.parse(n).preset
        if preset not in presets.available():
            raise ArgumentError(f"unknown CPU preset '{preset}' (choose one of: "
                                f"{', '.join(presets.available())}, or all)")
    return list(dict.fromkeys(names))


REPORTS_DIR = Path(__file__).resolve().parents[2] / "reports"
SCENES_DIR = Path(__file__).resolve().parents[2] / "scenes"
