"""A data-cache hierarchy of up to three levels (L1D, L2, optional board cache), compiled.

The hierarchy is non-inclusive ("inclusive of nothing"): a miss is filled into every level on the
miss path, and no level ever invalidates a line because another level evicted it. Each level is a
:mod:`sim.memory.cache` level; this module walks a request down the levels:

- a miss that allocates fetches the line from the next level first (a LOAD there), then writes
  its dirty victim, if any, back to the next level (a WRITEBACK there);
- a write that a level does not absorb (write-through, or a no-allocate miss) continues to the next
  level as the same kind of request (FORWARD);
- below the last level is memory, which counts line fills (LOAD), line writebacks (WRITEBACK) and
  partial writes (STORE: no-allocate or write-through writes that reached the bus).

The walk is depth first, so every level sees its requests in the order the hardware would issue
them. All levels must have the same line size (true of every CPU modelled: 32 bytes).

For the timing models: :func:`service` handles one CPU access (splitting it at line boundaries)
and returns a packed result telling which level supplied the data and how much memory traffic the
access caused; :func:`simulate` runs a whole trace. Both take the arrays of
:meth:`Hierarchy.arrays` and update them in place.

A data TLB (:meth:`Hierarchy.set_tlb`; the family models give their machine table's ``[tlb]
dtlb``): :func:`service` first translates the access's page; on a miss it walks the page tables
(a page-directory and a page-table read, 4 bytes each, down these same caches as loads: the
families cache paging entries in their data caches) and enters the page. The page tables lie at
synthetic physical addresses above the guest's (PT_BASE, PD_BASE). The result tells the core the
miss and the levels that served the two reads; the core charges the walk (docs/sources/memory.md,
"The data TLB"). Not modelled: the instruction TLB, large pages, accessed/dirty-bit writes.

Storage: all levels live in one ``tags``/``stamps``/``dirty`` array each, level k in rows
``row0 .. row0 + sets`` and its first ``ways`` columns (config columns CFG_ROW0/SETS/WAYS). One
array per field, not a tuple of per-level arrays, because indexing a tuple of arrays with a run-time
level costs numba reference counting on every request (measured: ~65 ns, the whole budget).
"""

from __future__ import annotations

import functools
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
from numba import njit

from sim.memory.cache import (
    ALLOC_ALWAYS, ALLOC_PAGE_SECTOR, ALLOCATED, DIRTY_VICTIM, EVICT, FETCH, FORWARD, HIT, HOT, LOAD,
    PAGE_BITS, STORE, WRITEBACK, CacheGeometry, CacheState, lookup, victim_address,
)

MAX_LEVELS = 3
POLICIES_FILE = Path(__file__).with_name("policies.toml")

# Columns of the per-level config array. The last two are the DRAM's page geometry (the same in
# every row; level 0's is read): log2 of the page (row) size in bytes, and the number of open pages
# the chipset tracks minus one (a power of two; 0 with no page model: every page is a miss). Part of
# the config so that a replay log (keyed on the config) is never reused across memories.
# The next two are the data TLB's geometry (sets, ways; 0 ways = no TLB), also in every row and
# read from row 0, for the same reason: a replay log is never reused across TLB geometries.
(CFG_OFFSET_BITS, CFG_WRITE_ALLOCATE, CFG_WRITE_BACK, CFG_REPLACEMENT, CFG_ROW0, CFG_SETS, CFG_WAYS,
 CFG_PAGE_SHIFT, CFG_PAGE_MASK, CFG_TLB_SETS, CFG_TLB_WAYS) = range(11)
NCFG = 11

# Columns of the counts array [levels + 1, NSTATS]; the last row is memory. A request of kind k
# (LOAD/STORE/WRITEBACK = 0/1/2) is counted in column 2k, and its hit in column 2k + 1. For memory,
# LOADS = line fills, STORES = partial writes, WRITEBACKS_IN = line writebacks.
(S_LOADS, S_LOAD_HITS, S_STORES, S_STORE_HITS, S_WRITEBACKS_IN, S_WRITEBACK_HITS, S_FILLS,
 S_EVICTIONS, S_WRITEBACKS, S_FORWARDED, S_COMPULSORY, S_CAPACITY, S_CONFLICT) = range(13)
NSTATS = 13

# Packed result of service(): the level that supplied the data (levels = memory) in bits 0-2, a
# data-TLB miss in bit 3 and the levels that served the miss's page walk (the page-directory entry
# in bits 4-5, the page-table entry in bits 6-7; levels <= 3), then 8-bit counts of the memory
# traffic the access caused, the lines touched (2 bits: 1 or 2), and 3-bit counts of the line
# fills and line writebacks that hit an open DRAM page. All below bit 40 (the replay log keeps its
# own fields above). The walk's own line fills are not in the traffic counts: the core charges
# each walk read as a load served at its level (its writebacks and partial writes are).
SERVED_MASK = 0x7
TLB_MISS = 1 << 3
PDE_LEVEL_SHIFT, PTE_LEVEL_SHIFT = 4, 6
MEM_FILL_SHIFT, MEM_WRITEBACK_SHIFT, MEM_PARTIAL_SHIFT, LINES_SHIFT = 8, 16, 24, 32
FILL_PAGE_HIT_SHIFT, WB_PAGE_HIT_SHIFT = 34, 37

