"""The data TLB (issue 24, sim/memory/hierarchy.py service and set_tlb): TLB reach, a miss per
load beyond it, set conflicts, the walk's reads in the data caches, the geometry in the replay
key, the families' geometry from their machine tables, and the walks InstLatX64 measured where
every load misses the TLB (the 4 KB column its walk clocks are calibrated on)."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from sim.cpus import families  # noqa: E402
from sim.cpus.build import make_model  # noqa: E402
from sim.cpus.contract import data_tlb  # noqa: E402
from sim.memory import CacheGeometry, Hierarchy, served_level, service  # noqa: E402
from sim.memory.hierarchy import (  # noqa: E402
    CFG_TLB_SETS, CFG_TLB_WAYS, PD_BASE, PT_BASE, tlb_missed, walk_pde_level, walk_pte_level,
)

PAGE = 4096
# data half-way into a page: its lines then share no L1 set with the page-table and directory lines
# of these pages (which are page-aligned structures, like the kernel's), so the tests see the TLB alone
BASE = 0x0100_0800


def p5_like() -> Hierarchy:
    """An 8 KB 2-way L1 and a 256 KB board cache with the Pentium's 64-entry 4-way data TLB."""
    h = Hierarchy([CacheGeometry("L1D", 8192, 2, 32), CacheGeometry("L2", 256 * 1024, 1, 32)])
    h.set_tlb(64, 4)
    return h


def misses(h: Hierarchy, addrs) -> list[int]:
    counts = h.new_counts()
    return [tlb_missed(service(*h.arrays(), counts, a, 4, False)) for a in addrs]


def test_a_walk_within_the_tlb_reach_misses_only_while_warming_up():
    h = p5_like()
    pages = [BASE + p * PAGE for p in range(64)]  # 64 pages: the whole TLB
    assert sum(misses(h, pages)) == 64
    assert sum(misses(h, pages * 3)) == 0


def test_a_4kb_stride_beyond_the_reach_misses_every_load():
    h = p5_like()
    pages = [BASE + p * PAGE for p in range(128)]  # twice the entries: 8 pages cycle through each 4-way set (LRU)
    misses(h, pages)
    assert misses(h, pages * 3) == [1] * (3 * 128)


def test_one_page_more_than_the_ways_in_one_set_thrashes():
    h = p5_like()
    sets = h.config[0, CFG_TLB_SETS]
    ways = h.config[0, CFG_TLB_WAYS]
    same_set = [BASE + k * sets * PAGE for k in range(ways + 1)]
    misses(h, same_set)
    assert misses(h, same_set * 4) == [1] * (4 * (ways + 1))
    h.reset()
    misses(h, same_set[:ways])
    assert sum(misses(h, same_set[:ways] * 4)) == 0  # as many pages as ways: no conflict


