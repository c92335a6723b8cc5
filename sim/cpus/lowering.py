"""Lower decoded instructions to the flat uop arrays a compiled timing core reads.

Per static instruction (index s): length, decoder class, branch kind, x87 stack move, and up to
MAX_OPS register sources and destinations, each tied to the uop that reads or writes it. Per uop
(flat index u): kind (compute / load / store-address / store-data / branch), allowed ports as a
bit mask, latency, and an optional non-pipelined resource with its occupancy (the family's own
unit: P6 occupancies are in hundredths of a cycle, K6 ones in cycles; see each core).

Which uop touches which operand (the same rule for every family; the table gives only counts,
ports and the instruction's latency):
- the uops run in the order load(s), compute, store-address, store-data, whatever order the row
  lists its ports in (a load-op instruction computes on what it loaded);
- address registers (base, index) feed the load and store-address uops;
- other sources feed the first compute uop, or the store-data uop when there is none (MOV m,r);
- destinations and flags are written by the last compute uop, or by the load (MOV r,m);
- compute uops form a chain that the cores enforce: each waits for the instruction's earlier
  loads and compute uops, and the store data waits for them too. Each takes 1 cycle except the
  last, which takes what is left of the instruction's latency after the load (BSR r,r, 2 uops,
  latency 2, is 1 + 1; DIV r32, latency 39, is 1 + 1 + 1 + 36; ADD r,m is load 3 + 1; a row
  without a latency, ADD m,r, is 1 cycle per compute uop);
- compute uops the latency leaves no cycle for run beside the chain (kind SIDE, 1 cycle, waiting
  only for their own sources; never the branch): XCHG r,r (3 uops, latency 2) is a chain of 2
  plus one beside it; POP r32 (latency 3 = the load) loads the register while its
  stack-pointer adder, which writes ESP, runs beside the load.

Each family's uop rules are in its package (the P6's: sim/cpus/p6/lowering.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.guest.decode import InsnRecord
from sim.errors import RetrosimError
from sim.cpus.table import InstructionTable, Match

# FNSAVE reads the eight x87 registers, the control and status words and up to three address
# registers (13); FRSTOR writes ten; PUSHAD reads eight: 16 covers every instruction.
MAX_OPS = 16

# uop kinds (SIDE: a compute uop beside the instruction's chain, e.g. POP's stack-pointer adder)
COMPUTE, LOAD, STA, STD, BRANCH, SIDE = range(6)
KIND_NAMES = ("alu", "load", "sta", "std", "branch", "alu")
# branch kinds per static instruction
BR_NONE, BR_COND, BR_DIRECT, BR_INDIRECT, BR_CALL, BR_RET = range(6)
# decoder classes
DEC_SIMPLE, DEC_COMPLEX, DEC_MSROM = range(3)
DECODER_NAMES = {"simple": DEC_SIMPLE, "complex": DEC_COMPLEX, "msrom": DEC_MSROM,
                 "short": DEC_SIMPLE, "long": DEC_COMPLEX, "vector": DEC_MSROM}

# register ids: GPRs 0-7, flags 8, x87 stack slots 9-16 (physical, via TOP), fpsw 17, fpcw 18, mm 19-26,
# xmm 27-34, anything else 35, and the x87 order token 36: written by every x87 instruction where
# the control word is not renamed (the P6), ready when ALL its writers are done, not the newest
# (a core keeps the latest completion), so that a control-word writer waits for every older x87
# instruction even when a later one overwrote its stack slot (FFREE, FSTP ST(i), a reused slot)
GPRS = ("eax", "ecx", "edx", "ebx", "esp", "ebp", "esi", "edi")
REG_FLAGS, REG_ST0, REG_FPSW, REG_FPCW, REG_MM0, REG_XMM0, REG_OTHER, REG_X87_ORDER = 8, 9, 17, 18, 19, 27, 35, 36
NREGS = 37
PART_MASK = {"low8": 1, "high8": 2, "word": 3, "dword": 15, "full": 15}
FLAG_BITS = {"CF": 1, "PF": 2, "AF": 4, "ZF": 8, "SF": 16, "OF": 32, "DF": 64, "IF": 128, "TF": 256}

# P6 occupancies are counted in hundredths of a cycle (fractional measured throughputs)
OCC_SCALE = 100
# REP string instructions (s_rep columns, per static; see rep_timing): kind, clocks per element in
# the microcode loop and with fast strings (hundredths), fast-string start-up and loop start-up (clocks)
REP_NONE, REP_LOOP, REP_FAST = range(3)
R_KIND, R_ELEMENT, R_FAST, R_FAST_START, R_START = range(5)
NREP = 5



class LoweringError(RetrosimError):
    """An instruction does not fit the lowering's layout (e.g. too many register operands)."""


