"""The P5 family model (Pentium P54C, Pentium MMX P55C): parameters from
sim/cpus/p5/p5_machine.toml and the CPU/memory presets, instruction facts (pairing class,
clocks, x87 overlap) from sim/cpus/p5/p5.toml, the cycle loop in :mod:`sim.cpus.p5.core`.

The interface is every family's (:class:`sim.cpus.contract.FamilyModel`): ``run(trace, decoder,
segments, timeline, stat_first)`` returns a run whose ``segment(k)`` gives the counters of one call.
The counters are the P5's own (``core.C_NAMES``); the contract's names the reports read (cycles,
instructions, l1d_*, l2_*, dram_*, branches, mispredicts) mean the same here, and ``uops`` counts
instructions (the P5 has no micro-ops). Its words (pipes, pairing, its own stall counters) are its
view's (sim/cpus/p5/view.py).

Simplifications (each stated where it applies): pairing marks come from executing an instruction
once (``first_pass_source`` in the machine file), not from the prefetch buffers' byte counts; the
P55C's instruction FIFO is assumed full (prefix clocks 0 for 0F/66/67, as VTune's static analysis
assumes); FDIV/FIDIV take the clocks of the x87 precision control in force (the trace's control
word, sim/cpus/precision.py); the MMX-x87 transition cost is not modelled. A REP string instruction
is one trace entry per element: its row gives the start-up (charged on the first element), the
per-element and the ECX = 0 clocks (p5_core.simulate).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.guest.decode import Decoder, InsnRecord
from sim.errors import RetrosimError
from sim.memory.dram import DramTiming, bus_ratio, core_clocks
from sim.guest.trace import Trace
from sim.cpus.p5 import core
from sim.cpus.contract import CoreRun, FamilyModel
from sim.cpus.record import machine_table
from sim.cpus.locking import lock_cost, locked_match, whole_clocks
from sim.cpus.lowering import COMPUTE, DEC_SIMPLE, GPRS, PART_MASK, StaticProgram, lower
from sim.cpus.presets import CpuPreset, model_by_cpuid
from sim.cpus.session import CoreSession, grown_state

CLASSES = {"NP": core.NP, "UV": core.UV, "PU": core.PU, "PV": core.PV, "FX": core.FX, "FXCH": core.FXCH,
           "MMX": core.MMX}
MMX_UNITS = {"alu": core.MX_ALU, "shift": core.MX_SHIFT, "mul": core.MX_MUL}
STACK_OPS = {"push", "pop", "call", "ret", "pushal", "popal", "pushfd", "popfd", "leave"}
SEG_LOCK_REP = {0x26, 0x2E, 0x36, 0x3E, 0x64, 0x65, 0xF0, 0xF2, 0xF3}

def _machine_table() -> dict:
    return machine_table("p5")


def _locked_row(row, kind, throughput, extra, fields) -> None:
    """A locked row on the P5 (sim/cpus/locking.py): its clocks are the lock's (XCHG's alone, a LOCK
    prefix's at least the unlocked row's), and it does not pair (XCHG is NP; a LOCK prefix already
    keeps it out of the V pipe)."""
    cycles = whole_clocks(throughput)
    extra["cycles"] = cycles if kind == "xchg" else max(cycles, int(row.extra.get("cycles", 0)))
    extra["pairing"] = "NP"


def model_key(preset: CpuPreset) -> str:
    """'p54c' or 'p55c' from the preset's CPUID model (p5_machine.toml [models])."""
    return model_by_cpuid(preset, _machine_table()["models"], "P5", "p5_machine.toml")


def _gpr_mask(refs) -> int:
    """Byte masks of the GPRs in `refs`, 4 bits per register (eax bits 0-3, ecx 4-7, ...)."""
    m = 0
    for ref in refs:
        if ref.full in GPRS:
            m |= PART_MASK.get(ref.part, 15) << (4 * GPRS.index(ref.full))
    return m


@dataclass
class P5Static:
    """Per static instruction arrays for p5_core.simulate (see its argument list)."""

    arrays: tuple
    classes: list[str]


