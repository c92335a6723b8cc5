"""The models' instruction count: host instructions per guest instruction of each model alone on
the speed check's trace, counted by valgrind, compared with counts recorded in the repository.

The speed check (sim/timing/speedcheck.py) times the models, and a time moves with where the
compiled code lands (about +-20 % for one placement of the P6 core) and with the host; a count
does not. Each model is counted in two child processes under ``valgrind --tool=cachegrind``: one
times the trace once after a warm-up, the other twice; the difference is one timing. Only code
without a symbol counts (valgrind's ``???``): numba's compiled functions, and Unicorn's translated
guest code, which both children run alike and the difference cancels; the interpreter, numpy and
LLVM have symbols and are left out, so the count is the compiled model's own.

The children compile for ``NUMBA_CPU_NAME=generic`` (no CPU features) into their own numba cache
(build/speedcount/), so the machine code, and with it the count, is the same on every x86-64 host
with the same Python, numba and llvmlite; the baseline names those versions. Same versions, same
source: the same count to a few parts in a million (where an array lands moves a few instructions
of a loop's alignment handling), whatever else the machine is doing. A change that makes a model cost more than TOLERANCE
more per guest instruction fails; a deliberate one re-records with `retrosim bench --count --record`.
"""

from __future__ import annotations

import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BASELINE_FILE = ROOT / "benchmarks" / "model_count.json"
CACHE_DIR = ROOT / "build" / "speedcount"  # the generic-CPU numba cache of the children
CPUS = ("pentium2-233", "k6-233", "pentium-mmx-233")  # one preset per family: P6, K6, P5
PIXELS = 1 << 16
TOLERANCE = 0.05  # fail a model costing 5 % more per guest instruction (a count repeats to parts in a million)
CHILD_SECONDS = 900  # one child under valgrind takes about 30 s; a hung one is stopped


def versions() -> dict:
    """What decides the compiled code besides the source: Python, numba, llvmlite."""
    import llvmlite
    import numba

    return {"python": platform.python_version(), "numba": numba.__version__, "llvmlite": llvmlite.__version__}


def _env() -> dict:
    env = dict(os.environ)
    env.update(NUMBA_CPU_NAME="generic", NUMBA_CACHE_DIR=str(CACHE_DIR), PYTHONHASHSEED="0",
               OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    env.pop("NUMBA_CPU_FEATURES", None)  # generic's default: none
    env.pop("NUMBA_DISABLE_JIT", None)
    return env


def _child_command(cpus, pixels: int, timings: int) -> list[str]:
    return [sys.executable, "-m", "sim.timing.speedcount", str(pixels), str(timings), *cpus]


def _run(command: list[str], what: str) -> str:
    from sim.errors import RetrosimError

    try:
        done = subprocess.run(command, env=_env(), capture_output=True, text=True, timeout=CHILD_SECONDS)
    except subprocess.TimeoutExpired:
        raise RetrosimError(f"instruction count: {what} did not finish in {CHILD_SECONDS} s")
    if done.returncode != 0:
        tail = "\n".join(done.stderr.strip().splitlines()[-5:])
        raise RetrosimError(f"instruction count: {what} failed (exit {done.returncode}):\n{tail}")
    return done.stdout


def unsymbolled_instructions(path: Path) -> int:
    """Instructions a cachegrind output file counts in code without a symbol (``fn=???``)."""
    total = 0
    counting = False
    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            if line.startswith("fn="):
                counting = line.strip() == "fn=???"
            elif counting and line[:1].isdigit():
                fields = line.split()
                if len(fields) > 1:
                    total += int(fields[1])
    return total


def measure(cpus=CPUS, pixels: int = PIXELS, progress=None) -> dict:
    """Host instructions per guest instruction of each model alone (see the module docstring)."""
    from sim.errors import ArgumentError

    valgrind = shutil.which("valgrind")
    if valgrind is None:
        raise ArgumentError("the instruction count needs valgrind on PATH (Debian: apt-get install valgrind)")
    CACHE_DIR.mkdir(parents=True, exist_ok=True)
    if progress is not None:
        progress("compiling or loading the models for a generic x86-64 CPU")
    _run(_child_command(cpus, min(pixels, 4096), 1), "compiling the models")  # natively: valgrind only loads them
    out = {}
    with tempfile.TemporaryDirectory(prefix="retrosim-count-") as tmp:
        for cpu in cpus:
            counts = []
            for timings in (1, 2):
                if progress is not None:
                    progress(f"{cpu}: counting {timings} timing(s) under valgrind")
                log = Path(tmp) / f"{cpu}.{timings}.out"
                stdout = _run([valgrind, "--tool=cachegrind", "--cache-sim=no", f"--cachegrind-out-file={log}",
                               *_child_command([cpu], pixels, timings)], f"{cpu} under valgrind")
                guest = json.loads(stdout.strip().splitlines()[-1])["instructions"]
                counts.append(unsymbolled_instructions(log))
            out[cpu] = {"host_per_guest": round((counts[1] - counts[0]) / guest, 1)}
    return {"pixels": pixels, "instructions": guest, "versions": versions(), "models": out}


def record(result: dict, path: Path = BASELINE_FILE) -> None:
    """Write the measured counts as the baseline (atomically)."""
    from sim.timing.speedcheck import write_baseline

    doc = {"about": "host instructions per guest instruction of each model alone on the speed check's trace, "
                    "counted by valgrind for a generic x86-64 CPU; `retrosim bench --count` fails when one grows "
                    f"more than {TOLERANCE:.0%}; `retrosim bench --count --record` re-measures",
           "versions": result["versions"], "pixels": result["pixels"],
           "host_per_guest": {cpu: v["host_per_guest"] for cpu, v in result["models"].items()}}
    write_baseline(path, doc, "instruction-count baseline")


def load(path: Path = BASELINE_FILE) -> dict:
    from sim.timing.speedcheck import read_baseline

    return read_baseline(path, "instruction-count baseline", "retrosim bench --count --record", lambda doc: {
        **doc, "host_per_guest": {str(k): float(v) for k, v in doc["host_per_guest"].items()},
        "versions": {str(k): str(v) for k, v in doc.get("versions", {}).items()},
        "pixels": int(doc.get("pixels", PIXELS))})


def regressions(result: dict, baseline: dict, tolerance: float = TOLERANCE) -> list[str]:
    """One line per model that costs more than `tolerance` more per guest instruction than recorded."""
    lines = []
    for cpu, want in baseline["host_per_guest"].items():
        got = result["models"].get(cpu)
        if got is not None and got["host_per_guest"] > want * (1 + tolerance):
            lines.append(f"{cpu}: {got['host_per_guest']:.1f} host instructions per guest instruction, recorded "
                         f"{want:.1f} ({got['host_per_guest'] / want - 1:+.1%}; more than {tolerance:.0%} more)")
    return lines


def _child(argv: list[str]) -> None:
    """Time the speed check's trace `timings` times on each CPU after one warm-up timing; print
    the guest instruction count as JSON (the parent counts the host instructions)."""
    from dataclasses import replace

    from sim.cpus.build import make_model
    from sim.timing.bench import span_emulation
    from sim.timing.kernel import time_emulation

    pixels, timings, cpus = int(argv[0]), int(argv[1]), argv[2:]
    emu = span_emulation(pixels)
    for cpu in cpus:
        model = make_model(cpu)
        for _ in range(1 + timings):  # the first compiles or loads the model's code
            time_emulation(replace(emu), model)
    print(json.dumps({"instructions": int(len(emu.trace.pc))}))


if __name__ == "__main__":
    _child(sys.argv[1:])
