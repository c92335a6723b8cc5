"""The models' speed check: each model alone on an emulated trace against the native trace's rate,
measured in one process, compared with ratios recorded in the repository.

A ratio of rates measured in one process moves little when the machine is loaded or slower: both
sides slow together. Each side is timed in the thread's CPU time (a preempted run does not count
the time it waited for a core) and the best of several interleaved rounds is kept. What is left
is the host's micro-architecture (caches, branch predictor), so the recorded ratios name the
machine they were measured on; `retrosim bench --record` measures them again.

The workload is `sim.timing.bench`'s Z-buffer span (fp16z_span), emulated once with the native
trace; "model alone" is `time_emulation` on a fresh copy of that emulation (decode, lowering and
the compiled core with its caches, as `bench`'s model_only), "native" is the same call emulated
again with the native trace.

Code placement. One compiled core runs at a speed that depends on where its machine code lands in
memory: byte-identical copies of the P6 core, each compiled and loaded at its own address, ran
5.6 to 9.6 M instructions/s in one process, each copy steady from run to run (the host's branch
predictor or instruction cache aliasing is suspected; this machine offers no counters to show
which). One placement is a random draw of about +-20 %, more than the 15 % the check guards, so
each model is timed in PLACEMENTS placements (the package's core and copies of its source under
build/speedcheck/, compiled once and cached) and its figure is their mean.
"""

from __future__ import annotations

import json
import os
import platform
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
BASELINE_FILE = ROOT / "benchmarks" / "model_speed.json"
PLACEMENT_DIR = ROOT / "build" / "speedcheck"  # the cores' copies (see the module docstring)
CPUS = ("pentium2-233", "k6-233", "pentium-mmx-233")  # one preset per family: P6, K6, P5
PIXELS = 1 << 18
ROUNDS = 3
PLACEMENTS = 4
TOLERANCE = 0.15  # a ratio more than 15 % below its recorded figure fails
ATTEMPTS = 3  # a failing measurement is repeated (a burst of load); a regression fails every time


def core_placements(family: str, n: int) -> list:
    """The family's compiled core module and n - 1 copies of its source, each a module of its own
    (numba compiles and caches each apart, so each lands at its own address). A copy's text carries
    a hash of the modules the cores compile in (sim/cpus, sim/memory): numba's cache of a copy
    would not see an edit to a helper it imports, a new text makes it compile again."""
    import importlib
    import importlib.util
    import sys

    from sim.inputfile import files_hash
    from sim.output import atomic_write

    package = importlib.import_module(f"sim.cpus.{family}.core")
    source = Path(package.__file__)
    compiled_in = files_hash((p for d in ("cpus", "memory") for p in (ROOT / "sim" / d).rglob("*.py")), ROOT)
    text = f"# speed-check copy of {source.relative_to(ROOT).as_posix()} ({compiled_in[:16]})\n" + source.read_text()
    modules = [package]
    PLACEMENT_DIR.mkdir(parents=True, exist_ok=True)
    for i in range(1, n):
        name = f"{family}_core_{i}"
        path = PLACEMENT_DIR / f"{name}.py"
        if not path.is_file() or path.read_text() != text:
            atomic_write(path, text.encode(), "speed-check copy of a core")
        spec = importlib.util.spec_from_file_location(f"sim_speedcheck_{name}", path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module
        spec.loader.exec_module(module)
        modules.append(module)
    return modules


def _placed(model, core_module) -> None:
    """Make `model`'s family time with `core_module` (a copy from :func:`core_placements`): the
    model module's core and its session class's (the two places a family's model reaches its core)."""
    import importlib

    module = importlib.import_module(type(model).__module__)
    module.core = core_module
    for value in vars(module).values():
        if isinstance(value, type) and getattr(value, "CORE", None) is not None:
            value.CORE = core_module


def measure(pixels: int = PIXELS, rounds: int = ROUNDS, cpus=CPUS, progress=None,
            placements: int = PLACEMENTS) -> dict:
    """Instructions per CPU-second of the native trace and of each model alone on the same trace,
    and each model's ratio to the native trace: per placement of its core the best of `rounds`
    interleaved rounds, the mean over `placements` placements (see the module docstring)."""
    from sim.cpus.build import make_model
    from sim.guest.emu import Machine
    from sim.guest.kernels import kernels_root
    from sim.timing.bench import SPAN_KERNEL, span_emulation, span_workload
    from sim.timing.kernel import time_emulation

    zinit, (z, dz, colour) = span_workload(pixels)
    source = kernels_root() / SPAN_KERNEL
    m = Machine.from_source(source)

    def native(n: int = pixels) -> tuple[float, int]:
        m.arena.reset()
        zb, fb = m.arena.put(zinit[:n]), m.arena.put(np.zeros(n, np.uint16))
        start = time.thread_time()
        r = m.call("fp16z_span", zb, fb, n, z, dz, colour, trace=True, budget=0)
        return time.thread_time() - start, r.instructions

    emu = span_emulation(pixels)
    models = {cpu: make_model(cpu) for cpu in cpus}
    native(4096)  # warm up: translation cache, trace buffer
    cores = {}
    for cpu in cpus:  # compile (or load) each placement of each core and touch its tables
        if progress is not None:
            progress(f"compiling or loading {placements} placement(s) of the {cpu} model's core")
        cores[cpu] = core_placements(models[cpu].family, placements)
        for module in cores[cpu]:
            _placed(models[cpu], module)
            time_emulation(replace(emu), models[cpu])
    best = {"native": float("inf"), **{(cpu, k): float("inf") for cpu in cpus for k in range(placements)}}
    instructions = 0
    try:
        for r in range(rounds):
            if progress is not None:
                progress(f"round {r + 1} of {rounds}")
            for cpu in cpus:
                for k, module in enumerate(cores[cpu]):
                    seconds, instructions = native()
                    best["native"] = min(best["native"], seconds)
                    _placed(models[cpu], module)
                    start = time.thread_time()
                    time_emulation(replace(emu), models[cpu])  # a fresh copy: nothing decoded is reused
                    best[(cpu, k)] = min(best[(cpu, k)], time.thread_time() - start)
    finally:
        for cpu in cpus:
            _placed(models[cpu], cores[cpu][0])
    native_ips = instructions / best["native"]
    out = {}
    for cpu in cpus:
        ips = [instructions / best[(cpu, k)] for k in range(placements)]
        mean = sum(ips) / len(ips)
        out[cpu] = {"ips": mean, "ratio": mean / native_ips, "placements": ips}
    return {"pixels": pixels, "rounds": rounds, "placements": placements, "instructions": instructions,
            "native_ips": native_ips, "models": out}


def machine() -> dict:
    """What the figures were measured on: the host CPU, its cores, Python and numba."""
    import numba

    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu": model, "cores": os.cpu_count(), "python": platform.python_version(), "numba": numba.__version__}


def record(result: dict, path: Path = BASELINE_FILE) -> None:
    """Write the measured ratios as the baseline (atomically)."""
    doc = {"about": "model speed ratios (each model alone / the native trace, instructions per CPU-second, "
                    "the mean over placements of each core of the best of the rounds); `retrosim bench --check` "
                    "fails when one falls more than "
                    f"{TOLERANCE:.0%} below; `retrosim bench --record` re-measures",
           "machine": machine(), "pixels": result["pixels"], "rounds": result["rounds"],
           "placements": result.get("placements", 1),
           "ratios": {cpu: round(v["ratio"], 4) for cpu, v in result["models"].items()}}
    write_baseline(path, doc, "speed baseline")


def load(path: Path = BASELINE_FILE) -> dict:
    return read_baseline(path, "speed baseline", "retrosim bench --record",
                         lambda doc: {**doc, "ratios": {str(k): float(v) for k, v in doc["ratios"].items()}})


def write_baseline(path: Path, doc: dict, what: str) -> None:
    """A benchmark baseline (JSON) written atomically."""
    from sim.output import atomic_write

    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, (json.dumps(doc, indent=2) + "\n").encode(), what)


