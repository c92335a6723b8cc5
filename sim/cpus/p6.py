"""The P6 family model (Pentium Pro, Pentium II, Celeron, Pentium III): parameters from
sim/cpus/tables/p6_machine.toml and the CPU/memory presets, instruction facts from
sim/cpus/tables/p6.toml, the cycle loop in :mod:`sim.cpus.p6_core`."""

from __future__ import annotations

import functools
import math
import tomllib
from dataclasses import dataclass

import numpy as np

from sim.guest.decode import Decoder
from sim.guest.elf import EXIT_ADDR
from sim.memory.cache import CacheGeometry
from sim.errors import RetrosimError
from sim.memory.dram import DramTiming, line_costs
from sim.memory.hierarchy import Hierarchy, family_policies
from sim.memory.replay import NO_LOG, AccessLogs
from sim.guest.trace import Trace
from sim.cpus import p6_core as core
from sim.cpus import vocabulary
from sim.cpus.locking import lock_cost, locked_match
from sim.cpus.lowering import P6Limits, StaticProgram, lower
from sim.cpus.presets import CacheSpec, CpuPreset, dram_overhead
from sim.cpus.session import CoreSession, grown_state
from sim.cpus.table import TABLES, InstructionTable, load_table

# Model choices with no figure in the sources (each says why it is what it is).
ESTIMATES = {
    "uop_queue": (6, "decoded-uop queue size: not found in any source; 6 = one cycle of full decode (4+1+1)"),
    "mispredict_restart": (6, "cycles from a mispredicted branch's execution to the decode of the correct path; "
                           "with decode->rename->dispatch (3) this gives the sourced minimum penalty of 9"),
    "static_redirect": (3, "a taken branch missing the BTB (predicted at decode): a few cycles to redirect fetch; estimate"),
    "partial_extra": (2, "cycles after the partial writer retires before the stalled read renames; with "
                      "rename->dispatch->execute this reproduces the measured +5 of a partial-register read "
                      "(p6_machine.toml [partial_register_stall], InstLatX64 PII/PPro chains)"),
    "forward_latency": (4, "store data ready -> forwarded load data ready; with the 1-cycle store-data uop this "
                        "makes the measured ~5-cycle store->load round trip (p6_machine.toml "
                        "[store_forwarding] measured_roundtrips, MOVD/MOVQ 5.1)"),
    "l2_bus_full_speed": (4, "core cycles the 64-bit backside bus is busy per 32-byte line at full speed (4 transfers)"),
    "msrom_rate": (3, "microcode sequencer uops per cycle (p6_machine.toml [decode.microcode], itself estimated)"),
}


@functools.cache
def _machine_table() -> dict:
    with open(TABLES / "p6_machine.toml", "rb") as f:
        return tomllib.load(f)


@dataclass(frozen=True)
class DramCost:
    """Core-clock costs of the memory behind the last cache level."""

    name: str
    lead_off: int        # from the request leaving the CPU to the critical chunk (core clocks)
    line_busy: int       # front-side bus busy per 32-byte line fill (core clocks)
    writeback_busy: int  # front-side bus busy per line writeback (core clocks)


def dram_cost(memory: DramTiming, preset: CpuPreset) -> DramCost:
    """The memory preset's burst (bus clocks at the CPU's FSB) in core clocks, rounded up; the
    lead-off adds the board's overhead (the preset's calibrated [memory] overhead_bus_clocks: bus
    protocol and chipset) to the burst's first transfer."""
    try:
        costs = line_costs(memory, preset.core_mhz, preset.fsb_mhz, dram_overhead(preset, memory.name))
    except ValueError as e:
        raise RetrosimError(f"{preset.name} with {memory.name}: {e}") from None
    return DramCost(memory.name, costs.lead_off, costs.fill, costs.writeback)


def _geometry(name: str, spec: CacheSpec, policy: dict) -> CacheGeometry:
    return CacheGeometry(name, spec.size_bytes, spec.ways, spec.line_bytes, replacement=policy["replacement"],
                         write_back=policy["write_back"], write_allocate=policy["write_allocate"])