class P5Rules:
    """How a P5 model reads its table rows and the decoded encoding."""

    def __init__(self, key: str, machine: dict):
        self.key = key
        self.m = machine["models"][key]
        self.mmx = key == "p55c"

    def klass(self, rec: InsnRecord, row) -> int:
        c = CLASSES[row.extra["pairing"]]
        if row.extra.get("acc_only") and not any(r.full == "eax" for r in rec.regs_read):
            c = core.NP
        return c

    def prefix_bytes(self, rec: InsnRecord) -> tuple[int, int]:
        """(decode clocks before the instruction, V-pipe restriction 0 none / 1 model-dependent / 2 always)."""
        seg = sum(1 for p in rec.prefixes if p in SEG_LOCK_REP)
        other = len(rec.prefixes) - seg
        escape = int(rec.opcode[:1] == b"\x0f" and not (rec.is_conditional_branch and rec.is_relative_branch))
        if self.m["prefix_0f_is_prefix"]:
            other += escape
        if self.mmx:  # the FIFO holds 0F/66/67 instructions decoded; segment/lock/rep cost a clock
            clocks = seg * self.m.get("segment_prefix_clocks", 0)
        else:
            clocks = (seg + other) * self.m["prefix_decode_clocks"]
        v = 2 if seg else (1 if other else 0)
        return clocks, v

    def static(self, program: StaticProgram) -> P5Static:
        n = len(program.records)
        z = {k: np.zeros(n, np.int64) for k in (
            "cls", "cyc", "pfx", "pfxv", "immdisp", "addr", "stack", "esp_agi", "rmask", "wmask", "rflags", "wflags",
            "jcc", "fp", "fplat", "fpnext", "fmul", "waitfpu", "mmx", "mmx_u", "mmxlat", "rep", "repstart", "rep0",
            "memkind", "fstore")}
        classes = []
        for s, (rec, match) in enumerate(zip(program.records, program.matches)):
            row = match.row
            if rec.is_mmx and not self.mmx:
                raise RetrosimError(f"pc {rec.pc:#010x} ({rec.mnemonic} {rec.op_str}): MMX instruction on a "
                                    f"{self.m['name']} (no MMX): the CPU raises #UD")
            c = self.klass(rec, row)
            classes.append(next(k for k, v in CLASSES.items() if v == c))
            cycles = int(row.extra["cycles"])  # at the static's precision for FDIV (lower's precisions)
            z["cls"][s] = c
            if rec.is_x87 and rec.mnemonic != "fxch":
                iov = int(row.extra.get("i_ov", 0))
                fpov = int(row.extra.get("fp_ov", 0))
                z["fp"][s] = 1
                z["cyc"][s] = max(1, cycles - iov)
                z["fplat"][s] = cycles
                z["fpnext"][s] = max(1, cycles - fpov)
                z["fmul"][s] = int(bool(row.extra.get("fmul")))
                z["waitfpu"][s] = int(bool(row.extra.get("waits_fpu")))
            else:
                z["cyc"][s] = cycles
            if c == core.MMX:
                z["mmx"][s] = MMX_UNITS[row.extra.get("mmx_unit", "alu")]
                z["mmxlat"][s] = int(row.latency or 1)
                touches_gpr = any(r.full in GPRS for r in rec.regs_read + rec.regs_written)
                z["mmx_u"][s] = int(bool(rec.mem_operands) or touches_gpr)
            z["pfx"][s], z["pfxv"][s] = self.prefix_bytes(rec)
            z["immdisp"][s] = int(rec.imm_size > 0 and rec.disp_size > 0)
            z["memkind"][s] = memory_kind(rec, c)
            z["fstore"][s] = int(rec.mnemonic in ("fst", "fstp") and bool(rec.mem_operands))
            addr = 0
            for op in rec.mem_operands:
                for r in (op.mem.base, op.mem.index):
                    if r and r in GPRS:
                        addr |= 1 << GPRS.index(r)
            stack = rec.mnemonic in STACK_OPS
            if stack:
                addr |= 1 << 4
            z["addr"][s] = addr
            z["stack"][s] = int(stack)
            writes_esp = any(r.full == "esp" for r in rec.regs_written)
            z["esp_agi"][s] = int(writes_esp and (not stack or (rec.mnemonic == "ret" and rec.imm_size > 0)))
            z["rmask"][s] = _gpr_mask(rec.regs_read)
            z["wmask"][s] = _gpr_mask(rec.regs_written)
            z["rflags"][s] = int(bool(rec.flags_read))
            z["wflags"][s] = int(bool(rec.flags_written))
            z["jcc"][s] = int(rec.is_conditional_branch)
            if rec.rep:  # REP string: start-up on the first element, ECX = 0 figure (p5_core REP_*)
                z["rep"][s] = core.REP_MOVS if rec.mnemonic.startswith("movs") else core.REP_OTHER
                z["repstart"][s] = int(row.extra["rep_startup"])
                z["rep0"][s] = int(row.extra["rep_ecx0"])
        arrays = (program.s_len, z["cls"], z["cyc"], z["pfx"], z["pfxv"], z["immdisp"], z["addr"], z["stack"],
                  z["esp_agi"], z["rmask"], z["wmask"], z["rflags"], z["wflags"], z["jcc"], program.s_branch,
                  z["fp"], z["fplat"], z["fpnext"], z["fmul"], z["waitfpu"], z["mmx"], z["mmx_u"], z["mmxlat"],
                  z["rep"], z["repstart"], z["rep0"], program.s_nsrc, program.s_src, program.s_ndst, program.s_dst, program.s_fpdelta,
                  z["memkind"], z["fstore"])
        return P5Static(arrays, classes)


