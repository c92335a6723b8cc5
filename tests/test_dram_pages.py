"""Page-mode DRAM (issue 24): a sequential stream of line fills hits open pages, a random chase
misses them, and a page hit saves the datasheet's tRP + tRCD.

Figures: PC100 SDRAM, tRP = tRCD = 20 ns = 2 + 2 bus clocks at 10 ns (Transcend PC100 CL2 SPD;
Micron 64Mb SDRAM MT48LC8M8A2 data sheet: a READ to an open row waits only the CAS latency, a row
miss adds PRECHARGE (tRP) and ACTIVE (tRCD)); a WRITE takes its data with the command (no CAS
latency, CL2 = 2 clocks).
"""

import numpy as np

from sim.cpus import make_model, presets
from sim.cpus.contract import dram_cost
from sim.memory.dram import load_memory_preset
from sim.memory.hierarchy import Hierarchy, memory_fill_page_hits, memory_fills, service


def _fills(h, addrs):
    tags, stamps, dirty, config, work = h.arrays()
    stats = h.new_counts()
    hits = fills = 0
    for a in addrs:
        r = service(tags, stamps, dirty, config, work, stats, np.int64(a), np.int64(4), False)
        hits += memory_fill_page_hits(r)
        fills += memory_fills(r)
    return hits, fills


def _hierarchy():
    h = Hierarchy.from_preset(presets.load("pentium2-233"))
    pages = load_memory_preset("sdram-pc100").pages
    h.set_dram_pages(pages.page_bytes, pages.open_pages)
    return h


def test_sequential_stream_hits_open_pages_and_random_chase_misses():
    seq = np.arange(0, 4 << 20, 32, dtype=np.int64)  # 4 MB, line by line: past the 512 KB L2
    hits, fills = _fills(_hierarchy(), seq)
    assert fills == len(seq)
    assert hits >= 0.95 * fills  # one miss per 4 KB row: 127 of 128 lines hit
    rng = np.random.default_rng(1)
    chase = rng.integers(0, 64 << 20, 20000, dtype=np.int64) & ~31
    hits, fills = _fills(_hierarchy(), chase)
    assert fills > 0.9 * len(chase)
    assert hits <= 0.01 * fills  # 4 open rows of 4 KB in 64 MB


def test_page_hit_saves_trp_plus_trcd_and_writes_save_cas():
    model = make_model("pentium2-233", memory="sdram-pc100")
    d = dram_cost(load_memory_preset("sdram-pc100"), model.preset)
    # 4 bus clocks (tRP + tRCD) x 3.5 core clocks per bus clock = 14
    assert d.lead_off - d.lead_off_hit == 14
    # bus time: 4-1-1-1 = 7 on a miss, 3 + 1 on a hit (never below the transfers), x 3.5
    assert (d.line_busy, d.line_busy_hit) == (25, 14)
    assert d.writeback_busy == 18  # 7 - CL2 = 5 bus clocks x 3.5 = 17.5 -> 18
    assert d.writeback_busy_hit == 14


def test_without_page_model_every_fill_misses():
    h = Hierarchy.from_preset(presets.load("pentium2-233"))
    hits, fills = _fills(h, np.arange(0, 1 << 20, 32, dtype=np.int64))
    assert hits == 0 and fills > 0
