"""The family-neutral contract of a timing model: what every CPU family's core fills and every
view, report and baseline reads, and the one way a family model is built.

- The counter schema (``C_NAMES``, ``C_*`` indices): the counters of one segment (a call). A family's
  core may append counters of its own after these (the K6: ``sim.cpus.k6.core.C_NAMES``) or keep its own
  and give these names in :meth:`CoreRun.segment` (the P5: ``sim.cpus.p5.model.p6_aliases``); the slots
  mean different hardware on each family (port 0 is a P6 port and the K6's X unit), which the family's
  view names (its :class:`sim.cpus.vocabulary.Vocabulary`, sim/cpus/NAME/view.py).
- The per-instruction schema (``S_NAMES``, ``S_*``): one row per static instruction (explain).
- The timeline schema (``T_NAMES``) and the stall causes (``CAUSES``) a timeline row names.
- :class:`CoreRun`, the result of a model's ``run``; :func:`dram_cost`, memory behind the last
  cache level in core clocks; :class:`FamilyModel`, the base class that loads a family's machine
  table, instruction table and estimates and builds its caches and data TLB (:func:`data_tlb`: the
  machine table's ``[tlb] dtlb``).

The compiled helpers the cores share (port calendar, BTB victim, store queue) are in
:mod:`sim.cpus.shared_core`; a family's record (name, marker, estimates, ...) in
:mod:`sim.cpus.record`, the registry of families in :mod:`sim.cpus.families`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.errors import RetrosimError
from sim.memory.dram import DramTiming
from sim.memory.hierarchy import Hierarchy
from sim.cpus import record as families  # the family's own record (not the registry above the models)
from sim.cpus.lowering import StaticProgram
from sim.cpus.presets import CpuPreset, line_costs_on
from sim.cpus.table import InstructionTable, load_table

# counter indices (per segment)
C_NAMES = ("cycles", "instructions", "uops", "decode_groups", "decoder0", "decoder1", "decoder2", "msrom_uops",
           "port0", "port1", "port2", "port3", "port4", "stall_decode", "stall_rob", "stall_rs", "stall_store_buffer",
           "stall_partial_register", "stall_partial_flags", "stall_dependency", "stall_port", "stall_mispredict",
           "stall_memory", "stall_store_forward", "branches", "mispredicts", "l1d_loads", "l1d_load_misses",
           "l1d_stores", "l1d_store_misses", "l2_accesses", "l2_misses", "dram_fills", "dram_writebacks",
           "dram_bus_cycles", "l1i_misses", "lcp_stalls", "store_forwards", "stall_fetch", "dram_page_hits",
           "dram_page_misses", "dtlb_misses", "stall_register_read")
NC = len(C_NAMES)
# numba needs plain integer globals, not a dict
C_CYCLES = 0
C_INSTRUCTIONS = 1
C_UOPS = 2
C_DECODE_GROUPS = 3
C_DECODER0 = 4
C_DECODER1 = 5
C_DECODER2 = 6
C_MSROM_UOPS = 7
C_PORT0 = 8
C_PORT1 = 9
C_PORT2 = 10
C_PORT3 = 11
C_PORT4 = 12
C_STALL_DECODE = 13
C_STALL_ROB = 14
C_STALL_RS = 15
C_STALL_STORE_BUFFER = 16
C_STALL_PARTIAL_REGISTER = 17
C_STALL_PARTIAL_FLAGS = 18
C_STALL_DEPENDENCY = 19
C_STALL_PORT = 20
C_STALL_MISPREDICT = 21
C_STALL_MEMORY = 22
C_STALL_STORE_FORWARD = 23
C_BRANCHES = 24
C_MISPREDICTS = 25
C_L1D_LOADS = 26
C_L1D_LOAD_MISSES = 27
C_L1D_STORES = 28
C_L1D_STORE_MISSES = 29
C_L2_ACCESSES = 30
C_L2_MISSES = 31
C_DRAM_FILLS = 32
C_DRAM_WRITEBACKS = 33
C_DRAM_BUS_CYCLES = 34
C_L1I_MISSES = 35
C_LCP_STALLS = 36
C_STORE_FORWARDS = 37
C_STALL_FETCH = 38
C_DRAM_PAGE_HITS = 39    # line fills whose DRAM row was open
C_DRAM_PAGE_MISSES = 40  # the other line fills
C_DTLB_MISSES = 41       # data accesses that missed the data TLB (each walked the page tables)
C_STALL_REGISTER_READ = 42  # P6: rename held by reads of completed registers (rob.register_read)

# per-static-instruction columns (for explain)
S_NAMES = ("executions", "uops", "decoder0", "decoder1", "decoder2", "msrom", "issue_to_retire", "stall_dependency",
           "stall_port", "stall_decode", "stall_partial", "stall_memory", "stall_mispredict", "mispredicts",
           "port0", "port1", "port2", "port3", "port4", "decode_to_retire", "stall_store_forward", "stall_window",
           "l1d_misses", "l2_misses")
NS = len(S_NAMES)
S_EXECUTIONS = 0
S_UOPS = 1
S_DECODER0 = 2
S_DECODER1 = 3
S_DECODER2 = 4
S_MSROM = 5
S_ISSUE_TO_RETIRE = 6
S_STALL_DEPENDENCY = 7
S_STALL_PORT = 8
S_STALL_DECODE = 9
S_STALL_PARTIAL = 10
S_STALL_MEMORY = 11
S_STALL_MISPREDICT = 12
S_MISPREDICTS = 13
S_PORT0 = 14
S_PORT1 = 15
S_PORT2 = 16
S_PORT3 = 17
S_PORT4 = 18
S_DECODE_TO_RETIRE = 19
S_STALL_STORE_FORWARD = 20
S_STALL_WINDOW = 21
S_L1D_MISSES = 22
S_L2_MISSES = 23

# timeline columns
T_NAMES = ("insn", "static", "decode", "alloc", "dispatch", "complete", "retire", "cause")
NT = len(T_NAMES)
CAUSES = ("none", "decode", "window", "partial", "dependency", "port", "memory", "store_forward", "mispredict")


@dataclass
class CoreRun:
    """A timed run: the counters of each segment, the per-instruction sums, the timeline rows and
    the cycle of each RDTSC. A family whose counters differ gives the contract's names in
    :meth:`segment` (a subclass)."""

    program: StaticProgram
    counters: np.ndarray     # [segments, NC]
    per_static: np.ndarray   # [static instructions, NS]
    timeline: np.ndarray     # [rows, NT]
    rdtsc: np.ndarray        # cycle of each dynamic RDTSC, in order
    total_cycles: int
    # {parameter index: (down, up)} where the family's core keeps rooms (the P6's), for FamilyModel.repeats
    rooms: dict | None = None

    def segment(self, k: int = -1) -> dict[str, int]:
        return {name: int(v) for name, v in zip(C_NAMES, self.counters[k])}


@dataclass(frozen=True)
class DramCost:
    """Core-clock costs of the memory behind the last cache level."""

    name: str
    lead_off: int        # from the request leaving the CPU to the critical chunk (core clocks)
    line_busy: int       # front-side bus busy per 32-byte line fill (core clocks)
    writeback_busy: int  # front-side bus busy per line writeback (core clocks)
    # the same three when the DRAM row is open (a page hit): equal to the above without a page model
    lead_off_hit: int = 0
    line_busy_hit: int = 0
    writeback_busy_hit: int = 0
    # a fill's whole bus cycle, request to last transfer (the board's overhead included), where the
    # bus does not overlap one line fill with the next (Socket 7, sim/cpus/k6/model.py)
    line_tenure: int = 0
    line_tenure_hit: int = 0


def dram_cost(memory: DramTiming, preset: CpuPreset) -> DramCost:
    """The memory preset's burst (bus clocks at the CPU's FSB) in core clocks, rounded up: lead-off =
    the board's overhead (the preset's calibrated [memory] overhead_bus_clocks: bus protocol,
    board-cache tag check, chipset) + the memory's first transfer; a fill or writeback keeps the
    bus for the whole burst (``line_tenure``: a fill's whole bus cycle, overhead included, which
    the K6 charges instead)."""
    costs = line_costs_on(preset, memory)
    return DramCost(memory.name, costs.lead_off, costs.fill, costs.writeback, costs.lead_off_hit,
                    costs.fill_hit, costs.writeback_hit, costs.fill_tenure, costs.fill_tenure_hit)


def caches(preset: CpuPreset) -> tuple[Hierarchy, Hierarchy]:
    """(data side, instruction side) of a preset. The data side is the preset's [l1d], [l2] and
    [l3] levels with the family's policies (sim/memory/policies.toml; a level's section may
    override them). The instruction side is the L1I alone, LRU, never allocating on a write: an
    L1I miss is charged by the core (the level below's latency) but does not enter the data
    side's caches. Kernels are a few hundred bytes, so code never competes with data for the L2."""
    return Hierarchy(preset.data_caches()), Hierarchy([preset.instruction_cache()])


def data_tlb(machine: dict, family: str) -> tuple[int, int]:
    """(entries, ways) of the family's data TLB for 4 KB pages: its machine table's ``[tlb] dtlb``."""
    try:
        d = machine["tlb"]["dtlb"]
        if d["page"] != "4 KB":
            raise ValueError(f"page = {d['page']!r}, the model has 4 KB pages only")
        return int(d["entries"]), int(d["ways"])
    except (KeyError, TypeError, ValueError) as e:
        raise RetrosimError(f"{family}_machine.toml [tlb] dtlb: missing or bad field {e}") from None


class FamilyModel:
    """What every family's timing model has: ``family`` (its key in :data:`sim.cpus.families.REGISTRY`),
    ``preset``, ``memory``, ``machine`` (its machine table), ``table`` (its instruction table),
    ``estimates`` (the machine table's [estimates] defaults, with make_model's overrides),
    ``dram`` (:func:`dram_cost`), ``dside`` and ``iside`` (:func:`caches`). A subclass adds its
    parameters, ``lower``, ``run`` and ``session``."""

    family: str = ""
    key: str = ""  # the model within the family a table row's `models` names (the K6's "k6-2"); "" if none

    def __init__(self, preset: CpuPreset, memory: DramTiming, estimates: dict | None = None):
        if preset.family != self.family:
            raise ValueError(f"{preset.name} is a {preset.family} part, not {self.family.upper()}")
        record = families.read(self.family)
        self.estimates = record.defaults() | dict(estimates or {})
        self.preset = preset
        self.memory = memory
        self.machine = record.machine
        self.table: InstructionTable = load_table(self.family)
        self.dram = dram_cost(memory, preset)
        self.dside, self.iside = caches(preset)
        if memory.pages is not None:  # the chipset's open DRAM pages, tracked by the data side's walk
            self.dside.set_dram_pages(memory.pages.page_bytes, memory.pages.open_pages)
        entries, ways = data_tlb(self.machine, self.family)
        self.dside.set_tlb(entries, ways)

    def lowering_key(self) -> tuple | None:
        """Everything the family's ``lower`` reads besides the records and their precisions, as a
        hashable value: two models with equal keys lower the same records to the same program, so
        sessions share it (sim.cpus.session :func:`lowered`). None: never shared."""
        return None

    def reset(self) -> None:
        """Cold caches: each run starts from reset."""
        self.dside.reset()
        self.iside.reset()

    def session(self, decoder, segments: list[int], stat_first: int = 0, check=None):
        """A run fed in chunks (sim/timing/stream.py): every family's model has one."""
        raise NotImplementedError(f"{type(self).__name__}.session")

    def same_but_params(self, other: "FamilyModel") -> bool:
        """Whether `other` is a model of this family that differs from this one in its parameters
        (a family model's ``params``) at most: the same lowering and caches."""
        return (type(other) is type(self) and self.lowering_key() is not None
                and other.lowering_key() == self.lowering_key()
                and np.array_equal(other.dside.config, self.dside.config)
                and np.array_equal(other.iside.config, self.iside.config))

    def repeats(self, run: CoreRun, other: "FamilyModel") -> bool:
        """Whether `other` would time the trace of `run` (this model's timing of it) exactly as `run`:
        a claims' re-timing that would repeat the nominal timing is not run (sim.scenes.claims).
        Here only where `other` is the same machine (an estimate's other value can round to the
        same parameters); a family whose core records more can tell more (the P6's rooms)."""
        return self.same_but_params(other) and np.array_equal(other.params, self.params)

    def board_cache_hit_clocks(self) -> int | None:
        """Clocks until a load that misses L1 and hits the level below has its data, where the model
        has one such figure (the P5's board cache); None otherwise."""
        return None