def port_mask(spec: str) -> int:
    """'p01' -> ports 0 and 1 -> 0b11; '' -> 0 (no port: e.g. FXCH, done at rename)."""
    spec = spec.strip().lower()
    if not spec:
        return 0
    if not spec.startswith("p"):
        raise ValueError(f"bad port spec {spec!r}")
    mask = 0
    for ch in spec[1:]:
        if ch.isdigit():
            mask |= 1 << int(ch)
    return mask


def reg_id(name: str, full: str) -> tuple[int, int]:
    """(register id, relative x87 index or -1) for a RegRef."""
    if full in GPRS:
        return GPRS.index(full), -1
    if full.startswith("st") and full[2:].isdigit():
        return REG_ST0, int(full[2:])
    if full.startswith("mm") and full[2:].isdigit():
        return REG_MM0 + int(full[2:]), -1
    if full.startswith("xmm") and full[3:].isdigit():
        return REG_XMM0 + int(full[3:]) % 8, -1
    return {"fpsw": (REG_FPSW, -1), "fpcw": (REG_FPCW, -1)}.get(full, (REG_OTHER, -1))


def flag_mask(flags) -> int:
    m = 0
    for f in flags:
        m |= FLAG_BITS.get(f, 0)
    return m


@dataclass
class StaticProgram:
    """Numpy arrays for the compiled core, plus the records and table rows for reports."""

    records: list[InsnRecord]
    matches: list[Match]
    s_len: np.ndarray
    s_pc: np.ndarray
    s_dec: np.ndarray
    s_lcp: np.ndarray
    s_branch: np.ndarray
    s_target: np.ndarray
    s_fpdelta: np.ndarray
    s_zero: np.ndarray
    s_nuops: np.ndarray
    s_uop0: np.ndarray
    s_nsrc: np.ndarray
    s_src: np.ndarray      # [n, MAX_OPS, 4]: reg id, mask, uop offset, x87 relative index (-1)
    s_ndst: np.ndarray
    s_dst: np.ndarray      # same layout; an x87 index is relative to TOP after the instruction
    u_kind: np.ndarray
    u_ports: np.ndarray
    u_lat: np.ndarray
    u_unit: np.ndarray
    u_occ: np.ndarray
    s_rep: np.ndarray      # [n, NREP]: REP string timing (rep_timing)

    def arrays(self):
        return (self.s_len, self.s_pc, self.s_dec, self.s_lcp, self.s_branch, self.s_target, self.s_fpdelta,
                self.s_zero, self.s_nuops, self.s_uop0, self.s_nsrc, self.s_src, self.s_ndst, self.s_dst,
                self.u_kind, self.u_ports, self.u_lat, self.u_unit, self.u_occ, self.s_rep)


def _branch_kind(rec: InsnRecord) -> int:
    if not rec.is_branch:
        return BR_NONE
    if rec.is_conditional_branch:
        return BR_COND
    if "ret" in rec.groups:
        return BR_RET
    if "call" in rec.groups:
        return BR_CALL
    return BR_DIRECT if rec.is_relative_branch else BR_INDIRECT


def rep_timing(rec: InsnRecord, match: Match, field=None) -> tuple[int, int, int, int, int]:
    """The s_rep row of a REP string instruction (zeros for anything else), from its table row.
    The trace holds one execution per element; the cores time the first through its uops and the
    later ones as the microcode loop's elements (no decode, no uops of their own; each element's
    accesses still go through the memory model), at `rep_element` clocks each (default: the row's
    throughput), after `rep_startup` clocks. A row with `fast_string_startup` moves whole lines
    when the P6's fast-string conditions hold (p6_core): its throughput is then the per-element
    figure and the start-up is `fast_string_startup`. `field(row, name)` reads a field with the
    family's overrides (K6 model_overrides)."""
    if not rec.rep:
        return (REP_NONE, 0, 0, 0, 0)
    row = match.row
    if field is None:
        def field(r, name):
            return getattr(r, name) if hasattr(r, name) else r.extra.get(name)
    throughput = float(field(row, "throughput") or 0)
    element = field(row, "rep_element")
    element = throughput if element is None else float(element)
    fast_start = field(row, "fast_string_startup")
    kind = REP_FAST if fast_start is not None else REP_LOOP
    return (kind, int(round(element * OCC_SCALE)), int(round(throughput * OCC_SCALE)),
            int(round(float(fast_start or 0))), int(round(float(field(row, "rep_startup") or 0))))