# The walk's work array: [0] the LRU clock (a request counter), [1 + level] the page of the level's
# last line fill (for the K6 "page+sector" write-allocate rule; -1 = none), then a stack of pending
# requests (at most two pushed per request and level: a few entries deep).
FILL_PAGE_BASE = 1
STACK_BASE = FILL_PAGE_BASE + MAX_LEVELS
# After the stack: the row open in each DRAM bank (-1 = closed), MAX_OPEN_PAGES of them. This is
# machine state (open pages survive from one call, and one chunk, to the next), kept here because
# the walk is the only place that sees the address of each request that reaches memory.
MAX_OPEN_PAGES = 16
OPEN_PAGE_BASE = 32
# After the open pages: the data TLB (machine state too, for the same reason): its LRU clock, the
# page translated last (-1 = none: it is the most recently used entry of its set, so a repeat needs
# no lookup and no re-stamping), then the tags (linear page numbers, -1 = empty) and stamps of up to
# MAX_TLB_ENTRIES entries, set s in slots s * ways .. s * ways + ways - 1.
MAX_TLB_ENTRIES = 256
TLB_CLOCK = OPEN_PAGE_BASE + MAX_OPEN_PAGES
TLB_LAST = TLB_CLOCK + 1
TLB_TAGS = TLB_LAST + 1
TLB_STAMPS = TLB_TAGS + MAX_TLB_ENTRIES
WORK_SIZE = TLB_STAMPS + MAX_TLB_ENTRIES

# The page tables the walk reads (an assumption: the kernels run under Linux-like 4 KB paging, two
# levels, no large pages). Their physical addresses are synthetic and lie above every guest address
# (the guest's are 32-bit), so they never share a line with guest data: the page-table entry of a
# linear page p at PT_BASE + 4p (one flat 4 MB array of every page table, as if the page tables of
# consecutive 4 MB regions were consecutive pages), the page-directory entry of p at
# PD_BASE + 4 (p >> 10). The caches and the DRAM page model see these addresses like any other
# (cache.VICTIM_SHIFT: addresses below 2**33).
TLB_PAGE_BITS = 12
PT_BASE = 1 << 32
PD_BASE = PT_BASE + (1 << 22)
# Rows of the miss-classification shadow array [levels, 4, distinct lines].
SH_SEEN, SH_IN, SH_PREV, SH_NEXT = range(4)
# Columns of the shadow meta array [levels, 4]: the fully-associative LRU list.
FA_HEAD, FA_TAIL, FA_COUNT, FA_CAPACITY = range(4)


@njit(cache=True, nogil=True, inline="always")
def served_level(result):
    """Level that supplied the line (0 = L1 hit; ``levels`` = memory) for a :func:`service` result;
    for a split access, the slower of its two lines. For a write that no level allocated: where it
    was absorbed."""
    return result & SERVED_MASK


@njit(cache=True, nogil=True, inline="always")
def tlb_missed(result):
    """1 if the access missed the data TLB (its page walk ran before the data access), else 0."""
    return (result >> 3) & 1


@njit(cache=True, nogil=True, inline="always")
def walk_pde_level(result):
    """Level that supplied the page-directory entry of a TLB miss's walk (as served_level)."""
    return (result >> PDE_LEVEL_SHIFT) & 0x3


@njit(cache=True, nogil=True, inline="always")
def walk_pte_level(result):
    """Level that supplied the page-table entry of a TLB miss's walk (as served_level)."""
    return (result >> PTE_LEVEL_SHIFT) & 0x3


@njit(cache=True, nogil=True, inline="always")
def walk_l1_fills(result):
    """L1 line fills the walk made: each walk read that missed L1 filled it (reads allocate)."""
    if not result & TLB_MISS:
        return 0
    return (1 if walk_pde_level(result) > 0 else 0) + (1 if walk_pte_level(result) > 0 else 0)


@njit(cache=True, nogil=True, inline="always")
def walk_read_result(level, nlevels):
    """A packed result standing for one walk read served at ``level``, for a core to charge as a
    load's: one line, one memory fill (on a closed DRAM page) if it came from memory."""
    return level | ((1 << MEM_FILL_SHIFT) if level == nlevels else 0) | (1 << LINES_SHIFT)


@njit(cache=True, nogil=True, inline="always")
def tlb_probe(config, work, addr):
    """Whether the data TLB holds ``addr``'s page (True with no TLB); a hit becomes the set's most
    recently used entry, a miss changes nothing. Set = page mod sets; LRU within the set. The page
    translated last needs no lookup (TLB_LAST); the set lookup is out of line. The cores' inline
    L1-hit path probes too (sim.cpus.shared_core.tlb_hit), before its own lookup: a hit leaves
    that page TLB_LAST, so service's probe of the same access changes nothing."""
    return work[TLB_LAST] == addr >> TLB_PAGE_BITS or _tlb_lookup(config, work, addr >> TLB_PAGE_BITS)


