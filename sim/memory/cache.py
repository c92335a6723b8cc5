"""One cache level: geometry and policy, state as numpy arrays, and a compiled ``access`` function.

The timing models call :func:`access` (or the hierarchy walk built on it, see
:mod:`sim.memory.hierarchy`) from inside their own ``@njit`` cycle loops, so the hot path is plain
numba functions over arrays; the classes here only build and hold those arrays.

Modelling choices (each one a deliberate simplification, stated so results can be judged):

- **Replacement.** True LRU (``"lru"``) or least-recently-allocated (``"fifo"``). Real parts use
  cheaper approximations: the Pentium's 4-way L1 uses a 3-bit tree pseudo-LRU (Intel Embedded
  Pentium Processor Family Developer's Manual, 1998, fig. 3-7) and the P6 is generally taken to do
  the same; we model true LRU because it is the reference every cache simulator agrees on, which is
  what lets us cross-check counts exactly against pycachesim. The AMD-K6 L1 *data* cache replaces
  the Least Recently *Allocated* line (AMD-K6 Processor Data Sheet 20695H, March 1998, sec. 8.6
  "Cache-Line Replacements"; its instruction cache is LRU): that is ``"fifo"`` here. Invalid ways
  are always filled first, lowest way first.
- **Write policy.** Write-back or write-through, with or without allocate-on-write-miss:
  - P6 (Pentium Pro/II/III, Celeron): write-back, write-allocate. Intel SDM vol. 3A sec. 11.3
    (253668-032US, p. 11-10), memory type WB: "Write misses cause cache line fills (in processor
    families starting with the P6 family processors)". The same sentence implies the P5 Pentium
    does *not* fill on a write miss: P5 = write-back, no-write-allocate.
  - AMD-K6 family: write-back, and write-allocate *conditionally*. (The brief for this module said
    "a K6 write miss does NOT allocate in the L1 on the original K6"; the AMD documents say
    otherwise.) "Write allocate is supported on every stepping for every model of the AMD-K6
    processor" (AMD application note 21326F, *Implementation of Write Allocate in the K86
    Processors*, Feb. 1999, step 1). A K6 write miss allocates when any of three mechanisms says the
    line is cacheable (AMD-K6 data sheet 20695H sec. 8.7 "Write Allocate"): the write is to the
    4 KB page of the last line fill ("Write to a Cacheable Page", page held in the CCR); the write
    hits a valid sector whose other line is present ("Write to a Sector"); or the address is below
    the Write Allocate Enable Limit, WHCR.WAELIM x 4 MB, MSR C000_0082h. With WAELIM = 0 the
    limit mechanism is off but the other two still allocate (AMD-K6 BIOS Design Guide 21329L,
    Dec. 1999, WHCR). BIOSes are told to program WAELIM to the installed RAM size, and Linux does it
    itself when the BIOS left it at 0 (arch/x86/kernel/cpu/amd.c ``init_amd_k6``, "Enabling old/new
    style K6 write allocation for N Mb"). Two settings model this (the CPU presets choose, in
    ``[write_allocate] mode``): ``write_allocate=True`` for a programmed WHCR ("full": every write
    miss to main memory allocates; the limit is the installed RAM, which our guest addresses are
    taken to be below), and ``write_allocate="page+sector"`` for WAELIM = 0: allocate only when the
    write is to the page of this level's last line fill, or when the other 32-byte line of its
    64-byte sector is present. We index lines, not sectors, so "sector hit" is approximated by the
    buddy line being resident; the K6's sector replacement (evicting a sector drops both lines) and
    its forward prefetch of a sector's second line are not modelled, and the CCR only sees data
    fills (instruction fetches are not simulated).
- **Request kinds.** A level sees three kinds of request: ``LOAD`` (a read of a line, from the CPU
  or a fill requested by the level above), ``STORE`` (a partial write from the CPU, or a write
  passed on by a write-through/no-allocate level above), and ``WRITEBACK`` (a whole dirty line
  evicted by the level above). A writeback carries the whole line, so when it misses and the level
  allocates it is installed *without* fetching it from below. A writeback hit marks the line dirty
  but does **not** refresh its LRU age: a writeback is not a use by the program (pycachesim and
  ChampSim's LRU make the same choice). Loads and stores refresh it.

State layout (per level, ``sets x ways``): ``tags`` int64 holds the full line number
(``address >> offset_bits``) of each way, ``-1`` when the way is invalid; ``stamps`` int64 the
value of ``now`` at the last use (LRU) or at the fill (FIFO), ``-1`` when invalid; ``dirty`` uint8.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba.core.cpu
import numpy as np
from numba import njit

# Options of the hot-path functions. They take arrays but never allocate one, so they are compiled
# without numba's reference counting (``_nrt=False``, a private option of numba's CPU target,
# checked with numba 0.68): otherwise numba increfs and decrefs every array argument on every call,
# with atomic operations its pruning pass fails to remove from these branchy functions. Measured on
# the hierarchy walk (all L1 hits): 6.5 M accesses/s with reference counting, 46 M/s without. If a
# numba release drops the option we fall back to the slow, safe default.
HOT = dict(cache=True, nogil=True)
if hasattr(numba.core.cpu.CPUTargetOptions, "_nrt"):
    HOT["_nrt"] = False

# Request kinds (the ``kind`` argument of :func:`access`).
LOAD = 0
STORE = 1
WRITEBACK = 2

# Write-allocate policies (the ``write_allocate`` argument of :func:`access`).
ALLOC_NEVER = 0
ALLOC_ALWAYS = 1
ALLOC_PAGE_SECTOR = 2  # the K6 with WHCR.WAELIM = 0: see the module docstring
PAGE_SECTOR = "page+sector"

# The words of a preset's ``[write_allocate] mode`` (and of the ``write_allocate.mode`` override)
# for each write_allocate setting: the K6 presets choose, the other families' policies imply one.
WRITE_ALLOCATE_MODES = {"full": True, "page+sector only": PAGE_SECTOR, "none": False}
PAGE_BITS = 12         # 4 KB pages (the K6's CCR holds a page address)

# Replacement policies (the ``replacement`` argument of :func:`access`).
LRU = 0
FIFO = 1
REPLACEMENT = {"lru": LRU, "fifo": FIFO}

# Result code of :func:`access`: flag bits, plus the victim's line address in the high bits.
HIT = 1            # the line was present
FETCH = 2          # missed and allocated: read the line from the next level (not for writebacks)
EVICT = 4          # allocating replaced a valid line (its address: victim_address(code))
DIRTY_VICTIM = 8   # ... and that line was dirty: write it back to the next level
FORWARD = 16       # the write continues to the next level (write-through, or a no-allocate miss)
ALLOCATED = 32     # missed and a way was (re)filled with this line
VICTIM_SHIFT = 8   # victim byte address << VICTIM_SHIFT; addresses are < 2**33, so this fits int64


@dataclass(frozen=True)
class CacheGeometry:
    """Geometry and policy of one cache level.

    ``size_bytes = sets * ways * line_bytes`` with ``sets`` and ``line_bytes`` powers of two
    (``ways`` need not be). Defaults are the P6 L1D policy: write-back, write-allocate, LRU.
    ``write_allocate`` is True, False, or ``"page+sector"`` (the K6 without its WHCR limit).
    """

    name: str
    size_bytes: int
    ways: int
    line_bytes: int = 32
    replacement: str = "lru"
    write_back: bool = True
    write_allocate: bool | str = True

    def __post_init__(self):
        def bad(msg: str):
            raise ValueError(f"{self.name}: {msg}")

        for field in ("size_bytes", "ways", "line_bytes"):
            value = getattr(self, field)
            if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value <= 0:
                bad(f"{field} must be a positive integer, got {value!r}")
        if not _is_pow2(self.line_bytes):
            bad(f"line_bytes {self.line_bytes} is not a power of two")
        sets, rest = divmod(self.size_bytes, self.ways * self.line_bytes)
        if rest or not _is_pow2(sets):
            bad(f"size {self.size_bytes} is not ways*line*power-of-two sets "
                f"({self.ways} ways x {self.line_bytes} B lines)")
        if self.replacement not in REPLACEMENT:
            bad(f"replacement {self.replacement!r} is not one of {sorted(REPLACEMENT)}")
        if self.write_allocate not in (True, False, PAGE_SECTOR):
            bad(f"write_allocate must be True, False or {PAGE_SECTOR!r}, got {self.write_allocate!r}")
        if not self.write_back and self.write_allocate:
            # A write-through cache that allocates on a write miss is legal hardware but nothing
            # we model uses it, and pycachesim (our cross-check) rejects it too.
            bad("write-through with write-allocate is not supported")

    @property
    def sets(self) -> int:
        return self.size_bytes // (self.ways * self.line_bytes)

    @property
    def lines(self) -> int:
        return self.size_bytes // self.line_bytes

    @property
    def offset_bits(self) -> int:
        return self.line_bytes.bit_length() - 1

    @property
    def set_bits(self) -> int:
        return self.sets.bit_length() - 1

    @property
    def replacement_id(self) -> int:
        return REPLACEMENT[self.replacement]

    @property
    def allocate_id(self) -> int:
        if self.write_allocate == PAGE_SECTOR:
            return ALLOC_PAGE_SECTOR
        return ALLOC_ALWAYS if self.write_allocate else ALLOC_NEVER

    @property
    def write_allocate_mode(self) -> str:
        """The write allocation in words (WRITE_ALLOCATE_MODES): "full", "page+sector only" or "none"."""
        return {ALLOC_ALWAYS: "full", ALLOC_NEVER: "none", ALLOC_PAGE_SECTOR: "page+sector only"}[self.allocate_id]

    @property
    def write_miss_words(self) -> str:
        """What the cache does on a write miss, as a sentence's verb phrase (the loop's write-policy line)."""
        return {ALLOC_ALWAYS: "allocates a line on every write miss", ALLOC_NEVER: "does not allocate a line on a write miss",
                ALLOC_PAGE_SECTOR: "allocates on a write miss only to the page of the last line fill or a present "
                "sector"}[self.allocate_id]

    def describe(self) -> str:
        allocate = {ALLOC_NEVER: "no-write-allocate", ALLOC_ALWAYS: "write-allocate",
                    ALLOC_PAGE_SECTOR: "write-allocate on page/sector hit"}[self.allocate_id]
        policy = ("write-back" if self.write_back else "write-through") + ", " + allocate
        return (f"{self.name}: {self.size_bytes // 1024} KB, {self.ways}-way, {self.line_bytes} B lines, "
                f"{self.sets} sets, {self.replacement.upper()}, {policy}")


def _is_pow2(n: int) -> bool:
    return n > 0 and n & (n - 1) == 0


class CacheState:
    """The arrays of one cache level, cold (all ways invalid) until used."""

    def __init__(self, geometry: CacheGeometry, storage: tuple | None = None):
        """``storage``: optional ``(tags, stamps, dirty)`` views ``[sets, ways]`` to use instead of
        new arrays (a :class:`~sim.memory.hierarchy.Hierarchy` keeps every level in one array)."""
        self.geometry = geometry
        shape = (geometry.sets, geometry.ways)
        if storage is None:
            storage = (np.empty(shape, np.int64), np.empty(shape, np.int64), np.empty(shape, np.uint8))
        self.tags, self.stamps, self.dirty = storage
        if self.tags.shape != shape or self.stamps.shape != shape or self.dirty.shape != shape:
            raise ValueError(f"{geometry.name}: storage arrays must have shape {shape}")
        self.fill_page = -1  # page of the last line fill (the K6's CCR), for "page+sector"
        self.reset()

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(tags, stamps, dirty)``, the first three arguments of :func:`access`."""
        return self.tags, self.stamps, self.dirty

    def reset(self) -> None:
        self.tags.fill(-1)
        self.stamps.fill(-1)
        self.dirty.fill(0)
        self.fill_page = -1

    def access(self, addr: int, kind: int = LOAD) -> int:
        """Convenience (Python-speed) call of :func:`access` with this level's policy and clock."""
        g = self.geometry
        now = int(self.stamps.max()) + 1  # later than every stamp so far
        code = int(access(self.tags, self.stamps, self.dirty, g.offset_bits, addr, kind, g.allocate_id,
                          g.write_back, g.replacement_id, now, self.fill_page))
        if code & FETCH:
            self.fill_page = addr >> PAGE_BITS
        return code

    def contains(self, addr: int) -> bool:
        line = addr >> self.geometry.offset_bits
        return bool(np.any(self.tags[line & (self.geometry.sets - 1)] == line))

    def resident_lines(self) -> np.ndarray:
        """Byte addresses of every valid line, sorted (for tests and reports)."""
        lines = self.tags[self.tags >= 0]
        return np.sort(lines) << self.geometry.offset_bits