def after_pop(rel: int, delta: int) -> int:
    """A destination's x87 index relative to TOP after the instruction, as the cores map
    destinations. The decoder names a popping instruction's destination before the pop (FADDP
    ST(1),ST writes st1, which is ST(0) afterwards; FSTP ST(0) writes the slot the pop frees, ST(7)
    afterwards) and a pushing one's after the push (FLD writes st0)."""
    return (rel + delta) & 7 if delta < 0 else rel


# x87 instructions that neither round nor compute: the control word does not concern them
_NO_CONTROL_WORD = frozenset("fxch ffree ffreep fincstp fdecstp fnop fnclex fnstsw wait".split())


def fpcw_sources(rec: InsnRecord) -> list[tuple[int, int]]:
    """Extra (register id, x87 relative index) sources where the x87 control word is not renamed
    (the P6: Intel's optimization manual, "On the Pentium III processor, the FLDCW instruction is
    an expensive operation"; docs/sources/p6.md "x87 control word"). An instruction that writes
    the control word (FLDCW, FLDENV, FRSTOR, FNINIT) waits for every older x87 instruction (the
    order token every x87 instruction writes, REG_X87_ORDER); every x87 instruction that reads
    the control word (its rounding and precision) waits for the newest write of it."""
    written = {r.full for r in rec.regs_written}
    read = {r.full for r in rec.regs_read}
    if "fpcw" in written:
        return [(REG_X87_ORDER, -1)]
    if "fpcw" in read:
        return []  # FNSTCW/FNSTENV/FNSAVE already read it
    if rec.mnemonic in _NO_CONTROL_WORD:
        return []
    if "fpsw" in written or any(n.startswith("st") and n[2:].isdigit() for n in written | read):
        return [(REG_FPCW, -1)]
    return []