def read_baseline(path: Path, what: str, record_command: str, parse) -> dict:
    """A benchmark baseline read as bounded input: `parse` turns its JSON into the figures, and any
    malformed part is one error naming the file and the command that records one."""
    from sim.errors import ArgumentError
    from sim.inputfile import read_bounded

    try:
        return parse(json.loads(read_bounded(path, 1 << 20, what, ArgumentError).decode("utf-8")))
    except (ValueError, KeyError, TypeError, AttributeError) as e:  # UnicodeDecodeError is a ValueError
        article = "an" if what[0] in "aeiou" else "a"
        raise ArgumentError(f"{path}: not {article} {what} ({e}); record one with `{record_command}`")


def regressions(result: dict, baseline: dict, tolerance: float = TOLERANCE) -> list[str]:
    """One line per model whose ratio fell more than `tolerance` below the baseline's."""
    lines = []
    for cpu, want in baseline["ratios"].items():
        got = result["models"].get(cpu)
        if got is not None and got["ratio"] < want * (1 - tolerance):
            lines.append(f"{cpu}: {got['ratio']:.3f} of the native trace's rate, recorded {want:.3f} "
                         f"({got['ratio'] / want - 1:+.0%}; more than {tolerance:.0%} slower)")
    return lines


def measure_fresh(**kw) -> dict:
    """:func:`measure` in a new process: the same compiled code runs up to a fifth slower or faster
    from one process to the next (where the code and the arrays land in memory), so a repeated
    measurement is made in another one."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(measure, **kw).result()


def check(baseline: dict, attempts: int = ATTEMPTS, progress=None, **kw) -> tuple[dict, list[str]]:
    """Measure and compare; a failing comparison is measured again in a new process, up to
    `attempts` times, and the best ratio of each model over the attempts is kept (load only ever
    lowers a ratio)."""
    cpus = tuple(baseline["ratios"])
    kw.setdefault("pixels", int(baseline.get("pixels", PIXELS)))
    best = None
    for attempt in range(attempts):
        result = (measure(cpus=cpus, progress=progress, **kw) if attempt == 0 else
                  measure_fresh(cpus=cpus, **kw))
        if best is None:
            best = result
        else:
            for cpu, v in result["models"].items():
                if v["ratio"] > best["models"][cpu]["ratio"]:
                    best["models"][cpu] = v
        failed = regressions(best, baseline)
        if not failed:
            break
        if progress is not None and attempt + 1 < attempts:
            progress(f"{len(failed)} ratio(s) below the baseline: measuring again")
    return best, failed