@njit(**HOT)
def access(tags, stamps, dirty, offset_bits, addr, kind, write_allocate, write_back, replacement, now,
           fill_page=-1):
    """Look up and update one level for one line-sized request; returns a result code.

    Arguments: the level's ``tags``/``stamps``/``dirty`` arrays ``[sets, ways]`` (updated in
    place); ``offset_bits`` = log2(line bytes); ``addr`` any byte address inside the line (the
    request must not cross a line: split it first with :func:`line_span`); ``kind`` LOAD, STORE or
    WRITEBACK; the level's policy (``write_allocate`` one of ALLOC_*); ``now`` a stamp that must
    grow from one call on this level to the next (ties would make two ways equally old; a running
    request counter is the simplest choice); ``fill_page``, for ALLOC_PAGE_SECTOR only, the page
    (``addr >> PAGE_BITS``) of this level's last line fill (FETCH), which the caller keeps.

    The code is a bit set: HIT, or a miss with ALLOCATED (+FETCH unless a writeback) and then EVICT
    and DIRTY_VICTIM when a valid (dirty) line was replaced; FORWARD when the write must continue to
    the next level. This function never talks to other levels: the caller fetches the line (FETCH),
    writes the victim back (DIRTY_VICTIM, address ``victim_address(code)``) and passes the write on
    (FORWARD), in that order (what the hardware does: the fill goes first, the victim waits in a
    writeback buffer).
    """
    return lookup(tags, stamps, dirty, 0, tags.shape[0], tags.shape[1], offset_bits, addr, kind,
                  write_allocate, write_back, replacement, now, fill_page)


