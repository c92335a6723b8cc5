"""The memory side of the timing models: data caches (one level: :mod:`.cache`; up to three:
:mod:`.hierarchy`) and main-memory timing (:mod:`.dram`). Hot paths are ``@njit`` functions over
numpy arrays, callable from the timing models' own compiled loops."""

from sim.memory.cache import (
    ALLOC_ALWAYS, ALLOC_NEVER, ALLOC_PAGE_SECTOR, ALLOCATED, DIRTY_VICTIM, EVICT, FETCH, FIFO, FORWARD, HIT,
    LOAD, LRU, PAGE_SECTOR, STORE, WRITEBACK, CacheGeometry, CacheState, access, line_span, lookup,
    victim_address,
)
from sim.memory.dram import (
    DramTiming, LineCosts, OpenRowModel, available_memory_presets, bus_ratio, core_clocks, line_costs,
    load_memory_preset, row_access, row_state,
)
from sim.memory.hierarchy import (
    NSTATS, Hierarchy, HierarchyStats, LevelStats, MemoryStats, lines_touched, memory_fills,
    memory_partial_writes, memory_writebacks, served_level, service, simulate, simulate_classified,
)