def test_the_walk_reads_the_page_tables_through_the_data_caches():
    h = p5_like()
    counts = h.new_counts()
    memory = len(h.geometries)
    r = service(*h.arrays(), counts, BASE, 4, False)
    assert tlb_missed(r) and walk_pde_level(r) == memory and walk_pte_level(r) == memory  # cold: from DRAM
    assert served_level(r) == memory
    # the next page's entry is 4 bytes further in the same page-table line, its directory entry the same
    r = service(*h.arrays(), counts, BASE + PAGE, 4, False)
    assert tlb_missed(r) and walk_pde_level(r) == 0 and walk_pte_level(r) == 0
    # the page-table and directory lines are in the L1 like data
    l1 = set(h.states[0].tags.ravel().tolist())
    assert (PT_BASE + (BASE // PAGE) * 4) >> 5 in l1 and (PD_BASE + (BASE >> 22) * 4) >> 5 in l1
    # the 8 entries of a page-table line cover 8 pages: the 9th page's entry is in the next line
    for p in range(2, 8):
        service(*h.arrays(), counts, BASE + p * PAGE, 4, False)
    r = service(*h.arrays(), counts, BASE + 8 * PAGE, 4, False)
    assert walk_pde_level(r) == 0 and walk_pte_level(r) == memory


def test_an_access_without_a_tlb_never_walks():
    h = Hierarchy([CacheGeometry("L1D", 8192, 2, 32)])
    counts = h.new_counts()
    assert not any(tlb_missed(service(*h.arrays(), counts, BASE + p * PAGE, 4, False)) for p in range(200))
    assert counts[0, 0] == 200  # L1 loads: the data accesses only


@pytest.mark.parametrize("entries, ways", [(64, 3), (96, 2), (512, 4), (0, 0)])
def test_a_bad_tlb_geometry_is_refused(entries, ways):
    with pytest.raises(ValueError, match="TLB"):
        p5_like().set_tlb(entries, ways)


def test_the_tlb_geometry_is_part_of_the_replay_key():
    """A replay log is keyed by the data caches' configuration: the TLB decides which accesses walk
    (and so which lines the walks bring in), so a log is never reused across TLB geometries."""
    a, b = p5_like(), p5_like()
    b.set_tlb(128, 2)
    assert a.config.tobytes() != b.config.tobytes()


@pytest.mark.parametrize("cpu, family", [("pentium-133", "p5"), ("pentium-pro-200", "p6"), ("k6-233", "k6")])
def test_each_family_model_has_its_machine_tables_data_tlb(cpu, family):
    entries, ways = data_tlb(families.family(family).machine, family)
    config = make_model(cpu).dside.config
    assert config[0, CFG_TLB_WAYS] == ways and config[0, CFG_TLB_SETS] * ways == entries


# --- the cores -------------------------------------------------------------------------------------

def ring_setup(pages: int, stride: int, loads: int):
    """A ring of dependent loads `stride` bytes apart through `pages` x 4 KB, walked `loads` times."""
    def setup(m):
        base = m.arena.alloc(pages * PAGE + stride, align=PAGE)
        n = pages * PAGE // stride
        words = np.zeros((pages * PAGE + stride) // 4, np.uint32)
        offs = np.arange(n) * stride
        words[offs // 4] = base + np.roll(offs, -1)
        m.uc.mem_write(base, words.tobytes())
        return [loads // 8, base]
    return setup


RING_LOADS = 4096


@pytest.fixture(scope="module")
def rings():
    from sim.timing.kernel import emulate
    k = Path("kernels/micro/memory.S")
    # 128 and 256 pages, one line per page, each line in another L1 set (stride 4 KB + 32 B): after
    # the first pass every line hits L1, while the TLB (64 or 128 entries) misses on every load
    return {pages: emulate(k, "chase", ring_setup(pages, PAGE + 32, RING_LOADS), repeat=1) for pages in (32, 128, 256)}


@pytest.mark.parametrize("cpu, beyond", [("pentium-133", 128), ("pentium-pro-200", 128), ("celeron-266", 128),
                                         ("k6-233", 256)])
def test_l1_hits_beyond_the_tlb_reach_still_miss_the_tlb(rings, cpu, beyond):
    """Every load of a ring over twice the TLB's pages misses it, though the lines stay in L1 (the
    P6's L1-hit path checks the TLB too), and costs more than the same ring within the reach."""
    from sim.timing.kernel import time_emulation
    far = time_emulation(rings[beyond], cpu).last
    near = time_emulation(rings[32], cpu).last
    assert far["dtlb_misses"] >= RING_LOADS  # every load of the ring (the stack's two loads aside)
    assert far["l1d_load_misses"] <= 2 * beyond  # the first pass, and a few lines the walks' lines evict
    assert near["dtlb_misses"] <= 32 + 1  # the first touch of each page (and the stack's)
    assert far["cycles"] / far["l1d_loads"] > near["cycles"] / near["l1d_loads"] + 1


# --- InstLatX64: every load a TLB miss -------------------------------------------------------------
# The 'Linear Read Latency' tables' 4 KB column at 16 MB: a new TLB entry and a new DRAM page per load.
# P54C and K6: the columns the walks' fixed clocks are calibrated on (p5/k6_machine.toml
# [estimates.tlb_walk_clocks]); the Celeron's is a check (the P6 walk's clocks are the minimum, fitted
# on the Pentium Pro's 512 B -> 2 KB step). The Pentium Pro's own 4 KB column (181) is another effect.
FOUR_KB = [("pentium-133", "edo-430fx", 51, "GenuineIntel0000526_P54C_MemLatX86.txt line 30"),
           ("k6-233", "sdram-pc66", 79, "AuthenticAMD0000562_K6_MemLatX86.txt line 30"),
           ("celeron-266", "sdram-pc66", 97, "GenuineIntel0000651_P2_Covington_MemLatX86.txt line 32")]


@pytest.fixture(scope="module")
def four_kb_walk():
    from test_calibration import instlat_walk_setup
    from sim.timing.kernel import emulate
    return emulate(Path("kernels/micro/memory.S"), "chase", instlat_walk_setup(PAGE, False), repeat=1)


@pytest.mark.parametrize("cpu, memory, clks, source", FOUR_KB)
def test_the_4kb_stride_walk_at_16mb_reproduces_instlatx64(four_kb_walk, cpu, memory, clks, source):
    from test_calibration import clks_per_load
    from sim.timing.kernel import time_emulation
    model = clks_per_load(four_kb_walk, cpu, memory)
    assert abs(model - clks) <= 0.10 * clks, (cpu, model, clks, source)
    c = time_emulation(four_kb_walk, cpu, memory).last
    assert c["dtlb_misses"] >= 0.99 * c["l1d_loads"]


@pytest.mark.parametrize("cpu", ["pentium-pro-200", "k6-233"])
def test_a_walk_clocks_retiming_replays_the_logged_walks_exactly(rings, cpu):
    """The claims' robustness pass re-times with the walk's clocks at each end of their range from
    the nominal run's access log (the TLB's misses and the walks' levels are in the logged results):
    the replay times exactly like a fresh run."""
    from sim.memory.replay import AccessLogs
    from sim.timing.kernel import time_emulation
    est = families.family(make_model(cpu).family).estimates["tlb_walk_clocks"]
    logs = AccessLogs(keep=4)
    nominal = time_emulation(rings[256], make_model(cpu), access_logs=logs).last
    for value in (est.low, est.high):
        model = make_model(cpu, overrides={"estimates.tlb_walk_clocks": value})
        replayed = time_emulation(rings[256], model, access_logs=logs).last
        assert len(logs._logs) == 1  # read back, not recorded again
        assert replayed == time_emulation(rings[256], make_model(cpu, overrides={"estimates.tlb_walk_clocks": value})).last
        assert replayed["dtlb_misses"] == nominal["dtlb_misses"]
    assert time_emulation(rings[256], make_model(cpu, overrides={"estimates.tlb_walk_clocks": est.high})).last["cycles"] \
        > nominal["cycles"]
