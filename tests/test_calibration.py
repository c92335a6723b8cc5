"""The memory model against published measurements of real boards (sim/memory/measured_boards.toml,
issue 24 part 4): a random pointer chase far beyond the caches, a STREAM copy, and lmbench's
lat_mem_rd and bw_mem loops as lmbench 1 ran them, timed on the closest preset, against the measured
nanoseconds and MB/s. The sources are in the data file and in
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
    for r in data["lmbench"]:
        assert r["source"] and r["system"] and r["benchmark"], r
        presets.load(r["preset"])
        # lmbench 1 reports a load's latency less one clock: the L1 figure is the L1 load-to-use
        # latency of the preset less one clock, at the measured clock (a check on cpu_mhz)
        l1_clks = r["l1_latency_ns"] * r["cpu_mhz"] / 1000 + 1
        assert abs(l1_clks - presets.load(r["preset"]).l1d.latency_cycles) <= 0.25, (r["system"], l1_clks)
    for r in data["latency"]:
        # clocks and nanoseconds agree with the measured clock
        assert abs(r["latency_clks"] * 1000 / r["cpu_mhz"] - r["latency_ns"]) <= 0.03 * r["latency_ns"], r["system"]


# InstLatX64's walks as it ran them (MemLatX86 'Linear' and 'Backward Read Latency' tables): a ring
# of dependent loads a fixed stride apart through a 16 MB block, forward or backward, timed by the
# `chase` kernel. 'Mem latency', the figure the boards' overheads are calibrated on, is the linear
# walk with a 1 KB stride ([Mode:1 Size: 16384K, Stride: 1024]); lmbench's lat_mem_rd walk is the
# backward one with a 128 B stride. On an open-page board most loads of both find their DRAM page
# open, unlike the random chase above (every fill a page miss), so the calibration replays the
# pattern itself (issue 24: the overheads fitted before with the random chase on these figures made
# every walk 9-16 clocks too fast).
INSTLAT_BYTES = 16 << 20
INSTLAT_MIN_LOADS = 16384
CALIBRATED = ("celeron-266", "pentium-pro-200", "k6-233", "pentium-133", "k6-3-450")
# The P5 board: its linear walks at 16 MB cost 19 clks (32 B stride) up to 51 (4 KB), as much as its
# random read: a TLB miss every 4 KB (the stride curve: 20, 21, 23, 29, 39, 51 at 128 B-4 KB
# strides). The model's data TLB (issue 24; p5_machine.toml [tlb]) walks the page tables on a miss,
# its fixed clocks calibrated on that curve's 4 KB column; the 1 KB walk, one TLB miss in four
# loads, is then a check (docs/sources/memory.md, "TLB").


def instlat_walk_setup(stride: int, backward: bool):
    """A ring through INSTLAT_BYTES: the word at each stride-aligned offset points to the next
    offset (forward) or the one before (backward), wrapping at the ends."""
    def setup(m):
        base = m.arena.alloc(INSTLAT_BYTES, align=4096)
        words = np.zeros(INSTLAT_BYTES // 4, np.uint32)
        offs = np.arange(0, INSTLAT_BYTES, stride)
        nxt = (offs + (-stride if backward else stride)) % INSTLAT_BYTES
        words[offs // 4] = base + nxt
        m.uc.mem_write(base, words.tobytes())
        start = INSTLAT_BYTES - stride if backward else 0
        return [max(INSTLAT_BYTES // stride, INSTLAT_MIN_LOADS) // 8, base + start]
    return setup


@pytest.fixture(scope="module")
def instlat():
    from sim.timing.kernel import emulate
    k = Path("kernels/micro/memory.S")
    return {"linear": emulate(k, "chase", instlat_walk_setup(1024, False), repeat=1),
            "walk": emulate(k, "chase", instlat_walk_setup(LMBENCH_STRIDE, True), repeat=1)}


def board_machine(r: dict) -> str:
    """The row's preset, at the measured clock when the preset's own differs by more than 1 % (the
    K6-III 400 against k6-3-450's 450 MHz: same 100 MHz bus, so the board overhead in bus clocks
    carries over)."""
    p = presets.load(r["preset"])
    assert abs(r["fsb_mhz"] - p.fsb_mhz) <= 0.01 * p.fsb_mhz, r["system"]
    if abs(p.core_mhz - r["cpu_mhz"]) <= 0.01 * r["cpu_mhz"]:
        return r["preset"]
    return f"{r['preset']}{{clock.core_mhz={r['cpu_mhz']}}}"


def clks_per_load(emulation, cpu: str, memory: str) -> float:
    from sim.timing.kernel import time_emulation
    c = time_emulation(emulation, cpu, memory).last
    assert c["dram_fills"] >= 0.99 * c["l1d_loads"]  # every load goes to memory
    return c["cycles"] / c["l1d_loads"]


# 'Mem latency' as InstLatX64 ran it, on the preset of the same CPU with the memory it is compared
# with, within 10 % (the calibration tolerance of docs/sources/p6.md and k6.md), in core clocks
# (the presets' clocks differ from the measured ones by under 1 %, at the same bus ratio).
@pytest.mark.parametrize("preset", CALIBRATED)
def test_mem_latency_as_instlatx64_ran_it(instlat, preset):
    r = row("latency", preset, "calibrated")
    assert r["pattern"] == "linear forward, 1 KB stride, 16 MB"
    model = clks_per_load(instlat["linear"], board_machine(r), r["memory_preset"])
    assert abs(model - r["latency_clks"]) <= 0.10 * r["latency_clks"], (preset, model, r["latency_clks"])


# lmbench's walk (backward, 128 B) on the same boards, not fitted: it checks the open-page saving
# ([pages] hit_saving_bus_clocks) against the page-miss lead-off calibrated above.
@pytest.mark.parametrize("preset", CALIBRATED)
def test_lmbench_walk_reproduces_the_measured_board(instlat, preset):
    r = row("latency", preset, "calibrated")
    model = clks_per_load(instlat["walk"], board_machine(r), r["memory_preset"])
    assert abs(model - r["walk_clks"]) <= 0.10 * r["walk_clks"], (preset, model, r["walk_clks"])


# The random chase (every fill a page miss) against InstLatX64's random read at 16 MB, not fitted.
# The measured random read also misses the TLB on nearly every load, and so does the chase (4 MB of
# 4 KB pages against 64 or 128 entries): on the P6 boards a miss is cheap (the Pentium Pro's linear
# 2 KB walk is 2-3 clocks dearer than its 512 B walk), on the K6 and the P54C far more (their 4
# KB-stride linear walks cost 79 and 51). The walks' fixed clocks are calibrated on those 4 KB
# columns, not on the random read.
@pytest.mark.parametrize("preset", CALIBRATED)
def test_random_chase_reproduces_the_measured_random_read(chase, preset):
    r = row("latency", preset, "calibrated")
    model = clks_per_load(chase, board_machine(r), r["memory_preset"])
    assert abs(model - r["random_clks"]) <= 0.10 * r["random_clks"], (preset, model, r["random_clks"])


# The Pentium 100 (1.5 x 66.67 MHz), not calibrated on: the P5 board overhead and TLB walk fitted on
# the Pentium 133 (pentium-*.toml [memory], p5_machine.toml [estimates.tlb_walk_clocks]), timed on
# the same P54C preset at the Pentium 100's clocks (the pentium-90 preset runs a 60 MHz bus) with
# the EDO the Pentium 133 was calibrated with, within 10 % of its measured 226 ns. 'Mem latency' is
# the linear 1 KB walk (GenuineIntel0000525_P54C_MemLatX86.txt line 30, 1K column: 23 clks), so the
# walk is timed as InstLatX64 ran it; the random chase (with a TLB miss per load) was compared
# before the model had a TLB.
def test_mem_latency_reproduces_the_pentium_100(instlat):
    r = row("latency", "pentium-90")
    assert r["fsb_mhz"] == presets.load("pentium-133").fsb_mhz
    cpu = f"pentium-133{{clock.core_mhz={r['cpu_mhz']}}}"
    from sim.timing.kernel import time_emulation
    c = time_emulation(instlat["linear"], cpu, r["memory_preset"]).last
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


# The same board with 60 ns EDO: 54.7 MB/s, within 20 %. (A strict xfail until the K6-233's board
# overhead was calibrated on InstLatX64's walk as it ran it: 73 MB/s with 9.5 bus clocks, about 64
# with 13.5; nothing was fitted on this figure.)
def test_stream_copy_reproduces_the_measured_k6_board_with_edo(copy):
    r = row("bandwidth", "k6-233", memory="edo")
    model = copy_mb_s(copy, STREAM_MACHINE, "edo")
    assert abs(model - r["copy_mb_s"]) <= 0.20 * r["copy_mb_s"], (model, r["copy_mb_s"])


@pytest.mark.xfail(strict=True, reason="modelled SDRAM/EDO STREAM copy ratio about 1.29 against the measured "
                                       "1.57: the model's EDO fill is 3 bus clocks dearer than PC66's, the "
                                       "measured Add - Copy difference 9 (issue 24)")
def test_stream_copy_sdram_over_edo_matches_the_measured_ratio(copy):
    measured = row("bandwidth", "k6-233", memory="sdram-pc66")["copy_mb_s"] / row(
        "bandwidth", "k6-233", memory="edo")["copy_mb_s"]
    model = copy_mb_s(copy, STREAM_MACHINE, "sdram-pc66") / copy_mb_s(copy, STREAM_MACHINE, "edo")
    assert abs(model - measured) <= 0.10 * measured, (model, measured)


# lmbench 1 (McVoy & Staelin, USENIX 1996) as its database was measured: sim/memory/measured_boards.toml
# [[lmbench]], docs/sources/memory.md. lat_mem_rd: a ring of pointers, each pointing one stride
# (128 bytes, the stride lmbench's summary is taken from) BACK, walked with p = *p in an unrolled
# loop; lmbench reports the time per load less one clock (the load instruction). The database's
# arrays reach 8 MB. bw_mem read: "an unrolled loop that sums up a series of integers ... a load and
# an add for each word of memory" (4-byte ints, every word); write: "an unrolled loop that stores a
# value into an integer ... and then increments the pointer". Both count the bytes of the array.
LMBENCH_LAT_BYTES = 8 << 20
LMBENCH_STRIDE = 128
LMBENCH_BW_BYTES = 8 << 20
LMBENCH_UNROLL = 32  # words per loop iteration (the paper says "unrolled", not how far)
LMBENCH_TOLERANCE = 0.20  # fixed before the model was timed on these kernels


def _unrolled(name: str, body) -> str:
    lines = [".intel_syntax noprefix", ".text", f".globl {name}", f"{name}:", "    mov ecx, [esp+4]",
             "    mov esi, [esp+8]", "    mov eax, 1" if name == "lm_wr" else "    xor eax, eax", f".L{name}:"]
    lines += [body(4 * i) for i in range(LMBENCH_UNROLL)]
    lines += [f"    add esi, {4 * LMBENCH_UNROLL}", "    dec ecx", f"    jnz .L{name}", "    ret", ""]
    return "\n".join(lines)


LMBENCH_RD = _unrolled("lm_rd", lambda off: f"    add eax, [esi+{off}]")
LMBENCH_WR = _unrolled("lm_wr", lambda off: f"    mov [esi+{off}], eax")


def lat_mem_rd_setup(m):
    """lat_mem_rd's ring: the word at offset i points to offset i - stride; offset 0 to the last one."""
    base = m.arena.alloc(LMBENCH_LAT_BYTES, align=4096)
    words = np.zeros(LMBENCH_LAT_BYTES // 4, np.uint32)
    offsets = np.arange(0, LMBENCH_LAT_BYTES, LMBENCH_STRIDE)
    words[offsets // 4] = base + np.where(offsets == 0, LMBENCH_LAT_BYTES - LMBENCH_STRIDE, offsets - LMBENCH_STRIDE)
    m.uc.mem_write(base, words.tobytes())
    return [LMBENCH_LAT_BYTES // LMBENCH_STRIDE // 8, base + LMBENCH_LAT_BYTES - LMBENCH_STRIDE]


def bw_mem_setup(m):
    base = m.arena.alloc(LMBENCH_BW_BYTES, align=4096)
    m.uc.mem_write(base, np.arange(LMBENCH_BW_BYTES // 4, dtype=np.uint32).tobytes())
    return [LMBENCH_BW_BYTES // (4 * LMBENCH_UNROLL), base]


def lmbench_machine(r: dict) -> str:
    """The preset at the measured clock (its bus clock kept: the ratio becomes cpu_mhz / fsb_mhz)."""
    assert r["fsb_mhz"] == presets.load(r["preset"]).fsb_mhz, r["system"]
    return f"{r['preset']}{{clock.core_mhz={r['cpu_mhz']}}}"


def lmbench_figures(d: Path) -> dict:
    """The modelled lmbench figures of the [[lmbench]] row: ns as lmbench reports them, MB/s."""
    from sim.timing.kernel import emulate, time_emulation
    r = row("lmbench", "pentium-pro-200")
    cpu, memory, mhz = lmbench_machine(r), r["memory_preset"], r["cpu_mhz"]
    (d / "rd.S").write_text(LMBENCH_RD)
    (d / "wr.S").write_text(LMBENCH_WR)
    lat = time_emulation(emulate(Path("kernels/micro/memory.S"), "chase", lat_mem_rd_setup, repeat=1), cpu, memory).last
    assert lat["dram_fills"] >= 0.99 * lat["l1d_loads"]
    rd = time_emulation(emulate(d / "rd.S", "lm_rd", bw_mem_setup, repeat=1), cpu, memory).last
    wr = time_emulation(emulate(d / "wr.S", "lm_wr", bw_mem_setup, repeat=1), cpu, memory).last
    mb_s = lambda c: LMBENCH_BW_BYTES / (c["cycles"] / (mhz * 1e6)) / 1e6  # noqa: E731
    return {"row": r, "latency_ns": (lat["cycles"] / lat["l1d_loads"] - 1) * 1000.0 / mhz,
            "read_mb_s": mb_s(rd), "write_mb_s": mb_s(wr)}


@pytest.fixture(scope="module")
def lmbench(tmp_path_factory):
    return lmbench_figures(tmp_path_factory.mktemp("lmbench"))


def lmbench_ratio(latency_ns: float, read_mb_s: float) -> float:
    """A dependent load's time over the time the read stream spends per 32-byte line: how much a
    board gains from streaming. lmbench's latency leaves out one clock; that clock is small
    against either, and left out on both sides."""
    return latency_ns / (32 / read_mb_s * 1000.0)


# The one published P6 machine with both a memory latency and a memory bandwidth in one source:
# lmbench 1's "Linux i686" (a Pentium Pro at 167 MHz; board, chipset and memory not stated), timed
# on pentium-pro-200 at that clock with its EDO, within 20 % (fixed before the model was timed).
#
# The latency: pentium-pro-200's board overhead is calibrated on another Pentium Pro 200
# (InstLatX64's linear 1 KB walk, 47 clks, replayed as it ran), not on this machine, so this checks
# it. lmbench's walk (backward, 128-byte stride) finds the DRAM page open, and the model now walks it
# at InstLatX64's measured 46 clks for that board (test_lmbench_walk_reproduces_the_measured_board):
# about 229 ns at 167 MHz, 18 % above this machine's 194 ns. lmbench's board is faster than
# InstLatX64's (200 ns per load at 167 MHz against 231 ns at 200 MHz; docs/sources/memory.md).
def test_lmbench_lat_mem_rd_reproduces_the_pentium_pro(lmbench):
    measured = lmbench["row"]["latency_ns"]
    assert abs(lmbench["latency_ns"] - measured) <= LMBENCH_TOLERANCE * measured, (lmbench["latency_ns"], measured)


# The read stream misses: the model's fills overlap (four L1 misses in flight, only the page-hit
# burst holds the bus: 8 bus clocks per line), where the machine spends 10.4 bus clocks per line,
# close to the 11.3 of an isolated page-hit load. What serialises them on the board (the memory
# controller of a 450KX/GX or 440FX) was not found.
@pytest.mark.xfail(strict=True, reason="bw_mem read on pentium-pro-200 at 167 MHz: model about 266 MB/s against "
                                       "205 MB/s: the model's line fills overlap more than the measured board's; "
                                       "no chipset timing found (issue 24)")
def test_lmbench_memory_read_reproduces_the_pentium_pro(lmbench):
    measured = lmbench["row"]["read_mb_s"]
    assert abs(lmbench["read_mb_s"] - measured) <= LMBENCH_TOLERANCE * measured, (lmbench["read_mb_s"], measured)


@pytest.mark.xfail(strict=True, reason="bw_mem write on pentium-pro-200 at 167 MHz: model about 96 MB/s against "
                                       "56 MB/s (a read for ownership and a writeback per line in both) (issue 24)")
def test_lmbench_memory_write_reproduces_the_pentium_pro(lmbench):
    measured = lmbench["row"]["write_mb_s"]
    assert abs(lmbench["write_mb_s"] - measured) <= LMBENCH_TOLERANCE * measured, (lmbench["write_mb_s"], measured)


# The done-when of issue 24: a stream and a chase on the same board give the measured ratio.
@pytest.mark.xfail(strict=True, reason="latency / read-stream time per line: model about 1.9 against the "
                                       "measured 1.24 on lmbench's Pentium Pro: the read stream is too fast "
                                       "(issue 24)")
def test_lmbench_latency_over_stream_matches_the_pentium_pro(lmbench):
    r = lmbench["row"]
    measured = lmbench_ratio(r["latency_ns"], r["read_mb_s"])
    model = lmbench_ratio(lmbench["latency_ns"], lmbench["read_mb_s"])
    assert abs(model - measured) <= LMBENCH_TOLERANCE * measured, (model, measured)


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


def walk_comparison() -> list[str]:
    """The walk table of docs/sources/memory.md: each calibrated board's three InstLatX64 patterns."""
    from test_p6 import chase_setup
    from sim.timing.kernel import emulate
    k = Path("kernels/micro/memory.S")
    emus = {"linear": emulate(k, "chase", instlat_walk_setup(1024, False), repeat=1),
            "walk": emulate(k, "chase", instlat_walk_setup(LMBENCH_STRIDE, True), repeat=1),
            "random": emulate(k, "chase", chase_setup(CHASE_BYTES), repeat=1)}
    out = ["| board (preset, memory) | linear 1 KB: measured / model | backward 128 B | random |",
           "|---|---|---|---|"]
    for r in measured()["latency"]:
        if "walk_clks" not in r:
            continue
        m = {k: clks_per_load(e, board_machine(r), r["memory_preset"]) for k, e in emus.items()}
        out.append(f"| {r['cpu'].split(' (')[0]} ({r['preset']}, {r['memory_preset']}) "
                   f"| {r['latency_clks']} / {m['linear']:.1f} | {r['walk_clks']} / {m['walk']:.1f} "
                   f"| {r['random_clks']} / {m['random']:.1f} |")
    return out


def lmbench_comparison() -> list[str]:
    """The lmbench table of docs/sources/memory.md."""
    import tempfile
    with tempfile.TemporaryDirectory() as d:
        m = lmbench_figures(Path(d))
    r = m["row"]
    return ["| figure | measured | model | model/measured |", "|---|---|---|---|",
            f"| lat_mem_rd, 128 B stride (ns, less one clock) | {r['latency_ns']} | {m['latency_ns']:.1f} | {m['latency_ns'] / r['latency_ns']:.2f} |",
            f"| bw_mem read (MB/s) | {r['read_mb_s']} | {m['read_mb_s']:.1f} | {m['read_mb_s'] / r['read_mb_s']:.2f} |",
            f"| bw_mem write (MB/s) | {r['write_mb_s']} | {m['write_mb_s']:.1f} | {m['write_mb_s'] / r['write_mb_s']:.2f} |",
            f"| latency / read time per 32 B line | {lmbench_ratio(r['latency_ns'], r['read_mb_s']):.2f} "
            f"| {lmbench_ratio(m['latency_ns'], m['read_mb_s']):.2f} | |"]


if __name__ == "__main__":
    print("\n".join(comparison()))
    print()
    print("\n".join(walk_comparison()))
    print()
    print("\n".join(lmbench_comparison()))
