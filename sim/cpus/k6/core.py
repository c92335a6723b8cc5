"""The compiled AMD K6 cycle model: one pass over the dynamic instruction stream, in program order.

The machine (AMD-K6 data sheet 20695H ch. 2; numbers in sim/cpus/k6/k6_machine.toml):

Front end. Decode clocks produce *opquads*, groups of four RISC86 ops padded with RISC86 NOPs.
In one clock either both short decoders work (two instructions of at most 7 bytes and 2 ops each;
an x87 instruction, and on the K6 model 6/7 an MMX instruction, only in the first), or the long
decoder (one instruction, up to 4 ops), or the vector decoder with its ROM sequencer (one
instruction, alone, for S_CYC clocks: at least two, and as many as the sequence runs). An
instruction with prefixes decodes alone at the measured prefix rate. An instruction whose
length-determining bytes lie in two 32-byte I-cache lines adds a clock to a decode group of
one clock (an inferred rule: predecode is per line; k6_machine.toml [decode.line_crossing]). A predicted-taken branch ends
the group; the branch target cache (BTC) supplies the target's bytes at once, and a BTC miss costs
a fetch clock. Branch prediction at decode: a 2-bit counter table of BHT entries indexed by the
branch address XOR a global history of the last HIST_BITS conditional outcomes; direct targets are
computed at decode (never mispredicted); returns use a return stack; indirect targets are guessed
from the BTC. A misprediction restarts decoding MISPREDICT clocks after the branch executes.
Scheduler. The centralised scheduler holds QUADS opquads (24 ops = 6 x 4, NOP padding included):
it is both the window and the reservation station. An opquad enters the clock after it is decoded
if its slot is free (the opquad QUADS older has retired); otherwise the decoder holds it. Ops issue
from any position, oldest first, to the units: X and Y (integer; shifts, multiplies, divides and on
the K6 MMX only on X), load, store (also LEA), branch, each one op per clock (the ``book_port``
calendar of sim/cpus/shared_core.py, shared with the P6 core), the x87 unit (not pipelined: busy for the op's reciprocal
throughput) and, on the K6-2/K6-III, one MMX multiplier, one MMX shifter and one 3DNow! unit
behind the X/Y issue slots. The multiplier and divider hold X for their whole occupancy. Opquads
retire in order, one per clock (four ops, padding included).
Memory. L1D/L1I, the board cache (L2; on the K6-III the on-die L2, and the board cache as L3) and
DRAM through :mod:`sim.memory.hierarchy`. The board cache and DRAM share the Socket 7 front-side
bus, serially; the K6-III's on-die L2 has its own port. Stores wait in a store queue of SQ entries
and write L1 after retirement; a write miss either allocates (a line fill) or, when the write-allocate
mode says no, becomes a single write on the bus. A data-TLB miss delays the access by its page walk
(_k6_walk: TLB_WALK cycles, then each walk read that missed L1 charged as a load; a store's at
commit). Loads take data from an overlapping older store in the queue with the ordinary load
latency once the store has issued (trace addresses: perfect disambiguation). Reading a full register after a partial write costs PARTIAL extra clocks.

Counters, per-static columns, timeline and stall causes are the contract's (:mod:`sim.cpus.contract`),
at the same indices, so views and reports read both models alike; the K6 fills what applies and adds
its own counters after the shared ones. Mapping: decoder0 = the first short decoder or the long
decoder, decoder1 = the second short decoder, decoder2 = 0, msrom_uops = vector-path ops,
port0..port4 = X, Y, load, store, branch; fpu_ops counts the x87 unit; stall_rob = scheduler full,
stall_rs = 0, lcp_stalls = decode clocks added by prefixes; l2_* = the level below L1 (the board
cache, or the K6-III's on-die L2), l3_* = the K6-III's board cache.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from sim.memory.hierarchy import (
    CFG_TLB_WAYS, S_FILLS, S_WRITEBACKS, memory_fill_page_hits, memory_fills, memory_writebacks, served_level,
    service, tlb_missed, walk_l1_fills, walk_pde_level, walk_pte_level, walk_read_result,
)
from sim.memory.replay import LOG_OFF, LOG_REPLAY, LOGGED_HIT, logged_service
from sim.cpus.lowering import (
    BR_CALL, BR_COND, BR_INDIRECT, BR_NONE, BR_RET, BRANCH, DEC_MSROM, LOAD, NREGS, OCC_SCALE, R_ELEMENT, R_KIND,
    R_START, REG_ST0, REP_NONE, STA,
)
from sim.cpus.contract import (
    C_BRANCHES, C_DECODE_GROUPS, C_DECODER0, C_DRAM_BUS_CYCLES, C_DRAM_FILLS, C_DRAM_PAGE_HITS,
    C_DRAM_PAGE_MISSES, C_DRAM_WRITEBACKS, C_DTLB_MISSES,
    C_INSTRUCTIONS, C_L1D_LOAD_MISSES, C_L1D_LOADS, C_L1D_STORE_MISSES, C_L1D_STORES, C_L1I_MISSES,
    C_L2_ACCESSES, C_L2_MISSES, C_LCP_STALLS, C_MISPREDICTS, C_MSROM_UOPS, C_NAMES as SHARED_C_NAMES, C_PORT0,
    C_STALL_DECODE, C_STALL_DEPENDENCY, C_STALL_FETCH, C_STALL_MEMORY, C_STALL_MISPREDICT,
    C_STALL_PARTIAL_REGISTER, C_STALL_PORT, C_STALL_ROB, C_STALL_STORE_BUFFER, C_STALL_STORE_FORWARD,
    C_STORE_FORWARDS, C_UOPS, C_CYCLES, CAUSES, NT, S_DECODE_TO_RETIRE, S_DECODER0, S_EXECUTIONS,
    S_ISSUE_TO_RETIRE, S_L1D_MISSES, S_L2_MISSES, S_MISPREDICTS, S_MSROM, S_NAMES as SHARED_S_NAMES, S_PORT0,
    S_STALL_DECODE, S_STALL_DEPENDENCY, S_STALL_MEMORY, S_STALL_MISPREDICT, S_STALL_PARTIAL, S_STALL_PORT,
    S_STALL_STORE_FORWARD, S_STALL_WINDOW, S_UOPS, T_NAMES,
)
from sim.cpus.shared_core import (
    FW, IDX, REPLAYED_HIT, WINDOW, access_end, add_l1_hits, btb_alloc, dram_busy, dram_lead_off, l1_geometry, l1_hit,
    plain_hit, queued_store, remember_store, segments_ended, tlb_hit, uncounted,
)
from sim.cpus.shared_core import book_port as _shared_book_port
from sim.memory.cache import HOT

__all__ = ["C_NAMES", "S_NAMES", "T_NAMES", "CAUSES", "NC", "NS", "NT", "simulate"]

# parameter vector indices
(P_QUADS, P_L1_LAT, P_ONDIE, P_L2_LAT, P_L2_BUS, P_BOARD_LEVEL, P_BOARD_LAT, P_BOARD_BUSY, P_DRAM_LAT,
 P_DRAM_LINE, P_DRAM_WB, P_BUS_WRITE, P_SQ, P_MISPREDICT, P_BTC, P_BTC_MISS, P_BHT, P_HIST_BITS, P_RSB,
 P_PARTIAL, P_IMISS, P_EXIT_ADDR, P_DRAM_LAT_HIT, P_DRAM_LINE_HIT, P_DRAM_WB_HIT, P_TLB_WALK) = range(26)
NPARAMS = 26

# K6 execution resources behind the issue slots (u_unit of a lowered op)
U_NONE, U_FPU, U_MMX_MUL, U_MMX_SHIFT, U_3DNOW, U_HOLD = range(6)
NUNITS = 6
# issue-slot bits (u_ports of a lowered op): the contract's "port" counters 0-4
X, Y, LOAD_SLOT, STORE_SLOT, BRANCH_SLOT = 1, 2, 4, 8, 16

# the contract's counters first (same indices), then the K6's own (numba's cache keys on this file's
# text, not the contract's: a counter added to the contract needs an edit here to recompile)
C_NAMES = SHARED_C_NAMES + ("fpu_ops", "vector_cycles", "nop_slots", "l3_accesses", "l3_misses", "bus_writes")
NC = len(C_NAMES)
C_FPU_OPS = len(SHARED_C_NAMES)
C_VECTOR_CYCLES = C_FPU_OPS + 1
C_NOP_SLOTS = C_FPU_OPS + 2
C_L3_ACCESSES = C_FPU_OPS + 3
C_L3_MISSES = C_FPU_OPS + 4
C_BUS_WRITES = C_FPU_OPS + 5
S_NAMES = SHARED_S_NAMES + ("fpu",)
NS = len(S_NAMES)
S_FPU = len(SHARED_S_NAMES)

# columns of simulate's per-static and per-op fact rows (copies of the lowering's arrays, row-major;
# F_GPRS.., UF_SRCS..: row ranges of its operand table)
(F_NUOPS, F_UOP0, F_CYC, F_FIRST, F_DEC, F_PFX, F_FPDELTA, F_GPRS, F_GPRS_END, F_BRANCH, F_LEN, F_TARGET,
 F_RDTSC, F_CROSS) = range(14)
NF = 16
UF_KIND, UF_PORTS, UF_LAT, UF_UNIT, UF_OCC, UF_SRCS, UF_DSTS, UF_DSTS_END = range(8)
NUF = 8



# The shared port calendar (sim/cpus/shared_core.py), compiled as an ordinary call (which LLVM inlines) rather than inlined
# into numba's IR (inline="always"): IR inlining increfs and decrefs the array argument at each call.
_book_port = njit(**HOT)(_shared_book_port.py_func)


@njit(**HOT)
def _book_run(book, ports, c, occ):
    """Earliest cycle >= c at which one allowed issue slot is free for `occ` consecutive cycles
    (a non-pipelined multiply or divide holds Integer X); books all of them. Same calendar as
    shared_core.book_port, which books a single cycle. Returns (cycle, slot)."""
    while True:
        for p in range(5):
            bit = 1 << p
            if ports & bit == 0:
                continue
            free = True
            for k in range(occ):
                e = book[(c + k) & (WINDOW - 1)]
                if (e >> 5) == c + k and e & bit:
                    free = False
                    break
            if free:
                for k in range(occ):
                    slot = (c + k) & (WINDOW - 1)
                    e = book[slot]
                    used = e & 31 if (e >> 5) == c + k else 0
                    book[slot] = ((c + k) << 5) | used | bit
                return c, p
        c += 1


@njit(cache=True, nogil=True, inline="always")
def _access_of(mem_write, acc, acc_end, write):
    """Index of the instruction's next memory access of the given direction (from `acc`), or -1."""
    for j in range(acc, acc_end):
        if mem_write[j] == write:
            return j
    return -1


