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

# STREAM copy (a[i] = b[i] on 8-byte elements; STREAM counts 16 bytes per element: read + write),
# with integer moves so no x87 timing enters: two loads and two stores per element.
COPY_KERNEL = """
    mov     ecx, [esp+4]
    mov     esi, [esp+8]
    mov     edi, [esp+12]
.Lcopy:
    mov     eax, [esi]
    mov     edx, [esi+4]
    mov     [edi], eax
    mov     [edi+4], edx
    add     esi, 8
    add     edi, 8
    dec     ecx
    jnz     .Lcopy
    ret
"""


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
    seconds = c["cycles"] / (presets.load(cpu).core_mhz * 1e6)
    return 2 * COPY_BYTES / seconds / 1e6


@pytest.fixture(scope="module")
def chase():
    from test_p6 import chase_setup
    from sim.timing.kernel import emulate
    return emulate(Path("kernels/micro/memory.S"), "chase", chase_setup(CHASE_BYTES), repeat=1)


def copy_setup(m):
    src = m.arena.alloc(COPY_BYTES, align=4096)
    dst = m.arena.alloc(COPY_BYTES, align=4096)
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
@pytest.mark.parametrize("preset", ["celeron-266", "k6-233"])
def test_chase_reproduces_the_measured_board(chase, preset):
    r = row("latency", preset, "calibrated")
    model = chase_ns(chase, preset, r["memory_preset"])
    assert abs(model - r["latency_ns"]) <= 0.10 * r["latency_ns"], (preset, model, r["latency_ns"])


# The K6-266 on the VIA VP2 board with EDO: STREAM copy 54.7 MB/s. Timed on the K6-233 preset with
# EDO: the copy is bound by the 66 MHz bus and the DRAM, not the core clock, so the 233/266 MHz
# difference is inside the 20 % tolerance. With page-mode DRAM (issue 24) the model gives about
# 37 MB/s: the copy is still too slow, by a cause not found yet (write buffers' drain to the bus,
# the board cache's write policy and the VP2's EDO timings are unmodelled or estimated).
@pytest.mark.xfail(strict=True, reason="the modelled STREAM copy (about 37 MB/s) is a third slower than the "
                                       "measured board (54.7 MB/s): cause not found (issue 24)")
def test_stream_copy_reproduces_the_measured_k6_board(copy):
    r = row("bandwidth", "k6-233", memory="edo")
    model = copy_mb_s(copy, "k6-233", "edo")
    assert abs(model - r["copy_mb_s"]) <= 0.20 * r["copy_mb_s"], (model, r["copy_mb_s"])


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