@njit(**HOT)
def lookup(tags, stamps, dirty, row0, nsets, ways, offset_bits, addr, kind, write_allocate, write_back,
           replacement, now, fill_page):
    """:func:`access` on a level stored in rows ``row0 .. row0 + nsets`` and the first ``ways``
    columns of larger arrays: the hierarchy keeps all its levels in one array per field, because
    picking one of several arrays at run time costs numba reference counting on every request."""
    # One exit only: should the _nrt option (see HOT) ever go, an early return would also keep numba
    # from pruning the reference counting of the array arguments.
    line = addr >> offset_bits
    s = row0 + (line & (nsets - 1))
    oldest = 0
    hit_way = -1
    for w in range(ways):
        if tags[s, w] == line:
            hit_way = w
            break
        if stamps[s, w] < stamps[s, oldest]:  # invalid ways have stamp -1: they go first
            oldest = w
    if hit_way >= 0:
        code = HIT
        if kind != WRITEBACK and replacement == LRU:
            stamps[s, hit_way] = now
        if kind != LOAD:
            if write_back:
                dirty[s, hit_way] = 1
            else:
                code |= FORWARD
    elif kind != LOAD and not _allocates(tags, row0, nsets, ways, offset_bits, addr, write_allocate,
                                        fill_page):
        code = FORWARD
    else:
        code = ALLOCATED
        if kind != WRITEBACK:
            code |= FETCH
        victim = tags[s, oldest]
        if victim >= 0:
            code |= EVICT | ((victim << offset_bits) << VICTIM_SHIFT)
            if dirty[s, oldest]:
                code |= DIRTY_VICTIM
        tags[s, oldest] = line
        stamps[s, oldest] = now
        if kind == LOAD:
            dirty[s, oldest] = 0
        elif write_back:
            dirty[s, oldest] = 1
        else:
            dirty[s, oldest] = 0
            code |= FORWARD
    return code