@njit(cache=True, nogil=True, inline="always")
def _new_writebacks(stats, seen, level):
    """Dirty victims `level` wrote back since the last call (0 for a level the hierarchy lacks)."""
    if level + 1 >= stats.shape[0]:
        return 0
    new = stats[level, S_WRITEBACKS] - seen[level]
    seen[level] = stats[level, S_WRITEBACKS]
    return new


@njit(cache=True, nogil=True, inline="always")
def _slot_of(rid, top, rel):
    """Register-file slot: x87 stack names are relative to TOP."""
    return REG_ST0 + ((top + rel) & 7) if rid == REG_ST0 else rid


@uncounted
def _k6_miss(r, lvl, start, P, bus, wb1, wb2, counters, cs):
    """Extra cycles beyond an L1 hit for an L1 miss served by level `lvl` (service() levels:
    1 = L2, ..., the last = memory). `bus[0]`: the front-side bus (board cache and DRAM), free from
    that cycle; `bus[1]`: the K6-III's on-die L2 port. `wb1`/`wb2`: dirty victims the access made
    L1 / L2 write back. The P6 helper (_miss_latency) has a private backside L2 and one bus level;
    on Socket 7 the board cache itself sits on the front-side bus, and the K6-III adds a level."""
    board = P[P_BOARD_LEVEL]
    t = start
    board_wb = wb1
    if P[P_ONDIE] == 1:
        counters[cs, C_L2_ACCESSES] += 1
        s = max(t, bus[1])
        bus[1] = s + P[P_L2_BUS] * (1 + wb1)
        if lvl == 1:
            return s + P[P_L2_LAT] - P[P_L1_LAT] - start
        counters[cs, C_L2_MISSES] += 1
        t = s + P[P_L2_LAT] - P[P_L1_LAT]  # the miss is known when a hit would have delivered
        board_wb = wb2
    fills = memory_fills(r)
    wbs = memory_writebacks(r)
    s = max(t, bus[0])
    dram = dram_busy(r, P[P_DRAM_LINE], P[P_DRAM_LINE_HIT], P[P_DRAM_WB], P[P_DRAM_WB_HIT])
    busy = dram
    done = s + dram_lead_off(r, P[P_DRAM_LAT], P[P_DRAM_LAT_HIT]) if fills > 0 else s
    if board > 0:
        busy += board_wb * P[P_BOARD_BUSY]
        c_acc = C_L2_ACCESSES if board == 1 else C_L3_ACCESSES
        counters[cs, c_acc] += 1
        if lvl == board:
            busy += P[P_BOARD_BUSY]
            done = start + P[P_BOARD_LAT] - P[P_L1_LAT] + (s - t)
        else:
            counters[cs, c_acc + 1] += 1  # C_L2_MISSES / C_L3_MISSES
    bus[0] = s + busy
    counters[cs, C_DRAM_FILLS] += fills
    counters[cs, C_DRAM_WRITEBACKS] += wbs
    counters[cs, C_DRAM_BUS_CYCLES] += dram
    counters[cs, C_DRAM_PAGE_HITS] += memory_fill_page_hits(r)
    counters[cs, C_DRAM_PAGE_MISSES] += fills - memory_fill_page_hits(r)
    return max(0, done - start)


@uncounted
def _k6_walk(r, levels, start, P, bus, counters, cs):
    """Extra cycles of a data-TLB miss's page walk, before the access itself: the walk's fixed
    cycles, then its page-directory and page-table reads, each charged as a load served at its
    level (_k6_miss: the board cache, the K6-III's L2, or a DRAM fill on a closed page)."""
    counters[cs, C_DTLB_MISSES] += 1
    t = start + P[P_TLB_WALK]
    for wl in (walk_pde_level(r), walk_pte_level(r)):
        if wl > 0:
            t += _k6_miss(walk_read_result(wl, levels), wl, t, P, bus, 0, 0, counters, cs)
    return t - start


