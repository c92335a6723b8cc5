"""Lower decoded instructions to the flat uop arrays a compiled timing core reads.

Per static instruction (index s): length, decoder class, branch kind, x87 stack move, and up to
MAX_OPS register sources and destinations, each tied to the uop that reads or writes it. Per uop
(flat index u): kind (compute / load / store-address / store-data / branch), allowed ports as a
bit mask, latency, and an optional non-pipelined unit with its occupancy.

Which uop touches which operand (the same rule for every family; the table gives only counts,
ports and the instruction's latency):
- address registers (base, index) feed the load and store-address uops;
- other sources feed the first compute uop, or the store-data uop when there is none (MOV m,r);
- destinations and flags are written by the last compute uop, or by the load (MOV r,m);
- compute uops form a chain: each takes 1 cycle except the last, which takes what is left of the
  instruction's latency after the load (so BSR r,r, 2 uops, latency 2, is 1 + 1; DIV r32,
  latency 39, is 1 + 1 + 1 + 36).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..decode import InsnRecord
from .table import InstructionTable, Match

MAX_OPS = 8

# uop kinds
COMPUTE, LOAD, STA, STD, BRANCH = range(5)
KIND_NAMES = ("alu", "load", "sta", "std", "branch")
# branch kinds per static instruction
BR_NONE, BR_COND, BR_DIRECT, BR_INDIRECT, BR_CALL, BR_RET = range(6)
# decoder classes
DEC_SIMPLE, DEC_COMPLEX, DEC_MSROM = range(3)
DECODER_NAMES = {"simple": DEC_SIMPLE, "complex": DEC_COMPLEX, "msrom": DEC_MSROM,
                 "short": DEC_SIMPLE, "long": DEC_COMPLEX, "vector": DEC_MSROM}

# register ids: GPRs 0-7, flags 8, x87 stack slots 9-16 (physical, via TOP), fpsw 17, fpcw 18, mm 19-26,
# xmm 27-34, anything else 35
GPRS = ("eax", "ecx", "edx", "ebx", "esp", "ebp", "esi", "edi")
REG_FLAGS, REG_ST0, REG_FPSW, REG_FPCW, REG_MM0, REG_XMM0, REG_OTHER = 8, 9, 17, 18, 19, 27, 35
NREGS = 36
PART_MASK = {"low8": 1, "high8": 2, "word": 3, "dword": 15, "full": 15}
FLAG_BITS = {"CF": 1, "PF": 2, "AF": 4, "ZF": 8, "SF": 16, "OF": 32, "DF": 64, "IF": 128, "TF": 256}

# units that are not pipelined (or issue at a reduced rate); the occupancy comes from the row's
# reciprocal throughput
UNIT_NONE, UNIT_DIV, UNIT_FMUL = 0, 1, 2
NUNITS = 3
_DIV = {"div", "idiv", "fdiv", "fdivp", "fdivr", "fdivrp", "fidiv", "fidivr", "fsqrt"}
_FMUL = {"fmul", "fmulp", "fimul"}


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
    s_dst: np.ndarray      # same layout
    u_kind: np.ndarray
    u_ports: np.ndarray
    u_lat: np.ndarray
    u_unit: np.ndarray
    u_occ: np.ndarray

    def arrays(self):
        return (self.s_len, self.s_pc, self.s_dec, self.s_lcp, self.s_branch, self.s_target, self.s_fpdelta,
                self.s_zero, self.s_nuops, self.s_uop0, self.s_nsrc, self.s_src, self.s_ndst, self.s_dst,
                self.u_kind, self.u_ports, self.u_lat, self.u_unit, self.u_occ)


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


def _uops_for(rec: InsnRecord, match: Match, load_latency: int) -> list[tuple[int, int, int, int, int]]:
    """[(kind, port mask, latency, unit, occupancy)] for one instruction."""
    row = match.row
    ports = list(row.ports) + ["p01"] * max(0, row.uops - len(row.ports))  # rows list one port per uop
    kinds = []
    for p in ports[:row.uops]:
        p = p.strip().lower()
        kinds.append(LOAD if p == "p2" else STA if p == "p3" else STD if p == "p4" else COMPUTE)
    if rec.is_branch:
        # the uop on port 1 (the jump unit) resolves the branch; otherwise the last compute uop
        idx = [i for i, p in enumerate(ports[:row.uops]) if port_mask(p) == 2 and kinds[i] == COMPUTE]
        idx = idx or [i for i, k in enumerate(kinds) if k == COMPUTE]
        if idx:
            kinds[idx[0]] = BRANCH
    has_load = LOAD in kinds
    compute = [i for i, k in enumerate(kinds) if k in (COMPUTE, BRANCH)]
    total = row.latency if row.latency is not None else 1
    work = max(1, int(round(total - (load_latency if has_load else 0))))
    unit = UNIT_DIV if rec.mnemonic in _DIV else UNIT_FMUL if rec.mnemonic in _FMUL else UNIT_NONE
    occ = int(round(row.throughput)) if (unit and row.throughput) else 0
    out = []
    for i, k in enumerate(kinds):
        if k in (COMPUTE, BRANCH):
            last = i == compute[-1]
            lat = max(1, work - (len(compute) - 1)) if last else 1
        elif k == LOAD:
            lat = load_latency
        else:
            lat = 1
        mask = port_mask(ports[i])
        first_compute = compute and i == compute[0]
        out.append((k, mask, lat, unit if first_compute else UNIT_NONE, occ if first_compute else 0))
    return out


def lower(records: list[InsnRecord], table: InstructionTable, load_latency: int = 3,
          simple_max_len: int = 7, uops_for=None, decoder_for=None) -> StaticProgram:
    """The static program of `records`. A family other than the P6 passes its own rules:
    `uops_for(rec, match, load_latency)` -> [(kind, ports, latency, unit, occupancy)] and
    `decoder_for(rec, match, uops)` -> DEC_* (the K6 model does; see sim/cpus/k6.py)."""
    n = len(records)
    s = {k: np.zeros(n, np.int64) for k in ("len", "pc", "dec", "lcp", "branch", "target", "fpdelta", "zero",
                                           "nuops", "uop0", "nsrc", "ndst")}
    s_src = np.zeros((n, MAX_OPS, 4), np.int64)
    s_dst = np.zeros((n, MAX_OPS, 4), np.int64)
    uops: list[tuple[int, int, int, int, int]] = []
    matches = []
    for i, rec in enumerate(records):
        # issue 8: a REP-prefixed string instruction has its own row ("rep movsd"), its per-element
        # cost; the trace holds one execution per element, so the total follows ECX.
        mnemonic = f"{rec.rep} {rec.mnemonic}" if rec.rep else rec.mnemonic
        match = table.require(mnemonic, rec.signature, f"pc {rec.pc:#010x} ({rec.mnemonic} {rec.op_str})")
        matches.append(match)
        us = (uops_for or _uops_for)(rec, match, load_latency)
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
        dsts = []
        for ref in rec.regs_written:
            rid, rel = reg_id(ref.name, ref.full)
            dsts.append((rid, PART_MASK.get(ref.part, 15), writer, rel))
        if rec.flags_written:
            dsts.append((REG_FLAGS, flag_mask(rec.flags_written), writer, -1))
        if len(srcs) > MAX_OPS or len(dsts) > MAX_OPS:
            srcs, dsts = srcs[:MAX_OPS], dsts[:MAX_OPS]  # only string/system instructions get here
        s["nsrc"][i], s["ndst"][i] = len(srcs), len(dsts)
        for j, v in enumerate(srcs):
            s_src[i, j] = v
        for j, v in enumerate(dsts):
            s_dst[i, j] = v
    u = np.array(uops, dtype=np.int64).reshape(-1, 5)
    return StaticProgram(records, matches, s["len"], s["pc"], s["dec"], s["lcp"], s["branch"], s["target"],
                         s["fpdelta"], s["zero"], s["nuops"], s["uop0"], s["nsrc"], s_src, s["ndst"], s_dst,
                         u[:, 0].copy(), u[:, 1].copy(), u[:, 2].copy(), u[:, 3].copy(), u[:, 4].copy())
