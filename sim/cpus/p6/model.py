"""The P6 family model (Pentium Pro, Pentium II, Celeron, Pentium III): parameters from
sim/cpus/p6/p6_machine.toml and the CPU/memory presets, instruction facts from
sim/cpus/p6/p6.toml, the cycle loop in :mod:`sim.cpus.p6.core`."""

from __future__ import annotations

import math

import numpy as np

from sim.guest.decode import Decoder
from sim.guest.elf import EXIT_ADDR
from sim.memory.dram import DramTiming
from sim.memory.replay import NO_LOG, AccessLogs
from sim.guest.trace import Trace
from sim.cpus.p6 import core
from sim.cpus.contract import CoreRun, FamilyModel
from sim.cpus.locking import lock_cost, locked_match
from sim.cpus.lowering import R_KIND, REP_NONE, StaticProgram, lower
from sim.cpus.p6.lowering import P6Limits, uops_rule
from sim.cpus.presets import CpuPreset
from sim.cpus.session import CoreSession, grown_state

class P6Model(FamilyModel):
    """The P6 model: parameters, caches and estimates as every family's (:class:`FamilyModel`); an
    L1I miss is charged the L2 latency (or the DRAM lead-off without an L2)."""

    family = "p6"

    def __init__(self, preset: CpuPreset, memory: DramTiming, estimates: dict | None = None):
        super().__init__(preset, memory, estimates)
        self.l1_latency = int(preset.l1d.latency_cycles or self.machine["load"]["l1_hit_latency"])
        self.params = self._params()
        self.lock = lock_cost(self.machine["lock"], "p6_machine.toml")
        P = self.params
        # what the machine charges without a held resource (sim/cpus/p6/lowering.py: natural_throughput)
        self.limits = P6Limits(width=int(min(P[core.P_RENAME], P[core.P_RETIRE])), msrom_rate=int(P[core.P_MSROM_RATE]),
                               taken_cycles=1 + int(P[core.P_TAKEN_BUBBLE]), lcp_cycles=1 + int(P[core.P_LCP]))

    def repeats(self, run: CoreRun, other: FamilyModel) -> bool:
        """Whether `other` times the trace of `run` (this model's timing of it) as `run`: it has the same
        caches, memory and lowering, and its parameters differ only in those the core keeps rooms
        for (core.rooms), each within its room. Then no event that reads one of them decides
        otherwise than in `run`, and by induction over the run's events neither does any other."""
        if run.rooms is None:
            return super().repeats(run, other)
        if not self.same_but_params(other):
            return False
        for i in np.flatnonzero(other.params != self.params):
            change = int(other.params[i] - self.params[i])
            down, up = run.rooms.get(int(i), (-1, -1))
            if change > up or -change > down:
                return False
        return True

    def locked(self, rec, match):
        """A locked instruction's row with the lock's cost (sim/cpus/locking.py)."""
        return locked_match(rec, match, self.lock)

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
            # backside-bus clocks from the L2 request to the tag RAM's miss signal, in core clocks
            P[core.P_L2_MISS_DETECT] = math.ceil(self.estimates["l2_miss_detect_bsb_clocks"] / p.l2.speed_ratio)
        P[core.P_DRAM_LAT] = self.dram.lead_off
        P[core.P_DRAM_LINE] = self.dram.line_busy
        P[core.P_DRAM_WB] = self.dram.writeback_busy
        P[core.P_DRAM_LAT_HIT] = self.dram.lead_off_hit
        P[core.P_DRAM_LINE_HIT] = self.dram.line_busy_hit
        P[core.P_DRAM_WB_HIT] = self.dram.writeback_busy_hit
        P[core.P_TLB_WALK] = self.estimates["tlb_walk_clocks"]
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
        P[core.P_BIND_TIE] = self.estimates["p01_tie_port"]
        P[core.P_RRF_READS] = m["rob"]["register_read"]["max_completed_register_reads_per_cycle"]
        P[core.P_RRF_RECENT] = m["rob"]["register_read"]["recent_groups"]
        P[core.P_EXIT_ADDR] = EXIT_ADDR
        return P

    def run(self, trace: Trace, decoder: Decoder, segments: list[int] | None = None,
            timeline: tuple[int, int] = (0, 0), stat_first: int = 0, access_logs: AccessLogs | None = None) -> "CoreRun":
        """Time `trace` from a cold machine. `segments`: instruction counts at which to cut the
        counters (e.g. one segment per call); `timeline`: (first instruction, count) to record;
        per-instruction sums cover instructions from `stat_first` on; `access_logs`: record the data
        caches' results, or replay those of an earlier run on the same caches (sim.memory.replay).
        The result carries the cycle at which each RDTSC executed."""
        return P6Session.whole(self, trace, decoder, segments, timeline, stat_first, access_logs)

    def session(self, decoder: Decoder, segments: list[int], stat_first: int = 0, check=None) -> "P6Session":
        """A run fed in chunks (sim/timing/stream.py); `segments` as for :meth:`run`, an end not yet known
        as a large number (set it with :meth:`P6Session.end_segment` before the chunk it ends).
        `check(records)` sees each chunk's new static instructions before they are lowered."""
        return P6Session(self, decoder, segments, (0, 0), stat_first, check)

    def lowering_key(self) -> tuple:
        # the table and machine table are loaded once per family (the lock's cost is the machine's)
        return (id(self.table), id(self.machine), self.l1_latency,
                self.machine["decode"]["simple_decoder_max_length"]["value"], self.limits)

    def lower(self, records, precisions) -> StaticProgram:
        return lower(records, self.table, self.l1_latency, self.machine["decode"]["simple_decoder_max_length"]["value"],
                     uops_for=uops_rule(self.limits), precisions=precisions, adjust=self.locked,
                     fpcw_serializes=True)