# Loop-carried scalar state, kept in an int64 vector between calls so that a trace can be timed in
# chunks exactly as in one call (sim/cpus/session.py; new_state gives the machine at reset).
(V_FP_TOP, V_NQ, V_Q_SLOT, V_Q_ENTRY, V_PREV_ENTRY, V_NSTORES, V_SQ_POS, V_LAST_COMMIT, V_FW_N,
 V_L1_FILL_SEEN, V_GHIST, V_RSB_TOP, V_DEC_FREE, V_FE_READY, V_FE_CAUSE, V_GRP_CYCLE, V_GRP_OPEN, V_HOLD_PSID,
 V_HOLD_CYCLES, V_LAST_RETIRE, V_CUR_SLOT, V_SEG, V_SEG_START, V_PREV_PC, V_REP_SID, V_REP_NEXT) = range(26)
NSTATE = 26
HOLD_SINK = -2  # hold_psid naming the sink row (whose index grows with the statics)


def new_state(P: np.ndarray, units: int) -> tuple:
    """The machine at reset: the scalar vector, then the arrays in the order simulate takes them.
    `units`: the largest resource id the program uses (sim.cpus.session.grown_state makes room for more)."""
    sv = np.zeros(NSTATE, np.int64)
    sv[V_PREV_ENTRY] = -1
    sv[V_HOLD_PSID] = -1  # per-static row of the last group's multi-clock decode (vector, prefixes)
    sv[V_RSB_TOP] = 1
    sv[V_PREV_PC] = -1   # the PC of the instruction before the chunk (a REP string's later element)
    sv[V_REP_SID] = -1   # the REP string whose run is open (-1: none)
    rsb = np.zeros(int(P[P_RSB]), np.int64)
    rsb[0] = P[P_EXIT_ADDR]  # the harness's call into the kernel: its return is predictable
    btc_ways = int(P[P_BTC])
    return (sv,
            np.zeros(NREGS, np.int64),               # reg_ready
            np.full(NREGS, 15, np.int64),            # reg_pmask: bytes written by the last writer (15 = whole)
            np.full(WINDOW, -1 << 5, np.int64),      # book: the issue-slot calendar
            # unit_free: ids from NUNITS on are resources held by single rows (k6.K6Rules._hold_unexplained)
            np.zeros(max(NUNITS, units + 1), np.int64),
            np.zeros(int(P[P_QUADS]), np.int64),     # qring: retire cycle of the last `quads` opquads
            np.zeros(int(P[P_SQ]), np.int64),        # sq_ring: commit cycle of the last sq_n stores
            np.zeros(2, np.int64),                   # bus
            np.full(FW, -1, np.int64),               # fw_addr
            np.zeros(FW, np.int64),                  # fw_size
            np.zeros(FW, np.int64),                  # fw_ready
            np.zeros(FW, np.int64),                  # fw_commit
            np.zeros(2, np.int64),                   # wb_seen: L1 and L2 writebacks already charged
            np.full(int(P[P_BHT]), 2, np.int64),     # bht
            np.full((1, btc_ways), -1, np.int64),    # btc_tag
            np.zeros((1, btc_ways), np.int64),       # btc_stamp
            np.zeros(btc_ways, np.int64),            # btc_target
            rsb,
            np.full(64, -1, np.int64))               # known: L1I lines that hit since the last miss


UNIT_FREE = 4  # position of unit_free in new_state's tuple
SQ_RING = 6  # position of sq_ring
LEARNED = tuple(range(12, 19))  # wb_seen, bht, btc_tag, btc_stamp, btc_target, rsb, known


@uncounted
def _predict(br, pc, nxt, fall, i, target, ghist, bht, bht_mask, hist_mask, rsb, rsb_top, rsb_n, btc_tag, btc_stamp,
             btc_target, btc_ways):
    """The branch predictors on a branch (kind `br`) at `pc` going to `nxt` (`fall`: the next
    instruction's address; `i`: the instruction's number; `target`: its direct target, -1 if none):
    the prediction checked and every table updated, in program order (warm). Returns
    (mispredicted, predicted taken, the BTC held it, global history, return stack top).
    These are simulate's branch-section updates; simulate keeps its own inline copy (the same code
    moved into this helper and called from simulate's loop made the compiled core slower: the speed
    check measured the P6 core 28 % slower, the K6's 7 %), and tests/test_warm_start.py checks that
    the two leave the same tables."""
    taken = nxt != fall
    predict_taken = True
    mispredicted = False
    if br == BR_COND:
        h = (pc ^ ghist) & bht_mask
        cnt = bht[h]
        predict_taken = cnt >= 2
        bht[h] = min(3, cnt + 1) if taken else max(0, cnt - 1)
        ghist = ((ghist << 1) | (1 if taken else 0)) & hist_mask
        mispredicted = predict_taken != taken
    elif br == BR_RET:
        rsb_top -= 1
        mispredicted = rsb_top < 0 or rsb[rsb_top % rsb_n] != nxt
        if rsb_top < 0:
            rsb_top = 0
    else:
        if br == BR_CALL:
            rsb[rsb_top % rsb_n] = fall
            rsb_top += 1
        if target < 0 or br == BR_INDIRECT:  # target unknown at decode: the BTC's guess
            mispredicted = True
            for w in range(btc_ways):
                if btc_tag[0, w] == pc:  # a branch has at most one entry (allocated on a miss)
                    mispredicted = btc_target[w] != nxt
                    break
    way = -1
    hit = False
    if taken:
        for w in range(btc_ways):
            if btc_tag[0, w] == pc:
                way = w
                btc_stamp[0, w] = i
                break
        hit = way >= 0
        if not hit:
            way = btb_alloc(btc_tag, btc_stamp, 0, btc_ways, pc, i)
        btc_target[way] = nxt
    return mispredicted, predict_taken, hit, ghist, rsb_top


@uncounted
def _data_service(dlog, log_off, dtags, dstamps, ddirty, dconfig, dclock, dstats, a, size, is_write):
    """A data access that is not a plain L1 hit (shared_core.plain_hit): service, or logged_service
    with an access log, called out of the cycle loop."""
    if log_off:
        return service(dtags, dstamps, ddirty, dconfig, dclock, dstats, a, size, is_write)
    return logged_service(dlog, dtags, dstamps, ddirty, dconfig, dclock, dstats, a, size, is_write)