@njit(**HOT)  # (no reference counts: the cores' inline L1-hit path reaches it, shared_core.tlb_hit)
def _tlb_lookup(config, work, page):
    ways = config[0, CFG_TLB_WAYS]
    if ways == 0:
        return True
    base = (page & (config[0, CFG_TLB_SETS] - 1)) * ways
    for w in range(ways):
        if work[TLB_TAGS + base + w] == page:
            now = work[TLB_CLOCK] + 1
            work[TLB_CLOCK] = now
            work[TLB_STAMPS + base + w] = now
            work[TLB_LAST] = page
            return True
    return False


@njit(cache=True, nogil=True, inline="always")
def _tlb_fill(config, work, page):
    """Enter ``page`` in its set in place of an empty entry or the least recently used one."""
    ways = config[0, CFG_TLB_WAYS]
    base = (page & (config[0, CFG_TLB_SETS] - 1)) * ways
    victim = 0
    for w in range(ways):
        if work[TLB_TAGS + base + w] == -1:
            victim = w
            break
        if work[TLB_STAMPS + base + w] < work[TLB_STAMPS + base + victim]:
            victim = w
    now = work[TLB_CLOCK] + 1
    work[TLB_CLOCK] = now
    work[TLB_TAGS + base + victim] = page
    work[TLB_STAMPS + base + victim] = now
    work[TLB_LAST] = page


@njit(cache=True, nogil=True, inline="always")
def memory_fills(result):
    return (result >> MEM_FILL_SHIFT) & 0xFF


@njit(cache=True, nogil=True, inline="always")
def memory_writebacks(result):
    return (result >> MEM_WRITEBACK_SHIFT) & 0xFF


@njit(cache=True, nogil=True, inline="always")
def memory_partial_writes(result):
    return (result >> MEM_PARTIAL_SHIFT) & 0xFF


@njit(cache=True, nogil=True, inline="always")
def lines_touched(result):
    return (result >> LINES_SHIFT) & 0x3


@njit(cache=True, nogil=True, inline="always")
def memory_fill_page_hits(result):
    """Line fills of the access whose DRAM row was open (the rest were page misses)."""
    return (result >> FILL_PAGE_HIT_SHIFT) & 0x7


@njit(cache=True, nogil=True, inline="always")
def memory_writeback_page_hits(result):
    return (result >> WB_PAGE_HIT_SHIFT) & 0x7


@njit(cache=True, nogil=True, inline="always")
def _page_access(config, work, addr):
    """Open ``addr``'s DRAM row in its bank; 1 if it was already open (a page hit), else 0. Address
    map (an assumption, see sim/memory/dram.py): the bits above the page offset pick the bank."""
    shift = config[0, CFG_PAGE_SHIFT]
    if shift == 0:
        return 0
    row = addr >> shift
    slot = OPEN_PAGE_BASE + (row & config[0, CFG_PAGE_MASK])
    hit = 1 if work[slot] == row else 0
    work[slot] = row
    return hit


@njit(**HOT)
def _fa_touch(sh, meta, k, i):
    """Move line id i to the MRU end of level k's shadow list (it is in the list)."""
    if meta[k, FA_HEAD] == i:
        return
    p, n = sh[k, SH_PREV, i], sh[k, SH_NEXT, i]
    sh[k, SH_NEXT, p] = n  # i is not the head, so p >= 0
    if n >= 0:
        sh[k, SH_PREV, n] = p
    else:
        meta[k, FA_TAIL] = p
    _fa_push(sh, meta, k, i)


@njit(**HOT)
def _fa_push(sh, meta, k, i):
    head = meta[k, FA_HEAD]
    sh[k, SH_PREV, i] = -1
    sh[k, SH_NEXT, i] = head
    if head >= 0:
        sh[k, SH_PREV, head] = i
    else:
        meta[k, FA_TAIL] = i
    meta[k, FA_HEAD] = i


@njit(**HOT)
def _fa_access(sh, meta, k, i, kind, allocate):
    """The fully-associative LRU cache of the same size as level k, fed the same requests and with
    the same touch and allocate rules; returns whether it hit."""
    if sh[k, SH_IN, i]:
        if kind != WRITEBACK:
            _fa_touch(sh, meta, k, i)
        return True
    if kind == LOAD or allocate:
        if meta[k, FA_COUNT] == meta[k, FA_CAPACITY]:
            t = meta[k, FA_TAIL]
            p = sh[k, SH_PREV, t]
            sh[k, SH_IN, t] = 0
            meta[k, FA_TAIL] = p
            if p >= 0:
                sh[k, SH_NEXT, p] = -1
            else:
                meta[k, FA_HEAD] = -1
            meta[k, FA_COUNT] -= 1
        _fa_push(sh, meta, k, i)
        sh[k, SH_IN, i] = 1
        meta[k, FA_COUNT] += 1
    return False


