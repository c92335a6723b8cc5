"""Compiled helpers the family cores share (numba): the port/issue-slot calendar, the BTB victim
choice, the queue of recent stores for store-to-load forwarding and the inline L1-hit path.
Family-neutral: each core imports them from here, never from another family's core."""

from __future__ import annotations

from numba import njit

from sim.memory.cache import LOAD as CACHE_LOAD
from sim.memory.cache import LRU
from sim.memory.cache import STORE as CACHE_STORE
from sim.memory.hierarchy import (
    CFG_OFFSET_BITS, CFG_REPLACEMENT, CFG_ROW0, CFG_SETS, CFG_WAYS, CFG_WRITE_BACK, memory_fill_page_hits,
    memory_fills, memory_writeback_page_hits, memory_writebacks, tlb_probe,
)
from sim.memory.replay import LOG_RECORD, LOG_REPLAY, record_hit, replayed_hit

# Masks a table index read from an array (a static id, uop id, register id, ring position): the
# value is the same (every such index is below 2**31), but the compiled code then knows it is not
# negative and drops numba's negative-index fix-up at each use (`retrosim bench --count`: about
# 12 % of the P6 core's host instructions, 9 % of the P5's)
IDX = (1 << 31) - 1
WINDOW = 8192  # port reservation ring: no in-flight uop dispatches more than this far from another
FW = 16  # recent stores remembered for forwarding (more than either family's store queue holds)
FW_MASK = FW - 1  # FW is a power of two: a ring position is fw_n & FW_MASK (no signed remainder)

# A helper of the cores' loops whose array arguments numba's reference counting left counted is
# compiled without counts (_nrt=False: none of them allocates); LLVM inlines the small ones. With
# counts, numba counts a helper's array arguments up and down around each call (an inlined one's
# at the call, another's at its entry and exits) and drops the pairs it can prove redundant; in
# the cores' loops it could not (a helper returning from several places, a conditional call), and
# the atomic counts left there took 12 % of the main job's CPU samples (perf): the P6's L1-hit,
# replay and miss paths, the K6's miss path, both warm-up walks. The cycles are the same either
# way (tests/test_core_refcounts.py checks the compiled loops).
uncounted = njit(cache=True, nogil=True, _nrt=False)


@njit(cache=True, nogil=True, inline="always")
def queued_store(fw_addr, fw_size, fw_commit, fw_n, a, size, t):
    """The youngest remembered store not yet in the cache at cycle t that overlaps [a, a + size), or -1.
    Stores reach the cache in the order they are remembered, each after the one before (both cores
    commit at max(retire, last commit + 1) or later), so the scan stops at the first one there."""
    for back in range(1, min(fw_n, FW) + 1):
        e = (fw_n - back) & FW_MASK
        if fw_commit[e] <= t:
            return -1
        if a < fw_addr[e] + fw_size[e] and fw_addr[e] < a + size:
            return e
    return -1


@njit(cache=True, nogil=True, inline="always")
def remember_store(fw_addr, fw_size, fw_ready, fw_commit, fw_n, a, size, ready, commit):
    """Record a store (its data is ready at `ready`, it reaches the cache at `commit`); returns fw_n + 1."""
    e = fw_n & FW_MASK
    fw_addr[e] = a
    fw_size[e] = size
    fw_ready[e] = ready
    fw_commit[e] = commit
    return fw_n + 1


@njit(cache=True, nogil=True, inline="always")
def book_port(book, ports, c):
    """Earliest cycle >= c where one of the allowed ports is free; books it. Callers go in program
    order, so an older uop always gets the earlier slot (oldest first). `book` is a ring of WINDOW
    cycles, each slot holding cycle << 5 | the ports already taken in it. Returns (cycle, port)."""
    while True:
        slot = c & (WINDOW - 1)
        entry = book[slot]
        used = entry & 31 if (entry >> 5) == c else 0
        free = ports & ~used
        if free != 0:
            p = 0
            while not free & (1 << p):
                p += 1
            book[slot] = (c << 5) | used | (1 << p)
            return c, p
        c += 1


@njit(cache=True, nogil=True, inline="always")
def btb_alloc(tag, stamp, s, ways, pc, now):
    """The way of BTB set `s` that a new branch `pc` takes (an empty way, else the least recently
    used), stamped `now`; returns the way."""
    victim = 0
    for w in range(ways):
        if tag[s, w] == -1:
            victim = w
            break
        if stamp[s, w] < stamp[s, victim]:
            victim = w
    tag[s, victim] = pc
    stamp[s, victim] = now
    return victim


@njit(cache=True, nogil=True, inline="always")
def dram_busy(r, line, line_hit, wb, wb_hit):
    """Front-side bus clocks of the memory traffic of one packed hierarchy result ``r``: each line
    fill and writeback at its page-miss cost (``line``, ``wb``) or, when its DRAM row was open,
    its page-hit cost (``line_hit``, ``wb_hit``)."""
    fills, wbs = memory_fills(r), memory_writebacks(r)
    fh, wh = memory_fill_page_hits(r), memory_writeback_page_hits(r)
    return (fills - fh) * line + fh * line_hit + (wbs - wh) * wb + wh * wb_hit