def memory_kind(rec: InsnRecord, klass: int) -> int:
    """AF97-PAIR sec. 10.4's kind of a pairable integer instruction: MK_RMW when it reads and writes a
    memory operand (ADD [mem],EAX), MK_READ_MODIFY when it reads one and computes (ADD EBX,[mem],
    CMP [mem],0), MK_PLAIN for MOV and register-only instructions (and anything not integer-pairable)."""
    if klass not in (core.UV, core.PU, core.PV):
        return core.MK_PLAIN
    access = {op.access for op in rec.operands if op.kind == "mem" and op.mem is not None and op.mem.size}
    if "rw" in access:
        return core.MK_RMW
    if "r" in access and rec.mnemonic != "mov":
        return core.MK_READ_MODIFY
    return core.MK_PLAIN


def _one_op(rec, match, load_latency):
    return [(COMPUTE, 0, 1, 0, 0)]


def p6_aliases(c: dict[str, int]) -> dict[str, int]:
    """The P6 counter names that scene reports and baselines read, in P5 terms: issue groups are
    the decode groups, the U and V pipes fill the port0/port1 columns (and decoder0/1), AGI and x87
    operand waits are dependency stalls, prefix and fetch clocks decode stalls, write-buffer waits
    store-buffer stalls; what the P5 does not have (ports 2-4, microcode, rename stalls) is 0."""
    zero = ("port2", "port3", "port4", "decoder2", "msrom_uops", "stall_rob", "stall_rs", "stall_partial_register",
            "stall_partial_flags", "stall_port", "stall_store_forward", "lcp_stalls", "store_forwards",
            "stall_register_read")
    a = {name: 0 for name in zero}
    a.update(decode_groups=c["pairs"] + c["alone"], port0=c["u_pipe"], port1=c["v_pipe"], decoder0=c["u_pipe"],
             decoder1=c["v_pipe"], stall_dependency=c["stall_agi"] + c["stall_fpu"],
             stall_decode=c["stall_prefix"], stall_store_buffer=c["stall_write_buffer"])
    return a


@dataclass
class P5CoreRun(CoreRun):
    """A P5 run: the contract's fields; counters named by p5_core.C_NAMES, then the contract's names
    the scene reports read (:func:`p6_aliases`)."""

    static: P5Static | None = None

    def segment(self, k: int = -1) -> dict[str, int]:
        c = dict(zip(core.C_NAMES, map(int, self.counters[k])))
        c.update(p6_aliases(c))
        return c