class P6Model:
    family = "p6"
    vocabulary = vocabulary.P6  # the words views use for its ports, decoders and stalls

    def __init__(self, preset: CpuPreset, memory: DramTiming, estimates: dict | None = None):
        if preset.family != "p6":
            raise ValueError(f"{preset.name} is a {preset.family} part, not P6")
        self.estimates = {k: v for k, (v, _) in ESTIMATES.items()} | dict(estimates or {})
        self.preset = preset
        self.memory = memory
        self.machine = _machine_table()
        self.table: InstructionTable = load_table("p6")
        self.dram = dram_cost(memory, preset)
        policies = family_policies()["p6"]
        self.l1_latency = int(preset.l1d.latency_cycles or self.machine["load"]["l1_hit_latency"])
        levels = [_geometry("L1D", preset.l1d, policies["l1d"])]
        if preset.l2 is not None:
            levels.append(_geometry("L2", preset.l2, policies["l2"]))
        self.dside = Hierarchy(levels)
        # The instruction side is the L1I alone: an L1I miss is charged the L2 latency (or the
        # DRAM lead-off without an L2) but does not enter the data side's L2. Kernels are a few
        # hundred bytes, so code never competes with data for the L2 in practice.
        self.iside = Hierarchy([_geometry("L1I", preset.l1i, {**policies["l1d"], "write_allocate": False})])
        self.params = self._params()
        self.lock = lock_cost(self.machine["lock"], "p6_machine.toml")
        P = self.params
        # what the machine charges without a held resource (lowering.natural_throughput)
        self.limits = P6Limits(width=int(min(P[core.P_RENAME], P[core.P_RETIRE])), msrom_rate=int(P[core.P_MSROM_RATE]),
                               taken_cycles=1 + int(P[core.P_TAKEN_BUBBLE]), lcp_cycles=1 + int(P[core.P_LCP]))

    def locked(self, rec, match):
        """A locked instruction's row with the lock's cost (sim/cpus/locking.py)."""
        return locked_match(rec, match, self.lock, "p6")

    def _params(self) -> np.ndarray:
        m, p = self.machine, self.preset
        P = np.zeros(core.NPARAMS, np.int64)
        P[core.P_ROB] = m["rob"]["entries"]
        P[core.P_RS] = m["rs"]["entries"]
        P[core.P_RENAME] = m["rename"]["uops_per_cycle"]
        P[core.P_RETIRE] = m["retire"]["uops_per_cycle"]
        P[core.P_QUEUE] = self.estimates["uop_queue"]
        P[core.P_FETCH_BLOCK] = m["fetch"]["block_bytes"]
        P[core.P_L1_LAT] = self.l1_latency
        if p.l2 is not None:
            P[core.P_HAS_L2] = 1
            P[core.P_L2_LAT] = int(p.l2.latency_cycles)
            P[core.P_L2_BUS] = math.ceil(self.estimates["l2_bus_full_speed"] / p.l2.speed_ratio)
        P[core.P_DRAM_LAT] = self.dram.lead_off
        P[core.P_DRAM_LINE] = self.dram.line_busy
        P[core.P_DRAM_WB] = self.dram.writeback_busy
        P[core.P_MSHR] = m["caches"]["l2_bus"]["concurrent_accesses"]
        P[core.P_SB] = m["store"]["store_buffer_entries"]
        P[core.P_MISPREDICT] = self.estimates["mispredict_restart"]
        P[core.P_TAKEN_BUBBLE] = m["branch"]["taken_correct_bubble_cycles"]
        P[core.P_BTB_SETS] = m["branch"]["btb_entries"] // m["branch"]["btb_ways"]
        P[core.P_BTB_WAYS] = m["branch"]["btb_ways"]
        P[core.P_HIST_BITS] = m["branch"]["btb_history_bits"]
        P[core.P_PARTIAL_EXTRA] = self.estimates["partial_extra"]
        P[core.P_FWD_FAIL] = m["store_forwarding"]["failure_penalty_cycles"]
        P[core.P_FWD_LAT] = self.estimates["forward_latency"]
        P[core.P_LCP] = math.ceil(m["decode"]["prefixes"]["lcp_penalty_cycles"]) - 1  # plus the group break
        P[core.P_STATIC_REDIRECT] = self.estimates["static_redirect"]
        P[core.P_RSB] = m["branch"]["return_stack_entries"]
        P[core.P_MSROM_RATE] = self.estimates["msrom_rate"]
        P[core.P_EXIT_ADDR] = EXIT_ADDR
        return P

    def reset(self) -> None:
        self.dside.reset()
        self.iside.reset()

    def run(self, trace: Trace, decoder: Decoder, segments: list[int] | None = None,
            timeline: tuple[int, int] = (0, 0), stat_first: int = 0, access_logs: AccessLogs | None = None) -> "CoreRun":
        """Time `trace` from a cold machine. `segments`: instruction counts at which to cut the
        counters (e.g. one segment per call); `timeline`: (first instruction, count) to record;
        per-instruction sums cover instructions from `stat_first` on; `access_logs`: record the data
        caches' results, or replay those of an earlier run on the same caches (sim.memory.replay).
        The result carries the cycle at which each RDTSC executed."""
        return P6Session.whole(self, trace, decoder, segments, timeline, stat_first, access_logs)

    def session(self, decoder: Decoder, segments: list[int], stat_first: int = 0, check=None) -> "P6Session":
        """A run fed in chunks (sim/stream.py); `segments` as for :meth:`run`, an end not yet known
        as a large number (set it with :meth:`P6Session.end_segment` before the chunk it ends).
        `check(records)` sees each chunk's new static instructions before they are lowered."""
        return P6Session(self, decoder, segments, (0, 0), stat_first, check)

    def lower(self, records, precisions) -> StaticProgram:
        return lower(records, self.table, self.l1_latency, self.machine["decode"]["simple_decoder_max_length"]["value"],
                     limits=self.limits, precisions=precisions, adjust=self.locked, fpcw_serializes=True)