@njit(**HOT)
def _classify(uniq, sh, meta, stats, level, line, kind, allocate, hit):
    """Dinero-style 3C: compulsory = first request for the line at this level; capacity = a
    fully-associative LRU cache of the same size misses too; conflict = the rest. ``allocate``:
    whether this write would allocate on a miss (the real cache's decision)."""
    i = np.searchsorted(uniq, line)
    first = sh[level, SH_SEEN, i] == 0
    sh[level, SH_SEEN, i] = 1
    fa_hit = _fa_access(sh, meta, level, i, kind, allocate)
    if not hit:
        if first:
            stats[level, S_COMPULSORY] += 1
        elif not fa_hit:
            stats[level, S_CAPACITY] += 1
        else:
            stats[level, S_CONFLICT] += 1


@njit(**HOT)
def _push(work, sp, addr, level, kind, primary):
    work[sp] = (addr << 8) | (level << 4) | (kind << 1) | primary
    return sp + 1


@njit(**HOT)
def _step(tags, stamps, dirty, config, work, stats, sp):
    """Pop one pending request off the stack in ``work``, perform it, and push the requests it
    causes in reverse order of execution (the fetch runs first, then the victim's writeback, then
    the forwarded write), so the walk is depth first, as in the hardware. Returns ``(sp, entry,
    code)``; ``code`` is -1 for a request that reached memory.

    The stack stands in for recursion, which numba cannot cache. An entry packs the line address,
    level, kind and a "primary" bit: the primary chain is the path the CPU's data takes (the fetch,
    or a write no level absorbed); its deepest level is the one that served the access.
    """
    sp -= 1
    e = work[sp]
    addr, level, kind, primary = e >> 8, (e >> 4) & 0xF, (e >> 1) & 0x7, e & 1
    stats[level, 2 * kind] += 1
    code = -1  # memory
    if level == config.shape[0]:
        code = -2 if _page_access(config, work, addr) else -1  # -2: memory, an open page
    else:  # (one exit only: see cache.lookup)
        now = work[0]
        work[0] = now + 1
        code = lookup(tags, stamps, dirty, config[level, CFG_ROW0], config[level, CFG_SETS],
                      config[level, CFG_WAYS], config[level, CFG_OFFSET_BITS], addr, kind,
                      config[level, CFG_WRITE_ALLOCATE], config[level, CFG_WRITE_BACK],
                      config[level, CFG_REPLACEMENT], now, work[FILL_PAGE_BASE + level])
        if code & HIT:
            stats[level, 2 * kind + 1] += 1
        if code & FORWARD:
            stats[level, S_FORWARDED] += 1
            absorbed = code & (HIT | ALLOCATED) != 0
            sp = _push(work, sp, addr, level + 1, kind, primary & (not absorbed))
        if code & EVICT:
            stats[level, S_EVICTIONS] += 1
            if code & DIRTY_VICTIM:
                stats[level, S_WRITEBACKS] += 1
                sp = _push(work, sp, victim_address(code), level + 1, WRITEBACK, 0)
        if code & FETCH:
            stats[level, S_FILLS] += 1
            work[FILL_PAGE_BASE + level] = addr >> PAGE_BITS
            sp = _push(work, sp, addr, level + 1, LOAD, primary)
    return sp, e, code


@njit(cache=True, nogil=True, inline="always")
def _account(result, e, code, nlevels):
    """Fold one performed request into the packed result: deepest primary level, memory traffic."""
    level, kind = (e >> 4) & 0xF, (e >> 1) & 0x7
    if e & 1 and level > (result & SERVED_MASK):
        result = (result & ~SERVED_MASK) | level
    if level == nlevels:
        result += 1 << (MEM_FILL_SHIFT if kind == LOAD else
                        MEM_WRITEBACK_SHIFT if kind == WRITEBACK else MEM_PARTIAL_SHIFT)
        if code == -2 and kind != STORE:
            result += 1 << (FILL_PAGE_HIT_SHIFT if kind == LOAD else WB_PAGE_HIT_SHIFT)
    return result


@njit(**HOT)
def _walk_read(tags, stamps, dirty, config, work, stats, addr):
    """One 4-byte page-table read of a walk, down the data caches like a load. Returns the level
    that served it and the memory traffic it caused, its line fills (and their page hits) left out."""
    ob = config[0, CFG_OFFSET_BITS]
    r = 0
    sp = _push(work, STACK_BASE, (addr >> ob) << ob, 0, LOAD, 1)
    while sp > STACK_BASE:
        sp, e, code = _step(tags, stamps, dirty, config, work, stats, sp)
        r = _account(r, e, code, config.shape[0])
    return r & SERVED_MASK, r & ~(SERVED_MASK | (0xFF << MEM_FILL_SHIFT) | (0x7 << FILL_PAGE_HIT_SHIFT))