class P5Model(FamilyModel):
    """The P5 model: caches, DRAM and estimates as every family's (:class:`FamilyModel`); the
    board cache (L2) on the Socket 7 bus behind L1."""

    family = "p5"
    counter_names = core.C_NAMES

    def __init__(self, preset: CpuPreset, memory: DramTiming, estimates: dict | None = None):
        # `estimates`: make_model's overrides; the P5's estimates (p5_machine.toml [estimates]) are
        # not overridable yet, so this is always empty (sim/cpus/__init__.py overridable)
        super().__init__(preset, memory, estimates)
        self.key = model_key(preset)
        self.rules = P5Rules(self.key, self.machine)
        self.ratio = bus_ratio(preset.core_mhz, preset.fsb_mhz)
        self.lock = lock_cost(self.machine["lock"], "p5_machine.toml", self.key, self.ratio)
        self.params = self._params()

    def _params(self) -> np.ndarray:
        m, mm, bus = self.rules.m, self.machine, self.machine["bus"]
        P = np.zeros(core.NPARAMS, np.int64)
        P[core.P_AGI] = mm["pipeline"]["agi_penalty"]
        P[core.P_MISALIGNED] = mm["pipeline"]["misaligned_penalty"]
        P[core.P_FIRST_PASS] = int(bool(mm["pipeline"]["first_pass_pairs"]))
        P[core.P_BANK] = int(bool(m["bank_conflicts"]))
        P[core.P_NWB] = m["write_buffers"]
        P[core.P_WRITE_BUS] = core_clocks(bus["write_bus_clocks"], self.ratio)
        P[core.P_MISP_U] = m["mispredict_u"]
        P[core.P_MISP_V] = m["mispredict_v"]
        P[core.P_BTB_WAYS] = m["btb_ways"]
        P[core.P_BTB_SETS] = m["btb_entries"] // m["btb_ways"]
        P[core.P_HIST_BITS] = m["history_bits"]
        board = self.preset.raw.get("l2", {}).get("latency_bus_clocks", bus["board_cache_latency_bus_clocks"])
        l1 = int(self.preset.l1d.latency_cycles or 1)
        # the core charges a miss its time beyond the L1 hit: an L1 slower than the level below
        # would make that negative (fewer cycles for a miss than for a hit)
        below = min(core_clocks(board, self.ratio), self.dram.lead_off)
        if l1 > below:
            raise ValueError(f"l1d.latency_cycles = {l1} exceeds the {below} core clocks of a board-cache "
                             "or memory access at this bus ratio")
        P[core.P_L2_LAT] = core_clocks(board, self.ratio) - l1
        P[core.P_L2_BUSY] = core_clocks(self.estimates["board_cache_line_bus_clocks"], self.ratio)
        P[core.P_DRAM_LAT] = self.dram.lead_off - l1
        P[core.P_DRAM_LINE] = self.dram.line_busy
        P[core.P_DRAM_WB] = self.dram.writeback_busy
        P[core.P_DRAM_LAT_HIT] = self.dram.lead_off_hit - l1
        P[core.P_DRAM_LINE_HIT] = self.dram.line_busy_hit
        P[core.P_DRAM_WB_HIT] = self.dram.writeback_busy_hit
        P[core.P_TLB_WALK] = self.estimates["tlb_walk_clocks"]
        P[core.P_FMUL_SPACING] = mm["x87"]["fmul_spacing"]
        P[core.P_IMMDISP_MODE] = {"never": 0, "u-only": 1}[m["imm_disp_pairs"]]
        P[core.P_PFX_V] = int(bool(m["prefixed_pairs_in_v"]))
        P[core.P_PFX_SHADOW] = int(bool(m.get("prefix_shadow", False)))
        pipe = mm["pipeline"]
        P[core.P_SAME_DWORD] = pipe["same_dword_penalty"]
        table = pipe["pair_clocks"]
        if len(table) != 3 or any(len(row) != 3 for row in table):
            raise RetrosimError("p5_machine.toml [pipeline] pair_clocks: expected 3 rows of 3 clocks "
                                "(first instruction: MOV or register only, read/modify, read/modify/write)")
        for u, row in enumerate(table):
            for v, clocks in enumerate(row):
                P[core.P_PAIR_CLOCKS + 3 * u + v] = int(clocks)
        P[core.P_FST_EARLY] = mm["x87"]["store_operand_early"]
        return P

    def board_cache_hit_clocks(self) -> int:
        """A load that misses L1 and hits the board cache: clocks until its data."""
        return int(self.params[core.P_L2_LAT]) + int(self.preset.l1d.latency_cycles or 1)

    def lowering_key(self) -> tuple:
        # the lock's cost reads the machine table, the model key and the bus ratio
        return (id(self.table), id(self.machine), self.key, self.ratio)

    def lower(self, records: list[InsnRecord], precisions: list[int | None] | None = None) -> StaticProgram:
        return lower(records, self.table, 1, uops_for=_one_op, decoder_for=lambda rec, match, uops: DEC_SIMPLE,
                     precisions=precisions, adjust=self.locked)

    def locked(self, rec, match):
        """A locked instruction's clocks at this preset's bus ratio (sim/cpus/locking.py)."""
        return locked_match(rec, match, self.lock, _locked_row)

    def run(self, trace: Trace, decoder: Decoder, segments: list[int] | None = None,
            timeline: tuple[int, int] = (0, 0), stat_first: int = 0, access_logs=None) -> P5CoreRun:
        """Time `trace` from a cold machine (the arguments and result are those of P6Model.run;
        `access_logs` is accepted and not used: the P5 core walks its caches on every run)."""
        return P5Session.whole(self, trace, decoder, segments, timeline, stat_first)

    def session(self, decoder: Decoder, segments: list[int], stat_first: int = 0, check=None) -> P5Session:
        """A run fed in chunks (sim/timing/stream.py), as :meth:`sim.cpus.p6.model.P6Model.session`."""
        return P5Session(self, decoder, segments, (0, 0), stat_first, check)