@njit(**HOT)
def _allocates(tags, row0, nsets, ways, offset_bits, addr, write_allocate, fill_page):
    """Whether a write miss allocates. The K6 "page+sector" rule: the write is to the page of the
    last line fill, or the other line of its 64-byte sector is present (see the module docstring)."""
    yes = write_allocate == ALLOC_ALWAYS
    if write_allocate == ALLOC_PAGE_SECTOR:
        yes = addr >> PAGE_BITS == fill_page
        buddy = (addr >> offset_bits) ^ 1
        s = row0 + (buddy & (nsets - 1))
        for w in range(ways):
            yes |= tags[s, w] == buddy
    return yes


@njit(cache=True, nogil=True, inline="always")
def victim_address(code):
    """Byte address of the line that :func:`access` evicted (meaningful when ``code & EVICT``)."""
    return code >> VICTIM_SHIFT


@njit(cache=True, nogil=True, inline="always")
def line_span(addr, size, offset_bits):
    """``(first_line_address, line_count)`` of the bytes ``[addr, addr + size)``.

    x86 allows misaligned accesses; one that crosses a line boundary touches two lines (and costs
    two cache accesses on these CPUs), so the caller issues one request per line.
    """
    first = addr >> offset_bits
    last = (addr + size - 1) >> offset_bits
    return first << offset_bits, last - first + 1