class P6Session(CoreSession):
    """One P6 run fed in order, chunk by chunk (the core's state is kept between chunks)."""

    CORE = core
    QUEUES = ((core.QUEUE_RING, core.V_Q_POS, core.V_U_GLOBAL),)  # the decoded-uop queue (estimates.uop_queue)
    KEEP_SLOTS = (core.V_FP_TOP, core.V_SEG, core.V_PREV_PC, core.V_RSB_TOP, core.V_LAST_ILINE)
    KEEP_ARRAYS = core.LEARNED  # BTB, pattern tables, return stack, the L1I lines known

    def grown(self, program) -> None:
        self.state = grown_state(self.state, core.UNIT_FREE, int(program.u_unit.max(initial=0)) + 1)

    rooms_kept = False  # keep_rooms

    def keep_rooms(self) -> None:
        """Time every chunk with the core's version that keeps the rooms (core.ROOM_SLOTS), and give them
        with the run (CoreRun.rooms: core.rooms, for P6Model.repeats); without this call the run has none."""
        self.rooms_kept = True

    def rare_paths(self, rdtsc_out: np.ndarray) -> bool | None:
        """core.simulate's `rare` for the next chunk: True where its REP string, RDTSC or timeline
        paths may run in it (the program has a REP string, a run of one is open, the chunk
        executes an RDTSC or a timeline is recorded) or the rooms are kept, else None: the version
        of the core compiled without those paths."""
        if (self.rooms_kept or self.timeline.shape[0] > 0 or rdtsc_out.shape[0] > 0
                or self.state[0][core.V_REP_SID] >= 0 or np.any(self.program.s_rep[:, R_KIND] != REP_NONE)):
            return True
        return None

    def time_chunk(self, chunk, index, next_pc, rdtsc_sid, rdtsc_out, access_logs) -> int:
        model, program = self.model, self.program
        dt, ds, dd, dc, dclk = model.dside.arrays()
        it, is_, id_, ic, iclk = model.iside.arrays()
        dlog = access_logs.start(model.family, chunk, program, dc) if access_logs is not None else NO_LOG
        total = core.simulate(self.base, next_pc, index, chunk.pc, chunk.mem_insn, chunk.mem_addr, chunk.mem_size,
                              chunk.mem_write, self.seg_end, *program.arrays(), model.params,
                              dt, ds, dd, dc, dclk, self.dstats, it, is_, id_, ic, iclk, self.istats,
                              self.counters, self.per_static, self.stat_first, self.timeline, self.tl_first,
                              rdtsc_sid, rdtsc_out, dlog, *self.state, self.rare_paths(rdtsc_out))
        if access_logs is not None:
            access_logs.finish(dlog)
        return total

    def result(self, program, counters, per_static, timeline, rdtsc, total) -> "CoreRun":
        sv = self.state[0]
        rooms = core.rooms(sv) if self.rooms_kept else None
        return CoreRun(program, counters, per_static, timeline, rdtsc, total, rooms=rooms)