def lower(records: list[InsnRecord], table: InstructionTable, load_latency: int = 3,
          simple_max_len: int = 7, *, uops_for, decoder_for=None,
          precisions: list[int | None] | None = None, adjust=None, fpcw_serializes: bool = False,
          rep_for=None) -> StaticProgram:
    """The static program of `records`; `precisions` gives each static's x87 precision index where
    its row depends on it (sim/cpus/precision.py), else the row's 64-bit figures are used.
    Each family passes its own rules (in its package: sim/cpus/p6/lowering.py, the K6's and the
    P5's models): `uops_for(rec, match, load_latency)` -> [(kind, ports, latency, unit, occupancy)]
    and, where the row's decoder class is not the family's, `decoder_for(rec, match, uops)` ->
    DEC_* (default: the row's decoder field, microcode above 4 uops, complex above one uop or
    `simple_max_len` bytes). `adjust(rec, match)` -> match lets the
    family replace a row's timing for this instruction (a locked access: sim/cpus/locking.py).
    `fpcw_serializes`: the x87 control word is not renamed (the P6, :func:`fpcw_sources`).
    `rep_for(rec, match)` -> the s_rep row (default :func:`rep_timing` on the row's own fields)."""
    n = len(records)
    s = {k: np.zeros(n, np.int64) for k in ("len", "pc", "dec", "lcp", "branch", "target", "fpdelta", "zero",
                                           "nuops", "uop0", "nsrc", "ndst")}
    s_src = np.zeros((n, MAX_OPS, 4), np.int64)
    s_dst = np.zeros((n, MAX_OPS, 4), np.int64)
    s_rep = np.zeros((n, NREP), np.int64)
    uops: list[tuple[int, int, int, int, int]] = []
    matches = []
    for i, rec in enumerate(records):
        # issue 8: a REP-prefixed string instruction has its own row ("rep movsd"), its per-element
        # cost; the trace holds one execution per element, so the total follows ECX.
        mnemonic = f"{rec.rep} {rec.mnemonic}" if rec.rep else rec.mnemonic
        match = table.require(mnemonic, rec.signature, f"pc {rec.pc:#010x} ({rec.mnemonic} {rec.op_str})")
        if precisions is not None and precisions[i] is not None:
            match = match.at_precision(precisions[i])
        if adjust is not None:
            match = adjust(rec, match)
        matches.append(match)
        s_rep[i] = (rep_for or rep_timing)(rec, match)
        us = uops_for(rec, match, load_latency)
        s["uop0"][i], s["nuops"][i] = len(uops), len(us)
        uops.extend(us)
        dec = DECODER_NAMES.get(match.row.decoder, DEC_COMPLEX)
        if len(us) > 4:
            dec = DEC_MSROM
        elif len(us) > 1 and dec == DEC_SIMPLE:
            dec = DEC_COMPLEX
        elif dec == DEC_SIMPLE and rec.length > simple_max_len:
            dec = DEC_COMPLEX  # the simple decoders take instructions of at most 7 bytes
        if decoder_for is not None:
            dec = decoder_for(rec, match, us)
        s["dec"][i] = dec
        s["len"][i], s["pc"][i] = rec.length, rec.pc
        s["lcp"][i] = int(rec.opsize_prefix and rec.imm_size == 2) or int(rec.addrsize_prefix and rec.disp_size == 2)
        s["branch"][i] = _branch_kind(rec)
        s["target"][i] = rec.branch_target if rec.branch_target is not None else -1
        s["fpdelta"][i] = rec.fpu_stack_delta
        s["zero"][i] = int(rec.is_zero_idiom)

        kinds = [u[0] for u in us]
        compute = [j for j, k in enumerate(kinds) if k in (COMPUTE, BRANCH)]
        sides = [j for j, k in enumerate(kinds) if k == SIDE]
        loads = [j for j, k in enumerate(kinds) if k == LOAD]
        stas = [j for j, k in enumerate(kinds) if k == STA]
        stds = [j for j, k in enumerate(kinds) if k == STD]
        first_compute = compute[0] if compute else (stds[0] if stds else (loads[0] if loads else 0))
        writer = compute[-1] if compute else (loads[-1] if loads else 0)
        address_regs = set()
        for op in rec.mem_operands:
            address_regs.update(r for r in (op.mem.base, op.mem.index) if r)
        srcs = []
        for ref in rec.regs_read:
            rid, rel = reg_id(ref.name, ref.full)
            mask = PART_MASK.get(ref.part, 15)
            if ref.name in address_regs or ref.full in address_regs:
                for j in (loads[:1] + stas[:1]) or [first_compute]:
                    srcs.append((rid, mask, j, rel))
            else:
                srcs.append((rid, mask, first_compute, rel))
        if rec.flags_read:
            srcs.append((REG_FLAGS, flag_mask(rec.flags_read), first_compute, -1))
        if fpcw_serializes:
            srcs.extend((rid, 15, first_compute, rel) for rid, rel in fpcw_sources(rec))
        dsts = []
        for ref in rec.regs_written:
            rid, rel = reg_id(ref.name, ref.full)
            if rel >= 0:
                rel = after_pop(rel, rec.fpu_stack_delta)
            w = sides[0] if (sides and ref.full == "esp") else writer  # the stack-pointer adder
            dsts.append((rid, PART_MASK.get(ref.part, 15), w, rel))
        if rec.flags_written:
            dsts.append((REG_FLAGS, flag_mask(rec.flags_written), writer, -1))
        if fpcw_serializes and rec.is_x87:  # done when its last uop is (fpcw_sources)
            dsts.append((REG_X87_ORDER, 15, len(us) - 1, -1))
        if len(srcs) > MAX_OPS or len(dsts) > MAX_OPS:
            raise LoweringError(f"pc {rec.pc:#010x} ({rec.mnemonic} {rec.op_str}): {len(srcs)} register sources "
                                f"and {len(dsts)} destinations, more than the {MAX_OPS} the timing cores track")
        s["nsrc"][i], s["ndst"][i] = len(srcs), len(dsts)
        for j, v in enumerate(srcs):
            s_src[i, j] = v
        for j, v in enumerate(dsts):
            s_dst[i, j] = v
    u = np.array(uops, dtype=np.int64).reshape(-1, 5)
    return StaticProgram(records, matches, s["len"], s["pc"], s["dec"], s["lcp"], s["branch"], s["target"],
                         s["fpdelta"], s["zero"], s["nuops"], s["uop0"], s["nsrc"], s_src, s["ndst"], s_dst,
                         u[:, 0].copy(), u[:, 1].copy(), u[:, 2].copy(), u[:, 3].copy(), u[:, 4].copy(), s_rep)
