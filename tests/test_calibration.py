"""The memory model against published measurements of real boards (sim/memory/measured_boards.toml,
issue 24 part 4): a random pointer chase far beyond the caches and a STREAM copy, timed on the
closest preset, against the measured nanoseconds and MB/s. The sources are in the data file and in
docs/sources/memory.md; `python tests/test_calibration.py` prints the comparison table of that page."""

import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from sim.cpus import presets  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / "sim" / "memory" / "measured_boards.toml"
CHASE_BYTES = 4 << 20   # far beyond every preset's caches (the largest is a 512 KB L2 or board cache)
COPY_BYTES = 2 << 20    # each STREAM array: four times the largest board cache

# STREAM's copy, c[j] = a[j] on 8-byte doubles (STREAM counts 16 bytes per element: 8 read + 8
# written), as an x87 load and store of each double: what the i386 compiler makes of a double
# assignment (gcc 12 -m32 -O3 -march=pentium, with its memcpy and vector rewrites off: fldl / fstpl per element; the measured board's egcs
# 1.1.2 run was not available), and what the measurement itself shows: Copy (54.66 MB/s) runs at
# the rate of Scale (54.24 MB/s), whose b[j] = scalar * c[j] must go through the x87 and store
# each double with one 8-byte FSTP. Integer moves would make two 4-byte stores per element, which
# a K6 that does not allocate on a write miss sends to the bus as two single writes.
COPY_KERNEL = """
    mov     ecx, [esp+4]
    mov     esi, [esp+8]
    mov     edi, [esp+12]
    xor     eax, eax
.Lcopy:
    fld     qword ptr [esi+eax*8]
    fstp    qword ptr [edi+eax*8]
    inc     eax
    cmp     eax, ecx
    jne     .Lcopy
    ret
"""
# STREAM's arrays are static, back to back: N = 1,000,000 doubles on the measured board (16 x N
# bytes / the minimum time 0.2927 s = 54.66 MB/s), so c lies 8,000,000 bytes after a. The test's
# 2 MB arrays keep that distance modulo the 512 KB direct-mapped board cache (8,000,000 mod 524,288
# = 135,680 bytes): a and c do not evict each other there, as in STREAM. (4 KB-aligned arrays 2 MB
# apart would map every line of c onto the board-cache line of a.)
STREAM_GAP = 8_000_000 % (512 << 10)
# The measured board ran Linux (2.2.14, and 2.4.0ac10 at the same copy rate), whose
# arch/i386/kernel/setup.c (amd_model) programs the K6's write-allocate limit (WHCR) when the BIOS
# left it 0 -- "Enabling old style K6 write allocation" on models 6, 7 and early 8 -- so its K6
# allocated on write misses: the k6-233 preset's own mode ('page+sector only') is InstLatX64's
# Windows XP system. (2.2.14 writes mbytes/4 unshifted, a limit of half the memory; 2.2.15 and 2.4
# shift it to all of it: copy 54.66 and 55.57 MB/s, so the arrays were write-allocated in both.)
STREAM_MACHINE = "k6-233{write_allocate.mode=full}"


def measured() -> dict:
    with open(DATA, "rb") as f:
        return tomllib.load(f)


def row(kind: str, preset: str, fit: str | None = None, memory: str | None = None) -> dict:
    rows = [r for r in measured()[kind] if r["preset"] == preset and (fit is None or r.get("fit") == fit)
            and (memory is None or r.get("memory_preset") == memory)]
    assert len(rows) == 1, (kind, preset, fit, memory)
    return rows[0]


def chase_ns(emulation, cpu: str, memory: str) -> float:
    """Modelled latency of one dependent load far beyond the caches, in ns at the preset's clock."""
    from sim.timing.kernel import time_emulation
    c = time_emulation(emulation, cpu, memory).last
    assert c["dram_fills"] >= 0.9 * c["l1d_loads"]
    return c["cycles"] / c["l1d_loads"] * 1000.0 / presets.load(cpu).core_mhz


def copy_mb_s(emulation, cpu: str, memory: str) -> float:
    """Modelled STREAM copy rate (bytes read + written per second) at the preset's clock."""
    from sim.timing.kernel import time_emulation
    c = time_emulation(emulation, cpu, memory).last
    seconds = c["cycles"] / (presets.load(cpu.split("{")[0]).core_mhz * 1e6)
    return 2 * COPY_BYTES / seconds / 1e6


@pytest.fixture(scope="module")
def chase():
    from test_p6 import chase_setup
    from sim.timing.kernel import emulate
    return emulate(Path("kernels/micro/memory.S"), "chase", chase_setup(CHASE_BYTES), repeat=1)


