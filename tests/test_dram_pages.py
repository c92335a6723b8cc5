"""Page-mode DRAM (issue 24): a sequential stream of line fills hits open pages, a random chase
misses them, and a page hit saves the datasheet's tRP + tRCD.

Figures: PC100 SDRAM, tRP = tRCD = 20 ns = 2 + 2 bus clocks at 10 ns (Transcend PC100 CL2 SPD;
Micron 64Mb SDRAM MT48LC8M8A2 data sheet: a READ to an open row waits only the CAS latency, a row
miss adds PRECHARGE (tRP) and ACTIVE (tRCD)); a WRITE takes its data with the command (no CAS
latency, CL2 = 2 clocks).
"""

import numpy as np
import pytest

from sim.cpus import presets

from sim.cpus.build import make_model
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
    h = Hierarchy(presets.load("pentium2-233").data_caches())
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
    h = Hierarchy(presets.load("pentium2-233").data_caches())
    hits, fills = _fills(h, np.arange(0, 1 << 20, 32, dtype=np.int64))
    assert hits == 0 and fills > 0


STREAM = """
    push esi
    mov esi, [esp+8]
    mov ecx, [esp+12]
1:  mov eax, [esi]
    add esi, 32
    dec ecx
    jnz 1b
    pop esi
    ret
"""


def _stream(write_kernel, size=2 << 20):
    """A sequential read of `size` bytes, one load per 32-byte line: past the 512 KB L2, so every
    line is a DRAM fill and nearly every fill's page is open."""
    from sim.timing.kernel import emulate

    src = write_kernel(STREAM, entry="stream")
    return emulate(src, "stream", lambda m: [m.arena.put(np.zeros(size, np.uint8)), size // 32], repeat=1)


def test_overriding_the_page_hit_saving_moves_a_sequential_stream(write_kernel):
    """edo.toml's page-hit saving is an estimate (2..4 bus clocks): overridden (``pages.FIELD``, as
    the claims' robustness pass does), a larger saving makes a stream of page hits faster."""
    from sim.timing.kernel import time_emulation

    emu = _stream(write_kernel)
    runs = {s: time_emulation(emu, make_model("pentium2-233", "edo", {"pages.hit_saving_bus_clocks": s})).last
            for s in (2, 3, 4)}
    assert runs[3]["dram_page_hits"] > 0.9 * runs[3]["dram_fills"]
    assert runs[4]["cycles"] < runs[3]["cycles"] < runs[2]["cycles"]
    assert runs[3] == time_emulation(emu, make_model("pentium2-233", "edo")).last  # 3 is the preset's figure


def test_a_page_geometry_override_never_replays_a_log_recorded_with_another(write_kernel):
    """The page geometry decides which fills are page hits, and it lives in the data caches'
    configuration a replay log is keyed by: a re-timing with another page size, handed the nominal
    run's logs, walks the caches itself and times exactly like a fresh run."""
    from sim.memory.replay import AccessLogs
    from sim.timing.kernel import time_emulation

    emu = _stream(write_kernel)
    logs = AccessLogs(keep=4)
    nominal = time_emulation(emu, make_model("pentium2-233", "edo"), access_logs=logs).last  # 8 KB pages
    small = {"pages.page_bytes": 4096}
    shared = time_emulation(emu, make_model("pentium2-233", "edo", small), access_logs=logs).last
    assert len(logs._logs) == 2  # a second recording, not a replay of the first
    assert shared == time_emulation(emu, make_model("pentium2-233", "edo", small)).last
    assert shared["dram_page_hits"] < nominal["dram_page_hits"]  # a row boundary every 128 lines, not 256


@pytest.mark.parametrize("edit, message", [
    (lambda s: s.replace("hit_saving_bus_clocks = { low = 2, high = 4,", "hit_saving_bus_clocks = { low = 4, high = 5,"),
     r"\[pages.ranges\] hit_saving_bus_clocks = 4..5 does not hold the model's 3"),
    (lambda s: s[: s.index("write_saving_bus_clocks = { low")],
     r"\[pages.ranges\] must give a range for exactly the estimated fields"),
    (lambda s: s.replace("page_bytes = { low = 4096,", "page_bytes = { low = 5000,"), r"\[pages.ranges\] page_bytes ends must be powers of two"),
    (lambda s: s.replace('open_pages = { low = 1, high = 2, reason = "', 'open_pages = { low = 1, high = 2, why = "'),
     r"\[pages.ranges\] open_pages must be \{ low = INT, high = INT, reason"),
])
def test_an_estimated_page_figure_needs_a_range_holding_it(tmp_path, monkeypatch, edit, message):
    from sim.memory import dram

    text = (dram.MEMORY_PRESETS_DIR / "edo.toml").read_text()
    (tmp_path / "edo.toml").write_text(edit(text))
    monkeypatch.setattr(dram, "MEMORY_PRESETS_DIR", tmp_path)
    with pytest.raises(ValueError, match=r"^edo.toml: " + message):
        dram.load_memory_preset("edo")


def test_a_preset_edited_between_two_loads_is_read_again(tmp_path, monkeypatch):
    # presets are parsed once and shared (sim.tomlfile read_toml's `shared`): an edit must still show
    from sim.memory import dram

    text = (dram.MEMORY_PRESETS_DIR / "edo.toml").read_text()
    monkeypatch.setattr(dram, "MEMORY_PRESETS_DIR", tmp_path)
    (tmp_path / "edo.toml").write_text(text)
    first = dram.load_memory_preset("edo")
    assert dram.load_memory_preset("edo") == first
    (tmp_path / "edo.toml").write_text(text.replace("hit_saving_bus_clocks = { low = 2, high = 4,",
                                                    "hit_saving_bus_clocks = { low = 2, high = 40,"))
    again = dram.load_memory_preset("edo")
    assert again.pages.ranges["hit_saving_bus_clocks"][1] == 40 != first.pages.ranges["hit_saving_bus_clocks"][1]
