"""The texture-mapping article's span loops (kernels/texture/loops.S), a study: bit-exact
references, a workload, and the cycles per pixel and divide costs of every preset, which the
report renders (``retrosim texture-loops``, reports/texture-loops.md through
sim/reports/texture_loops.py).

Cycles per pixel are measured as the difference between a span of 2N and one of N pixels on the
same model (warm caches, second call of two), so the setup and call overhead cancel; the counters
shown are the same difference, per pixel. Nothing here is fitted to the article's figures: they
are what the models are compared with.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim import output
from sim.cpus import presets
from sim.cpus.build import make_model
from sim.cpus.families import order as family_order
from sim.guest.kernels import kernels_root
from sim.reports.texture_loops import render
from sim.timing.kernel import time_kernel

KERNEL = "texture/loops.S"
LOOPS = {"tex9": "the 9-instruction loop", "tex5": "the reordered 5-clock loop",
         "tex4": "the 4-clock loop (count and pointer combined)"}
TEX_ALIGN = 1 << 16


def texture(seed: int = 1997) -> np.ndarray:
    """A 256x256 8-bit texture (rows on 256-byte boundaries, as the loops require)."""
    return np.random.default_rng(seed).integers(0, 256, 65536, dtype=np.uint8)


def span_reference(tex: np.ndarray, count: int, u: int, v: int, du: int, dv: int) -> np.ndarray:
    """The span in exact 16.16 arithmetic: pixel k = tex[Vi * 256 + Ui] of u + k du, v + k dv,
    integer parts modulo 256 (what tex5 and tex4 compute)."""
    k = np.arange(count, dtype=np.int64)
    uk = (u + k * du) & 0xFFFFFFFF
    vk = (v + k * dv) & 0xFFFFFFFF
    return tex[(((vk >> 16) & 255) << 8) | ((uk >> 16) & 255)]


def tex9_reference(tex: np.ndarray, count: int, u: int, v: int, du: int, dv: int) -> np.ndarray:
    """tex9 register by register: its ADD EAX,ECX also adds the count in CX to AX (see loops.S)."""
    M = 0xFFFFFFFF
    ui, vi = (u >> 16) & 255, (v >> 16) & 255
    edx = ((u << 16) & M) | (((dv >> 16) & 255) << 8) | ((du >> 16) & 255)
    eax = (v << 16) & M
    esi = (du << 16) & M
    ecx = ((dv << 16) & M) | count
    out = np.empty(count, np.uint8)
    for k in range(count):
        al = int(tex[(vi << 8) | ui])
        eax = (eax & ~0xFF & M) | al
        out[k] = al
        s = edx + esi
        cf = s >> 32
        edx = s & M
        t = ui + (edx & 255) + cf
        ui = t & 255
        s = eax + ecx
        cf = s >> 32
        eax = s & M
        vi = (vi + ((edx >> 8) & 255) + cf) & 255
        ecx = (ecx & 0xFFFF0000) | (((ecx & 0xFFFF) - 1) & 0xFFFF)
    return out


REFERENCES = {"tex9": tex9_reference, "tex5": span_reference, "tex4": span_reference}


def setup(count: int, u: int, v: int, du: int, dv: int, tex: np.ndarray | None = None):
    """A timing-harness setup: texture on a 64 KB boundary, a destination span."""
    tex = texture() if tex is None else tex

    def make(m):
        t = m.arena.put(tex, align=TEX_ALIGN)
        dst = m.arena.put(np.zeros(count, np.uint8))
        return [dst, t, count, u, v, du, dv]

    return make


# A span that walks the texture diagonally: u and v both advance, about 0.7 texel per pixel.
SPAN = dict(u=0x0012_8000, v=0x0034_4000, du=0x0000_B400, dv=0x0000_3C00)


def cycles_per_pixel(cpu: str, loop: str, n: int = 256) -> dict:
    """Cycles and counters per pixel of `loop` on `cpu`: (calls with 2n pixels) - (n pixels), / n."""
    path = kernels_root() / KERNEL
    runs = [time_kernel(path, loop, setup(c, **SPAN), cpu=cpu, repeat=2).last for c in (n, 2 * n)]
    per = {k: (runs[1][k] - runs[0][k]) / n for k in runs[0] if isinstance(runs[0][k], int)}
    return per


FDIV_KERNEL = "texture/fdiv.S"
DIVISOR = 3.0


def fdiv_setup(count: int):
    """A sub-span setup (fdiv.S): the span of SPAN plus c = [divisor, 1/divisor out]."""
    base = setup(count, **SPAN)

    def make(m):
        return base(m) + [m.arena.put(np.array([DIVISOR, 0.0], np.float32))]

    return make


def divide_costs(cpu: str, n: int = 256) -> dict:
    """Clocks per 16-pixel sub-span that the perspective divide adds, overlapped with the inner
    loop and serial, (2n - n pixel difference, as cycles_per_pixel), and the TIMESNAP overhead."""
    path = kernels_root() / FDIV_KERNEL
    per = {}
    for entry in ("sub16", "sub16_overlap", "sub16_serial", "sub16_overlap_single", "sub16_serial_single"):
        c = [time_kernel(path, entry, fdiv_setup(k), cpu=cpu, repeat=2).last["cycles"] for k in (n, 2 * n)]
        per[entry] = (c[1] - c[0]) / (n // 16)
    snap = time_kernel(path, "timesnap", None, cpu=cpu, repeat=2).run.rdtsc
    return {"overlap": per["sub16_overlap"] - per["sub16"], "serial": per["sub16_serial"] - per["sub16"],
            "overlap_single": per["sub16_overlap_single"] - per["sub16"],
            "serial_single": per["sub16_serial_single"] - per["sub16"],
            "subspan": per["sub16"], "timesnap": int(snap[-1] - snap[-2])}


def l1_miss_clocks(cpu: str) -> int | None:
    """A load that misses L1 and hits the board cache: clocks until its data (the model's figure;
    None for a family with no board cache)."""
    return make_model(cpu).board_cache_hit_clocks()


@dataclass(frozen=True)
class Machine:
    """A preset as the report names it."""

    name: str
    family: str
    core_mhz: float


@dataclass
class Results:
    """What the report renders: per preset (in family order, then clock), the counters per pixel
    of each loop, the divide costs and the L1 miss clocks."""

    n: int                                  # pixels of the shorter span
    loops: dict[str, str]                   # loop entry -> what it is
    machines: list[Machine]
    per_pixel: dict[tuple[str, str], dict]  # (preset, loop) -> counters per pixel
    divide: dict[str, dict]                 # preset -> divide_costs
    l1_miss: dict[str, int | None]          # preset -> l1_miss_clocks


def run(cpus: list[str] | None = None, n: int = 256) -> Results:
    """Time every loop, the divide and the L1 miss on `cpus` (default: every preset)."""
    loaded = [presets.load(p) for p in (cpus or presets.available())]
    loaded.sort(key=lambda p: (family_order(p.family), p.core_mhz))
    machines = [Machine(p.name, p.family, p.core_mhz) for p in loaded]
    per_pixel = {(m.name, loop): cycles_per_pixel(m.name, loop, n) for m in machines for loop in LOOPS}
    return Results(n, dict(LOOPS), machines, per_pixel, {m.name: divide_costs(m.name, n) for m in machines},
                   {m.name: l1_miss_clocks(m.name) for m in machines})


def report(cpus: list[str] | None = None, n: int = 256) -> str:
    """The Markdown of reports/texture-loops.md."""
    return render(run(cpus, n))


def write_report(out: Path, cpus: list[str] | None = None) -> Path:
    """Write the report to `out` through the checked writer (sim.output), the target checked first."""
    out = output.check_output_file(out, "--out")
    output.atomic_write(out, report(cpus).encode(), "--out")
    return out
