"""The AMD K6 family model (K6 model 6/7, K6-2 model 8, K6-III model 9): parameters from
sim/cpus/k6/k6_machine.toml and the CPU/memory presets, instruction facts (RISC86 ops, decoder,
units, latency, throughput) from sim/cpus/k6/k6.toml, the cycle loop in :mod:`sim.cpus.k6.core`.

The interface is every family's (:class:`sim.cpus.contract.FamilyModel`): ``run(trace, decoder,
segments, timeline, stat_first)`` returns a :class:`K6CoreRun` whose counters carry the contract's
names at the contract's indices, followed by the K6's own (``k6_core.C_NAMES``).

How a table row becomes ops (:class:`K6Rules`):
- one op per entry of ``units``: int-x -> issue slot X, int-y -> Y, int-xy -> X or Y, load, store
  (a store op carries address and data; LEA, which writes no memory, is an ordinary op on the store
  slot), branch; fpu -> the x87 unit (no issue-slot calendar: it is not pipelined, busy for the
  row's reciprocal throughput); mmx -> X on the K6 model 6/7, X or Y on the K6-2/K6-III; mmx-mul,
  mmx-shift, 3dnow -> the same slots plus the single multiplier / shifter / 3DNow! unit (one op per
  clock; on the K6 the multiplier holds X for its throughput); no units -> an op that completes
  when it enters the scheduler (MOV r,imm, NOP);
- latency: the row's, which includes the 2-clock load for r,m forms; the ops after the load form a
  chain, 1 clock each except the last, which takes the rest;
- the integer multiplier and divider are not pipelined: the last op holds X for the rest of the
  row's throughput (IMUL r32,r32 = 2 ops on X: 1 + 2 clocks, X busy 3);
- any other short or long row whose measured throughput its decoder, slots and units do not give
  holds a resource of its own (mnemonic and issue slot) for that throughput (K6Rules._hold_unexplained);
- decoder: the row's class, promoted when the encoding breaks the class's limits (short: <= 7
  bytes and <= 2 ops; long: <= 11 bytes and <= 4 ops; else vector); on the K6 and the pre-CXT K6-2
  a 0x0F instruction whose SIB byte decides its length (ModRM 00-xxx-100) one class further
  (k6_machine.toml [decode.length_bytes]);
- decode clocks: a short instruction without prefixes pairs (0); long 1; vector: the vector
  decoder and ROM sequencer are busy for max(2, ceil(ops / 4), the row's throughput when no
  non-pipelined unit explains it) clocks; prefixes: the measured rate (one prefix 1 clock alone, 2
  with a 16-bit immediate; two prefixes 3; n >= 3: 2n - 2); an instruction whose length-determining
  bytes cross a 32-byte I-cache line adds one clock to a decode of at most one clock (an inferred
  rule, k6_machine.toml [decode.line_crossing]: predecode is per line, DS-K6 p.12).

Vector sequences. The table gives BSR/BSF one op with latency 10 and throughput 10 (measured on
three K6 generations; the op count is 86Box's guess). One pipelined op cannot have throughput 10,
and a non-pipelined op on X or Y would give 5 with two units; the model therefore reads such a
throughput as the length of the ROM sequence: the vector decoder is busy for 10 clocks and decodes
nothing else meanwhile (k6_machine.toml [rules] vector_sequence). The same rule gives ADC, ROL, CDQ, SETcc
their measured 2-2.5 and RDTSC its 8.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim.guest.decode import Decoder, InsnRecord
from sim.guest.elf import EXIT_ADDR
from sim.errors import RetrosimError
from sim.memory.dram import DramTiming, bus_ratio, core_clocks
from sim.memory.replay import NO_LOG, AccessLogs
from sim.guest.trace import Trace
from sim.cpus.k6 import core
from sim.cpus.contract import CoreRun, FamilyModel
from sim.cpus.record import machine_table
from sim.cpus.locking import lock_cost, locked_match
from sim.cpus.lowering import (
    BRANCH, COMPUTE, DEC_COMPLEX, DEC_MSROM, DEC_SIMPLE, LOAD, STA, StaticProgram, lower, rep_timing,
)
from sim.cpus.presets import CpuPreset, model_by_cpuid
from sim.cpus.session import CoreSession, grown_state
from sim.cpus.table import Match

PORT_BITS = {"int-x": core.X, "int-y": core.Y, "int-xy": core.X | core.Y, "load": core.LOAD_SLOT,
             "store": core.STORE_SLOT, "branch": core.BRANCH_SLOT}
NON_PIPELINED_INT = {"imul", "mul", "div", "idiv"}


def _machine_table() -> dict:
    return machine_table("k6")


def _locked_row(row, kind, throughput, extra, fields) -> None:
    """A locked row on the K6 (sim/cpus/locking.py): the per-model figures of the measured systems
    give way to the bus-ratio rule; the locked sequence is vector-decoded like XCHG m32,r32 (86Box),
    holding the decoder for its length."""
    extra.pop("model_overrides", None)
    fields["decoder"] = "vector"


def model_key(preset: CpuPreset) -> str:
    """'k6', 'k6-2' or 'k6-3' from the preset's CPUID model (k6_machine.toml [models])."""
    return model_by_cpuid(preset, _machine_table()["models"], "K6", "k6_machine.toml")