@njit(**HOT)
def _page_walk(tags, stamps, dirty, config, work, stats, page):
    """The data TLB missed ``page``: read its page-directory entry, then its page-table entry,
    through the caches (both families cache paging entries in their data caches), enter the page
    in the TLB, and return the packed walk bits and the walk's memory traffic (see service). The
    walk's line fills do not count as the K6 write-allocate rule's last fill (left as it was)."""
    keep0, keep1, keep2 = work[FILL_PAGE_BASE], work[FILL_PAGE_BASE + 1], work[FILL_PAGE_BASE + 2]
    pde, t1 = _walk_read(tags, stamps, dirty, config, work, stats, PD_BASE + ((page >> 10) << 2))
    pte, t2 = _walk_read(tags, stamps, dirty, config, work, stats, PT_BASE + (page << 2))
    work[FILL_PAGE_BASE], work[FILL_PAGE_BASE + 1], work[FILL_PAGE_BASE + 2] = keep0, keep1, keep2
    _tlb_fill(config, work, page)
    return TLB_MISS | (pde << PDE_LEVEL_SHIFT) | (pte << PTE_LEVEL_SHIFT), t1 + t2


@njit(**HOT)
def service(tags, stamps, dirty, config, work, stats, addr, size, is_write):
    """One CPU data access of ``size`` bytes at ``addr`` (read, or write if ``is_write``).

    ``tags``/``stamps``/``dirty`` (all levels in one array each), ``config`` int64
    ``[levels, NCFG]`` and ``work`` int64 ``[WORK_SIZE]`` (the LRU clock, the walk's stack, the
    open DRAM pages and the data TLB) are as given by :meth:`Hierarchy.arrays`; ``stats`` int64
    ``[levels + 1, NSTATS]`` gets the counts added (:meth:`Hierarchy.new_counts`).

    With a data TLB (:meth:`Hierarchy.set_tlb`), a page the TLB does not hold is walked first
    (:func:`_page_walk`: two reads through the same caches, counted in ``stats`` like any request).

    Returns a packed int64: ``served_level(r)`` (0 = L1 hit, ``levels`` = memory; for an access
    that crosses a line boundary, the slower line), ``memory_fills(r)``, ``memory_writebacks(r)``,
    ``memory_partial_writes(r)``, ``lines_touched(r)``, and for a TLB miss ``tlb_missed(r)``,
    ``walk_pde_level(r)`` and ``walk_pte_level(r)`` (an access that crosses into a second missing
    page: one miss, each walk read at the slower of its two levels).
    """
    nlevels = config.shape[0]
    ob = config[0, CFG_OFFSET_BITS]
    first, last = addr >> ob, (addr + size - 1) >> ob
    kind = STORE if is_write else LOAD
    served = 0
    traffic = 0
    if config[0, CFG_TLB_WAYS] > 0:
        for page in range(addr >> TLB_PAGE_BITS, ((addr + size - 1) >> TLB_PAGE_BITS) + 1):
            if not tlb_probe(config, work, page << TLB_PAGE_BITS):
                bits, t = _page_walk(tags, stamps, dirty, config, work, stats, page)
                traffic += t
                if served & TLB_MISS:  # a second walk: keep the slower level of each read
                    bits = (TLB_MISS | (max(walk_pde_level(bits), walk_pde_level(served)) << PDE_LEVEL_SHIFT)
                            | (max(walk_pte_level(bits), walk_pte_level(served)) << PTE_LEVEL_SHIFT))
                served = bits
    walk = served
    served = 0
    for line in range(first, last + 1):
        r = 0
        sp = _push(work, STACK_BASE, line << ob, 0, kind, 1)
        while sp > STACK_BASE:
            sp, e, code = _step(tags, stamps, dirty, config, work, stats, sp)
            r = _account(r, e, code, nlevels)
        served = max(served, r & SERVED_MASK)
        traffic += r & ~SERVED_MASK
    return served | walk | traffic | ((last - first + 1) << LINES_SHIFT)


@njit(cache=True, nogil=True)
def simulate(tags, stamps, dirty, config, work, mem_addr, mem_size, mem_write):
    """Run a whole trace through the hierarchy (state updated in place; a warm start is allowed).

    Returns the counts, int64 ``[levels + 1, NSTATS]`` (columns ``S_*``; the last row is memory).
    Counts are per line: an access that crosses a line boundary is two L1 requests.
    """
    stats = np.zeros((config.shape[0] + 1, NSTATS), np.int64)
    for j in range(mem_addr.shape[0]):
        service(tags, stamps, dirty, config, work, stats, np.int64(mem_addr[j]), np.int64(mem_size[j]),
                mem_write[j])
    return stats