def copy_setup(m):
    src = m.arena.alloc(COPY_BYTES + STREAM_GAP, align=4096)
    dst = m.arena.alloc(COPY_BYTES, align=8)
    assert (dst - src) % (512 << 10) == STREAM_GAP
    m.uc.mem_write(src, np.arange(COPY_BYTES // 4, dtype=np.uint32).tobytes())
    return [COPY_BYTES // 8, src, dst]


@pytest.fixture(scope="module")
def copy(tmp_path_factory):
    from sim.timing.kernel import emulate
    path = tmp_path_factory.mktemp("stream") / "copy.S"
    path.write_text(".intel_syntax noprefix\n.text\n.globl copy\ncopy:\n" + COPY_KERNEL)
    return emulate(path, "copy", copy_setup, repeat=2)  # the first call warms nothing it reuses: 2 x 4 MB


def test_every_measurement_names_its_source_and_a_preset():
    data = measured()
    assert data["latency"] and data["bandwidth"]
    for kind in ("latency", "bandwidth"):
        for r in data[kind]:
            assert r["source"] and r["system"] and r["benchmark"], r
            presets.load(r["preset"])  # an unknown preset is an error
    for r in data["latency"]:
        # clocks and nanoseconds agree with the measured clock
        assert abs(r["latency_clks"] * 1000 / r["cpu_mhz"] - r["latency_ns"]) <= 0.03 * r["latency_ns"], r["system"]


# The boards the presets' board overheads were calibrated on, timed on the preset of the same CPU
# with the memory it is compared with: the chase reproduces the measured ns within 10 %
# (the calibration tolerance of docs/sources/p6.md and k6.md).
@pytest.mark.parametrize("preset", ["celeron-266", "k6-233", "pentium-133"])
def test_chase_reproduces_the_measured_board(chase, preset):
    r = row("latency", preset, "calibrated")
    model = chase_ns(chase, preset, r["memory_preset"])
    assert abs(model - r["latency_ns"]) <= 0.10 * r["latency_ns"], (preset, model, r["latency_ns"])


# The Pentium 100 (1.5 x 66.67 MHz), not calibrated on: the P5 board overhead fitted on the
# Pentium 133 (pentium-*.toml [memory]), timed on the same P54C preset at the Pentium 100's clocks
# (the pentium-90 preset runs a 60 MHz bus) with the EDO the Pentium 133 was calibrated with,
# within 10 % of its measured 226 ns.
def test_chase_reproduces_the_pentium_100(chase):
    r = row("latency", "pentium-90")
    assert r["fsb_mhz"] == presets.load("pentium-133").fsb_mhz
    cpu = f"pentium-133{{clock.core_mhz={r['cpu_mhz']}}}"
    from sim.timing.kernel import time_emulation
    c = time_emulation(chase, cpu, r["memory_preset"]).last
    ns = c["cycles"] / c["l1d_loads"] * 1000.0 / r["cpu_mhz"]
    assert abs(ns - r["latency_ns"]) <= 0.10 * r["latency_ns"], (ns, r["latency_ns"])


# The K6-266 on the VIA VP2 board (Tyan 1592S) with PC133 SDRAM at 66 MHz: STREAM copy 85.8 MB/s,
# timed on the k6-233 preset with PC66 SDRAM and the measured system's write allocation
# (STREAM_MACHINE). The copy is bound by the 66 MHz bus and the DRAM, not the core clock, so the
# 233/266 MHz difference is inside the 20 % tolerance. The chase of the same preset is calibrated
# on InstLatX64's K6-233 (test_chase_reproduces_the_measured_board): stream and chase on one board.
def test_stream_copy_reproduces_the_measured_k6_board_with_sdram(copy):
    r = row("bandwidth", "k6-233", memory="sdram-pc66")
    model = copy_mb_s(copy, STREAM_MACHINE, "sdram-pc66")
    assert abs(model - r["copy_mb_s"]) <= 0.20 * r["copy_mb_s"], (model, r["copy_mb_s"])


# The same board with 60 ns EDO: 54.7 MB/s, and the SDRAM/EDO ratio 1.57. The model gives about
# 73 MB/s (ratio 1.34): its EDO line fill is the calibrated board overhead plus the 5-2-2-2 burst
# (20.5 bus clocks, 3 more than PC66's), where the measured Add - Copy difference gives 29 bus
# clocks per line read on EDO against 20 on SDRAM. The EDO page-miss lead-off of a VP2 (or any
# Socket 7 chipset) was not found: docs/sources/memory.md.
@pytest.mark.xfail(strict=True, reason="the modelled STREAM copy with EDO (about 73 MB/s) is a third faster "
                                       "than the measured board (54.7 MB/s): the EDO page-miss lead-off on "
                                       "the VP2 is not sourced (issue 24)")
def test_stream_copy_reproduces_the_measured_k6_board_with_edo(copy):
    r = row("bandwidth", "k6-233", memory="edo")
    model = copy_mb_s(copy, STREAM_MACHINE, "edo")
    assert abs(model - r["copy_mb_s"]) <= 0.20 * r["copy_mb_s"], (model, r["copy_mb_s"])


@pytest.mark.xfail(strict=True, reason="modelled SDRAM/EDO STREAM copy ratio about 1.34 against the measured "
                                       "1.57: the EDO fill is too cheap (see the EDO test)")
def test_stream_copy_sdram_over_edo_matches_the_measured_ratio(copy):
    measured = row("bandwidth", "k6-233", memory="sdram-pc66")["copy_mb_s"] / row(
        "bandwidth", "k6-233", memory="edo")["copy_mb_s"]
    model = copy_mb_s(copy, STREAM_MACHINE, "sdram-pc66") / copy_mb_s(copy, STREAM_MACHINE, "edo")
    assert abs(model - measured) <= 0.10 * measured, (model, measured)


def comparison() -> list[str]:
    """The markdown table of docs/sources/memory.md: each latency row against its preset's model."""
    from test_p6 import chase_setup
    from sim.timing.kernel import emulate
    emu = emulate(Path("kernels/micro/memory.S"), "chase", chase_setup(CHASE_BYTES), repeat=1)
    out = ["| measured system | measured ns (clks) | preset, memory | model ns (clks) | model/measured |",
           "|---|---|---|---|---|"]
    for r in measured()["latency"]:
        ns = chase_ns(emu, r["preset"], r["memory_preset"])
        clks = ns * presets.load(r["preset"]).core_mhz / 1000
        out.append(f"| {r['system']} | {r['latency_ns']:.1f} ({r['latency_clks']}) | {r['preset']}, {r['memory_preset']} "
                   f"| {ns:.1f} ({clks:.0f}) | {ns / r['latency_ns']:.2f} |")
    return out


if __name__ == "__main__":
    print("\n".join(comparison()))
