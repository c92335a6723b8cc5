"""Speed benchmark: the same Z-buffer workload emulated three ways, measured in one run.

End to end (emulate with the native trace, decode, time on a CPU model: `sim.timing.kernel.time_kernel`,
which runs the model beside the emulator on the streamed trace, sim/timing/stream.py) is compared with the
native trace alone; `model_only` is the timing model alone on an emulated trace (decode included),
the part of end to end that emulation does not hide. `cores` says how many host cores the run could
use: with one, streaming cannot overlap the two.

Figures are ratios of one run on one machine; absolute numbers vary between machines, which is
why nothing here is asserted in tests.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from sim import reference as ref
from sim.guest.emu import Machine
from sim.guest.kernels import kernels_root

SPAN_KERNEL = "zbuffer/fp16z.S"


def span_workload(pixels: int) -> tuple[np.ndarray, tuple[int, int, int]]:
    """A depth buffer holding an earlier noisy surface, and a ramp that crosses it: the depth
    test passes and fails in long and short runs, as it does in a scene."""
    rng = np.random.default_rng(1998)
    x = np.arange(pixels)
    earlier = (0x30000000 + 0x08000000 * np.sin(x / 900.0) + rng.integers(0, 1 << 22, pixels)).astype(np.uint32)
    return ref.fp16z_encode(earlier), (0x28000000, 0x18000000 // pixels, 0x7BEF)


def span_emulation(pixels: int, isa_cpu: str | None = None):
    """The span workload's call emulated once with the native trace (no instruction budget): the
    trace every model-alone measurement times (bench's model_only, the speed check, the instruction count)."""
    from sim.timing.kernel import emulate

    zinit, (z, dz, colour) = span_workload(pixels)

    def setup(m):
        return [m.arena.put(zinit), m.arena.put(np.zeros(pixels, np.uint16)), pixels, z, dz, colour]

    return emulate(kernels_root() / SPAN_KERNEL, "fp16z_span", setup, repeat=1, budget=0, isa_cpu=isa_cpu)


def run_bench(pixels: int = 1 << 20, progress=None) -> dict:
    m = Machine.from_source(kernels_root() / SPAN_KERNEL)
    zinit, (z, dz, colour) = span_workload(pixels)

    def once(trace, n=pixels):
        m.arena.reset()
        zb = m.arena.put(zinit[:n])
        fb = m.arena.put(np.zeros(n, np.uint16))
        start = time.perf_counter()
        r = m.call("fp16z_span", zb, fb, n, z, dz, colour, trace=trace, budget=0)
        return time.perf_counter() - start, r

    from sim.parallel import default_jobs

    results: dict = {"pixels": pixels, "cores": default_jobs()}
    for mode, trace in (("unicorn_bare", False), ("python_hook", "python"), ("native_trace", True)):
        if progress is not None:
            progress.print(f"[dim]measuring {mode.replace('_', ' ')} ...[/]")
        once(trace, 4096)  # warm up: translation cache, trace buffer, numba
        seconds, r = once(trace)
        if trace is True:
            results["instructions"] = r.instructions
        results[f"{mode}_seconds"] = seconds
    if progress is not None:
        progress.print("[dim]measuring end to end (emulate + trace + decode + P6 model on pentium2-233) ...[/]")
    results["end_to_end_seconds"] = _end_to_end(zinit, z, dz, colour, pixels, "pentium2-233")
    if progress is not None:
        progress.print("[dim]measuring the P6 model alone on the emulated trace (pentium2-233) ...[/]")
    results["model_only_seconds"] = _model_only(pixels, "pentium2-233")
    if progress is not None:
        progress.print("[dim]measuring end to end with the K6 model (k6-233) ...[/]")
    results["k6_end_to_end_seconds"] = _end_to_end(zinit, z, dz, colour, pixels, "k6-233")
    if progress is not None:
        progress.print("[dim]measuring end to end with the P5 model (pentium-mmx-233) ...[/]")
    results["p5_end_to_end_seconds"] = _end_to_end(zinit, z, dz, colour, pixels, "pentium-mmx-233")
    for prefix, cpu in (("k6_", "k6-233"), ("p5_", "pentium-mmx-233")):
        if progress is not None:
            progress.print(f"[dim]measuring the {prefix[:2].upper()} model alone on the emulated trace ({cpu}) ...[/]")
        results[f"{prefix}model_only_seconds"] = _model_only(pixels, cpu)
    n = results["instructions"]
    for mode in ("unicorn_bare", "python_hook", "native_trace", "end_to_end", "model_only", "k6_end_to_end",
                 "p5_end_to_end", "k6_model_only", "p5_model_only"):
        results[f"{mode}_ips"] = n / results[f"{mode}_seconds"]
    for prefix in ("", "k6_", "p5_"):  # each model alone against the native trace (issue 34's target: >= 0.8)
        results[f"{prefix}model_only_vs_native"] = results[f"{prefix}model_only_ips"] / results["native_trace_ips"]
    results["end_to_end_vs_native"] = results["end_to_end_ips"] / results["native_trace_ips"]
    results["native_vs_python"] = results["native_trace_ips"] / results["python_hook_ips"]
    results["bare_vs_native"] = results["unicorn_bare_ips"] / results["native_trace_ips"]
    results["bare_vs_end_to_end"] = results["unicorn_bare_ips"] / results["end_to_end_ips"]
    return results


def _end_to_end(zinit, z, dz, colour, pixels, cpu: str) -> float:
    """Seconds to emulate (traced), decode and time one call on `cpu` with its caches."""
    from sim.timing.kernel import time_kernel

    def setup(m):
        return [m.arena.put(zinit[:n]), m.arena.put(np.zeros(n, np.uint16)), n, z, dz, colour]

    n = 4096
    time_kernel(kernels_root() / SPAN_KERNEL, "fp16z_span", setup, cpu=cpu, repeat=1)  # warm up
    n = pixels
    best = float("inf")
    for _ in range(2):  # the best of two: the first also pays for first-touch page faults
        start = time.perf_counter()
        time_kernel(kernels_root() / SPAN_KERNEL, "fp16z_span", setup, cpu=cpu, repeat=1, budget=0)
        best = min(best, time.perf_counter() - start)
    return best


def _model_only(pixels, cpu: str) -> float:
    """Seconds to time an already emulated call on `cpu` (decode, ISA check, model with its caches):
    the best of two, each on a fresh emulation object so that nothing decoded is reused."""
    from sim.cpus.build import make_model
    from sim.timing.kernel import time_emulation

    model = make_model(cpu)
    emu = span_emulation(pixels, isa_cpu=cpu)
    best = float("inf")
    for _ in range(2):
        fresh = replace(emu)  # the same trace, no decoder cached yet
        start = time.perf_counter()
        time_emulation(fresh, model)
        best = min(best, time.perf_counter() - start)
    return best