@njit(cache=True, nogil=True)
def simulate_classified(tags, stamps, dirty, config, work, mem_addr, mem_size, mem_write, uniq):
    """:func:`simulate` plus the compulsory/capacity/conflict split of every level's misses
    (columns S_COMPULSORY, S_CAPACITY, S_CONFLICT). Start from cold caches. ``uniq`` is the sorted
    array of every line number the trace touches; lines are identified by their index in it."""
    nlevels = config.shape[0]
    stats = np.zeros((nlevels + 1, NSTATS), np.int64)
    sh = np.zeros((nlevels, 4, uniq.shape[0]), np.int64)
    sh[:, SH_PREV, :] = -1
    sh[:, SH_NEXT, :] = -1
    meta = np.full((nlevels, 4), -1, np.int64)
    for k in range(nlevels):
        meta[k, FA_COUNT] = 0
        meta[k, FA_CAPACITY] = config[k, CFG_SETS] * config[k, CFG_WAYS]
    for j in range(mem_addr.shape[0]):
        a = np.int64(mem_addr[j])
        ob = config[0, CFG_OFFSET_BITS]
        for line in range(a >> ob, ((a + mem_size[j] - 1) >> ob) + 1):
            sp = _push(work, STACK_BASE, line << ob, 0, STORE if mem_write[j] else LOAD, 1)
            while sp > STACK_BASE:
                sp, e, code = _step(tags, stamps, dirty, config, work, stats, sp)
                if code >= 0:
                    level = (e >> 4) & 0xF
                    policy = config[level, CFG_WRITE_ALLOCATE]
                    # under the K6 rule a present line means a present sector: it would allocate
                    allocate = policy == ALLOC_ALWAYS or (policy == ALLOC_PAGE_SECTOR
                                                          and code & (HIT | ALLOCATED) != 0)
                    _classify(uniq, sh, meta, stats, level, (e >> 8) >> config[level, CFG_OFFSET_BITS],
                              (e >> 1) & 0x7, allocate, code & HIT)
    return stats


@njit(cache=True, nogil=True)
def _trace_lines(mem_addr, mem_size, offset_bits):
    total = 0
    for j in range(mem_addr.shape[0]):
        a = np.int64(mem_addr[j])
        total += ((a + mem_size[j] - 1) >> offset_bits) - (a >> offset_bits) + 1
    out = np.empty(total, np.int64)
    n = 0
    for j in range(mem_addr.shape[0]):
        a = np.int64(mem_addr[j])
        for line in range(a >> offset_bits, ((a + mem_size[j] - 1) >> offset_bits) + 1):
            out[n] = line
            n += 1
    return out


# --- results -----------------------------------------------------------------------------------

@dataclass(frozen=True)
class LevelStats:
    """Counts of one level, per line-sized request. ``loads``/``stores`` come from the CPU (L1) or
    the level above (fills it requested, writes it passed on); ``writebacks_in`` are dirty lines
    the level above evicted. ``fills`` = lines fetched from the next level, ``evictions`` = valid
    lines replaced, ``writebacks`` = dirty ones among them, ``forwarded`` = writes passed on.
    The 3C split is None unless the run asked for it."""

    name: str
    loads: int
    load_hits: int
    stores: int
    store_hits: int
    writebacks_in: int
    writeback_hits: int
    fills: int
    evictions: int
    writebacks: int
    forwarded: int
    compulsory: int | None = None
    capacity: int | None = None
    conflict: int | None = None

    @property
    def load_misses(self) -> int:
        return self.loads - self.load_hits

    @property
    def store_misses(self) -> int:
        return self.stores - self.store_hits

    @property
    def writeback_misses(self) -> int:
        return self.writebacks_in - self.writeback_hits

    @property
    def requests(self) -> int:
        return self.loads + self.stores + self.writebacks_in

    @property
    def hits(self) -> int:
        return self.load_hits + self.store_hits + self.writeback_hits

    @property
    def misses(self) -> int:
        return self.requests - self.hits

    @property
    def miss_rate(self) -> float:
        return self.misses / self.requests if self.requests else 0.0


@dataclass(frozen=True)
class MemoryStats:
    line_fills: int
    line_writebacks: int
    partial_writes: int


@dataclass(frozen=True)
class HierarchyStats:
    accesses: int               # CPU data accesses in the trace
    levels: tuple[LevelStats, ...]
    memory: MemoryStats

    @property
    def line_accesses(self) -> int:
        return self.levels[0].loads + self.levels[0].stores

    @property
    def crossing_accesses(self) -> int:
        """Accesses that touched more than one line (for accesses no larger than a line)."""
        return self.line_accesses - self.accesses

    def level(self, name: str) -> LevelStats:
        for s in self.levels:
            if s.name == name:
                return s
        raise KeyError(f"no cache level named {name!r} (levels: {', '.join(s.name for s in self.levels)})")

    def table(self) -> list[dict[str, object]]:
        """One row per level, then one for memory, for reports (md/csv/json)."""
        rows: list[dict[str, object]] = []
        for s in self.levels:
            row = {"level": s.name, "loads": s.loads, "load_misses": s.load_misses, "stores": s.stores,
                   "store_misses": s.store_misses, "writebacks_in": s.writebacks_in,
                   "writeback_misses": s.writeback_misses, "hits": s.hits, "misses": s.misses,
                   "miss_rate": round(s.miss_rate, 6), "fills": s.fills, "evictions": s.evictions,
                   "writebacks": s.writebacks, "forwarded": s.forwarded}
            if s.compulsory is not None:
                row.update(compulsory=s.compulsory, capacity=s.capacity, conflict=s.conflict)
            rows.append(row)
        m = self.memory
        rows.append({"level": "memory", "line_fills": m.line_fills, "line_writebacks": m.line_writebacks,
                     "partial_writes": m.partial_writes})
        return rows

    @classmethod
    def from_counts(cls, names: Sequence[str], counts: np.ndarray, accesses: int,
                    classified: bool = False) -> HierarchyStats:
        levels = []
        for name, row in zip(names, counts[:-1]):
            c = [int(x) for x in row]
            levels.append(LevelStats(
                name, c[S_LOADS], c[S_LOAD_HITS], c[S_STORES], c[S_STORE_HITS], c[S_WRITEBACKS_IN],
                c[S_WRITEBACK_HITS], c[S_FILLS], c[S_EVICTIONS], c[S_WRITEBACKS], c[S_FORWARDED],
                *((c[S_COMPULSORY], c[S_CAPACITY], c[S_CONFLICT]) if classified else (None, None, None))))
        mem = counts[-1]
        return cls(int(accesses), tuple(levels),
                   MemoryStats(int(mem[S_LOADS]), int(mem[S_WRITEBACKS_IN]), int(mem[S_STORES])))