class P6Session(CoreSession):
    """One P6 run fed in order, chunk by chunk (the core's state is kept between chunks)."""

    CORE = core

    def grown(self, program) -> None:
        self.state = grown_state(self.state, core.UNIT_FREE, int(program.u_unit.max(initial=0)) + 1)

    def time_chunk(self, chunk, index, next_pc, rdtsc_sid, rdtsc_out, access_logs) -> int:
        model, program = self.model, self.program
        dt, ds, dd, dc, dclk = model.dside.arrays()
        it, is_, id_, ic, iclk = model.iside.arrays()
        dlog = access_logs.start(model.family, chunk, program, dc) if access_logs is not None else NO_LOG
        total = core.simulate(self.base, next_pc, index, chunk.pc, chunk.mem_insn, chunk.mem_addr, chunk.mem_size,
                              chunk.mem_write, self.seg_end, *program.arrays(), model.params,
                              dt, ds, dd, dc, dclk, self.dstats, it, is_, id_, ic, iclk, self.istats,
                              self.counters, self.per_static, self.stat_first, self.timeline, self.tl_first,
                              rdtsc_sid, rdtsc_out, dlog, *self.state)
        if access_logs is not None:
            access_logs.finish(dlog)
        return total

    def result(self, program, counters, per_static, timeline, rdtsc, total) -> "CoreRun":
        return CoreRun(program, counters, per_static, timeline, rdtsc, total)


@dataclass
class CoreRun:
    program: StaticProgram
    counters: np.ndarray     # [segments, NC]
    per_static: np.ndarray   # [static instructions, NS]
    timeline: np.ndarray     # [rows, NT]
    rdtsc: np.ndarray        # cycle of each dynamic RDTSC, in order
    total_cycles: int

    def segment(self, k: int = -1) -> dict[str, int]:
        return {name: int(v) for name, v in zip(core.C_NAMES, self.counters[k])}
