"""The compiled P5 cycle model (Pentium P54C, Pentium MMX P55C): one pass over the dynamic
instruction stream, in program order, one issue group (one instruction, or a U/V pair) at a time.

The P5 is in order: a group enters the execute stage when the group before it has left it, and
the whole pipe waits for anything that delays one of its instructions (a cache miss, an AGI, a
busy x87 unit). So a group's start is the previous group's end plus the stalls that apply to it,
and those stalls are the counters. Per group:
- pairing: the instruction at i takes i + 1 into the V pipe when both classes allow it (U: UV or
  PU; V: UV or PV; FXCH after an FX-class x87 instruction; MMX pairs on the P55C with one
  multiplier and one shifter), i + 1 neither reads (RAW) nor writes (WAW) a register byte i
  writes (flags excepted for a Jcc in V, ESP between two stack instructions), neither breaks the
  prefix or displacement-plus-immediate limits of the model, and i has executed before or is one
  byte long (pairing marks come from the code cache). The first failed rule is the reason the
  instruction ran alone, with the register when it is a dependency;
- decode: prefix clocks of the model before the group;
- AGI: an address register written by the group in the preceding clock delays the group one clock
  (ESP changed by PUSH/POP/CALL is predicted: no AGI);
- x87: an x87 instruction starts when the x87 unit accepts a new instruction (after the previous
  one's non-overlapped clocks, FMUL spacing) and its stack operands are ready; it holds the integer
  pipe only for its non-overlapped clocks (FDIV runs beside integer code); FNSTSW/FLDCW wait for
  the x87 to finish;
- x87 stores: FST(P) m needs its operand FST_EARLY clocks before its execute stage (AF97-FP);
- group duration: the longer instruction's clocks (ALU reg,mem 2, ALU mem,reg 3, MUL 10, ...), or
  more for a read/modify/write in U with a read/modify(/write) in V: PAIR_CLOCKS by the two
  instructions' memory kinds (AF97-PAIR sec. 10.4: ADD [m],EAX / ADD [m2],EBX takes 5);
- memory (data side of sim.memory): a load miss stalls the pipe for the board cache or DRAM
  latency, with the bus busy for the line; a data-TLB miss (load or store) stalls it for the page
  walk first (TLB_WALK clocks, then each walk read that missed L1 as a load: _page_walk); a
  misaligned access costs MISALIGNED; a U/V pair whose accesses touch one dword costs SAME_DWORD
  (both models, reads and writes, AF97-PAIR sec. 10.2),
  one whose accesses hit the same 4-byte bank of different dwords one clock (P54C); both are counted
  as stall_bank (Agner's rule 10.3 extends 10.2 to the bank); a write that misses
  L1 (no allocation) takes a write buffer, which drains to the bus in WRITE_BUS clocks; the pipe
  stalls only when every buffer is busy;
- REP strings (not pairable): one trace entry per element; the first element takes the row's
  start-up clocks besides its per-element clocks, and alone the prefix decode and any AGI (the later
  elements repeat inside the instruction: no decode, their ESI/EDI updates raise no AGI); an entry
  with no memory access is the ECX = 0 case when it comes first (the row's ECX = 0 clocks) and the
  closing count check otherwise (no clocks), so n elements cost start-up + n x per-element; every
  element's accesses go through the memory model like any other; on the P54C a REP MOVS element
  whose read hits the bank of the previous element's write (another dword) costs one clock;
- branches: a BTB of BTB_SETS x BTB_WAYS entries with 2-bit counters indexed by HIST_BITS of local
  history (0 on the P54C); a mispredicted or BTB-missing taken branch costs MISP_U or MISP_V
  clocks by the pipe it ran in.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from sim.memory.hierarchy import (
    CFG_TLB_WAYS, memory_fill_page_hits, memory_fills, memory_writebacks, served_level, service, tlb_missed,
    walk_pde_level, walk_pte_level, walk_read_result,
)
from sim.cpus.lowering import BR_COND, BR_NONE, BR_RET, REG_ST0
from sim.cpus.shared_core import (
    IDX, add_l1_hits, dram_busy, dram_lead_off, l1_geometry, l1_hit, l1_way, tlb_hit, uncounted,
)
from sim.cpus.shared_core import btb_alloc  # shared BTB victim choice (LRU by last use)

# parameter vector indices
(P_PFX_0F, P_AGI, P_MISALIGNED, P_BANK, P_NWB, P_WRITE_BUS, P_MISP_U, P_MISP_V, P_BTB_SETS, P_BTB_WAYS,
 P_HIST_BITS, P_L2_LAT, P_L2_BUSY, P_DRAM_LAT, P_DRAM_LINE, P_DRAM_WB, P_FMUL_SPACING, P_FIRST_PASS,
 P_IMMDISP_MODE, P_PFX_V, P_SAME_DWORD, P_FST_EARLY) = range(22)
P_PAIR_CLOCKS = 22   # 3 x 3 clocks of a pair by the memory kinds of its U and V instructions (MK_*)
P_PFX_SHADOW = 31    # 1: a multi-clock instruction hides later prefix decode clocks (P54C, AF97 sec. 13)
P_DRAM_LAT_HIT, P_DRAM_LINE_HIT, P_DRAM_WB_HIT = 32, 33, 34  # the DRAM costs on an open page
P_TLB_WALK = 35      # a data-TLB miss's page walk: clocks besides its two reads' misses (p5_machine.toml [tlb])
NPARAMS = 36
# memory kinds of a pairable integer instruction (AF97-PAIR sec. 10.4's table)
MK_PLAIN, MK_READ_MODIFY, MK_RMW = range(3)

# pairing classes
NP, UV, PU, PV, FX, FXCH, MMX = range(7)
CLASS_NAMES = ("NP", "UV", "PU", "PV", "FX", "FXCH", "MMX")
# MMX units
MX_NONE, MX_ALU, MX_SHIFT, MX_MUL = range(4)
# REP string kinds (REP MOVS reads the next element while it writes this one: bank conflicts)
REP_NONE, REP_OTHER, REP_MOVS = range(3)

# why an instruction ran alone (it could not take the next one into the V pipe)
REASONS = ("paired", "not pairable (NP)", "V-pipe-only class in U", "next not pairable in V (class)",
           "next reads a register this writes (RAW)", "both write a register (WAW)",
           "next reads flags this writes", "displacement + immediate", "prefix", "first execution (not yet in code cache)",
           "x87 without FXCH", "MMX unit conflict", "MMX memory/integer access only in U", "branch / end of stream")
R_PAIRED, R_NP, R_PV_IN_U, R_NEXT_CLASS, R_RAW, R_WAW, R_FLAGS, R_IMMDISP, R_PREFIX, R_FIRST, R_FP, R_MMX_UNIT, \
    R_MMX_U, R_BRANCH = range(14)
NR = len(REASONS)

C_NAMES = ("cycles", "instructions", "uops", "pairs", "u_pipe", "v_pipe", "alone", "stall_agi", "stall_prefix",
           "stall_fpu", "stall_memory", "stall_misaligned", "stall_bank", "stall_write_buffer", "stall_fetch",
           "stall_mispredict", "branches", "mispredicts", "l1d_loads", "l1d_load_misses",
           "l1d_stores", "l1d_store_misses", "l2_accesses", "l2_misses", "dram_fills", "dram_writebacks",
           "dram_bus_cycles", "l1i_misses", "bus_writes") + tuple("alone_" + str(k) for k in range(NR)) + (
           "dram_page_hits", "dram_page_misses", "dtlb_misses")
NC = len(C_NAMES)
(C_CYCLES, C_INSTRUCTIONS, C_UOPS, C_PAIRS, C_U, C_V, C_ALONE, C_AGI, C_PREFIX, C_FPU, C_MEMORY, C_MISALIGNED,
 C_BANK, C_WB, C_FETCH, C_MISPREDICT, C_BRANCHES, C_MISPREDICTS, C_L1D_LOADS, C_L1D_LOAD_MISSES,
 C_L1D_STORES, C_L1D_STORE_MISSES, C_L2_ACCESSES, C_L2_MISSES, C_DRAM_FILLS, C_DRAM_WRITEBACKS, C_DRAM_BUS,
 C_L1I_MISSES, C_BUS_WRITES) = range(29)
C_REASON0 = 29
C_DRAM_PAGE_HITS = C_REASON0 + NR
C_DRAM_PAGE_MISSES = C_DRAM_PAGE_HITS + 1
C_DTLB_MISSES = C_DRAM_PAGE_MISSES + 1

S_NAMES = ("executions", "u_pipe", "v_pipe", "paired_u", "group_cycles", "stall_agi", "stall_prefix", "stall_fpu",
           "stall_memory", "stall_misaligned", "stall_bank", "stall_write_buffer", "stall_mispredict", "mispredicts",
           "l1d_misses", "reason_reg") + tuple("alone_" + str(k) for k in range(NR))
NS = len(S_NAMES)
(S_EXEC, S_U, S_V, S_PAIRED_U, S_CYCLES, S_AGI, S_PREFIX, S_FPU, S_MEMORY, S_MISALIGNED, S_BANK, S_WB,
 S_MISPREDICT, S_MISPREDICTS, S_L1D_MISSES, S_REASON_REG) = range(16)
S_REASON0 = 16

# timeline columns: the P6 layout (views read it), with issue as decode/alloc/dispatch
T_NAMES = ("insn", "static", "decode", "alloc", "dispatch", "complete", "retire", "cause")
NT = len(T_NAMES)


@uncounted
def _pair_reason(a, b, s_cls, s_len, s_rmask, s_wmask, s_rflags, s_wflags, s_jcc, s_stack, s_immdisp, s_pfxv,
                 s_mmx, s_mmx_u, immdisp_mode, pfx_v, first_pass_ok):
    """(reason code, register) why static a cannot take static b into the V pipe; R_PAIRED if it can."""
    ca = s_cls[a]
    cb = s_cls[b]
    if ca == NP:
        return R_NP, -1
    if ca == PV:
        return R_PV_IN_U, -1
    if ca == FXCH:
        return R_NEXT_CLASS, -1
    if ca == FX:
        return (R_PAIRED, -1) if cb == FXCH else (R_FP, -1)
    if cb == FXCH or cb == FX or cb == NP or cb == PU:
        return R_NEXT_CLASS, -1
    if ca == MMX and cb == MMX:
        if s_mmx[a] == s_mmx[b] and s_mmx[a] != 1:
            return R_MMX_UNIT, -1
    if s_mmx_u[b] == 1:
        return R_MMX_U, -1
    if (ca == MMX) != (cb == MMX) and (s_mmx_u[a] == 1):
        return R_MMX_U, -1
    if first_pass_ok == 0 and s_len[a] > 1:
        return R_FIRST, -1
    if immdisp_mode == 0 and (s_immdisp[a] == 1 or s_immdisp[b] == 1):
        return R_IMMDISP, -1
    if immdisp_mode == 1 and s_immdisp[b] == 1:
        return R_IMMDISP, -1
    if s_pfxv[b] == 1 and pfx_v == 0:
        return R_PREFIX, -1
    if s_pfxv[b] == 2:  # segment / lock / repeat prefixes: U pipe only on both models
        return R_PREFIX, -1
    stack_pair = s_stack[a] == 1 and s_stack[b] == 1
    for r in range(8):
        if r == 4 and stack_pair:
            continue
        wa = (s_wmask[a] >> (4 * r)) & 15
        if wa == 0:
            continue
        if (s_rmask[b] >> (4 * r)) & wa:
            return R_RAW, r
        if (s_wmask[b] >> (4 * r)) & wa:
            return R_WAW, r
    if s_wflags[a] != 0 and s_rflags[b] != 0 and s_jcc[b] == 0:
        return R_FLAGS, 8
    return R_PAIRED, -1


@njit(cache=True, nogil=True, inline="always")
def _load_miss(r, lvl, now, P, bus_free, ctr):
    """Extra clocks for a load that missed L1 (served at level lvl), and the new bus_free."""
    b = max(now, bus_free)
    ctr[C_L2_ACCESSES] += 1
    if lvl == 1:
        done = b + P[P_L2_LAT]
        bus_free = b + P[P_L2_BUSY]
    else:
        ctr[C_L2_MISSES] += 1
        fills = memory_fills(r)
        busy = dram_busy(r, P[P_DRAM_LINE], P[P_DRAM_LINE_HIT], P[P_DRAM_WB], P[P_DRAM_WB_HIT])
        ctr[C_DRAM_FILLS] += fills
        ctr[C_DRAM_WRITEBACKS] += memory_writebacks(r)
        ctr[C_DRAM_BUS] += busy
        ctr[C_DRAM_PAGE_HITS] += memory_fill_page_hits(r)
        ctr[C_DRAM_PAGE_MISSES] += fills - memory_fill_page_hits(r)
        done = b + dram_lead_off(r, P[P_DRAM_LAT], P[P_DRAM_LAT_HIT])
        bus_free = b + busy
    return done - now, bus_free


@njit(cache=True, nogil=True, inline="always")
def _page_walk(r, levels, now, P, bus_free, ctr):
    """Extra clocks of a data-TLB miss's page walk (before the access itself), and the new bus_free:
    the walk's fixed clocks, then its page-directory and page-table reads, each charged as a load
    served at its level (_load_miss: the board cache, or a DRAM fill on a closed page)."""
    ctr[C_DTLB_MISSES] += 1
    t = now + P[P_TLB_WALK]
    for lvl in (walk_pde_level(r), walk_pte_level(r)):
        if lvl > 0:
            extra, bus_free = _load_miss(walk_read_result(lvl, levels), lvl, t, P, bus_free, ctr)
            t += extra
    return t - now, bus_free


# Loop-carried scalar state: kept in an int64 vector between calls, so a trace can be timed in
# chunks (a streamed emulation) exactly as in one call (see :func:`new_state`).
(V_ESP_AGI, V_FP_TOP, V_FP_FREE, V_FMUL_FREE, V_FP_DONE, V_WB_POS, V_BUS_FREE, V_REP_PREV_STORE, V_LAST_ILINE,
 V_T, V_SEG, V_SEG_START, V_PREV_PC, V_STOPPED, V_NRDTSC, V_SHADOW, V_SHADOW_GROUPS) = range(17)
NSTATE = 17


def new_state(P: np.ndarray, nstatic: int) -> tuple:
    """The machine at reset, for :func:`simulate`: the scalar vector, then the arrays in the order
    simulate takes them. `nstatic`: static instructions so far; sim.cpus.session.grown_state makes room
    for more between calls."""
    sv = np.zeros(NSTATE, np.int64)
    sv[V_REP_PREV_STORE] = -1   # the previous REP MOVS element's store address
    sv[V_LAST_ILINE] = -1
    sv[V_PREV_PC] = -1          # the PC of the instruction before the chunk (-1: none)
    btb_sets, btb_ways, hist_bits = int(P[P_BTB_SETS]), int(P[P_BTB_WAYS]), int(P[P_HIST_BITS])
    return (sv,
            np.zeros(8, np.int64),                      # reg_avail: cycle a GPR's value reaches the execute stage
            np.zeros(40, np.int64),                     # ext_ready: x87 slots (physical) and MMX registers
            np.zeros(max(1, int(P[P_NWB])), np.int64),  # wb_free: write buffers
            np.zeros(nstatic, np.int64),                # seen: executions so far, per static
            # pairing depends only on the two statics (and whether the first has run before): the
            # static after a non-branch is always the same one, so each answer is computed once
            np.full((nstatic, 2), -1, np.int64),        # pair_cache: [a, first_ok] -> reason * 16 + register + 1
            np.full((btb_sets, btb_ways), -1, np.int64),  # btb_tag
            np.zeros((btb_sets, btb_ways), np.int64),     # btb_stamp
            np.zeros((btb_sets, btb_ways), np.int64),     # btb_hist
            np.zeros((btb_sets, btb_ways), np.int64),     # btb_target
            np.full((btb_sets, btb_ways, 1 << hist_bits), 2, np.int64),  # pht
            np.full(16, -1, np.int64))                  # iline_seen: lines fetched since the last L1I miss


SEEN, PAIR_CACHE = 4, 5  # positions in new_state's tuple of the arrays with a row per static
LEARNED = tuple(range(4, 12))  # seen, pair_cache, btb_tag, btb_stamp, btb_hist, btb_target, pht, iline_seen


(F_LEN, F_CLS, F_CYC, F_PFX, F_ADDR, F_ESP_AGI, F_WMASK, F_BRANCH, F_FP, F_FPLAT, F_FPNEXT, F_FMUL, F_WAITFPU,
 F_MMX, F_MMXLAT, F_REP, F_REPSTART, F_REP0, F_NSRC, F_NDST, F_FPDELTA, F_MEMKIND, F_FSTORE) = range(23)
NF = 23  # the columns of simulate's per-static rows (sf)


@njit(cache=True, nogil=True)
def simulate(base, next_pc, dyn_sid, dyn_pc, first, acc, mem_insn, mem_addr, mem_size, mem_write, seg_end,
             s_len, s_cls, s_cyc, s_pfx, s_pfxv, s_immdisp, s_addr, s_stack, s_esp_agi, s_rmask, s_wmask, s_rflags,
             s_wflags, s_jcc, s_branch, s_fp, s_fplat, s_fpnext, s_fmul, s_waitfpu, s_mmx, s_mmx_u, s_mmxlat,
             s_rep, s_repstart, s_rep0, s_nsrc, s_src, s_ndst, s_dst, s_fpdelta, s_memkind, s_fstore, P,
             dtags, dstamps, ddirty, dconfig, dclock, dstats, itags, istamps, idirty, iconfig, iclock, istats,
             counters, per_static, stat_first, timeline, tl_first, rdtsc_sid, rdtsc_out,
             sv, reg_avail, ext_ready, wb_free, seen, pair_cache, btb_tag, btb_stamp, btb_hist,
             btb_target, pht, iline_seen):
    """Time the chunk's instructions (run instructions base, base + 1, ...), continuing from the
    state (`sv` and the arrays after it, from :func:`new_state`) and leaving it for the next call.
    The chunk's arrays are its own; everything else counts instructions from the run's start.
    `next_pc`: the PC of the instruction after the chunk, -1 at the end of the run. (The loop index
    starts at the constant 0 and the caller passes views for a later start, the chunk's instruction
    `first`: from an argument, every array index would need a check for negative values, a few per
    cent slower.) The accesses are walked in order: ``mem_insn`` (sorted, counting from the chunk's
    instruction 0) from `acc`, the first access of instruction `first` or later (per-instruction
    start and count arrays were 16 bytes per instruction written by every timing).

    Pairing looks one instruction ahead: the chunk's last instruction may need the next chunk's
    first as its V partner (or, its pairing not yet known, that instruction's static). Then the
    call stops before it (sv[V_STOPPED] = its index, else the index after the last group) and the
    caller times it with its successor first (p5.P5Session). Such an instruction is never NP, so
    never an RDTSC. Returns the cycle the last group ended."""
    n = dyn_sid.shape[0]
    n_acc = mem_insn.shape[0]
    sink = per_static.shape[0] - 1  # per-static sums only from stat_first: earlier ones go to this row
    btb_sets, btb_ways, hist_bits = P[P_BTB_SETS], P[P_BTB_WAYS], P[P_HIST_BITS]
    btb_set_mask = btb_sets - 1 if btb_sets & (btb_sets - 1) == 0 else -1  # sets a power of two: a mask
    esp_agi = sv[V_ESP_AGI]          # cycle ESP written by a non-stack instruction reaches execute
    fp_top = sv[V_FP_TOP]
    fp_free = sv[V_FP_FREE]
    fmul_free = sv[V_FMUL_FREE]
    fp_done = sv[V_FP_DONE]
    wb_pos = sv[V_WB_POS]
    bus_free = sv[V_BUS_FREE]
    rep_prev_store = sv[V_REP_PREV_STORE]
    last_iline = sv[V_LAST_ILINE]
    t = sv[V_T]
    seg = sv[V_SEG]
    seg_start = sv[V_SEG_START]
    shadow = sv[V_SHADOW]                # prefix decode clocks a recent multi-clock group can still hide
    shadow_groups = sv[V_SHADOW_GROUPS]  # groups that may still use them
    # what counts instructions from the run's start, counted from the chunk's
    first_l = stat_first - base
    tl_first_l = tl_first - base
    seg_end_l = seg_end - base
    nrdtsc = 0
    # plain L1 data hits are done inline (shared_core's L1-hit path), with the hierarchy's LRU clock
    # and the hit counts in locals (written back around each service call and at the end)
    l1_ob, l1_row0, l1_set_mask, l1_ways, l1_lru, l1_write_back = l1_geometry(dconfig)
    d_now = dclock[0]
    has_tlb = dconfig[0, CFG_TLB_WAYS] > 0
    l1_load_hits = 0
    l1_store_hits = 0
    # the facts the loop reads per instruction, one row each: one array instead of two dozen keeps
    # fewer values live in the loop (as the P6 and K6 cores)
    sf = np.zeros((s_len.shape[0], NF), np.int64)
    for s in range(s_len.shape[0]):
        sf[s, F_LEN], sf[s, F_CLS], sf[s, F_CYC], sf[s, F_PFX] = s_len[s], s_cls[s], s_cyc[s], s_pfx[s]
        sf[s, F_ADDR], sf[s, F_ESP_AGI] = s_addr[s], s_esp_agi[s]
        sf[s, F_WMASK], sf[s, F_BRANCH] = s_wmask[s], s_branch[s]
        sf[s, F_FP], sf[s, F_FPLAT], sf[s, F_FPNEXT], sf[s, F_FMUL] = s_fp[s], s_fplat[s], s_fpnext[s], s_fmul[s]
        sf[s, F_WAITFPU], sf[s, F_MMX], sf[s, F_MMXLAT], sf[s, F_REP] = s_waitfpu[s], s_mmx[s], s_mmxlat[s], s_rep[s]
        sf[s, F_REPSTART], sf[s, F_REP0], sf[s, F_NSRC], sf[s, F_NDST] = s_repstart[s], s_rep0[s], s_nsrc[s], s_ndst[s]
        sf[s, F_FPDELTA], sf[s, F_MEMKIND], sf[s, F_FSTORE] = s_fpdelta[s], s_memkind[s], s_fstore[s]
    li = 0  # (from a constant: indexing with it needs no check for negative indices)
    while li < n:
        a = dyn_sid[li] & IDX
        pa = a if li >= first_l else sink
        pc_a = np.int64(dyn_pc[li])
        # a later element of a REP string instruction: the same PC again
        if sf[a, F_REP] != REP_NONE:
            rep_later = (np.int64(dyn_pc[li - 1]) if li > 0 else sv[V_PREV_PC]) == pc_a
        else:
            rep_later = False
        # ---- pairing ----------------------------------------------------------------------
        reason = R_BRANCH
        rreg = -1
        group = 1
        # (next_pc -1, the run's end, is no instruction's successor)
        if sf[a, F_BRANCH] == BR_NONE and \
                (np.int64(dyn_pc[li + 1]) if li + 1 < n else next_pc) == pc_a + sf[a, F_LEN] and \
                not (seg < seg_end_l.shape[0] and li + 1 == seg_end_l[seg]):
            first_ok = 1 if (P[P_FIRST_PASS] == 1 or seen[a] > 0 or sf[a, F_LEN] == 1) else 0
            code = pair_cache[a, first_ok]
            if code < 0:
                if li + 1 < n:
                    b = dyn_sid[li + 1] & IDX
                elif sf[a, F_CLS] == NP or sf[a, F_CLS] == PV or sf[a, F_CLS] == FXCH:
                    b = a  # the answer does not depend on the next instruction (_pair_reason)
                else:
                    break  # the next instruction's static is in the next chunk: hold this one back
                reason, rreg = _pair_reason(a, b, s_cls, s_len, s_rmask, s_wmask, s_rflags, s_wflags, s_jcc,
                                            s_stack, s_immdisp, s_pfxv, s_mmx, s_mmx_u, P[P_IMMDISP_MODE],
                                            P[P_PFX_V], first_ok)
                code = reason * 16 + rreg + 1
                pair_cache[a, first_ok] = code
            reason = code // 16
            rreg = code % 16 - 1
            if reason == R_PAIRED:
                if li + 1 >= n:
                    break  # its V partner is in the next chunk: hold this one back
                group = 2
        elif sf[a, F_CLS] == NP:
            reason = R_NP
        elif sf[a, F_CLS] == PV:
            reason = R_PV_IN_U
        start = t
        # ---- code fetch (L1I) ------------------------------------------------------------
        stall_fetch = 0
        for k in range(group):
            pc = np.int64(dyn_pc[li + k])
            for half in range(2):
                line = (pc >> 5) if half == 0 else ((pc + sf[dyn_sid[li + k], F_LEN] - 1) >> 5)
                if line != last_iline and iline_seen[line & 15] != line:
                    # (a line fetched since the last miss is still resident: its lookup is a hit, and
                    # only its LRU refresh is lost, which matters only for code larger than the L1I)
                    r = service(itags, istamps, idirty, iconfig, iclock, istats, line << 5, 1, False)
                    if served_level(r) > 0:
                        counters[seg, C_L1I_MISSES] += 1
                        stall_fetch += P[P_L2_LAT]
                        iline_seen[:] = -1
                    iline_seen[line & 15] = line
                last_iline = line
        start += stall_fetch
        counters[seg, C_FETCH] += stall_fetch
        # ---- decode: prefixes --------------------------------------------------------------
        pfx = 0 if rep_later else sf[a, F_PFX]
        if group == 2:
            pfx += sf[dyn_sid[li + 1], F_PFX]
        if pfx > 0 and shadow_groups > 0:
            # AF97 sec. 13: each extra execute clock of a recent instruction decodes one prefix of
            # the next two instructions or pairs (the P54C; the P55C's FIFO is modelled as full)
            hidden = min(pfx, shadow)
            pfx -= hidden
            shadow -= hidden
        start += pfx
        exec_from = start
        counters[seg, C_PREFIX] += pfx
        per_static[pa, S_PREFIX] += pfx
        # ---- AGI: an address register written in the preceding clock ------------------------
        agi = 0
        for k in range(0 if rep_later else group):
            s = dyn_sid[li + k] & IDX
            m = sf[s, F_ADDR]
            r = 0
            while m != 0:
                if m & 1:
                    # ESP moved by PUSH/POP/CALL is predicted (no AGI); esp_agi tracks other writers
                    avail = esp_agi if r == 4 else reg_avail[r]
                    if avail > start - P[P_AGI] and avail - (start - P[P_AGI]) > agi:
                        agi = avail - (start - P[P_AGI])
                m >>= 1
                r += 1
        if agi > P[P_AGI]:
            agi = P[P_AGI]
        start += agi
        counters[seg, C_AGI] += agi
        per_static[pa, S_AGI] += agi
        # ---- x87 and MMX readiness -----------------------------------------------------------
        fp_wait = 0
        for k in range(group):
            s = dyn_sid[li + k] & IDX
            if sf[s, F_FP] == 0 and sf[s, F_MMX] == 0:
                continue
            ready = start
            if sf[s, F_FP] == 1:
                ready = max(ready, fp_free)
                if sf[s, F_FMUL] == 1:
                    ready = max(ready, fmul_free)
                if sf[s, F_WAITFPU] == 1:
                    ready = max(ready, fp_done)
            for j in range(sf[s, F_NSRC]):
                rid = s_src[s, j, 0]
                if rid == REG_ST0:
                    rid = REG_ST0 + ((fp_top + s_src[s, j, 3]) & 7)
                if rid >= REG_ST0 and rid < 40:
                    # FST(P) m takes its operand a clock before its execute stage (AF97-FP)
                    ready = max(ready, ext_ready[rid] + (P[P_FST_EARLY] if sf[s, F_FSTORE] == 1 else 0))
            if ready - start > fp_wait:
                fp_wait = ready - start
        start += fp_wait
        counters[seg, C_FPU] += fp_wait
        per_static[pa, S_FPU] += fp_wait
        # ---- execute: duration, memory --------------------------------------------------------
        dur = sf[a, F_CYC]
        if group == 2:
            b = dyn_sid[li + 1] & IDX
            if sf[b, F_CYC] > dur:
                dur = sf[b, F_CYC]
            # a read/modify/write in U with a read/modify or read/modify/write in V overlaps it
            # only in part (AF97-PAIR sec. 10.4's table of the pair's clocks)
            pc2 = P[P_PAIR_CLOCKS + 3 * sf[a, F_MEMKIND] + sf[b, F_MEMKIND]]
            if pc2 > dur:
                dur = pc2
        if sf[a, F_REP] != REP_NONE:
            if not (acc < n_acc and mem_insn[acc] == li + first):
                dur = 0 if rep_later else sf[a, F_REP0]  # closing count check / ECX = 0 on entry
            elif not rep_later:
                dur += sf[a, F_REPSTART]
        rep_load = np.int64(-1)
        rep_store = np.int64(-1)
        mem = 0
        mis = 0
        bank = 0
        wbw = 0
        wbw_u = 0  # the part of wbw the U instruction's stores waited (the V's waited the rest)
        u_lo = np.int64(-1)   # dword range of the U instruction's accesses
        u_hi = np.int64(-2)
        for k in range(group):
            s = dyn_sid[li + k] & IDX
            ps = s if li + k >= first_l else sink
            while acc < n_acc and mem_insn[acc] == li + k + first:
                q = acc
                acc += 1
                addr = np.int64(mem_addr[q])
                sz = np.int64(mem_size[q])
                span = 8 if sz > 4 else 4
                if (addr & (span - 1)) + sz > span:  # (span is 4 or 8: a mask)
                    mis += P[P_MISALIGNED]
                    per_static[ps, S_MISALIGNED] += P[P_MISALIGNED]
                lo = addr >> 2
                hi = (addr + sz - 1) >> 2
                if k == 0:
                    if u_hi < u_lo:
                        u_lo, u_hi = lo, hi
                    else:
                        u_lo, u_hi = min(u_lo, lo), max(u_hi, hi)
                elif u_hi >= u_lo:
                    if lo <= u_hi and hi >= u_lo:
                        # both pipes in one dword: the accesses cannot go together (AF97-PAIR 10.2)
                        bank = max(bank, P[P_SAME_DWORD])
                    elif P[P_BANK] == 1 and (lo & 7) == (u_lo & 7):
                        bank = 1  # different dwords, one cache bank (P54C)
                if sf[s, F_REP] == REP_MOVS:
                    if mem_write[q]:
                        rep_store = addr
                    else:
                        rep_load = addr
                now = start + mem + mis
                w_ = mem_write[q] != 0
                counters[seg, C_L1D_STORES if w_ else C_L1D_LOADS] += 1
                row, way = -1, -1
                if (l1_write_back or not w_) and tlb_hit(has_tlb, dconfig, dclock, addr):
                    row, way = l1_way(dtags, addr, sz, l1_ob, l1_row0, l1_set_mask, l1_ways)
                if row >= 0:  # a plain L1 hit, inline (shared_core)
                    if w_:
                        l1_store_hits += 1
                    else:
                        l1_load_hits += 1
                    d_now = l1_hit(dstamps, ddirty, row, way, w_, l1_lru, d_now)
                else:
                    dclock[0] = d_now
                    r = service(dtags, dstamps, ddirty, dconfig, dclock, dstats, addr, sz, w_)
                    d_now = dclock[0]
                    if tlb_missed(r):  # the pipe waits for the translation
                        extra, bus_free = _page_walk(r, dconfig.shape[0], now, P, bus_free, counters[seg])
                        mem += extra
                        per_static[ps, S_MEMORY] += extra
                        now += extra
                    lvl = served_level(r)
                    if lvl > 0 and w_:
                        counters[seg, C_L1D_STORE_MISSES] += 1
                        counters[seg, C_BUS_WRITES] += 1
                        per_static[ps, S_L1D_MISSES] += 1
                        # a write buffer: wait for the oldest when all are busy, then drain to the bus
                        w = wb_free[wb_pos]
                        if w > now + wbw:  # the store that waits pays it (in a pair, not the U instruction)
                            wbw = w - now
                        d0 = max(now + wbw, bus_free)
                        bus_free = d0 + P[P_WRITE_BUS]
                        wb_free[wb_pos] = bus_free
                        wb_pos = (wb_pos + 1) % wb_free.shape[0]
                    elif lvl > 0:
                        counters[seg, C_L1D_LOAD_MISSES] += 1
                        per_static[ps, S_L1D_MISSES] += 1
                        extra, bus_free = _load_miss(r, lvl, now, P, bus_free, counters[seg])
                        mem += extra
                        per_static[ps, S_MEMORY] += extra
            if k == 0:
                wbw_u = wbw
        if sf[a, F_REP] == REP_MOVS:
            if P[P_BANK] == 1 and rep_later and rep_load >= 0 and rep_prev_store >= 0 and \
                    ((rep_load >> 2) & 7) == ((rep_prev_store >> 2) & 7) and (rep_load >> 2) != (rep_prev_store >> 2):
                bank = 1  # AF 26.3: this element's read meets the previous element's write in one bank
            rep_prev_store = rep_store
        counters[seg, C_MEMORY] += mem
        counters[seg, C_MISALIGNED] += mis
        counters[seg, C_BANK] += bank
        counters[seg, C_WB] += wbw
        per_static[pa, S_BANK] += bank
        # the write-buffer wait per store that waited: added here, not where it waits (measured: an
        # update inside that branch made the whole loop about 11 % slower)
        per_static[pa, S_WB] += wbw_u
        if group == 2:
            per_static[dyn_sid[li + 1] if li + 1 >= first_l else sink, S_WB] += wbw - wbw_u
        end = start + dur + mem + mis + bank + wbw
        if P[P_PFX_SHADOW] == 1:
            # any delay but a decode delay or a mispredict (AGI, execute clocks, misses) casts the shadow
            if shadow_groups > 0:
                shadow_groups -= 1
                if shadow_groups == 0:
                    shadow = 0
            if end - exec_from - 1 > 0 and end - exec_from - 1 >= shadow:
                shadow = end - exec_from - 1
                shadow_groups = 2
        # ---- results --------------------------------------------------------------------------
        for k in range(group):
            s = dyn_sid[li + k] & IDX
            done = start + (dur if group == 1 else sf[s, F_CYC]) + mem + mis
            w = sf[s, F_WMASK]
            r = 0
            while w != 0:
                if w & 15:
                    reg_avail[r] = done
                w >>= 4
                r += 1
            if sf[s, F_ESP_AGI] == 1:
                esp_agi = done
            if sf[s, F_FP] == 0 and sf[s, F_MMX] == 0 and sf[s, F_CLS] != FXCH:
                continue
            top_after = (fp_top - sf[s, F_FPDELTA]) & 7
            if sf[s, F_CLS] == FXCH and sf[s, F_NSRC] >= 2:  # FXCH swaps the two slots' readiness
                r0 = REG_ST0 + ((fp_top + s_src[s, 0, 3]) & 7) if s_src[s, 0, 0] == REG_ST0 else -1
                r1 = REG_ST0 + ((fp_top + s_src[s, 1, 3]) & 7) if s_src[s, 1, 0] == REG_ST0 else -1
                if r0 >= 0 and r1 >= 0:
                    tmp = ext_ready[r0]
                    ext_ready[r0] = ext_ready[r1]
                    ext_ready[r1] = tmp
                fp_top = top_after
                continue
            fplat = sf[s, F_FPLAT]
            fpnext = sf[s, F_FPNEXT]
            if sf[s, F_FP] == 1:
                fp_free = start + fpnext
                if sf[s, F_FMUL] == 1:
                    fmul_free = start + P[P_FMUL_SPACING]
                if start + fplat > fp_done:
                    fp_done = start + fplat
            for j in range(sf[s, F_NDST]):
                rid = s_dst[s, j, 0]
                if rid == REG_ST0:
                    rid = REG_ST0 + ((top_after + s_dst[s, j, 3]) & 7)
                if rid >= REG_ST0 and rid < 40:
                    ext_ready[rid] = start + (fplat if sf[s, F_FP] == 1 else sf[s, F_MMXLAT])
            fp_top = top_after
        # ---- branches -----------------------------------------------------------------------
        last = li + group - 1
        sb = dyn_sid[last] & IDX
        psb = sb if last >= first_l else sink
        if sf[sb, F_BRANCH] != BR_NONE:
            counters[seg, C_BRANCHES] += 1
            pc = np.int64(dyn_pc[last])
            if last + 1 < n:
                nxt = np.int64(dyn_pc[last + 1])
            else:
                nxt = next_pc if next_pc >= 0 else pc + sf[sb, F_LEN]
            taken = nxt != pc + sf[sb, F_LEN]
            bset = pc & btb_set_mask if btb_set_mask >= 0 else pc % btb_sets
            way = -1
            for w in range(btb_ways):
                if btb_tag[bset, w] == pc:
                    way = w
            mispredicted = False
            if sf[sb, F_BRANCH] == BR_COND:
                if way >= 0:
                    h = btb_hist[bset, way]
                    cnt = pht[bset, way, h]
                    predict = cnt >= 2
                    pred_target = btb_target[bset, way]
                    mispredicted = predict != taken or (taken and pred_target != nxt)
                    pht[bset, way, h] = min(3, cnt + 1) if taken else max(0, cnt - 1)
                    btb_hist[bset, way] = ((h << 1) | (1 if taken else 0)) & ((1 << hist_bits) - 1)
                    btb_stamp[bset, way] = base + li
                else:
                    mispredicted = taken  # not in the BTB: predicted not taken
                    if taken:
                        way = btb_alloc(btb_tag, btb_stamp, bset, btb_ways, pc, base + li)
                        btb_hist[bset, way] = 1 & ((1 << hist_bits) - 1)
                        for h in range(1 << hist_bits):
                            pht[bset, way, h] = 3  # p5_machine.toml [estimates.btb_new_entry]
            else:
                mispredicted = way < 0 or btb_target[bset, way] != nxt
                if way < 0:
                    way = btb_alloc(btb_tag, btb_stamp, bset, btb_ways, pc, base + li)
                if sf[sb, F_BRANCH] == BR_RET and last + 1 >= n and next_pc < 0:
                    mispredicted = False  # the return to the harness ends the stream
            if way >= 0 and taken:
                btb_target[bset, way] = nxt
            if mispredicted:
                pen = P[P_MISP_V] if group == 2 else P[P_MISP_U]
                end += pen
                counters[seg, C_MISPREDICTS] += 1
                counters[seg, C_MISPREDICT] += pen
                per_static[psb, S_MISPREDICTS] += 1
                per_static[psb, S_MISPREDICT] += pen
        # ---- bookkeeping ----------------------------------------------------------------------
        if group == 2:
            counters[seg, C_PAIRS] += 1
            counters[seg, C_U] += 1
            counters[seg, C_V] += 1
            pb = dyn_sid[li + 1] & IDX if li + 1 >= first_l else sink
            per_static[pa, S_U] += 1
            per_static[pa, S_PAIRED_U] += 1
            per_static[pb, S_V] += 1
        else:
            counters[seg, C_ALONE] += 1
            counters[seg, C_U] += 1
            counters[seg, C_REASON0 + reason] += 1
            per_static[pa, S_U] += 1
            per_static[pa, S_REASON0 + reason] += 1
            if rreg >= 0:
                per_static[pa, S_REASON_REG] = rreg
        per_static[pa, S_CYCLES] += end - t
        for k in range(group):
            s = dyn_sid[li + k] & IDX
            seen[s] += 1
            ps = s if li + k >= first_l else sink
            per_static[ps, S_EXEC] += 1
            if nrdtsc < rdtsc_out.shape[0] and rdtsc_sid[s] == 1:
                rdtsc_out[nrdtsc] = start
                nrdtsc += 1
            if tl_first_l <= li + k < tl_first_l + timeline.shape[0]:
                row = timeline[li + k - tl_first_l]
                row[0] = base + li + k
                row[1] = s
                row[2] = t
                row[3] = start
                row[4] = start
                row[5] = end
                row[6] = end
                row[7] = 0 if group == 2 else reason
            counters[seg, C_INSTRUCTIONS] += 1
            counters[seg, C_UOPS] += 1
        t = end
        li += group
        while seg < seg_end_l.shape[0] and li >= seg_end_l[seg]:
            counters[seg, C_CYCLES] = t - seg_start
            seg_start = t
            seg += 1

    if li > 0:
        sv[V_PREV_PC] = np.int64(dyn_pc[li - 1])
    sv[V_STOPPED] = li
    dclock[0] = d_now
    add_l1_hits(dstats, l1_load_hits, l1_store_hits)
    sv[V_NRDTSC] = nrdtsc  # RDTSC values written (outputs, not state)
    sv[V_ESP_AGI] = esp_agi
    sv[V_FP_TOP] = fp_top
    sv[V_FP_FREE] = fp_free
    sv[V_FMUL_FREE] = fmul_free
    sv[V_FP_DONE] = fp_done
    sv[V_WB_POS] = wb_pos
    sv[V_BUS_FREE] = bus_free
    sv[V_REP_PREV_STORE] = rep_prev_store
    sv[V_LAST_ILINE] = last_iline
    sv[V_T] = t
    sv[V_SEG] = seg
    sv[V_SEG_START] = seg_start
    sv[V_SHADOW] = shadow
    sv[V_SHADOW_GROUPS] = shadow_groups
    return t

