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
"""

from __future__ import annotations

import json
import os
import platform
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

BASELINE_FILE = Path(__file__).resolve().parents[2] / "benchmarks" / "model_speed.json"
CPUS = ("pentium2-233", "k6-233", "pentium-mmx-233")  # one preset per family: P6, K6, P5
PIXELS = 1 << 18
ROUNDS = 5
TOLERANCE = 0.15  # a ratio more than 15 % below its recorded figure fails
ATTEMPTS = 3  # a failing measurement is repeated (a burst of load); a regression fails every time


def measure(pixels: int = PIXELS, rounds: int = ROUNDS, cpus=CPUS, progress=None) -> dict:
    """Instructions per CPU-second of the native trace and of each model alone on the same trace,
    the best of `rounds` interleaved rounds, and each model's ratio to the native trace."""
    from sim.cpus.build import make_model
    from sim.guest.emu import Machine
    from sim.guest.kernels import kernels_root
    from sim.timing.bench import SPAN_KERNEL, span_workload
    from sim.timing.kernel import emulate, time_emulation

    zinit, (z, dz, colour) = span_workload(pixels)
    source = kernels_root() / SPAN_KERNEL
    m = Machine.from_source(source)

    def native(n: int = pixels) -> tuple[float, int]:
        m.arena.reset()
        zb, fb = m.arena.put(zinit[:n]), m.arena.put(np.zeros(n, np.uint16))
        start = time.thread_time()
        r = m.call("fp16z_span", zb, fb, n, z, dz, colour, trace=True, budget=0)
        return time.thread_time() - start, r.instructions

    def setup(mm):
        return [mm.arena.put(zinit), mm.arena.put(np.zeros(pixels, np.uint16)), pixels, z, dz, colour]

    emu = emulate(source, "fp16z_span", setup, repeat=1, budget=0)
    models = {cpu: make_model(cpu) for cpu in cpus}
    native(4096)  # warm up: translation cache, trace buffer
    for cpu in cpus:  # compile (or load) each core and touch its tables
        if progress is not None:
            progress(f"warming the {cpu} model")
        time_emulation(replace(emu), models[cpu])
    best = {"native": float("inf"), **{cpu: float("inf") for cpu in cpus}}
    instructions = 0
    for r in range(rounds):
        if progress is not None:
            progress(f"round {r + 1} of {rounds}")
        for cpu in cpus:
            seconds, instructions = native()
            best["native"] = min(best["native"], seconds)
            start = time.thread_time()
            time_emulation(replace(emu), models[cpu])  # a fresh copy: nothing decoded is reused
            best[cpu] = min(best[cpu], time.thread_time() - start)
    native_ips = instructions / best["native"]
    return {"pixels": pixels, "rounds": rounds, "instructions": instructions, "native_ips": native_ips,
            "models": {cpu: {"ips": instructions / best[cpu], "ratio": best["native"] / best[cpu]} for cpu in cpus}}


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
    from sim.output import atomic_write

    doc = {"about": "model speed ratios (each model alone / the native trace, instructions per CPU-second, "
                    "best of the rounds); `retrosim bench --check` fails when one falls more than "
                    f"{TOLERANCE:.0%} below; `retrosim bench --record` re-measures",
           "machine": machine(), "pixels": result["pixels"], "rounds": result["rounds"],
           "ratios": {cpu: round(v["ratio"], 4) for cpu, v in result["models"].items()}}
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, (json.dumps(doc, indent=2) + "\n").encode(), "speed baseline")


def load(path: Path = BASELINE_FILE) -> dict:
    from sim.errors import ArgumentError
    from sim.inputfile import read_bounded

    try:
        doc = json.loads(read_bounded(path, 1 << 20, "speed baseline", ArgumentError).decode("utf-8"))
        ratios = {str(k): float(v) for k, v in doc["ratios"].items()}
    except (ValueError, KeyError, TypeError, AttributeError) as e:  # UnicodeDecodeError is a ValueError
        raise ArgumentError(f"{path}: not a speed baseline ({e}); record one with `retrosim bench --record`")
    return {**doc, "ratios": ratios}


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