# --- builder -----------------------------------------------------------------------------------

class Hierarchy:
    """Builder and holder of a hierarchy's arrays; :meth:`run` simulates a trace."""

    def __init__(self, geometries: Sequence[CacheGeometry]):
        geometries = tuple(geometries)
        if not 1 <= len(geometries) <= MAX_LEVELS:
            raise ValueError(f"a hierarchy has 1 to {MAX_LEVELS} cache levels, got {len(geometries)}")
        names = [g.name for g in geometries]
        if len(set(names)) != len(names):
            raise ValueError(f"cache level names must be unique, got {names}")
        line = geometries[0].line_bytes
        for g in geometries[1:]:
            if g.line_bytes != line:
                raise ValueError(f"{g.name}: line size {g.line_bytes} differs from {geometries[0].name}'s "
                                 f"{line}; all levels must share one line size")
        self.geometries = geometries
        # One array per field for all levels (see the module docstring), padded to the widest level.
        rows = sum(g.sets for g in geometries)
        width = max(g.ways for g in geometries)
        self.tags = np.full((rows, width), -1, np.int64)
        self.stamps = np.full((rows, width), -1, np.int64)
        self.dirty = np.zeros((rows, width), np.uint8)
        config, states, row0 = [], [], 0
        for g in geometries:
            view = np.s_[row0:row0 + g.sets, :g.ways]
            states.append(CacheState(g, (self.tags[view], self.stamps[view], self.dirty[view])))
            config.append([g.offset_bits, g.allocate_id, g.write_back, g.replacement_id, row0, g.sets, g.ways, 0, 0, 0, 0])
            row0 += g.sets
        self.states = tuple(states)
        self.config = np.array(config, dtype=np.int64)
        self.work = np.zeros(WORK_SIZE, np.int64)
        self.reset()

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(g.name for g in self.geometries)

    def arrays(self):
        """``(tags, stamps, dirty, config, work)``: the first five arguments of :func:`service`,
        :func:`simulate` and :func:`simulate_classified` (all levels in one array per field)."""
        return self.tags, self.stamps, self.dirty, self.config, self.work

    def contents(self) -> tuple:
        """A copy of what the caches, TLB and DRAM pages hold, with the configuration, for :meth:`restore`."""
        return tuple(a.copy() for a in (self.tags, self.stamps, self.dirty, self.work, self.config))

    def restore(self, contents: tuple) -> bool:
        """Hold again what :meth:`contents` saved, from a hierarchy of the same caches and TLB (False
        otherwise, nothing changed). One of another DRAM page geometry is taken with every page
        closed: which rows its accesses would have left open here is not known."""
        *arrays, config = contents
        pages = [CFG_PAGE_SHIFT, CFG_PAGE_MASK]
        if not np.array_equal(np.delete(self.config, pages, axis=1), np.delete(config, pages, axis=1)):
            return False
        for into, saved in zip((self.tags, self.stamps, self.dirty, self.work), arrays):
            np.copyto(into, saved)
        if not np.array_equal(self.config[:, pages], config[:, pages]):
            self.work[OPEN_PAGE_BASE:OPEN_PAGE_BASE + MAX_OPEN_PAGES] = -1
        return True

    def new_counts(self) -> np.ndarray:
        """A zeroed counts array for :func:`service`."""
        return np.zeros((len(self.states) + 1, NSTATS), np.int64)

    def reset(self) -> None:
        self.tags.fill(-1)
        self.stamps.fill(-1)
        self.dirty.fill(0)
        self.work.fill(0)
        self.work[FILL_PAGE_BASE:FILL_PAGE_BASE + MAX_LEVELS] = -1
        self.work[OPEN_PAGE_BASE:OPEN_PAGE_BASE + MAX_OPEN_PAGES] = -1
        self.work[TLB_LAST:TLB_TAGS + MAX_TLB_ENTRIES] = -1

    def set_dram_pages(self, page_bytes: int, open_pages: int) -> None:
        """Track open DRAM pages below the last level: ``open_pages`` banks (one open row each) of
        ``page_bytes``-byte rows, both powers of two (see :class:`sim.memory.dram.PageModel`).
        Without this call every memory request is a page miss."""
        for what, n, top in (("page_bytes", page_bytes, 1 << 30), ("open_pages", open_pages, MAX_OPEN_PAGES)):
            if not 0 < n <= top or n & (n - 1):
                raise ValueError(f"{what} must be a power of two up to {top}, got {n}")
        self.config[:, CFG_PAGE_SHIFT] = page_bytes.bit_length() - 1
        self.config[:, CFG_PAGE_MASK] = open_pages - 1

    def set_tlb(self, entries: int, ways: int) -> None:
        """Translate every access through a data TLB of ``entries`` 4 KB-page entries in sets of
        ``ways`` (LRU), walking the page tables through these caches on a miss (see :func:`service`).
        Without this call there is no TLB (every page is mapped)."""
        if not 0 < ways <= entries <= MAX_TLB_ENTRIES or entries % ways:
            raise ValueError(f"a data TLB has 1 to {MAX_TLB_ENTRIES} entries in whole sets of its ways, "
                             f"got {entries} entries, {ways} ways")
        sets = entries // ways
        if sets & (sets - 1):
            raise ValueError(f"a data TLB's sets must be a power of two, got {entries} / {ways} = {sets}")
        self.config[:, CFG_TLB_SETS] = sets
        self.config[:, CFG_TLB_WAYS] = ways
        self.work[TLB_LAST:TLB_TAGS + MAX_TLB_ENTRIES] = -1

    def prefill(self, mem_addr, mem_size) -> None:
        """Bring every line the accesses touch into the caches, in address order, as reads would
        bring them (each line read once, through the data TLB if there is one), as far as they fit:
        the "warm data" start of `retrosim loop --data warm`. Counts go nowhere (a throwaway array)."""
        ob = self.geometries[0].offset_bits
        lines = _trace_lines(np.ascontiguousarray(mem_addr, dtype=np.uint32),
                             np.ascontiguousarray(mem_size, dtype=np.uint8), ob)
        addr = (np.unique(lines) << ob).astype(np.uint32)  # sorted: address order
        simulate(*self.arrays(), addr, np.ones(addr.size, np.uint8), np.zeros(addr.size, np.bool_))

    def run(self, trace, *, classify: bool = False, cold: bool = True) -> HierarchyStats:
        """Simulate ``trace`` (anything with ``mem_addr``/``mem_size``/``mem_write`` arrays, e.g. a
        :class:`sim.guest.trace.Trace`). ``cold`` empties the caches first; ``classify`` adds the
        compulsory/capacity/conflict split of each level's misses (needs a cold start)."""
        addr = np.ascontiguousarray(trace.mem_addr, dtype=np.uint32)
        size = np.ascontiguousarray(trace.mem_size, dtype=np.uint8)
        write = np.ascontiguousarray(trace.mem_write, dtype=np.bool_)
        if not addr.shape == size.shape == write.shape or addr.ndim != 1:
            raise ValueError("trace mem_addr, mem_size and mem_write must be 1-D arrays of one length")
        if size.size and not size.min():
            raise ValueError("trace mem_size: zero-byte access")
        if cold:
            self.reset()
        elif classify:
            raise ValueError("miss classification needs a cold start (cold=True)")
        if classify:
            uniq = np.unique(_trace_lines(addr, size, self.geometries[0].offset_bits))
            counts = simulate_classified(*self.arrays(), addr, size, write, uniq)
        else:
            counts = simulate(*self.arrays(), addr, size, write)
        return HierarchyStats.from_counts(self.names, counts, addr.size, classified=classify)


@functools.cache
def family_policies() -> dict:
    """policies.toml: the data caches' policies per family (read once; not to be mutated)."""
    with open(POLICIES_FILE, "rb") as f:
        return tomllib.load(f)


def write_allocate_full_when(family: str) -> str | None:
    """Where a preset of `family` may set its L1 data cache's write allocation
    (``[write_allocate] mode``): the machine whose L1 allocates every write miss, in words
    (policies.toml ``full_allocation``); None where the family's allocation is fixed."""
    return family_policies().get(family, {}).get("l1d", {}).get("full_allocation")


__all__ = [
    "Hierarchy", "HierarchyStats", "LevelStats", "MemoryStats", "service", "simulate",
    "simulate_classified", "served_level", "memory_fills", "memory_writebacks",
    "memory_partial_writes", "lines_touched", "memory_fill_page_hits", "memory_writeback_page_hits", "NSTATS", "family_policies",
    "tlb_missed", "walk_pde_level", "walk_pte_level", "walk_l1_fills", "tlb_probe",
    "walk_read_result",
]