@njit(cache=True, nogil=True)
def simulate(base, next_pc, dyn_sid, dyn_pc, mem_insn, mem_addr, mem_size, mem_write, seg_end,
             s_len, s_pc, s_dec, s_lcp, s_branch, s_target, s_fpdelta, s_zero, s_nuops, s_uop0, s_nsrc, s_src,
             s_ndst, s_dst, u_kind, u_ports, u_lat, u_unit, u_occ, s_rep, s_cyc, s_first, s_pfx, s_cross,
             P, dtags, dstamps, ddirty, dconfig, dclock, dstats, itags, istamps, idirty, iconfig, iclock, istats,
             counters, per_static, stat_first, timeline, tl_first, rdtsc_sid, rdtsc_out, dlog,
             sv, reg_ready, reg_pmask, book, unit_free, qring, sq_ring, bus, fw_addr,
             fw_size, fw_ready, fw_commit, wb_seen, bht, btc_tag, btc_stamp, btc_target, rsb, known):
    """Time instructions base .. base + len(dyn_sid) - 1 of a run, continuing from the state
    (`sv` and the arrays after it, from :func:`new_state`) and leaving it for the next chunk; the
    chunk's arrays are its own, everything else counts from the run's start (as
    :func:`sim.cpus.p6.core.simulate`). `next_pc`: the PC after the chunk, -1 at the run's end."""
    n = dyn_sid.shape[0]
    nstatic = s_len.shape[0]
    sink = per_static.shape[0] - 1  # per-static sums only from stat_first: earlier ones go to this row
    # the facts the loop reads per instruction and per op, one row each: one array instead of a
    # dozen keeps fewer values live in the loop
    sf = np.zeros((nstatic, NF), np.int64)
    for s in range(nstatic):
        sf[s, F_NUOPS], sf[s, F_UOP0], sf[s, F_CYC], sf[s, F_FIRST] = s_nuops[s], s_uop0[s], s_cyc[s], s_first[s]
        sf[s, F_DEC], sf[s, F_PFX], sf[s, F_FPDELTA] = s_dec[s], s_pfx[s], s_fpdelta[s]
        sf[s, F_BRANCH], sf[s, F_LEN], sf[s, F_TARGET], sf[s, F_RDTSC] = s_branch[s], s_len[s], s_target[s], rdtsc_sid[s]
        sf[s, F_CROSS] = s_cross[s]
    uf = np.zeros((u_kind.shape[0], NUF), np.int64)
    for u in range(u_kind.shape[0]):
        uf[u, UF_KIND], uf[u, UF_PORTS], uf[u, UF_LAT], uf[u, UF_UNIT], uf[u, UF_OCC] = (
            u_kind[u], u_ports[u], u_lat[u], u_unit[u], u_occ[u])
    # the register operands regrouped per op (the lowering lists them per instruction, each naming
    # its op), in the lowering's order: op u reads rows uf[u, UF_SRCS] .. uf[u, UF_DSTS] - 1 and
    # writes rows .. uf[u, UF_DSTS_END] - 1 (register id, byte/flag mask, x87 relative index); rows
    # sf[s, F_GPRS] .. sf[s, F_GPRS_END] - 1 are static s's GPR destinations (id, bytes written)
    nrows = 0
    for s in range(nstatic):
        nrows += s_nsrc[s] + 2 * s_ndst[s]
    opnd = np.zeros((nrows, 3), np.int64)
    row = 0
    for s in range(nstatic):
        for k in range(s_nuops[s]):
            u = s_uop0[s] + k
            uf[u, UF_SRCS] = row
            for j in range(s_nsrc[s]):
                if s_src[s, j, 2] == k:
                    opnd[row, 0], opnd[row, 1], opnd[row, 2] = s_src[s, j, 0], s_src[s, j, 1], s_src[s, j, 3]
                    row += 1
            uf[u, UF_DSTS] = row
            for j in range(s_ndst[s]):
                if s_dst[s, j, 2] == k:
                    opnd[row, 0], opnd[row, 1], opnd[row, 2] = s_dst[s, j, 0], s_dst[s, j, 1], s_dst[s, j, 3]
                    row += 1
            uf[u, UF_DSTS_END] = row
        sf[s, F_GPRS] = row
        for j in range(s_ndst[s]):
            if s_dst[s, j, 0] < 8:
                opnd[row, 0], opnd[row, 1] = s_dst[s, j, 0], s_dst[s, j, 1]
                row += 1
        sf[s, F_GPRS_END] = row
    quads, sq_n = P[P_QUADS], P[P_SQ]
    d_levels = dconfig.shape[0]
    n_acc = mem_insn.shape[0]

    bht_mask = P[P_BHT] - 1
    hist_mask = (1 << P[P_HIST_BITS]) - 1
    btc_ways = P[P_BTC]
    rsb_n = P[P_RSB]
    fp_top = sv[V_FP_TOP]
    nq = sv[V_NQ]
    q_slot = sv[V_Q_SLOT]
    q_entry = sv[V_Q_ENTRY]
    prev_entry = sv[V_PREV_ENTRY]
    nstores = sv[V_NSTORES]
    sq_pos = sv[V_SQ_POS]  # nstores % sq_n, kept incrementally
    last_commit = sv[V_LAST_COMMIT]
    fw_n = sv[V_FW_N]
    l1_fill_seen = sv[V_L1_FILL_SEEN]
    ghist = sv[V_GHIST]
    rsb_top = sv[V_RSB_TOP]
    dec_free = sv[V_DEC_FREE]    # first cycle the decoders can start a new group
    fe_ready = sv[V_FE_READY]    # first cycle the front end has bytes after a redirect or an L1I miss
    fe_cause = sv[V_FE_CAUSE]    # what set fe_ready: 1 mispredict, 2 fetch (L1I miss, BTC miss)
    grp_cycle = sv[V_GRP_CYCLE]
    grp_open = sv[V_GRP_OPEN] != 0  # the current group has the second short decoder free
    hold_psid = sink if sv[V_HOLD_PSID] == HOLD_SINK else sv[V_HOLD_PSID]  # the sink row moves as statics grow
    hold_cycles = sv[V_HOLD_CYCLES]
    last_retire = sv[V_LAST_RETIRE]
    cur_slot = sv[V_CUR_SLOT]
    seg = sv[V_SEG]
    seg_start = sv[V_SEG_START]
    prev_pc = sv[V_PREV_PC]
    rep_sid = sv[V_REP_SID]
    rep_next = sv[V_REP_NEXT]  # hundredths of a cycle: when the REP loop's latest element was issued
    last_seg = counters.shape[0] - 1
    cs = min(seg, last_seg)  # the counters row: the segment's, the last row once every segment has ended
    nrdtsc = 0
    log_off = dlog[0] == LOG_OFF  # no access log (a log, once on, stays on: replay.logged_service)
    # plain L1 data hits are done inline (shared_core's L1-hit path), with the hierarchy's LRU clock
    # and the hit counts in locals (written back around each service call and at the end); a
    # replayed log says itself which accesses were plain hits: no TLB state then
    l1_ob, l1_row0, l1_set_mask, l1_ways, l1_lru, l1_write_back = l1_geometry(dconfig)
    d_now = dclock[0]
    has_tlb = dconfig[0, CFG_TLB_WAYS] > 0 and dlog[0] != LOG_REPLAY
    l1_load_hits = 0
    l1_store_hits = 0
    acc_next = 0  # the chunk's first access of instruction li (accesses are in program order: mem_insn sorted)

    for li in range(n):
        i = base + li
        sid = dyn_sid[li] & IDX
        pc = np.int64(dyn_pc[li])  # (uint32: pc >> 5 would be uint64, compared with int64 through floats)
        nu = sf[sid, F_NUOPS]
        u0 = sf[sid, F_UOP0] & IDX
        cyc = sf[sid, F_CYC]
        psid = sid if i >= stat_first else sink
        rep_later = rep_sid == sid and prev_pc == pc
        prev_pc = pc
        if rep_sid >= 0 and not rep_later:
            rep_end = -(-rep_next // OCC_SCALE)  # nothing decodes before the REP loop's last element
            if rep_end > dec_free:
                dec_free = rep_end
            rep_sid = -1
        if rep_later:
            # ---- a later element of a REP string: the ROM sequencer's loop, no decode or ops of its
            # own, `rep_element` clocks after the last; its accesses through the memory model
            acc = acc_next
            acc_end = acc
            while acc_end < n_acc and mem_insn[acc_end & IDX] == li:
                acc_end += 1
            acc_next = acc_end
            wait = 0
            if acc_end == acc:
                rep_sid = -1  # the closing execution (ECX = 0): the run ends
                t = -(-rep_next // OCC_SCALE)
            else:
                rep_next += s_rep[sid, R_ELEMENT]
                t = -(-rep_next // OCC_SCALE)
                for j in range(acc, acc_end):
                    a, sz = np.int64(mem_addr[j]), np.int64(mem_size[j])
                    w_ = mem_write[j] != 0
                    row, way = plain_hit(dlog, log_off, dtags, a, sz, l1_ob, l1_row0, l1_set_mask, l1_ways,
                                         (l1_write_back or not w_) and tlb_hit(has_tlb, dconfig, dclock, a))
                    if row >= 0:  # a plain L1 hit: service's updates here (shared_core)
                        if w_:
                            l1_store_hits += 1
                        else:
                            l1_load_hits += 1
                        d_now = l1_hit(dstamps, ddirty, row, way, w_, l1_lru, d_now)
                        r = LOGGED_HIT
                    elif row == REPLAYED_HIT:
                        r = LOGGED_HIT
                    else:
                        dclock[0] = d_now
                        r = _data_service(dlog, log_off, dtags, dstamps, ddirty, dconfig, dclock, dstats, a, sz, w_)
                        d_now = dclock[0]
                    lvl = served_level(r)
                    counters[cs, C_L1D_STORES if w_ else C_L1D_LOADS] += 1
                    walk = 0
                    if tlb_missed(r):  # the walk's own L1 fills are not this access's
                        l1_fill_seen += walk_l1_fills(r)
                        walk = _k6_walk(r, d_levels, t, P, bus, counters, cs)
                    filled = dstats[0, S_FILLS] != l1_fill_seen
                    if walk > 0 and not (lvl > 0 or filled):
                        if not w_:
                            counters[cs, C_STALL_MEMORY] += walk
                            per_static[psid, S_STALL_MEMORY] += walk
                        if walk > wait:
                            wait = walk
                    if lvl > 0 or filled:
                        counters[cs, C_L1D_STORE_MISSES if w_ else C_L1D_LOAD_MISSES] += 1
                        per_static[psid, S_L1D_MISSES] += 1
                        if lvl == d_levels:
                            per_static[psid, S_L2_MISSES] += 1
                        wb1 = _new_writebacks(dstats, wb_seen, 0)
                        wb2 = _new_writebacks(dstats, wb_seen, 1)
                        if not w_ or filled:
                            l1_fill_seen = dstats[0, S_FILLS]
                            w = walk + _k6_miss(r, max(lvl, 1), t + walk, P, bus, wb1, wb2, counters, cs)
                        else:  # a write not allocated: one write on the front-side bus
                            b = max(t + walk, bus[0])
                            extra = dram_busy(r, P[P_DRAM_LINE], P[P_DRAM_LINE_HIT], P[P_DRAM_WB], P[P_DRAM_WB_HIT])
                            bus[0] = b + P[P_BUS_WRITE] + extra + wb1 * P[P_BOARD_BUSY]
                            w = b + P[P_BUS_WRITE] - t
                            counters[cs, C_BUS_WRITES] += 1
                        if not w_:
                            counters[cs, C_STALL_MEMORY] += w
                            per_static[psid, S_STALL_MEMORY] += w
                        if w > wait:
                            wait = w  # the loop waits for its memory
                rep_next += wait * OCC_SCALE
            done = t + wait + 1
            for j in range(s_ndst[sid]):
                rid = s_dst[sid, j, 0] & IDX
                if rid < NREGS and rid != REG_ST0:
                    reg_ready[rid] = done
            if done > last_retire:
                last_retire = done
            if t > dec_free:
                dec_free = t
            grp_open = False
            if t > last_commit:
                last_commit = t
            counters[cs, C_INSTRUCTIONS] += 1
            per_static[psid, S_EXECUTIONS] += 1
            per_static[psid, S_ISSUE_TO_RETIRE] += done - t
            per_static[psid, S_DECODE_TO_RETIRE] += done - t
            k = i - tl_first
            if 0 <= k < timeline.shape[0]:
                for col, v in enumerate((i, np.int64(sid), t, t, t, done - 1, done, np.int64(0))):
                    timeline[k, col] = v
            if seg < seg_end.shape[0] and i + 1 == seg_end[seg]:
                counters[cs, C_CYCLES] = last_retire - seg_start
                seg_start = last_retire
                seg += 1
                cs = min(seg, last_seg)
            continue

        # ---- fetch: the L1I ----------------------------------------------------------------------
        # Only code fills the L1I, so a line that hit stays resident until the next miss: `known`
        # remembers such lines and skips their lookups (their LRU refresh is lost, which matters
        # only for code larger than the 32 KB L1I).
        iline = pc >> 5
        if known[iline & 63] != iline:
            known[iline & 63] = iline
            if served_level(service(itags, istamps, idirty, iconfig, iclock, istats, pc, 1, False)) > 0:
                known[:] = -1
                known[iline & 63] = iline
                counters[cs, C_L1I_MISSES] += 1
                t = max(dec_free, fe_ready) + P[P_IMISS]
                if t > fe_ready:
                    fe_ready = t
                    fe_cause = 2
                grp_open = False

        # ---- decode: join the open group in the second short decoder, or start an opquad -------
        new_quad = not (cyc == 0 and grp_open and sf[sid, F_FIRST] == 0)
        cross = sf[sid, F_CROSS]  # decode clocks added by length bytes across an I-cache line
        cause_alloc = 0
        if new_quad:
            d = dec_free
            if fe_ready > d:
                counters[cs, C_STALL_MISPREDICT if fe_cause == 1 else C_STALL_FETCH] += fe_ready - d
                if fe_cause == 1:
                    per_static[psid, S_STALL_MISPREDICT] += fe_ready - d
                d = fe_ready
                cause_alloc = 1 if fe_cause == 2 else 8
            free_at = qring[q_slot] if nq >= quads else 0
            entry = max(d + 1 + cross, free_at)
            if free_at > d + 1 + cross:
                counters[cs, C_STALL_ROB] += free_at - (d + 1 + cross)
                per_static[psid, S_STALL_WINDOW] += free_at - (d + 1 + cross)
                cause_alloc = 2
            if nq > 0:
                # the scheduler could take an opquad but the decoders have none (redirects apart):
                # charged to the multi-clock decode that held the decoders, if any, else to this one
                starved = min(d, dec_free) + 1 - max(prev_entry + 1, free_at)
                if starved > 0:
                    counters[cs, C_STALL_DECODE] += starved
                    held = min(starved, hold_cycles) if hold_psid >= 0 else 0
                    if held > 0:
                        per_static[hold_psid, S_STALL_DECODE] += held
                    per_static[psid, S_STALL_DECODE] += starved - held
            busy = max(cyc, 1) + cross  # decode clocks of this group so far
            hold_psid = psid if busy > 1 else -1
            hold_cycles = busy - 1
            prev_entry = entry
            q_entry = entry
            cur_slot = q_slot
            q_slot = q_slot + 1 if q_slot + 1 < quads else 0
            nq += 1
            dec_free = max(d + busy, entry)  # the decoder holds its group until it enters
            grp_cycle = d
            grp_open = cyc == 0
            counters[cs, C_DECODE_GROUPS] += 1
            counters[cs, C_NOP_SLOTS] += 4 - nu
            slot = 0
        else:
            d = grp_cycle
            entry = q_entry
            grp_open = False
            dec_free += cross  # the open group takes the extra clock; its ops still enter with it
            counters[cs, C_NOP_SLOTS] -= nu
            slot = 1
        if sf[sid, F_DEC] == DEC_MSROM:
            counters[cs, C_MSROM_UOPS] += nu
            counters[cs, C_VECTOR_CYCLES] += cyc
            per_static[psid, S_MSROM] += 1
        else:
            counters[cs, C_DECODER0 + slot] += 1
            per_static[psid, S_DECODER0 + slot] += 1
        counters[cs, C_LCP_STALLS] += sf[sid, F_PFX]

        # ---- ops: issue, execute ---------------------------------------------------------------
        top_before = fp_top
        top_after = (fp_top - sf[sid, F_FPDELTA]) & 7
        acc = acc_next
        acc_end = acc
        while acc_end < n_acc and mem_insn[acc_end & IDX] == li:
            acc_end += 1
        acc_next = acc_end
        intra = 0           # latest result of this instruction's earlier ops (the op chain)
        inst_complete = entry
        first_dispatch = entry
        branch_done = 0
        store_ready = -1    # issue cycle of the store op (its data is in the queue from then)
        cause_disp = 0
        for k in range(nu):
            u = (u0 + k) & IDX
            kind = uf[u, UF_KIND]
            ready = entry + 1
            partial = 0
            for j in range(uf[u, UF_SRCS] & IDX, uf[u, UF_DSTS]):
                rid = _slot_of(opnd[j, 0] & IDX, top_before, opnd[j, 2])
                r = reg_ready[rid]
                if rid < 8 and (opnd[j, 1] & ~reg_pmask[rid]) != 0:
                    r += P[P_PARTIAL]  # merge a partial write (k6_machine.toml [partial_register])
                    if r > ready:
                        partial = max(partial, min(P[P_PARTIAL], r - ready))
                if r > ready:
                    ready = r
            if kind != LOAD and intra > ready:
                ready = intra  # the instruction's own earlier ops (load -> ALU -> store)
            dep_wait = ready - (entry + 1)
            if kind == STA and nstores >= sq_n and sq_ring[sq_pos & IDX] > ready:
                w = sq_ring[sq_pos & IDX]
                counters[cs, C_STALL_STORE_BUFFER] += w - ready
                ready = w
            unit = uf[u, UF_UNIT] & IDX
            ports = uf[u, UF_PORTS]
            rdy_u = ready
            if unit != U_NONE and unit != U_HOLD and unit_free[unit] > rdy_u:
                rdy_u = unit_free[unit]
            port = -1
            if ports == 0:
                disp = rdy_u if unit != U_NONE else entry  # MOV r,imm and NOP complete at decode
            elif unit == U_HOLD and uf[u, UF_OCC] > 1:
                disp, port = _book_run(book, ports, rdy_u, uf[u, UF_OCC])
            else:
                disp, port = _book_port(book, ports, rdy_u)
            if unit != U_NONE and unit != U_HOLD:
                unit_free[unit] = disp + uf[u, UF_OCC]
            lat = uf[u, UF_LAT]
            mem_wait = 0
            fwd_wait = 0
            if kind == LOAD:
                j = _access_of(mem_write, acc, acc_end, False)
                if j >= 0:
                    acc = j + 1
                    a, sz = np.int64(mem_addr[j]), np.int64(mem_size[j])
                    e = queued_store(fw_addr, fw_size, fw_commit, fw_n, a, sz, disp)
                    if e >= 0:  # the queued store's data, with the ordinary load latency
                        counters[cs, C_STORE_FORWARDS] += 1
                        fwd_wait = max(0, fw_ready[e] - disp)
                        counters[cs, C_STALL_STORE_FORWARD] += fwd_wait
                        per_static[psid, S_STALL_STORE_FORWARD] += fwd_wait
                    row, way = plain_hit(dlog, log_off, dtags, a, sz, l1_ob, l1_row0, l1_set_mask, l1_ways,
                                         tlb_hit(has_tlb, dconfig, dclock, a))
                    if row >= 0:  # a plain L1 hit: service's updates here (shared_core)
                        l1_load_hits += 1
                        d_now = l1_hit(dstamps, ddirty, row, way, False, l1_lru, d_now)
                        r = LOGGED_HIT
                    elif row == REPLAYED_HIT:
                        r = LOGGED_HIT
                    else:
                        dclock[0] = d_now
                        r = _data_service(dlog, log_off, dtags, dstamps, ddirty, dconfig, dclock, dstats, a, sz, False)
                        d_now = dclock[0]
                    lvl = served_level(r)
                    counters[cs, C_L1D_LOADS] += 1
                    walk = 0
                    if tlb_missed(r):  # the walk's own L1 fills are not this access's
                        l1_fill_seen += walk_l1_fills(r)
                        walk = _k6_walk(r, d_levels, disp, P, bus, counters, cs)
                        mem_wait = walk
                        if lvl == 0 and fwd_wait == 0:
                            counters[cs, C_STALL_MEMORY] += walk
                            per_static[psid, S_STALL_MEMORY] += walk
                    if lvl > 0:
                        counters[cs, C_L1D_LOAD_MISSES] += 1
                        per_static[psid, S_L1D_MISSES] += 1
                        wb1 = _new_writebacks(dstats, wb_seen, 0)
                        wb2 = _new_writebacks(dstats, wb_seen, 1)
                        l1_fill_seen = dstats[0, S_FILLS]
                        mem_wait = walk + _k6_miss(r, lvl, disp + walk, P, bus, wb1, wb2, counters, cs)
                        if lvl == d_levels:
                            per_static[psid, S_L2_MISSES] += 1
                        if fwd_wait == 0:
                            counters[cs, C_STALL_MEMORY] += mem_wait
                            per_static[psid, S_STALL_MEMORY] += mem_wait
            complete = disp + lat + max(mem_wait, fwd_wait)
            if kind == STA:
                store_ready = disp
            else:
                intra = max(intra, complete)
            if kind == BRANCH:
                branch_done = complete
            for j in range(uf[u, UF_DSTS] & IDX, uf[u, UF_DSTS_END]):
                reg_ready[_slot_of(opnd[j, 0] & IDX, top_after, opnd[j, 2])] = complete
            if port >= 0:
                counters[cs, C_PORT0 + port] += 1
                per_static[psid, S_PORT0 + port] += 1
            elif unit == U_FPU:
                counters[cs, C_FPU_OPS] += 1
                per_static[psid, S_FPU] += 1
            if k == 0:
                first_dispatch = disp
            if partial > 0:
                counters[cs, C_STALL_PARTIAL_REGISTER] += partial
                per_static[psid, S_STALL_PARTIAL] += partial
                cause_disp = max(cause_disp, 3)
            if dep_wait - partial > 0:
                counters[cs, C_STALL_DEPENDENCY] += dep_wait - partial
                per_static[psid, S_STALL_DEPENDENCY] += dep_wait - partial
                cause_disp = max(cause_disp, 4)
            if disp - ready > 0:
                counters[cs, C_STALL_PORT] += disp - ready
                per_static[psid, S_STALL_PORT] += disp - ready
                cause_disp = max(cause_disp, 5)
            if mem_wait > 0:
                cause_disp = max(cause_disp, 6)
            if fwd_wait > 0:
                cause_disp = max(cause_disp, 7)
            if complete > inst_complete:
                inst_complete = complete

        # ---- retire: in order, one opquad per cycle ---------------------------------------------
        rt = inst_complete + 1
        floor = last_retire + 1 if new_quad else last_retire
        if rt < floor:
            rt = floor
        last_retire = rt
        qring[cur_slot] = rt
        for j in range(sf[sid, F_GPRS] & IDX, sf[sid, F_GPRS_END]):
            reg_pmask[opnd[j, 0] & IDX] = opnd[j, 1]
        fp_top = top_after

        # ---- stores: commit to L1 after retirement, in order -----------------------------------
        if store_ready >= 0:
            commit = max(rt, last_commit + 1)
            j = _access_of(mem_write, acc, acc_end, True)
            if j >= 0:
                a, sz = np.int64(mem_addr[j]), np.int64(mem_size[j])
                row, way = plain_hit(dlog, log_off, dtags, a, sz, l1_ob, l1_row0, l1_set_mask, l1_ways,
                                     l1_write_back and tlb_hit(has_tlb, dconfig, dclock, a))
                if row >= 0:  # a plain L1 hit: service's updates here (shared_core)
                    l1_store_hits += 1
                    d_now = l1_hit(dstamps, ddirty, row, way, True, l1_lru, d_now)
                    r = LOGGED_HIT
                elif row == REPLAYED_HIT:
                    r = LOGGED_HIT
                else:
                    dclock[0] = d_now
                    r = _data_service(dlog, log_off, dtags, dstamps, ddirty, dconfig, dclock, dstats, a, sz, True)
                    d_now = dclock[0]
                lvl = served_level(r)
                counters[cs, C_L1D_STORES] += 1
                if tlb_missed(r):  # translated at commit (a simplification); the walk's L1 fills are not the store's
                    l1_fill_seen += walk_l1_fills(r)
                    commit += _k6_walk(r, d_levels, commit, P, bus, counters, cs)
                if lvl > 0 or dstats[0, S_FILLS] != l1_fill_seen:
                    counters[cs, C_L1D_STORE_MISSES] += 1
                    per_static[psid, S_L1D_MISSES] += 1
                    wb1 = _new_writebacks(dstats, wb_seen, 0)
                    wb2 = _new_writebacks(dstats, wb_seen, 1)
                    if dstats[0, S_FILLS] != l1_fill_seen:  # write-allocate: fetch the line first
                        l1_fill_seen = dstats[0, S_FILLS]
                        commit += _k6_miss(r, max(lvl, 1), commit, P, bus, wb1, wb2, counters, cs)
                    else:  # not allocated: one write on the front-side bus
                        s = max(commit, bus[0])
                        extra = dram_busy(r, P[P_DRAM_LINE], P[P_DRAM_LINE_HIT], P[P_DRAM_WB], P[P_DRAM_WB_HIT])
                        bus[0] = s + P[P_BUS_WRITE] + extra + wb1 * P[P_BOARD_BUSY]
                        commit = s + P[P_BUS_WRITE]
                        counters[cs, C_BUS_WRITES] += 1
                    if lvl == d_levels:
                        per_static[psid, S_L2_MISSES] += 1
                fw_n = remember_store(fw_addr, fw_size, fw_ready, fw_commit, fw_n, a, sz, store_ready, commit)
            sq_ring[sq_pos & IDX] = commit
            sq_pos = sq_pos + 1 if sq_pos + 1 < sq_n else 0
            nstores += 1
            last_commit = commit

        if s_rep[sid, R_KIND] != REP_NONE:
            # the first element of a REP string: the ROM sequencer's loop starts after it
            rep_sid = sid
            rep_next = (inst_complete + s_rep[sid, R_START]) * OCC_SCALE

        # ---- branches: predicted at decode, resolved by the branch op ---------------------------
        br = sf[sid, F_BRANCH]
        if br != BR_NONE:
            counters[cs, C_BRANCHES] += 1
            fall = pc + sf[sid, F_LEN]
            nxt = dyn_pc[li + 1] if li + 1 < n else (next_pc if next_pc >= 0 else fall)
            taken = nxt != fall
            predict_taken = True
            mispredicted = False
            if br == BR_COND:
                h = (pc ^ ghist) & bht_mask
                cnt = bht[h]
                predict_taken = cnt >= 2
                bht[h] = min(3, cnt + 1) if taken else max(0, cnt - 1)
                ghist = ((ghist << 1) | (1 if taken else 0)) & hist_mask
                mispredicted = predict_taken != taken
            elif br == BR_RET:
                rsb_top -= 1
                mispredicted = rsb_top < 0 or rsb[rsb_top % rsb_n] != nxt
                if rsb_top < 0:
                    rsb_top = 0
            else:
                if br == BR_CALL:
                    rsb[rsb_top % rsb_n] = fall
                    rsb_top += 1
                if sf[sid, F_TARGET] < 0 or br == BR_INDIRECT:  # target unknown at decode: the BTC's guess
                    mispredicted = True
                    for w in range(btc_ways):
                        if btc_tag[0, w] == pc:  # a branch has at most one entry (allocated on a miss)
                            mispredicted = btc_target[w] != nxt
                            break
            way = -1
            hit = False
            if taken:
                for w in range(btc_ways):
                    if btc_tag[0, w] == pc:
                        way = w
                        btc_stamp[0, w] = i
                        break
                hit = way >= 0
                if not hit:
                    way = btb_alloc(btc_tag, btc_stamp, 0, btc_ways, pc, i)
                btc_target[way] = nxt
            if mispredicted:
                counters[cs, C_MISPREDICTS] += 1
                per_static[psid, S_MISPREDICTS] += 1
                restart = (branch_done if branch_done > 0 else inst_complete) + P[P_MISPREDICT]
                if restart > fe_ready:
                    fe_ready = restart
                    fe_cause = 1
                grp_open = False
            elif predict_taken and taken:
                bubble = d + 1 + (0 if hit else P[P_BTC_MISS])
                if bubble > fe_ready:
                    fe_ready = bubble
                    fe_cause = 2
                grp_open = False

        # ---- RDTSC values, timeline, per-static sums, segments ---------------------------------
        if sf[sid, F_RDTSC] == 1 and nrdtsc < rdtsc_out.shape[0]:
            rdtsc_out[nrdtsc] = first_dispatch  # what the guest's RDTSC reads in the replay
            nrdtsc += 1
        counters[cs, C_INSTRUCTIONS] += 1
        counters[cs, C_UOPS] += nu
        per_static[psid, S_EXECUTIONS] += 1
        per_static[psid, S_UOPS] += nu
        per_static[psid, S_ISSUE_TO_RETIRE] += rt - first_dispatch
        per_static[psid, S_DECODE_TO_RETIRE] += rt - d
        k = i - tl_first
        if 0 <= k < timeline.shape[0]:
            cause = cause_disp if cause_disp > 0 else cause_alloc
            for col, v in enumerate((i, np.int64(sid), d, entry, first_dispatch, inst_complete, rt, cause)):
                timeline[k, col] = v
        if seg < seg_end.shape[0] and i + 1 == seg_end[seg]:
            counters[cs, C_CYCLES] = last_retire - seg_start
            seg_start = last_retire
            seg += 1
            cs = min(seg, last_seg)

    dclock[0] = d_now
    add_l1_hits(dstats, l1_load_hits, l1_store_hits)
    sv[V_FP_TOP] = fp_top
    sv[V_NQ] = nq
    sv[V_Q_SLOT] = q_slot
    sv[V_Q_ENTRY] = q_entry
    sv[V_PREV_ENTRY] = prev_entry
    sv[V_NSTORES] = nstores
    sv[V_SQ_POS] = sq_pos
    sv[V_LAST_COMMIT] = last_commit
    sv[V_FW_N] = fw_n
    sv[V_L1_FILL_SEEN] = l1_fill_seen
    sv[V_GHIST] = ghist
    sv[V_RSB_TOP] = rsb_top
    sv[V_DEC_FREE] = dec_free
    sv[V_FE_READY] = fe_ready
    sv[V_FE_CAUSE] = fe_cause
    sv[V_GRP_CYCLE] = grp_cycle
    sv[V_GRP_OPEN] = 1 if grp_open else 0
    sv[V_HOLD_PSID] = HOLD_SINK if hold_psid == sink else hold_psid
    sv[V_HOLD_CYCLES] = hold_cycles
    sv[V_LAST_RETIRE] = last_retire
    sv[V_CUR_SLOT] = cur_slot
    sv[V_SEG] = seg
    sv[V_SEG_START] = seg_start
    sv[V_PREV_PC] = prev_pc
    sv[V_REP_SID] = rep_sid
    sv[V_REP_NEXT] = rep_next
    return last_retire


@uncounted
def _warm_access(dtags, dstamps, ddirty, dconfig, dclock, dstats, a, size, w, wb_seen, l1_fill_seen):
    """One access of :func:`warm`: service, and the bookkeeping simulate keeps of the fills and
    writebacks it has charged (the same at every access site). Returns the new l1_fill_seen."""
    r = service(dtags, dstamps, ddirty, dconfig, dclock, dstats, a, size, w)
    if tlb_missed(r):  # the walk's own L1 fills are not this access's
        l1_fill_seen += walk_l1_fills(r)
    filled = dstats[0, S_FILLS] != l1_fill_seen
    if served_level(r) > 0 or filled:
        _new_writebacks(dstats, wb_seen, 0)
        _new_writebacks(dstats, wb_seen, 1)
        if not w or filled:
            l1_fill_seen = dstats[0, S_FILLS]
    return l1_fill_seen


@njit(cache=True, nogil=True)
def warm(base, next_pc, dyn_sid, dyn_pc, mem_insn, mem_addr, mem_size, mem_write, seg_end,
         s_len, s_pc, s_dec, s_lcp, s_branch, s_target, s_fpdelta, s_zero, s_nuops, s_uop0, s_nsrc, s_src,
         s_ndst, s_dst, u_kind, u_ports, u_lat, u_unit, u_occ, s_rep, s_cyc, s_first, s_pfx, s_cross,
         P, dtags, dstamps, ddirty, dconfig, dclock, dstats, itags, istamps, idirty, iconfig, iclock, istats,
         sv, reg_ready, reg_pmask, book, unit_free, qring, sq_ring, bus, fw_addr,
         fw_size, fw_ready, fw_commit, wb_seen, bht, btc_tag, btc_stamp, btc_target, rsb, known):
    """Instructions base .. base + len(dyn_sid) - 1 as a warm-up (CoreSession.warm): what simulate
    does to the caches, TLB, DRAM pages, L1I, BHT, global history, BTC, return stack, x87 top and
    its count of the fills and writebacks charged, in its order (a REP string's later elements'
    accesses in turn; an instruction's loads, one per load op, then its store; the fetch line
    before them), and nothing it times. The hierarchy is walked through service for every access,
    which leaves what simulate's inline L1-hit path leaves. The session drains the timing state
    after it (tests/test_warm_start.py: the same learned state as timing the chunk)."""
    n = dyn_sid.shape[0]
    bht_mask = P[P_BHT] - 1
    hist_mask = (1 << P[P_HIST_BITS]) - 1
    btc_ways = P[P_BTC]
    rsb_n = P[P_RSB]
    fp_top = sv[V_FP_TOP]
    ghist = sv[V_GHIST]
    rsb_top = sv[V_RSB_TOP]
    l1_fill_seen = sv[V_L1_FILL_SEEN]
    prev_pc = sv[V_PREV_PC]
    rep_sid = sv[V_REP_SID]
    acc_next = 0
    for li in range(n):
        i = base + li
        sid = dyn_sid[li] & IDX
        pc = dyn_pc[li]
        rep_later = rep_sid == sid and prev_pc == pc
        prev_pc = pc
        if rep_sid >= 0 and not rep_later:
            rep_sid = -1
        acc = acc_next
        acc_end = access_end(mem_insn, acc, li)
        acc_next = acc_end
        if rep_later:
            if acc_end == acc:
                rep_sid = -1  # the closing execution
            for j in range(acc, acc_end):
                l1_fill_seen = _warm_access(dtags, dstamps, ddirty, dconfig, dclock, dstats, np.int64(mem_addr[j]),
                                            np.int64(mem_size[j]), mem_write[j] != 0, wb_seen, l1_fill_seen)
            continue
        iline = pc >> 5
        if known[iline & 63] != iline:
            known[iline & 63] = iline
            if served_level(service(itags, istamps, idirty, iconfig, iclock, istats, pc, 1, False)) > 0:
                known[:] = -1
                known[iline & 63] = iline
        is_store = False
        u0 = s_uop0[sid] & IDX
        for k in range(s_nuops[sid]):
            kind = u_kind[(u0 + k) & IDX]
            if kind == LOAD:
                j = _access_of(mem_write, acc, acc_end, False)
                if j >= 0:
                    acc = j + 1
                    l1_fill_seen = _warm_access(dtags, dstamps, ddirty, dconfig, dclock, dstats, np.int64(mem_addr[j]),
                                                np.int64(mem_size[j]), False, wb_seen, l1_fill_seen)
            elif kind == STA:
                is_store = True
        if is_store:
            j = _access_of(mem_write, acc, acc_end, True)
            if j >= 0:
                l1_fill_seen = _warm_access(dtags, dstamps, ddirty, dconfig, dclock, dstats, np.int64(mem_addr[j]),
                                            np.int64(mem_size[j]), True, wb_seen, l1_fill_seen)
        fp_top = (fp_top - s_fpdelta[sid]) & 7
        if s_rep[sid, R_KIND] != REP_NONE:
            rep_sid = sid
        br = s_branch[sid]
        if br != BR_NONE:
            fall = pc + s_len[sid]
            nxt = dyn_pc[li + 1] if li + 1 < n else (next_pc if next_pc >= 0 else fall)
            _, _, _, ghist, rsb_top = _predict(br, pc, nxt, fall, i, s_target[sid], ghist, bht, bht_mask, hist_mask,
                                               rsb, rsb_top, rsb_n, btc_tag, btc_stamp, btc_target, btc_ways)
    sv[V_SEG] = segments_ended(seg_end, sv[V_SEG], base + n)
    sv[V_FP_TOP] = fp_top
    sv[V_GHIST] = ghist
    sv[V_RSB_TOP] = rsb_top
    sv[V_L1_FILL_SEEN] = l1_fill_seen
    sv[V_PREV_PC] = prev_pc
    sv[V_REP_SID] = rep_sid