@njit(cache=True, nogil=True, inline="always")
def dram_lead_off(r, miss, hit):
    """Lead-off of an access's line fills: the open-page figure only if every line it waits for hit."""
    return hit if memory_fill_page_hits(r) == memory_fills(r) else miss


@njit(cache=True, nogil=True, inline="always")
def access_end(mem_insn, acc, li):
    """The end (exclusive) of chunk instruction li's accesses, the first of which is `acc`
    (mem_insn lists each access's instruction, in program order)."""
    end = acc
    while end < mem_insn.shape[0] and mem_insn[end & IDX] == li:
        end += 1
    return end


@njit(cache=True, nogil=True, inline="always")
def segments_ended(seg_end, seg, count):
    """The first segment from `seg` not yet ended after `count` instructions of the run."""
    while seg < seg_end.shape[0] and seg_end[seg] <= count:
        seg += 1
    return seg


# ---- the inline L1-hit path ---------------------------------------------------------------------
# A core does a plain first-level hit itself, with the updates service would make (the data TLB's
# probe, tlb_hit; the line's LRU stamp from the hierarchy's clock, kept in a local; the dirty bit;
# the request and hit counts, kept in locals and added by add_l1_hits), and calls service for every
# other access, out of its loop: service inline at each access site made the loops long. The TLB
# is probed first, as service does: a page it holds is re-stamped and becomes the page translated
# last, so when the line then misses, service's own probe of that access changes nothing; a page it
# lacks changes nothing, and service walks it.

@uncounted  # LLVM inlines it
def l1_geometry(dconfig):
    """What the inline path reads of the first data level, once before a core's loop: (offset
    bits, first row, set mask, ways, LRU replacement, write-back)."""
    return (dconfig[0, CFG_OFFSET_BITS], dconfig[0, CFG_ROW0], dconfig[0, CFG_SETS] - 1, dconfig[0, CFG_WAYS],
            dconfig[0, CFG_REPLACEMENT] == LRU, dconfig[0, CFG_WRITE_BACK] != 0)


@uncounted  # LLVM inlines it into the loops
def l1_way(tags, addr, size, ob, row0, set_mask, ways):
    """(row, way) of the first-level line holding [addr, addr + size) (the lookup of
    sim.memory.cache.lookup, without updates), or (-1, -1): not there, or crossing a line."""
    line = addr >> ob
    if (addr + size - 1) >> ob == line:
        s = row0 + (line & set_mask)
        for w in range(ways):
            if tags[s, w] == line:
                return s, w
    return -1, -1


REPLAYED_HIT = -2  # plain_hit: a plain L1 hit read back from an access log (the caches are not touched)


@uncounted  # LLVM inlines it into the loops
def plain_hit(dlog, log_off, tags, addr, size, ob, row0, set_mask, ways, eligible):
    """l1_way for an access that may take the inline path, with an access log (sim/memory/replay.py,
    `log_off` False): (-1, -1) when not `eligible` (the caller takes this path only for a page the
    TLB holds, tlb_hit, and a store only to a write-back L1); a log being recorded gets the entry
    service would have given the hit; a replayed log says itself whether the access was one,
    (REPLAYED_HIT, 0), and the caches are not touched. Any other access goes through service
    (logged_service with a log)."""
    row, way = -1, -1
    if eligible:
        if not log_off and dlog[0] == LOG_REPLAY:
            if replayed_hit(dlog):
                row, way = REPLAYED_HIT, 0
        else:
            row, way = l1_way(tags, addr, size, ob, row0, set_mask, ways)
            if row >= 0 and not log_off and dlog[0] == LOG_RECORD:
                record_hit(dlog)
    return row, way


@uncounted  # LLVM inlines it into the loops
def l1_hit(stamps, dirty, row, way, is_write, lru, now):
    """service's updates of a plain first-level hit at (row, way) found by plain_hit: the line's LRU
    stamp (`now`, the hierarchy's clock, when `lru`), its dirty bit for a store. Returns the clock
    after the access."""
    if is_write:
        dirty[row, way] = 1
    if lru:
        stamps[row, way] = now
    return now + 1


@uncounted  # LLVM inlines it into the loops
def tlb_hit(has_tlb, dconfig, dwork, a):
    """Whether the data TLB holds the page of `a` (True with no TLB to model: `has_tlb` False), as
    service's probe (sim.memory.hierarchy.tlb_probe: a hit is re-stamped, a miss changes nothing).
    `dwork`: the data hierarchy's work array (the cores' dclock)."""
    return not has_tlb or tlb_probe(dconfig, dwork, a)


@njit(cache=True, nogil=True, inline="always")
def add_l1_hits(dstats, load_hits, store_hits):
    """Add the plain L1 hits a core counted in locals to the first level's requests and hits."""
    dstats[0, 2 * CACHE_LOAD] += load_hits
    dstats[0, 2 * CACHE_LOAD + 1] += load_hits
    dstats[0, 2 * CACHE_STORE] += store_hits
    dstats[0, 2 * CACHE_STORE + 1] += store_hits