def _whole(x: float) -> int:
    """Clocks from a measured figure: nearest integer, halves up (SETcc 2.5 -> 3)."""
    return int(math.floor(x + 0.5))


class K6Rules:
    """The K6's reading of its table rows (see the module docstring), for one model."""

    def __init__(self, key: str, machine: dict):
        self.key = key
        d = machine["decode"]
        self.short_len, self.short_ops = d["short"]["max_length_bytes"], d["short"]["max_ops"]
        self.long_len, self.long_ops = d["long"]["max_length_bytes"], d["long"]["max_ops"]
        self.vector_rate = d["vector"]["ops_per_cycle"]
        self.vector_min = d["vector"]["min_cycles_per_instruction"]
        self.mmx_first_only = bool(d["short"]["mmx_first_decoder_only"][key])
        self.line_bytes = d["line_crossing"]["line_bytes"]
        self.crossing_cycles = d["line_crossing"]["extra_decode_cycles"]
        self.sib_degrades = bool(d["length_bytes"]["sib_after_0f_degrades"][key])
        self.resources: dict = {}  # (mnemonic, issue slots) -> resource id (see _hold_unexplained)

    def field(self, row, name):
        """A row field with the model's override applied (k6.toml model_overrides)."""
        over = row.extra.get("model_overrides", {}).get(self.key, {})
        if name in over:
            return over[name]
        return getattr(row, name) if hasattr(row, name) else row.extra.get(name)

    def uops(self, rec: InsnRecord, match: Match, load_latency: int) -> list[tuple[int, int, int, int, int]]:
        row = match.row
        models = row.extra.get("models")
        if models and self.key not in models:
            raise RetrosimError(f"pc {rec.pc:#010x} ({rec.mnemonic} {rec.op_str}): not on the {self.key} "
                                f"(k6.toml row '{row.key}' models = {models}); the CPU raises #UD")
        units = list(row.extra.get("units", [])) or ["none"] * max(1, row.uops)
        latency = self.field(row, "latency")
        throughput = self.field(row, "throughput")
        mmx_slot = core.X if self.key == "k6" else core.X | core.Y
        ops = []  # [kind, slots, unit, occupancy]
        for name in units:
            if name in ("load", "branch") or name.startswith("int-"):
                kind = LOAD if name == "load" else BRANCH if name == "branch" else COMPUTE
                ops.append([kind, PORT_BITS[name], core.U_NONE, 0])
            elif name == "store":
                ops.append([STA if rec.writes_memory else COMPUTE, core.STORE_SLOT, core.U_NONE, 0])
            elif name == "fpu":
                occ = _whole(throughput or latency or 2)
                ops.append([COMPUTE, 0, core.U_FPU, max(1, occ)])
            elif name == "mmx":
                ops.append([COMPUTE, mmx_slot, core.U_NONE, 0])
            elif name in ("mmx-mul", "mmx-shift", "3dnow"):
                if self.key == "k6":  # one multimedia pipe, on X
                    occ = _whole(throughput or 1)
                    ops.append([COMPUTE, core.X, core.U_HOLD if occ > 1 else core.U_NONE, occ])
                else:
                    unit = {"mmx-mul": core.U_MMX_MUL, "mmx-shift": core.U_MMX_SHIFT, "3dnow": core.U_3DNOW}[name]
                    ops.append([COMPUTE, mmx_slot, unit, 1])
            elif name == "none":
                ops.append([COMPUTE, 0, core.U_NONE, 0])
            else:
                raise RetrosimError(f"k6.toml row '{row.key}': unknown unit {name!r}")
        chain = [j for j, op in enumerate(ops) if op[0] in (COMPUTE, BRANCH)]
        has_load = any(op[0] == LOAD for op in ops)
        total = 1 if latency is None else latency
        work = max(0 if has_load else 1, _whole(total - (load_latency if has_load else 0)))
        if rec.mnemonic in NON_PIPELINED_INT and chain:
            occ = _whole(throughput or total) - (len(chain) - 1)
            ops[chain[-1]][2:] = [core.U_HOLD, max(1, occ)]
        self._hold_unexplained(rec, row, ops, throughput)
        out = []
        for j, (kind, slots, unit, occ) in enumerate(ops):
            if kind == LOAD:
                lat = load_latency
            elif kind == STA:
                lat = 1
            elif slots == 0 and unit == core.U_NONE:
                lat = 0 if latency is None else _whole(latency)
            elif chain and j == chain[-1]:
                lat = max(0, work - (len(chain) - 1))
            else:
                lat = 1
            out.append((kind, slots, lat, unit, occ))
        return out

    def natural_throughput(self, rec: InsnRecord, row, ops) -> float:
        """Reciprocal throughput the machine gives the instruction without a held resource:
        its decoder (two short decodes per clock, one long; a vector sequence's own length is
        handled by vector_cycles), its prefixes, its issue slots and its units."""
        bound = {"short": 0.5, "long": 1.0}.get(row.decoder, float("inf"))
        if row.decoder == "short" and (rec.is_x87 or (self.mmx_first_only and rec.is_mmx)):
            bound = 1.0  # the first short decoder only
        if len(ops) > self.short_ops or rec.length > self.short_len:
            bound = max(bound, 1.0)
        bound = max(bound, self.prefix_cycles(rec))
        only = {}
        either = 0
        for kind, slots, unit, occ in ops:
            if slots == core.X | core.Y:
                either += 1
            elif slots:
                only[slots] = only.get(slots, 0) + (occ if unit == core.U_HOLD else 1)
            if unit not in (core.U_NONE, core.U_HOLD):
                bound = max(bound, occ)
        xy = only.get(core.X, 0) + only.get(core.Y, 0) + either
        return max([bound, xy / 2] + list(only.values()))

    def _hold_unexplained(self, rec: InsnRecord, row, ops, throughput) -> None:
        """A short- or long-decoded row whose measured throughput the machine does not otherwise
        give (XCHG r32,r32 2, MOVD mm,r32 2, PREFETCH 2) holds a resource of its own mnemonic and
        issue slot for that many clocks: its next instance waits, other instructions do not.
        (Vector rows are held in the decoder instead: vector_cycles.)"""
        if not throughput or row.decoder not in ("short", "long") or not ops:
            return
        if any(op[2] != core.U_NONE for op in ops):
            return  # a unit already sets the rate (x87, multiplier, MMX units)
        # the K6 rules count whole clocks (_whole): a measured excess under half a clock (ADD
        # r32,i8 0.56 against two per clock) is below that resolution and not held
        if throughput < self.natural_throughput(rec, row, ops) + 0.5:
            return
        occ = _whole(throughput)
        holder = next((op for op in ops if op[1]), None)
        if holder is None:
            return
        holder[2:] = [self.resources.setdefault((row.mnemonic, holder[1]), core.NUNITS + len(self.resources)), occ]

    def decoder(self, rec: InsnRecord, match: Match, uops) -> int:
        dec = {"short": DEC_SIMPLE, "long": DEC_COMPLEX}.get(match.row.decoder, DEC_MSROM)
        if dec == DEC_SIMPLE and (rec.length > self.short_len or len(uops) > self.short_ops):
            dec = DEC_COMPLEX
        if dec == DEC_COMPLEX and (rec.length > self.long_len or len(uops) > self.long_ops):
            dec = DEC_MSROM
        if self.sib_degrades and self.length_needs_four_bytes(rec):
            dec = DEC_COMPLEX if dec == DEC_SIMPLE else DEC_MSROM
        return dec

    @staticmethod
    def length_needs_four_bytes(rec: InsnRecord) -> bool:
        """0x0F, opcode, ModRM 00-xxx-100 and the SIB byte all decide the length (with mod 00 the SIB's
        base says whether a displacement follows): on the K6 and the pre-CXT K6-2 such an instruction
        decodes one class lower (k6_machine.toml [decode.length_bytes], GMP's K6 notes citing AMD
        21924D p.67)."""
        return (rec.escape_0f and rec.modrm is not None and not rec.addrsize_prefix
                and rec.modrm >> 6 == 0 and rec.modrm & 7 == 4)

    def vector_cycles(self, match: Match, uops) -> int:
        cycles = max(self.vector_min, -(-len(uops) // self.vector_rate))
        explained = any(u[3] == core.U_FPU or (u[3] == core.U_HOLD and u[4] > 1) for u in uops)
        throughput = self.field(match.row, "throughput")
        if throughput and not explained:
            cycles = max(cycles, _whole(throughput))
        return cycles

    @staticmethod
    def prefix_cycles(rec: InsnRecord) -> int:
        """Decode clocks of an instruction with legacy prefixes, alone (k6_machine.toml
        [decode.prefixes], measured); 0 without prefixes."""
        n = len(rec.prefixes)
        if n == 0:
            return 0
        if n == 1:
            return 2 if rec.opsize_prefix and rec.imm_size == 2 else 1
        return 3 if n == 2 else 2 * n - 2

    def crosses_line(self, rec: InsnRecord) -> bool:
        """Whether the instruction's length-determining bytes (prefixes, 0x0F, opcode, ModRM, SIB:
        everything before the displacement and immediate; a 3DNow! suffix byte comes after them)
        lie in two I-cache lines (k6_machine.toml [decode.line_crossing], an inferred rule)."""
        tail = rec.disp_size + rec.imm_size + (1 if rec.opcode[:2] == b"\x0f\x0f" else 0)
        last = rec.pc + max(1, rec.length - tail) - 1
        return rec.pc // self.line_bytes != last // self.line_bytes

    def decode_arrays(self, program: StaticProgram):
        """(s_cyc, s_first, s_pfx, s_cross): decode clocks when alone (0 = pairs in the short
        decoders), first-short-decoder-only flag, decode clocks added by prefixes, decode clocks
        added by length-determining bytes across an I-cache line (only to a decode of at most
        one clock: a longer decode hides it, k6_machine.toml [decode.line_crossing])."""
        n = len(program.records)
        cyc, first, pfx, cross = (np.zeros(n, np.int64) for _ in range(4))
        for s, (rec, match) in enumerate(zip(program.records, program.matches)):
            dec = program.s_dec[s]
            u0, nu = program.s_uop0[s], program.s_nuops[s]
            uops = [tuple(int(a[u]) for a in (program.u_kind, program.u_ports, program.u_lat, program.u_unit,
                                                program.u_occ)) for u in range(u0, u0 + nu)]
            own = self.vector_cycles(match, uops) if dec == DEC_MSROM else 1
            p = self.prefix_cycles(rec)
            cyc[s] = max(own, p) if (p or dec != DEC_SIMPLE) else 0
            pfx[s] = max(0, p - own)
            first[s] = int(rec.is_x87 or (self.mmx_first_only and rec.is_mmx))
            if cyc[s] <= 1 and self.crosses_line(rec):
                cross[s] = self.crossing_cycles
        return cyc, first, pfx, cross


@dataclass
class K6CoreRun(CoreRun):
    """A K6 run: the contract's fields; counters named by k6_core.C_NAMES (the contract's names first)."""

    def segment(self, k: int = -1) -> dict[str, int]:
        return dict(zip(core.C_NAMES, map(int, self.counters[k])))


class K6Model(FamilyModel):
    """The K6 model: parameters, caches and estimates as every family's (:class:`FamilyModel`), the
    Socket 7 board cache (or the K6-III's on-die L2 and board cache) behind L1."""

    family = "k6"

    def __init__(self, preset: CpuPreset, memory: DramTiming, estimates: dict | None = None):
        super().__init__(preset, memory, estimates)
        self.key = model_key(preset)
        self.rules = K6Rules(self.key, self.machine)
        self.ratio = bus_ratio(preset.core_mhz, preset.fsb_mhz)
        self.lock = lock_cost(self.machine["lock"], "k6_machine.toml", self.key, self.ratio)
        self.l1_latency = int(preset.l1d.latency_cycles or self.machine["units"]["load"]["l1_hit_latency"])
        self.params = self._params()

    def _board(self) -> tuple[int, dict]:
        """(level index in the data hierarchy, raw preset section) of the motherboard cache."""
        raw = self.preset.raw
        if self.preset.board_cache is not None:  # K6-III: on-die L2, board cache = L3
            return 2, raw.get("l3") or raw["board_cache"]
        if self.preset.l2 is not None:
            return 1, raw["l2"]
        return 0, {}

    def _params(self) -> np.ndarray:
        m, p = self.machine, self.preset
        P = np.zeros(core.NPARAMS, np.int64)
        P[core.P_QUADS] = m["scheduler"]["entries_risc86_ops"] // m["decode"]["risc86_ops_per_decode_cycle"]
        P[core.P_L1_LAT] = self.l1_latency
        level, section = self._board()
        P[core.P_BOARD_LEVEL] = level
        if level:
            P[core.P_BOARD_LAT] = int((p.board_cache if level == 2 else p.l2).latency_cycles)  # typed: overrides apply
            P[core.P_BOARD_BUSY] = core_clocks(sum(section.get("burst_bus_clocks", [3, 1, 1, 1])), self.ratio)
        if level == 2:
            P[core.P_ONDIE] = 1
            P[core.P_L2_LAT] = int(p.l2.latency_cycles)
            P[core.P_L2_BUS] = self.estimates["ondie_l2_port"]
        P[core.P_IMISS] = P[core.P_L2_LAT] if level == 2 else (P[core.P_BOARD_LAT] or self.dram.lead_off)
        P[core.P_DRAM_LAT] = self.dram.lead_off
        # a DRAM line fill holds the Socket 7 bus for its whole cycle, request to last transfer
        # (k6_machine.toml [bus] fill_tenure): the next fill's lead-off cannot hide under it
        P[core.P_DRAM_LINE] = self.dram.line_tenure
        P[core.P_DRAM_WB] = self.dram.writeback_busy
        P[core.P_DRAM_LAT_HIT] = self.dram.lead_off_hit
        P[core.P_DRAM_LINE_HIT] = self.dram.line_tenure_hit
        P[core.P_DRAM_WB_HIT] = self.dram.writeback_busy_hit
        P[core.P_TLB_WALK] = self.estimates["tlb_walk_clocks"]
        P[core.P_BUS_WRITE] = core_clocks(self.estimates["bus_write_bus_clocks"], self.ratio)
        P[core.P_SQ] = self.estimates["store_queue"]
        P[core.P_MISPREDICT] = self.estimates["mispredict_restart"]
        b = m["branch"]
        P[core.P_BTC] = b["btc_entries"]
        P[core.P_BTC_MISS] = b["btc_miss_taken_penalty_cycles"]
        P[core.P_BHT] = b["bht_entries"]
        P[core.P_HIST_BITS] = self.estimates["bht_history_bits"]
        P[core.P_RSB] = b["return_stack_entries"]
        P[core.P_PARTIAL] = m["partial_register"]["penalty_cycles"]
        P[core.P_EXIT_ADDR] = EXIT_ADDR
        return P

    def lowering_key(self) -> tuple:
        # the rules read the model key and the machine table; the lock's cost those and the bus ratio
        return (id(self.table), id(self.machine), self.key, self.ratio, self.l1_latency)

    def lower(self, records: list[InsnRecord], precisions: list[int | None] | None = None) -> StaticProgram:
        return lower(records, self.table, self.l1_latency, uops_for=self.rules.uops, decoder_for=self.rules.decoder,
                     precisions=precisions, adjust=self.locked,
                     rep_for=lambda rec, match: rep_timing(rec, match, self.rules.field))

    def locked(self, rec, match):
        """A locked instruction's row with the lock's cost at this preset's bus ratio (sim/cpus/locking.py)."""
        return locked_match(rec, match, self.lock, _locked_row)

    def run(self, trace: Trace, decoder: Decoder, segments: list[int] | None = None,
            timeline: tuple[int, int] = (0, 0), stat_first: int = 0, access_logs: AccessLogs | None = None) -> K6CoreRun:
        """Time `trace` from a cold machine (the arguments and result are those of P6Model.run)."""
        return K6Session.whole(self, trace, decoder, segments, timeline, stat_first, access_logs)

    def session(self, decoder: Decoder, segments: list[int], stat_first: int = 0, check=None) -> "K6Session":
        """A run fed in chunks (sim/timing/stream.py), as :meth:`sim.cpus.p6.model.P6Model.session`."""
        return K6Session(self, decoder, segments, (0, 0), stat_first, check)


class K6Session(CoreSession):
    """One K6 run fed in order, chunk by chunk (the core's state is kept between chunks)."""

    CORE = core
    QUEUES = ((core.SQ_RING, core.V_SQ_POS, core.V_NSTORES),)  # the store queue (estimates.store_queue)
    # the global history and the count of L1 fills already charged go with the caches' counts
    KEEP_SLOTS = (core.V_FP_TOP, core.V_SEG, core.V_PREV_PC, core.V_RSB_TOP, core.V_GHIST, core.V_L1_FILL_SEEN)
    KEEP_ARRAYS = core.LEARNED  # writebacks already charged, BHT, BTC, return stack, L1I lines known

    def __init__(self, model: K6Model, decoder: Decoder, segments: list[int], timeline: tuple[int, int] = (0, 0),
                 stat_first: int = 0, check=None):
        super().__init__(model, decoder, segments, timeline, stat_first, check)
        self.k6_static = model.rules.decode_arrays(self.program)

    def grown(self, program) -> None:
        self.k6_static = self.model.rules.decode_arrays(program)
        self.state = grown_state(self.state, core.UNIT_FREE, int(program.u_unit.max(initial=0)) + 1)

    def time_chunk(self, chunk, index, next_pc, rdtsc_sid, rdtsc_out, access_logs) -> int:
        model, program = self.model, self.program
        darrays = model.dside.arrays()
        dlog = access_logs.start(model.family, chunk, program, darrays[3]) if access_logs is not None else NO_LOG
        total = core.simulate(self.base, next_pc, index, chunk.pc, chunk.mem_insn, chunk.mem_addr, chunk.mem_size,
                              chunk.mem_write, self.seg_end, *program.arrays(), *self.k6_static, model.params,
                              *darrays, self.dstats, *model.iside.arrays(), self.istats,
                              self.counters, self.per_static, self.stat_first, self.timeline, self.tl_first,
                              rdtsc_sid, rdtsc_out, dlog, *self.state)
        if access_logs is not None:
            access_logs.finish(dlog)
        return total

    def family_statics(self) -> tuple:
        return self.k6_static

    def result(self, program, counters, per_static, timeline, rdtsc, total) -> K6CoreRun:
        return K6CoreRun(program, counters, per_static, timeline, rdtsc, total)