class P5Session(CoreSession):
    """One P5 run fed in order, chunk by chunk (the core's state is kept between chunks).

    Pairing looks one instruction ahead, so a chunk's last instruction may need the next chunk's
    first (its V partner, or its static to decide). The core then leaves it untimed and it is
    held here; the next chunk times it first, in a call on just the two instructions (the held
    one and the new chunk's first, which goes with it into the V pipe, or is timed alone, or is
    held back in turn), then the rest of the chunk: the groups are those of the whole trace."""

    CORE = core
    KEEP_SLOTS = (core.V_FP_TOP, core.V_SEG, core.V_PREV_PC, core.V_LAST_ILINE)
    KEEP_ARRAYS = core.LEARNED  # executions per static, pairing answers, BTB, pattern tables, L1I lines known

    def __init__(self, model: P5Model, decoder: Decoder, segments: list[int], timeline: tuple[int, int] = (0, 0),
                 stat_first: int = 0, check=None):
        super().__init__(model, decoder, segments, timeline, stat_first, check)
        self.static = model.rules.static(self.program)
        self.held: tuple[Trace, int] | None = None  # an instruction waiting for its successor, and its static id

    def grown(self, program) -> None:
        self.static = self.model.rules.static(program)
        n = len(program.records)
        self.state = grown_state(grown_state(self.state, core.SEEN, n), core.PAIR_CACHE, n, fill=-1)

    def family_state(self) -> dict:
        return {"held": self.held}

    def drain(self) -> None:
        assert self.held is None, "drained between two instructions that may pair"
        super().drain()

    def _simulate(self, base, next_pc, first, index, chunk, rdtsc_sid, rdtsc_out) -> int:
        """Time `chunk` from its instruction `first` (run instruction `base`)."""
        model = self.model
        acc = int(np.searchsorted(chunk.mem_insn, first)) if first else 0  # its first access
        return core.simulate(base, next_pc, index[first:], chunk.pc[first:], first, acc, chunk.mem_insn,
                             chunk.mem_addr, chunk.mem_size, chunk.mem_write, self.seg_end, *self.static.arrays,
                             model.params, *model.dside.arrays(), self.dstats, *model.iside.arrays(), self.istats,
                             self.counters, self.per_static, self.stat_first, self.timeline, self.tl_first,
                             rdtsc_sid, rdtsc_out, *self.state)

    def time_chunk(self, chunk, index, next_pc, rdtsc_sid, rdtsc_out, access_logs) -> int:
        n = chunk.instructions
        sv = self.state[0]
        first = 0  # the chunk's first instruction not yet timed
        if self.held is not None and n:
            held, sid = self.held
            self.held = None
            two = Trace.concatenate([held, chunk.part(0, 1)])
            self._simulate(self.base - 1, int(chunk.pc[1]) if n > 1 else next_pc, 0,
                           np.array([sid, index[0]], index.dtype), two, rdtsc_sid, rdtsc_out)
            first = int(sv[core.V_STOPPED]) - 1  # 1: the chunk's first instruction was timed too
            rdtsc_out = rdtsc_out[int(sv[core.V_NRDTSC]):]
        # the rest from `first` (the core's loop index starts at 0: see p5_core.simulate)
        total = self._simulate(self.base + first, next_pc, first, index, chunk, rdtsc_sid, rdtsc_out)
        stopped = first + int(sv[core.V_STOPPED])
        if stopped < n:  # held back: only ever the last instruction, never an RDTSC (NP)
            self.held = (chunk.part(stopped, n), int(index[stopped]))
            assert stopped == n - 1 and not rdtsc_sid[index[stopped]]
        return total

    def result(self, program, counters, per_static, timeline, rdtsc, total) -> P5CoreRun:
        assert self.held is None, "the run's last chunk was fed with a next PC"
        static = self.static if program is self.program else self.model.rules.static(program)
        return P5CoreRun(program, counters, per_static, timeline, rdtsc, total, static=static)
