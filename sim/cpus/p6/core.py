"""The compiled P6 cycle model: one pass over the dynamic instruction stream, in program order.

Each uop gets five times: decode, allocate (rename into ROB and RS), dispatch (to a port),
complete, retire. Every time is the maximum of the constraints that apply to it, so the reason a
uop waited is the constraint that set its time; those reasons are the stall counters.

Front end: 16-byte IFETCH blocks that start at an instruction boundary (at the aligned chunk after
a fetch restart), three decoders with the 4-1-1 rule (decoder 0 takes 1-4 uops, decoders 1 and 2
only 1-uop instructions, in order), microcode sequencer for longer instructions
(alone, MSROM_RATE uops per cycle), a decode group ends at a taken branch (plus a fetch bubble) and
at a length-changing prefix (plus a penalty); a decoded-uop queue of QUEUE uops.
Back end: RENAME uops per cycle into a ROB of ROB entries and an RS of RS entries; ports 0-4
(bit masks per uop), one uop per port per cycle, oldest uop first; a uop that may use port 0 or 1
is bound to one of them as it enters the RS, by the counts of uops waiting for each
(:func:`_bind_port`, Intel patent US 5,689,674), and waits for that port; the uops of one instruction
form a chain (each compute uop and the store data wait for the instruction's earlier loads and
compute uops; see sim/cpus/lowering.py); non-pipelined resources held for a row's measured
reciprocal throughput (divider, FP multiplier, microcoded instructions; counted in hundredths of a
cycle so fractional throughputs average out); RETIRE uops per cycle in order. Partial-register and partial-flags
reads wait at rename until the partial writer has retired. Loads wait for every older store
address (no memory disambiguation on P6), take forwarded data from a matching older store, and
wait for a mismatching one to reach the cache. Stores commit to L1 after retirement through a
store buffer of SB entries.
Memory: the data hierarchy of sim.memory (L1D, L2 when present), a fill-buffer limit of MSHR
outstanding misses, a backside-bus occupancy per L2 line and a front-side-bus occupancy per DRAM
line fill and writeback; a data-TLB miss runs its page walk before the access (TLB_WALK cycles, then
each walk read that missed L1 charged as a load, in _access_slow; the inline L1-hit path probes the
TLB as service does; a store's walk at commit; walks are not serialised). Instruction fetch goes through its own
L1I, which misses to the L2 (no instruction TLB).
Branches: BTB of BTB_SETS x BTB_WAYS entries with HIST_BITS of local history and a table of 2-bit
counters per entry (two-level adaptive); static prediction on a BTB miss (backward taken); a
return stack; the front end restarts MISPREDICT cycles after a mispredicted branch executes.
REP strings: the trace holds one execution per element. The first is decoded and runs its row's
uops; the later ones are the microcode loop's (simulate's `rep_later` branch): no decode and no uops of
their own, each `rep_element` clocks after the last (after the row's start-up), its accesses through the
memory model (the loop waits for a miss). Fast strings (REP MOVS/STOS, rows with
`fast_string_startup`; Intel SDM vol. 3 sec. 8.2.4, Agner Fog sec. 26.3): when ESI and EDI are
8-aligned, |EDI - ESI| >= 32, the copy runs forward and ECX >= 64, the elements take the row's
throughput and the run the fast start-up. ECX is known only when the run ends, so the loop charges
the fast rate from the second element (when the direction is known) and either adds the fast
start-up at the 64th element or, when the run ends shorter, the rest of the slow rate: the run's
total is the source's either way. Nothing after the run decodes before its last element.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from sim.memory.hierarchy import (
    memory_fill_page_hits, memory_fills, memory_writeback_page_hits, memory_writebacks, served_level, service,
    CFG_TLB_WAYS, tlb_missed, walk_pde_level, walk_pte_level, walk_read_result,
)
from sim.memory.replay import LOG_OFF, LOG_REPLAY, logged_service
from sim.cpus.lowering import (
    BR_CALL, BR_COND, BR_INDIRECT, BR_NONE, BR_RET, BRANCH, DEC_MSROM, DEC_SIMPLE, LOAD, NREGS, OCC_SCALE,
    R_ELEMENT, R_FAST, R_FAST_START, R_KIND, R_START, REG_FLAGS, REG_ST0, REP_FAST, REP_NONE, SIDE, STA, STD,
    REG_X87_ORDER, REG_FPSW, REG_MM0, REG_OTHER,
)
from sim.cpus.contract import (
    C_NAMES, NC, C_CYCLES, C_INSTRUCTIONS, C_UOPS, C_DECODE_GROUPS, C_DECODER0, C_DECODER1, C_DECODER2,
    C_MSROM_UOPS, C_PORT0, C_PORT1, C_PORT2, C_PORT3, C_PORT4, C_STALL_DECODE, C_STALL_ROB, C_STALL_RS,
    C_STALL_STORE_BUFFER, C_STALL_PARTIAL_REGISTER, C_STALL_PARTIAL_FLAGS, C_STALL_DEPENDENCY, C_STALL_PORT,
    C_STALL_MISPREDICT, C_STALL_MEMORY, C_STALL_STORE_FORWARD, C_BRANCHES, C_MISPREDICTS, C_L1D_LOADS,
    C_L1D_LOAD_MISSES, C_L1D_STORES, C_L1D_STORE_MISSES, C_L2_ACCESSES, C_L2_MISSES, C_DRAM_FILLS,
    C_DRAM_WRITEBACKS, C_DRAM_BUS_CYCLES, C_L1I_MISSES, C_LCP_STALLS, C_STORE_FORWARDS, C_STALL_FETCH,
    C_DRAM_PAGE_HITS, C_DRAM_PAGE_MISSES, C_DTLB_MISSES, C_STALL_REGISTER_READ,
    S_NAMES, NS, S_EXECUTIONS, S_UOPS, S_DECODER0, S_DECODER1, S_DECODER2, S_MSROM, S_ISSUE_TO_RETIRE,
    S_STALL_DEPENDENCY, S_STALL_PORT, S_STALL_DECODE, S_STALL_PARTIAL, S_STALL_MEMORY, S_STALL_MISPREDICT,
    S_MISPREDICTS, S_PORT0, S_PORT1, S_PORT2, S_PORT3, S_PORT4, S_DECODE_TO_RETIRE, S_STALL_STORE_FORWARD,
    S_STALL_WINDOW, S_L1D_MISSES, S_L2_MISSES, T_NAMES, NT, CAUSES,
)
from sim.cpus.shared_core import (
    FW, IDX, REPLAYED_HIT, WINDOW, access_end, add_l1_hits, book_port, btb_alloc, l1_geometry, l1_hit, plain_hit,
    queued_store, remember_store, segments_ended, tlb_hit, uncounted,
)

# parameter vector indices (the counter, per-instruction and timeline schemas are the contract's)
(P_ROB, P_RS, P_RENAME, P_RETIRE, P_QUEUE, P_FETCH_BLOCK, P_L1_LAT, P_L2_LAT, P_DRAM_LAT, P_DRAM_LINE,
 P_DRAM_WB, P_MSHR, P_SB, P_MISPREDICT, P_TAKEN_BUBBLE, P_BTB_SETS, P_BTB_WAYS, P_HIST_BITS, P_PARTIAL_EXTRA,
 P_FWD_FAIL, P_LCP, P_STATIC_REDIRECT, P_HAS_L2, P_L2_BUS, P_RSB, P_MSROM_RATE, P_EXIT_ADDR, P_FWD_LAT,
 P_L2_MISS_DETECT, P_DRAM_LAT_HIT, P_DRAM_LINE_HIT, P_DRAM_WB_HIT, P_BIND_TIE, P_TLB_WALK, P_RRF_READS,
 P_RRF_RECENT) = range(36)
NPARAMS = 36

# Loop-carried scalar state: kept in an int64 vector between calls, so a trace can be timed in
# chunks (a streamed emulation) exactly as in one call (see :func:`new_state`).
(V_FLAGS_MASK, V_FLAGS_RETIRE, V_FP_TOP, V_RS_PENDING, V_RS_TIME, V_NSTORES, V_SB_POS, V_LAST_COMMIT,
 V_LAST_STA_DONE, V_BUS_FREE, V_L2BUS_FREE, V_FW_N, V_RSB_TOP, V_DEC_CYCLE, V_DEC_POS, V_DEC_LIMIT,
 V_FETCH_RESTART, V_FE_READY, V_LAST_ILINE, V_REN_CYCLE, V_REN_COUNT, V_RET_CYCLE, V_RET_COUNT, V_U_GLOBAL,
 V_ROB_POS, V_Q_POS, V_SEG, V_SEG_START_RETIRE, V_MAX_RETIRE, V_PREV_PC, V_REP_SID, V_REP_COUNT, V_REP_NEXT,
 V_REP_MODE, V_REP_ADDR, V_BOUND0, V_BOUND1, V_RR_MASK, V_RR_N, V_RR_GROUP, V_ROOM_FORWARD,
 V_ROOM_REDIRECT) = range(42)
NSTATE = 42
# Rooms: how far two parameters could rise without changing any decision of the run since its
# state was new (a drain renews them), each the least over the events that read the parameter
# (rooms() below; P6Model.repeats proves a re-timing equal to the run with them). The forwarding
# latency and the static redirect bubble are each added to a time that sets another only where it
# is the later: the room is how far short of that the sum came; where it never reached it (a room
# >= 0), lowering the parameter changes nothing either.
ROOM_SLOTS = (V_ROOM_FORWARD, V_ROOM_REDIRECT)
ROOM_NONE = 1 << 40  # no event yet: any change
# V_REP_MODE bits: fast strings possible (kind, alignment, distance), direction seen forward / backward
REP_CAPABLE, REP_FORWARD, REP_BACKWARD = 1, 2, 4
FAST_MIN_COUNT = 64  # fast strings need ECX >= 64 (Intel SDM vol. 3 sec. 8.2.4; Agner Fog sec. 26.3)


def rooms(sv: np.ndarray) -> dict[int, tuple[int, int]]:
    """{parameter index: (down, up)}: the parameter may be lowered by up to `down` or raised by up
    to `up` without changing any decision the run made (the run's state vector `sv`)."""
    forward, redirect = int(sv[V_ROOM_FORWARD]), int(sv[V_ROOM_REDIRECT])
    return {P_FWD_LAT: (ROOM_NONE if forward >= 0 else -1, forward),
            P_STATIC_REDIRECT: (ROOM_NONE if redirect >= 0 else -1, redirect)}


def new_state(P: np.ndarray, units: int) -> tuple:
    """The machine at reset, for :func:`simulate`: the scalar vector, then the arrays in the order
    simulate takes them. `units`: how many non-pipelined resources the program has (ids 1..units);
    :func:`sim.cpus.session.grown_state` makes room for more between calls."""
    sv = np.zeros(NSTATE, np.int64)
    sv[V_FLAGS_MASK] = 0x1FF
    sv[V_DEC_POS] = 3         # slots used in the current decode group (3 = start a new group)
    sv[V_DEC_LIMIT] = -1      # end (exclusive) of the current IFETCH block
    sv[V_FETCH_RESTART] = 1   # fetch (re)starts at an aligned 16-byte chunk: program start, taken branch
    sv[V_LAST_ILINE] = -1
    sv[V_REN_CYCLE] = -1
    sv[V_RET_CYCLE] = -1
    sv[V_PREV_PC] = -1   # the PC of the instruction before the chunk (a REP string's later element)
    sv[V_REP_SID] = -1   # the REP string whose run is open (-1: none)
    for slot in ROOM_SLOTS:
        sv[slot] = ROOM_NONE
    btb_sets, btb_ways, hist_bits = int(P[P_BTB_SETS]), int(P[P_BTB_WAYS]), int(P[P_HIST_BITS])
    rsb = np.zeros(int(P[P_RSB]), np.int64)
    rsb[0] = P[P_EXIT_ADDR]  # the harness's call into the kernel: its return is predictable
    sv[V_RSB_TOP] = 1
    return (sv,
            np.zeros(2 * NREGS, np.int64),        # reg_ready; then each register's writer's rename group
            np.full(NREGS, 15, np.int64),         # reg_pmask: bytes written by the last (partial) writer
            np.zeros(NREGS, np.int64),            # reg_pretire: its retire cycle
            np.zeros(NREGS, np.int64),            # reg_zeroed: upper bytes known zero (XOR/SUB idiom)
            np.zeros(int(P[P_ROB]), np.int64),    # rob_ring
            # RS occupancy: uops allocated but not yet dispatched, counted by dispatch cycle in a ring
            # (exact, like a heap of dispatch times, but O(1) per uop: allocation times only move forward);
            # column 0 every uop, columns 1 and 2 those bound to port 0 and to port 1 (the binding counters)
            np.zeros((WINDOW, 3), np.int64),      # rs_by_cycle
            np.zeros(max(int(P[P_QUEUE]), 1), np.int64),  # queue_ring
            np.full(WINDOW, -1 << 5, np.int64),   # book: port reservations
            np.zeros(units + 1, np.int64),        # unit_free: per resource, hundredths of a cycle
            np.zeros(int(P[P_SB]), np.int64),     # sb_ring
            np.zeros(int(P[P_MSHR]), np.int64),   # mshr
            np.full(FW, -1, np.int64),            # fw_addr
            np.zeros(FW, np.int64),               # fw_size
            np.zeros(FW, np.int64),               # fw_ready
            np.zeros(FW, np.int64),               # fw_commit
            np.full((btb_sets, btb_ways), -1, np.int64),  # btb_tag
            np.zeros((btb_sets, btb_ways), np.int64),     # btb_stamp
            np.zeros((btb_sets, btb_ways), np.int64),     # btb_hist
            np.zeros((btb_sets, btb_ways), np.int64),     # btb_target
            np.full((btb_sets, btb_ways, 1 << hist_bits), 2, np.int64),  # pht
            rsb,
            np.full(16, -1, np.int64))            # iline_seen


QUEUE_RING = 7  # position of queue_ring in new_state's tuple
LEARNED = tuple(range(16, 23))  # btb_tag, btb_stamp, btb_hist, btb_target, pht, rsb, iline_seen
UNIT_FREE = 9  # position of unit_free in new_state's tuple
P01 = 3  # the port mask of a uop that may use port 0 or port 1 (sim/cpus/lowering.py port_mask)


@njit(cache=True, nogil=True, inline="always")
def _rs_leave(rs_by_cycle, cycle, rs_pending, bound0, bound1):
    """The uops that dispatch in `cycle` leave the RS: the occupancy and the two binding counters
    drop by them (their ring slot is cleared for reuse). Returns (rs_pending, bound0, bound1)."""
    slot = cycle & (WINDOW - 1)
    rs_pending -= rs_by_cycle[slot, 0]
    bound0 -= rs_by_cycle[slot, 1]
    bound1 -= rs_by_cycle[slot, 2]
    rs_by_cycle[slot, 0] = 0
    rs_by_cycle[slot, 1] = 0
    rs_by_cycle[slot, 2] = 0
    return rs_pending, bound0, bound1


@njit(cache=True, nogil=True, inline="always")
def _bind_port(ports, bound0, bound1, tie):
    """The port mask a uop is bound to when it enters the RS. Intel patent US 5,689,674 (Griffith,
    Gupta, Hinton; filed 1995): a counter keeps the number of instructions pending dispatch from a
    port, and an instruction is bound to a dispatch port when it is received, by that count
    (docs/sources/p6.md, "Port choice for p01 uops"). A p01 uop goes to the port with fewer uops
    bound to it and not yet dispatched (`bound0`, `bound1`, counted over every uop of the port);
    on equal counts to port `tie` (estimates.p01_tie_port: no source says). It then waits for that
    port even when the other is free. Other masks are a single port: returned as they are."""
    if ports != P01:
        return ports
    if bound0 < bound1 or (bound0 == bound1 and tie == 0):
        return 1
    return 2


@uncounted
def _access_slow(dlog, dtags, dstamps, ddirty, dconfig, dclock, dstats, a, size, is_write, start, P, mshr, bus_free,
                 l2bus_free, counters, per_static, seg, psid):
    """A data access that is not a plain L1 hit (see shared_core.plain_hit), out of the cycle loop (which runs
    faster without this code inline): the hierarchy walk, the miss counts and the miss's extra
    cycles from `start`. Returns (extra, bus_free, l2bus_free)."""
    r = (service(dtags, dstamps, ddirty, dconfig, dclock, dstats, a, size, is_write) if dlog[0] == LOG_OFF
         else logged_service(dlog, dtags, dstamps, ddirty, dconfig, dclock, dstats, a, size, is_write))
    lvl = served_level(r)
    levels = dconfig.shape[0]
    wait = 0
    if tlb_missed(r):
        # the page walk first: its fixed clocks, then the page-directory and page-table reads,
        # each charged as a load served at its level; the access itself starts after it
        counters[seg, C_DTLB_MISSES] += 1
        t = start + P[P_TLB_WALK]
        for wl in (walk_pde_level(r), walk_pte_level(r)):
            if wl > 0:
                extra, bus_free, l2bus_free = _miss_latency(walk_read_result(wl, levels), wl, levels, t, P, mshr,
                                                            bus_free, l2bus_free, counters[seg])
                t += extra
        wait = t - start
    if lvl > 0:
        counters[seg, C_L1D_STORE_MISSES if is_write else C_L1D_LOAD_MISSES] += 1
        per_static[psid, S_L1D_MISSES] += 1
        if lvl == levels:
            per_static[psid, S_L2_MISSES] += 1
        w, bus_free, l2bus_free = _miss_latency(r, lvl, levels, start + wait, P, mshr, bus_free, l2bus_free,
                                                counters[seg])
        wait += w
    if wait > 0 and not is_write:
        counters[seg, C_STALL_MEMORY] += wait
        per_static[psid, S_STALL_MEMORY] += wait
    return wait, bus_free, l2bus_free


@njit(cache=True, nogil=True, inline="always")
def _add_counts(counters, seg, insns, uops, groups, stall_decode, stall_dep, stall_port, loads, stores, branches,
                dec0, dec1, dec2, port0, port1, port2, port3, port4):
    """Add the counts simulate keeps in locals to segment `seg`."""
    counters[seg, C_INSTRUCTIONS] += insns
    counters[seg, C_UOPS] += uops
    counters[seg, C_DECODE_GROUPS] += groups
    counters[seg, C_STALL_DECODE] += stall_decode
    counters[seg, C_STALL_DEPENDENCY] += stall_dep
    counters[seg, C_STALL_PORT] += stall_port
    counters[seg, C_L1D_LOADS] += loads
    counters[seg, C_L1D_STORES] += stores
    counters[seg, C_BRANCHES] += branches
    counters[seg, C_DECODER0] += dec0
    counters[seg, C_DECODER1] += dec1
    counters[seg, C_DECODER2] += dec2
    counters[seg, C_PORT0] += port0
    counters[seg, C_PORT1] += port1
    counters[seg, C_PORT2] += port2
    counters[seg, C_PORT3] += port3
    counters[seg, C_PORT4] += port4

ALWAYS_SCAN = 1 << 8  # see _operand_lists: p_gpr_bits


@njit(cache=True, nogil=True)
def _operand_lists(s_nuops, s_uop0, s_nsrc, s_src, s_ndst, s_dst, u_ports, nuops):
    """Per-uop and per-instruction operand lists, so the loops over them touch only their own
    operands (in the order of the instruction's lists, which some updates depend on):
    - per uop u: its sources (register id, x87 relative index) and destinations, a destination
      list without FXCH's two swapped slots and whether the uop is such a swap;
    - per instruction: the sources and destinations that partial-register/flags tracking sees
      (GPRs and flags), as (register id, mask)."""
    nstatic = s_nuops.shape[0]
    width = max(s_src.shape[1], 1)
    u_nsrc = np.zeros(nuops, np.int64)
    u_src = np.zeros((nuops, width, 2), np.int64)
    u_ndst = np.zeros(nuops, np.int64)
    u_dst = np.zeros((nuops, width, 2), np.int64)
    u_swap = np.zeros(nuops, np.int64)
    p_nsrc = np.zeros(nstatic, np.int64)
    p_src = np.zeros((nstatic, width, 2), np.int64)
    p_ndst = np.zeros(nstatic, np.int64)
    p_dst = np.zeros((nstatic, width, 2), np.int64)
    # when the partial-source scan can find nothing: bits of the GPRs read (and "always scan" for a
    # GPR mask beyond the 4 byte bits), the flags read
    p_gpr_bits = np.zeros(nstatic, np.int64)
    p_flags_read = np.zeros(nstatic, np.int64)
    for sid in range(nstatic):
        nu = s_nuops[sid]
        u0 = s_uop0[sid]
        for j in range(s_nsrc[sid]):
            off = s_src[sid, j, 2]
            if 0 <= off < nu:
                u = u0 + off
                u_src[u, u_nsrc[u], 0] = s_src[sid, j, 0]
                u_src[u, u_nsrc[u], 1] = s_src[sid, j, 3]
                u_nsrc[u] += 1
            rid = s_src[sid, j, 0]
            if rid < 8 or rid == REG_FLAGS:
                p_src[sid, p_nsrc[sid], 0] = rid
                p_src[sid, p_nsrc[sid], 1] = s_src[sid, j, 1]
                p_nsrc[sid] += 1
            if rid < 8:
                p_gpr_bits[sid] |= (1 << rid) | (ALWAYS_SCAN if s_src[sid, j, 1] & ~15 else 0)
            elif rid == REG_FLAGS:
                p_flags_read[sid] |= s_src[sid, j, 1]
        st_pair = s_ndst[sid] >= 2 and s_dst[sid, 0, 0] == REG_ST0 and s_dst[sid, 1, 0] == REG_ST0
        for k in range(nu):
            u = u0 + k
            swap = u_ports[u] == 0 and st_pair
            u_swap[u] = 1 if swap else 0
            for j in range(2 if swap else 0, s_ndst[sid]):
                if s_dst[sid, j, 2] == k:
                    u_dst[u, u_ndst[u], 0] = s_dst[sid, j, 0]
                    u_dst[u, u_ndst[u], 1] = s_dst[sid, j, 3]
                    u_ndst[u] += 1
        for j in range(s_ndst[sid]):
            rid = s_dst[sid, j, 0]
            if rid < 8 or rid == REG_FLAGS:
                p_dst[sid, p_ndst[sid], 0] = rid
                p_dst[sid, p_ndst[sid], 1] = s_dst[sid, j, 1]
                p_ndst[sid] += 1
    return u_nsrc, u_src, u_ndst, u_dst, u_swap, p_nsrc, p_src, p_ndst, p_dst, p_gpr_bits, p_flags_read


@njit(cache=True, nogil=True, inline="always")
def _register_reads(u, u_nsrc, u_src, top, reg_ready, t, old_group, mask, n):
    """Add uop u's reads of completed registers to a rename group's set (`mask`, `n` distinct):
    integer, flags, x87 and MMX/XMM registers, as Agner Fog counts them (the status and control
    words and other pseudo-registers do not count). A register whose writer was renamed in a
    group after `old_group` (reg_ready[NREGS + rid]) or has not completed by cycle t is free."""
    for j in range(u_nsrc[u]):
        rid = u_src[u, j, 0] & IDX
        if rid == REG_ST0:
            rid = REG_ST0 + ((top + u_src[u, j, 1]) & 7)
        if (rid < REG_FPSW or REG_MM0 <= rid < REG_OTHER) and reg_ready[rid] <= t and \
                reg_ready[NREGS + rid] <= old_group:
            bit = np.int64(1) << rid
            if mask & bit == 0:
                mask |= bit
                n += 1
    return mask, n


@uncounted
def _predict(br, pc, length, nxt, i, bset, target, btb_tag, btb_stamp, btb_hist, btb_target, pht, rsb, rsb_top,
             btb_ways, hist_bits):
    """The branch predictors on a branch (kind `br`) at `pc` going to `nxt` (instruction `i`; BTB set
    `bset`; `target`: its direct target, -1 if none): the prediction checked and every table updated,
    in program order (warm). Returns (mispredicted, redirected at decode, return stack top).
    These are simulate's branch-section updates; simulate keeps its own inline copy (the same code
    moved into this helper and called from simulate's loop made the compiled core slower: the speed
    check measured the P6 core 28 % slower, the K6's 7 %), and tests/test_warm_start.py checks that
    the two leave the same tables."""
    taken = nxt != pc + length
    mispredicted = False
    redirect = False
    way = -1
    for w in range(btb_ways):
        if btb_tag[bset, w] == pc:
            way = w
    if br == BR_COND:
        if way >= 0:
            h = btb_hist[bset, way] & IDX
            predict = pht[bset, way, h] >= 2
            cnt = pht[bset, way, h]
            pht[bset, way, h] = min(3, cnt + 1) if taken else max(0, cnt - 1)
            btb_hist[bset, way] = ((h << 1) | (1 if taken else 0)) & ((1 << hist_bits) - 1)
            btb_stamp[bset, way] = i
        else:
            predict = target >= 0 and target < pc  # static: backward taken, forward not taken
            redirect = predict  # a static taken prediction redirects fetch at decode
            if taken:
                way = btb_alloc(btb_tag, btb_stamp, bset, btb_ways, pc, i)
                btb_hist[bset, way] = 1
                for h in range(1 << hist_bits):
                    pht[bset, way, h] = 2
        mispredicted = predict != taken
    elif br == BR_RET:
        predicted_target = -1
        if rsb_top > 0:
            rsb_top -= 1
            predicted_target = rsb[rsb_top % rsb.shape[0]]
        mispredicted = predicted_target != nxt
    else:
        if br == BR_CALL:
            rsb[rsb_top % rsb.shape[0]] = pc + length
            rsb_top += 1
        if way >= 0 and btb_target[bset, way] == nxt:
            btb_stamp[bset, way] = i
        elif br == BR_INDIRECT:
            mispredicted = True
        else:
            redirect = True  # direct target known at decode: a short redirect bubble
        if way < 0:
            way = btb_alloc(btb_tag, btb_stamp, bset, btb_ways, pc, i)
    if way >= 0:
        btb_target[bset, way] = nxt if taken else btb_target[bset, way]
    return mispredicted, redirect, rsb_top


# columns of simulate's per-static rows (sf) and per-uop rows (uf); a row's width is a power of two
(F_S_LEN, F_S_NUOPS, F_S_UOP0, F_S_DEC, F_S_LCP, F_P_GPR_BITS, F_P_FLAGS_READ, F_P_NSRC, F_S_FPDELTA, F_P_NDST,
 F_S_ZERO, F_S_BRANCH, F_S_BSET, F_S_TARGET) = range(14)
NF = 16
UF_U_KIND, UF_U_PORTS, UF_U_LAT, UF_U_UNIT, UF_U_OCC, UF_U_NSRC, UF_U_NDST, UF_U_SWAP = range(8)
NUF = 8


# error_model="numpy": no zero-divisor checks on the loop's divisions (every divisor is a machine
# size that lowering or new_state has already divided by or indexed with); measurably faster
@njit(cache=True, nogil=True, error_model="numpy")
def simulate(base, next_pc, dyn_sid, dyn_pc, mem_insn, mem_addr, mem_size, mem_write, seg_end,
             s_len, s_pc, s_dec, s_lcp, s_branch, s_target, s_fpdelta, s_zero, s_nuops, s_uop0, s_nsrc, s_src,
             s_ndst, s_dst, u_kind, u_ports, u_lat, u_unit, u_occ, s_rep,
             P, dtags, dstamps, ddirty, dconfig, dclock, dstats, itags, istamps, idirty, iconfig, iclock, istats,
             counters, per_static, stat_first, timeline, tl_first, rdtsc_sid, rdtsc_out, dlog,
             sv, reg_ready, reg_pmask, reg_pretire, reg_zeroed, rob_ring, rs_by_cycle, queue_ring, book, unit_free,
             sb_ring, mshr, fw_addr, fw_size, fw_ready, fw_commit, btb_tag, btb_stamp, btb_hist, btb_target, pht,
             rsb, iline_seen, rare):
    """Time instructions base .. base + len(dyn_sid) - 1 of a run, continuing from the state
    (`sv` and the arrays after it, from :func:`new_state`) and leaving it for the next chunk.
    The chunk's arrays are its own (``mem_insn`` counts from the chunk's first instruction);
    everything else counts instructions from the run's start. `next_pc`: the PC of the
    instruction after the chunk, -1 at the end of the run. Returns the latest retire cycle.

    `rare`: None where no REP string, RDTSC or timeline path can run in the chunk and no rooms are
    kept (sim.cpus.p6.model P6Session.rare_paths), else True. numba compiles one version per
    argument type, and the None version leaves the code of those paths out: on the speed check's
    trace it ran 1.13-1.22x as fast, the two alternated in one process. The results are the same
    either way (tests/test_p6_core_paths.py). Only the True version keeps the rooms (ROOM_SLOTS):
    with the same two updates in both, the None version took 53-72 ms for the speed check's trace
    in three processes, against 41-44 ms without them."""
    n = dyn_sid.shape[0]
    sink = (per_static.shape[0] - 1) & IDX  # per-static sums only from stat_first: earlier ones go to this row
    rob_n, rs_n, rename_w, retire_w = P[P_ROB], P[P_RS], P[P_RENAME], P[P_RETIRE]
    queue_n, block = P[P_QUEUE], P[P_FETCH_BLOCK]
    l2_lat = P[P_L2_LAT]
    sb_n = P[P_SB]
    n_acc = mem_insn.shape[0]
    nstatic = s_len.shape[0]
    # per static instruction, what would otherwise be a division per dynamic one: its BTB set
    s_bset = np.zeros(nstatic, np.int64)
    for s in range(nstatic):
        s_bset[s] = s_pc[s] % P[P_BTB_SETS]
    btb_ways, hist_bits = P[P_BTB_WAYS], P[P_HIST_BITS]
    u_nsrc, u_src, u_ndst, u_dst, u_swap, p_nsrc, p_src, p_ndst, p_dst, p_gpr_bits, p_flags_read = _operand_lists(
        s_nuops, s_uop0, s_nsrc, s_src, s_ndst, s_dst, u_ports, u_kind.shape[0])

    # the facts the loop reads per instruction and per uop, one row each (as the K6 core's): one
    # array instead of two dozen keeps fewer values live in the loop
    sf = np.zeros((nstatic, NF), np.int64)
    for s in range(nstatic):
        sf[s, F_S_LEN], sf[s, F_S_NUOPS], sf[s, F_S_UOP0], sf[s, F_S_DEC] = s_len[s], s_nuops[s], s_uop0[s], s_dec[s]
        sf[s, F_S_LCP], sf[s, F_P_GPR_BITS], sf[s, F_P_FLAGS_READ] = s_lcp[s], p_gpr_bits[s], p_flags_read[s]
        sf[s, F_P_NSRC], sf[s, F_S_FPDELTA] = p_nsrc[s], s_fpdelta[s]
        sf[s, F_P_NDST], sf[s, F_S_ZERO] = p_ndst[s], s_zero[s]
        sf[s, F_S_BRANCH], sf[s, F_S_BSET], sf[s, F_S_TARGET] = s_branch[s], s_bset[s], s_target[s]
    uf = np.zeros((u_kind.shape[0], NUF), np.int64)
    for u in range(u_kind.shape[0]):
        uf[u, UF_U_KIND], uf[u, UF_U_PORTS], uf[u, UF_U_LAT] = u_kind[u], u_ports[u], u_lat[u]
        uf[u, UF_U_UNIT], uf[u, UF_U_OCC], uf[u, UF_U_SWAP] = u_unit[u], u_occ[u], u_swap[u]
        uf[u, UF_U_NSRC], uf[u, UF_U_NDST] = u_nsrc[u], u_ndst[u]

    flags_mask = sv[V_FLAGS_MASK]
    flags_retire = sv[V_FLAGS_RETIRE]
    fp_top = sv[V_FP_TOP]
    rs_pending = sv[V_RS_PENDING]  # uops in the RS at cycle rs_time (dispatch cycle > rs_time)
    rs_time = sv[V_RS_TIME]
    bound0 = sv[V_BOUND0]  # of those, the uops bound to port 0 and to port 1 (_bind_port)
    bound1 = sv[V_BOUND1]
    bind_tie = P[P_BIND_TIE]
    rr_mask = sv[V_RR_MASK]  # completed registers the current rename group reads (_register_reads)
    rr_n = sv[V_RR_N]
    rr_group = sv[V_RR_GROUP]  # rename groups so far
    rrf_reads, rrf_recent = P[P_RRF_READS], P[P_RRF_RECENT]
    nstores = sv[V_NSTORES]
    sb_pos = sv[V_SB_POS]  # nstores % sb_n, kept incrementally
    last_commit = sv[V_LAST_COMMIT]
    last_sta_done = sv[V_LAST_STA_DONE]
    bus_free = sv[V_BUS_FREE]
    l2bus_free = sv[V_L2BUS_FREE]
    fw_n = sv[V_FW_N]
    rsb_top = sv[V_RSB_TOP]
    dec_cycle = sv[V_DEC_CYCLE]
    dec_pos = sv[V_DEC_POS]
    dec_limit = sv[V_DEC_LIMIT]
    fetch_restart = sv[V_FETCH_RESTART] != 0
    fe_ready = sv[V_FE_READY]
    last_iline = sv[V_LAST_ILINE]
    ren_cycle = sv[V_REN_CYCLE]
    ren_count = sv[V_REN_COUNT]
    ret_cycle = sv[V_RET_CYCLE]
    ret_count = sv[V_RET_COUNT]
    u_global = sv[V_U_GLOBAL]
    rob_pos = sv[V_ROB_POS]  # u_global % rob_n, kept incrementally (a division per uop is measurable)
    q_pos = sv[V_Q_POS]  # u_global % queue_n
    seg = sv[V_SEG]
    seg_start_retire = sv[V_SEG_START_RETIRE]
    seg_next = seg_end[seg] if seg < seg_end.shape[0] else -1  # the instruction count that ends segment seg
    max_retire = sv[V_MAX_RETIRE]
    prev_pc = sv[V_PREV_PC]
    rep_sid = sv[V_REP_SID]
    # the open run's other state (V_REP_COUNT; V_REP_NEXT, in hundredths of a cycle: when the loop's
    # latest element was issued; V_REP_MODE; V_REP_ADDR) is read and written in sv itself, not in
    # locals: the loop then carries four values fewer and the hot path runs faster (measured in one
    # process against the locals: 1.04-1.29x), though the REP code never runs on most traces
    # Plain L1 hits (the common case) are done here, not by sim.memory.hierarchy.service: the same
    # updates (LRU clock and stamp, dirty bit, request and hit counts), with the clock and the
    # counts kept in locals (written back around each service call and at the end)
    l1_ob, l1_row0, l1_set_mask, l1_ways, l1_lru, l1_write_back = l1_geometry(dconfig)
    d_now = dclock[0]
    # The data TLB is probed on the inline L1-hit path (shared_core, tlb_hit). A replayed log says
    # itself which accesses were plain hits (plain_hit): no TLB state then.
    has_tlb = dconfig[0, CFG_TLB_WAYS] > 0 and dlog[0] != LOG_REPLAY
    log_off = dlog[0] == LOG_OFF  # a log, once on, stays on (it may only overflow: replay.logged_service)
    # GPRs whose last writer was partial (reg_pmask != 15), as bits, plus ALWAYS_SCAN
    partial_live = ALWAYS_SCAN
    for r in range(8):
        if reg_pmask[r] != 15:
            partial_live |= 1 << r
    l1_load_hits = 0
    l1_store_hits = 0
    # the most frequent counts of the current segment, in locals (added to counters at its end)
    n_insns = n_uops = n_groups = n_stall_decode = n_stall_dep = n_stall_port = n_loads = n_stores = 0
    n_branches = n_dec0 = n_dec1 = n_dec2 = n_port0 = n_port1 = n_port2 = n_port3 = n_port4 = 0
    acc_next = 0  # the chunk's first access of instruction li (accesses are in program order: mem_insn sorted)
    nrdtsc = 0

    for li in range(n):
        i = base + li
        sid = dyn_sid[li] & IDX
        pc = dyn_pc[li]
        length = sf[sid, F_S_LEN]
        nu = sf[sid, F_S_NUOPS]
        u0 = sf[sid, F_S_UOP0] & IDX
        dec = sf[sid, F_S_DEC]
        psid = sid if i >= stat_first else sink
        rep_later = rep_sid == sid and prev_pc == pc
        prev_pc = pc
        if rare is not None:  # a REP string's run (see `rare` above)
            if rep_sid >= 0 and not rep_later:
                # the run ended without a closing execution (REPE/REPNE on the flags): settle it
                sv[V_REP_NEXT] = _rep_settle(s_rep, rep_sid, sv[V_REP_COUNT], sv[V_REP_NEXT], sv[V_REP_MODE])
                rep_end = -(-sv[V_REP_NEXT] // OCC_SCALE)
                if rep_end > dec_cycle:
                    dec_cycle = rep_end
                rep_sid = -1
        if rare is not None:  # a REP string's run
            if rep_later:
                # ---- a later element of a REP string: the microcode loop ----------------------------
                acc = acc_next
                acc_end = acc
                while acc_end < n_acc and mem_insn[acc_end & IDX] == li:
                    acc_end += 1
                acc_next = acc_end
                if acc_end == acc:
                    # the closing execution (ECX = 0): the run ends
                    sv[V_REP_NEXT] = _rep_settle(s_rep, sid, sv[V_REP_COUNT], sv[V_REP_NEXT], sv[V_REP_MODE])
                    rep_sid = -1
                    t = -(-sv[V_REP_NEXT] // OCC_SCALE)
                    wait = 0
                else:
                    sv[V_REP_COUNT] += 1
                    a = np.int64(mem_addr[acc & IDX])
                    if sv[V_REP_COUNT] == 2:
                        sv[V_REP_MODE] |= REP_FORWARD if a > sv[V_REP_ADDR] else REP_BACKWARD
                    fast = (sv[V_REP_MODE] & (REP_CAPABLE | REP_FORWARD)) == REP_CAPABLE | REP_FORWARD
                    sv[V_REP_NEXT] += s_rep[sid, R_FAST] if fast else s_rep[sid, R_ELEMENT]
                    if fast and sv[V_REP_COUNT] == FAST_MIN_COUNT:
                        sv[V_REP_NEXT] += max(0, s_rep[sid, R_FAST_START] - s_rep[sid, R_START]) * OCC_SCALE
                    t = -(-sv[V_REP_NEXT] // OCC_SCALE)
                    wait = 0
                    while acc < acc_end:
                        a = np.int64(mem_addr[acc & IDX])
                        sz = np.int64(mem_size[acc & IDX])
                        w_ = mem_write[acc & IDX] != 0
                        acc += 1
                        if w_:
                            n_stores += 1
                        else:
                            n_loads += 1
                        hit_row, hit_way = plain_hit(
                            dlog, log_off, dtags, a, sz, l1_ob, l1_row0, l1_set_mask, l1_ways,
                            (l1_write_back or not w_) and tlb_hit(has_tlb, dconfig, dclock, a))
                        if hit_row >= 0:
                            if w_:
                                l1_store_hits += 1
                            else:
                                l1_load_hits += 1
                            d_now = l1_hit(dstamps, ddirty, hit_row, hit_way, w_, l1_lru, d_now)
                        elif hit_row != REPLAYED_HIT:
                            dclock[0] = d_now
                            w, bus_free, l2bus_free = _access_slow(dlog, dtags, dstamps, ddirty, dconfig, dclock, dstats,
                                                                   a, sz, w_, t, P, mshr, bus_free, l2bus_free, counters,
                                                                   per_static, seg, psid)
                            d_now = dclock[0]
                            if w > wait:
                                wait = w  # the loop waits for its memory
                    sv[V_REP_NEXT] += wait * OCC_SCALE
                done = t + wait + 1
                for j in range(s_ndst[sid]):
                    rid = s_dst[sid, j, 0] & IDX
                    if rid < NREGS and rid != REG_ST0:
                        reg_ready[rid] = done
                        reg_ready[NREGS + rid] = rr_group
                if done > ret_cycle:
                    ret_cycle = done
                    ret_count = 0
                if t > dec_cycle:
                    dec_cycle = t  # nothing decodes before the loop has issued its last element
                dec_pos = 3
                if t > last_sta_done:
                    last_sta_done = t
                if t > last_commit:
                    last_commit = t
                if done > max_retire:
                    max_retire = done
                n_insns += 1
                per_static[psid, S_EXECUTIONS] += 1
                per_static[psid, S_ISSUE_TO_RETIRE] += done - t
                per_static[psid, S_DECODE_TO_RETIRE] += done - t
                if tl_first <= i < tl_first + timeline.shape[0]:
                    row = timeline[i - tl_first]
                    row[0] = i
                    row[1] = sid
                    row[2] = t
                    row[3] = t
                    row[4] = t
                    row[5] = done - 1
                    row[6] = done
                    row[7] = 0
                if i + 1 == seg_next:
                    counters[seg, C_CYCLES] = max_retire - seg_start_retire
                    _add_counts(counters, seg, n_insns, n_uops, n_groups, n_stall_decode, n_stall_dep, n_stall_port,
                                n_loads, n_stores, n_branches, n_dec0, n_dec1, n_dec2, n_port0, n_port1, n_port2,
                                n_port3, n_port4)
                    n_insns = n_uops = n_groups = n_stall_decode = n_stall_dep = n_stall_port = n_loads = n_stores = 0
                    n_branches = n_dec0 = n_dec1 = n_dec2 = n_port0 = n_port1 = n_port2 = n_port3 = n_port4 = 0
                    seg_start_retire = max_retire
                    seg += 1
                    seg_next = seg_end[seg] if seg < seg_end.shape[0] else -1
                continue

        # ---- front end: fetch (L1I) and decode ------------------------------------------------
        stall_fetch = 0
        iline = pc >> 5
        if iline != last_iline and iline_seen[iline & 15] != iline:
            # Lines fetched since the last L1I miss are still resident (nothing was filled since),
            # so their lookups are skipped: a hit. What is lost is their LRU refresh, which can only
            # matter once code outgrows the 16 KB L1I; kernels are a few hundred bytes.
            r = service(itags, istamps, idirty, iconfig, iclock, istats, pc, 1, False)
            lvl = served_level(r)
            if lvl > 0:
                counters[seg, C_L1I_MISSES] += 1
                extra = l2_lat if P[P_HAS_L2] == 1 else P[P_DRAM_LAT]
                fe_ready = max(fe_ready, dec_cycle + extra)
                stall_fetch = extra
                iline_seen[:] = -1
            iline_seen[iline & 15] = iline
        last_iline = iline
        d = dec_cycle
        new_group = dec_pos >= 3 or (dec != DEC_SIMPLE and dec_pos > 0) or sf[sid, F_S_LCP] == 1
        if block > 0 and pc + length > dec_limit:
            new_group = True  # the instruction does not end inside the current IFETCH block
        if new_group:
            d = dec_cycle + 1 if dec_pos > 0 else dec_cycle
        # uop queue: uop u0 enters only when uop u0 - queue_n has left it (been allocated)
        if queue_n > 0 and u_global >= queue_n:
            qfree = queue_ring[q_pos & IDX]
            if qfree > d:
                d = qfree
                new_group = True
        if fe_ready > d:
            counters[seg, C_STALL_MISPREDICT if stall_fetch == 0 else C_STALL_FETCH] += fe_ready - d
            d = fe_ready
            new_group = True
        if sf[sid, F_S_LCP] == 1:
            d += P[P_LCP]  # the length decoder restarts for a length-changing prefix
            counters[seg, C_LCP_STALLS] += P[P_LCP]
        if new_group:
            dec_pos = 0
            # IFETCH blocks (Agner Fog, microarchitecture manual, PPro/PII/PIII "Instruction fetch";
            # PIIDM IFU2/IFU3: the pre-decoded double buffer is rotated to align instructions to the
            # decoders): 16 bytes from an instruction boundary, the group's first instruction. Right
            # after fetch restarts only the aligned chunk holding the target is there (IA32-OPT: a
            # branch target at offset 14 yields 2 useful bytes in the first cycle).
            if block > 0:
                dec_limit = (pc // block + 1) * block if fetch_restart else pc + block
            fetch_restart = False
            n_groups += 1
        slot = dec_pos
        if dec == DEC_MSROM:
            counters[seg, C_MSROM_UOPS] += nu
            per_static[psid, S_MSROM] += 1
            dec_pos = 3
        else:
            dec_pos += 1
            if dec != DEC_SIMPLE:
                dec_pos = max(dec_pos, 1)
        if slot < 3 and dec != DEC_MSROM:
            n_dec0 += slot == 0
            n_dec1 += slot == 1
            n_dec2 += slot == 2
            per_static[psid, S_DECODER0 + (slot & IDX)] += 1
        decode_time = d
        dec_cycle = d
        if dec == DEC_MSROM:
            dec_cycle = d + (nu - 1) // P[P_MSROM_RATE]

        # ---- rename-time constraints of the whole instruction ---------------------------------
        inst_ready = decode_time + 1
        rename_free = ren_cycle if ren_count < rename_w else ren_cycle + 1
        if i > 0 and inst_ready > rename_free:  # rename idle, waiting for the front end
            n_stall_decode += inst_ready - rename_free
            per_static[psid, S_STALL_DECODE] += inst_ready - rename_free
        cause_alloc = 0
        partial_wait = 0
        # the scan finds nothing unless a GPR read is partially written or a flag read is stale
        scan = (sf[sid, F_P_GPR_BITS] & partial_live) != 0 or (sf[sid, F_P_FLAGS_READ] & ~flags_mask) != 0
        for k in range(sf[sid, F_P_NSRC] if scan else 0):
            rid = p_src[sid, k, 0] & IDX
            mask = p_src[sid, k, 1]
            if rid < 8:
                if (mask & ~reg_pmask[rid]) != 0 and reg_zeroed[rid] == 0:
                    partial_wait = max(partial_wait, reg_pretire[rid] + P[P_PARTIAL_EXTRA])
            elif rid == REG_FLAGS:
                if (mask & ~flags_mask) != 0:
                    if flags_retire + P[P_PARTIAL_EXTRA] > partial_wait:
                        partial_wait = flags_retire + P[P_PARTIAL_EXTRA]
                        if partial_wait > inst_ready:
                            counters[seg, C_STALL_PARTIAL_FLAGS] += partial_wait - inst_ready
        if partial_wait > inst_ready:
            counters[seg, C_STALL_PARTIAL_REGISTER] += partial_wait - inst_ready
            per_static[psid, S_STALL_PARTIAL] += partial_wait - inst_ready
            inst_ready = partial_wait
            cause_alloc = 3

        # x87 register names are relative to TOP: map to physical slots
        top_before = fp_top
        top_after = (fp_top - sf[sid, F_S_FPDELTA]) & 7

        # ---- per uop ----------------------------------------------------------------------------
        acc_first = acc_next
        acc = acc_next
        acc_end = acc
        while acc_end < n_acc and mem_insn[acc_end & IDX] == li:
            acc_end += 1
        acc_next = acc_end
        inst_complete = 0
        inst_retire = 0
        first_alloc = 0
        first_dispatch = 0
        cause_disp = 0
        branch_done = 0
        is_store = False
        store_std = 0
        intra = 0  # latest result of this instruction's loads and compute uops (the uop chain)
        for k in range(nu):
            u = (u0 + k) & IDX
            kind = uf[u, UF_U_KIND]
            t = inst_ready if k == 0 else max(inst_ready, decode_time + 1 + k // 3)
            # rename bandwidth
            if t == ren_cycle and ren_count >= rename_w:
                t += 1
            if t < ren_cycle:
                t = ren_cycle if ren_count < rename_w else ren_cycle + 1
            # ROB entry of the uop rob_n older must have retired
            if u_global >= rob_n and rob_ring[rob_pos & IDX] > t:
                counters[seg, C_STALL_ROB] += rob_ring[rob_pos & IDX] - t
                per_static[psid, S_STALL_WINDOW] += rob_ring[rob_pos & IDX] - t
                t = rob_ring[rob_pos & IDX]
                cause_alloc = max(cause_alloc, 2)
            # RS entries are freed at dispatch; a full RS holds allocation until one leaves
            while rs_time < t:
                rs_time += 1
                rs_pending, bound0, bound1 = _rs_leave(rs_by_cycle, rs_time, rs_pending, bound0, bound1)
            if rs_pending >= rs_n:
                w = t
                while rs_pending >= rs_n:
                    w += 1
                    rs_pending, bound0, bound1 = _rs_leave(rs_by_cycle, w, rs_pending, bound0, bound1)
                rs_time = w
                counters[seg, C_STALL_RS] += w - t
                per_static[psid, S_STALL_WINDOW] += w - t
                t = w
                cause_alloc = max(cause_alloc, 2)
            # a store needs a store-buffer entry
            if kind == STA and nstores >= sb_n and sb_ring[sb_pos & IDX] > t:
                counters[seg, C_STALL_STORE_BUFFER] += sb_ring[sb_pos & IDX] - t
                t = sb_ring[sb_pos & IDX]
                cause_alloc = max(cause_alloc, 2)
            if rrf_reads > 0 and uf[u, UF_U_SWAP] == 0:
                # register read stall (p6_machine.toml [rob.register_read]): a rename group reads at
                # most rrf_reads completed registers per clock, so the next group waits for the rest
                if t > ren_cycle:
                    hold = ren_cycle + (rr_n + rrf_reads - 1) // rrf_reads
                    if hold > t:
                        counters[seg, C_STALL_REGISTER_READ] += hold - t
                        t = hold
                    rr_mask, rr_n = 0, 0
                    rr_group += 1
                rr_mask, rr_n = _register_reads(u, u_nsrc, u_src, top_before, reg_ready, t, rr_group - rrf_recent,
                                                rr_mask, rr_n)
            if t > ren_cycle:
                ren_cycle = t
                ren_count = 0
            ren_count += 1
            alloc = t
            if queue_n > 0:
                queue_ring[q_pos & IDX] = alloc
                q_pos = q_pos + 1 if q_pos + 1 < queue_n else 0
            if k == 0:
                first_alloc = alloc
            # sources
            ready = alloc + 1
            for j in range(uf[u, UF_U_NSRC]):
                rid = u_src[u, j, 0] & IDX
                if rid == REG_ST0:
                    rid = REG_ST0 + ((top_before + u_src[u, j, 1]) & 7)
                if reg_ready[rid] > ready:
                    ready = reg_ready[rid]
            if kind == LOAD and last_sta_done > ready:
                ready = last_sta_done  # P6 loads never pass a store whose address is unknown
            if kind != LOAD and kind != STA and kind != SIDE and intra > ready:
                ready = intra  # the instruction's own earlier uops: load -> compute -> ... -> store data
            dep_wait = ready - (alloc + 1)
            ready_unit = ready
            if uf[u, UF_U_UNIT] != 0:
                free = -(-unit_free[uf[u, UF_U_UNIT] & IDX] // OCC_SCALE)  # held through part of a cycle: the next one
                if free > ready:
                    ready_unit = free
            if uf[u, UF_U_PORTS] == 0:
                disp, port = ready_unit, -1
            else:
                # a uop that may use port 0 or 1 was bound to one of them when it entered the RS
                disp, port = book_port(book, _bind_port(uf[u, UF_U_PORTS], bound0, bound1, bind_tie), ready_unit)
            port_wait = disp - ready  # includes waiting for a busy non-pipelined unit
            if uf[u, UF_U_UNIT] != 0:
                # a resource held for a fractional throughput (EMMS 5.67) averages it: the hold
                # runs from when it was due, not from the whole cycle the uop waited for
                unit_free[uf[u, UF_U_UNIT] & IDX] = max(unit_free[uf[u, UF_U_UNIT] & IDX], disp * OCC_SCALE - OCC_SCALE + 1) + uf[u, UF_U_OCC]
            lat = uf[u, UF_U_LAT]
            mem_wait = 0
            fwd_wait = 0
            if kind == LOAD and acc < acc_end:
                # find the access this load makes (the next read of this instruction)
                while acc < acc_end and mem_write[acc & IDX]:
                    acc += 1
                if acc < acc_end:
                    a = np.int64(mem_addr[acc & IDX])
                    sz = np.int64(mem_size[acc & IDX])
                    acc += 1
                    # store forwarding: newest older store still in the store buffer that overlaps
                    fwd = queued_store(fw_addr, fw_size, fw_commit, fw_n, a, sz, disp)
                    n_loads += 1
                    hit_row, hit_way = plain_hit(
                        dlog, log_off, dtags, a, sz, l1_ob, l1_row0, l1_set_mask, l1_ways,
                        tlb_hit(has_tlb, dconfig, dclock, a))
                    if hit_row >= 0:
                        l1_load_hits += 1
                        d_now = l1_hit(dstamps, ddirty, hit_row, hit_way, False, l1_lru, d_now)
                    elif hit_row == REPLAYED_HIT:
                        pass
                    else:
                        dclock[0] = d_now
                        mem_wait, bus_free, l2bus_free = _access_slow(dlog, dtags, dstamps, ddirty, dconfig, dclock, dstats,
                                                                      a, sz, False, disp, P, mshr, bus_free, l2bus_free,
                                                                      counters, per_static, seg, psid)
                        d_now = dclock[0]
                    if fwd >= 0:
                        if fw_addr[fwd] == a and sz <= fw_size[fwd]:
                            counters[seg, C_STORE_FORWARDS] += 1
                            if fw_ready[fwd] + P[P_FWD_LAT] > disp + lat:
                                fwd_wait = fw_ready[fwd] + P[P_FWD_LAT] - (disp + lat)
                            if rare is not None and disp + lat - (fw_ready[fwd] + P[P_FWD_LAT]) < sv[V_ROOM_FORWARD]:
                                sv[V_ROOM_FORWARD] = disp + lat - (fw_ready[fwd] + P[P_FWD_LAT])  # rooms kept
                        else:  # forwarding fails: wait until the store has written the cache
                            # forwarding fails: the load replays once the store has written L1, and
                            # its data arrives FWD_FAIL cycles after that (p6_machine.toml, estimated)
                            fwd_wait = max(0, max(fw_commit[fwd], disp) + P[P_FWD_FAIL] - (disp + lat))
                        counters[seg, C_STALL_STORE_FORWARD] += fwd_wait
                        per_static[psid, S_STALL_STORE_FORWARD] += fwd_wait
            complete = disp + lat + max(mem_wait, fwd_wait)
            if kind == STA:
                is_store = True
                if complete > last_sta_done:
                    last_sta_done = complete
            if kind == STD:
                store_std = complete
            elif kind != STA and kind != SIDE and complete > intra:
                intra = complete
            if kind == BRANCH:
                branch_done = complete
            # destinations
            for j in range(uf[u, UF_U_NDST]):
                rid = u_dst[u, j, 0] & IDX
                if rid == REG_ST0:
                    rid = REG_ST0 + ((top_after + u_dst[u, j, 1]) & 7)
                elif rid == REG_X87_ORDER and reg_ready[rid] > complete:
                    continue  # the order token: ready when every x87 writer is (lowering.py)
                reg_ready[rid] = complete
                reg_ready[NREGS + rid] = rr_group
            if uf[u, UF_U_SWAP] != 0:
                # FXCH: done in the register renamer (AF29n note f), it swaps which stack slot holds
                # which value without waiting for either: each value keeps its own ready time
                ra = REG_ST0 + ((top_after + s_dst[sid, 0, 3]) & 7)
                rb = REG_ST0 + ((top_after + s_dst[sid, 1, 3]) & 7)
                ta = reg_ready[ra]
                reg_ready[ra] = max(reg_ready[rb], alloc)
                reg_ready[rb] = max(ta, alloc)
            # retire in order, retire_w per cycle
            rt = complete + 1
            if rt < ret_cycle:
                rt = ret_cycle
            if rt == ret_cycle and ret_count >= retire_w:
                rt += 1
            if rt > ret_cycle:
                ret_cycle = rt
                ret_count = 0
            ret_count += 1
            rob_ring[rob_pos & IDX] = rt
            rob_pos = rob_pos + 1 if rob_pos + 1 < rob_n else 0
            # enter the RS (left at dispatch)
            if uf[u, UF_U_PORTS] != 0:
                slot = disp & (WINDOW - 1)
                rs_by_cycle[slot, 0] += 1
                rs_pending += 1
                if port == 0:
                    rs_by_cycle[slot, 1] += 1
                    bound0 += 1
                elif port == 1:
                    rs_by_cycle[slot, 2] += 1
                    bound1 += 1
            if port >= 0:
                n_port0 += port == 0
                n_port1 += port == 1
                n_port2 += port == 2
                n_port3 += port == 3
                n_port4 += port == 4
                per_static[psid, S_PORT0 + port] += 1
            if k == 0:
                first_dispatch = disp
            if dep_wait > 0:
                n_stall_dep += dep_wait
                per_static[psid, S_STALL_DEPENDENCY] += dep_wait
                cause_disp = max(cause_disp, 4)
            if port_wait > 0:
                n_stall_port += port_wait
                per_static[psid, S_STALL_PORT] += port_wait
                cause_disp = max(cause_disp, 5)
            if mem_wait > 0:
                cause_disp = max(cause_disp, 6)
            if fwd_wait > 0:
                cause_disp = max(cause_disp, 7)
            inst_complete = max(inst_complete, complete)
            inst_retire = rt
            u_global += 1

        # ---- after the instruction: register state, stores, branches --------------------------
        for j in range(sf[sid, F_P_NDST]):
            rid = p_dst[sid, j, 0] & IDX
            mask = p_dst[sid, j, 1]
            if rid < 8:
                if mask == 15:
                    reg_pmask[rid] = 15
                    reg_zeroed[rid] = sf[sid, F_S_ZERO]
                    partial_live &= ~(1 << rid)
                else:
                    reg_pmask[rid] = mask
                    reg_pretire[rid] = inst_retire
                    partial_live |= 1 << rid
            elif rid == REG_FLAGS:
                # a writer of all six status flags leaves nothing to merge, control flags included:
                # Agner Fog (PPro/PII/PIII partial flags stalls) lists NEG, ADD, CMP ... followed
                # by PUSHF(D), which reads DF/IF/TF too, as no stall; CLD / SETZ does stall
                flags_mask = mask | 0x1C0 if (mask & 0x3F) == 0x3F else mask
                flags_retire = inst_retire
        fp_top = top_after
        if rare is not None:  # a REP string's run
            if s_rep[sid, R_KIND] != REP_NONE:
                # the first element of a REP string: the microcode loop starts after it
                rep_sid = sid
                sv[V_REP_COUNT] = 1 if acc_end > acc_first else 0
                sv[V_REP_NEXT] = (inst_complete + s_rep[sid, R_START]) * OCC_SCALE
                sv[V_REP_MODE] = 0
                sv[V_REP_ADDR] = np.int64(mem_addr[acc_first]) if acc_end > acc_first else 0
                if s_rep[sid, R_KIND] == REP_FAST:
                    sv[V_REP_MODE] = REP_CAPABLE
                    src, dst = np.int64(-1), np.int64(-1)
                    for q in range(acc_first, acc_end):
                        if mem_write[q]:
                            dst = np.int64(mem_addr[q])
                        else:
                            src = np.int64(mem_addr[q])
                    if dst < 0 or dst % 8 != 0 or (src >= 0 and (src % 8 != 0 or abs(dst - src) < 32)):
                        sv[V_REP_MODE] = 0
        if is_store:
            # commit after retirement, in order; a write miss first fetches the line (write-allocate)
            commit = max(inst_retire, last_commit + 1)
            while acc < acc_end and not mem_write[acc & IDX]:
                acc += 1
            if acc < acc_end:
                a = np.int64(mem_addr[acc & IDX])
                sz = np.int64(mem_size[acc & IDX])
                n_stores += 1
                hit_row, hit_way = plain_hit(
                    dlog, log_off, dtags, a, sz, l1_ob, l1_row0, l1_set_mask, l1_ways,
                    l1_write_back and tlb_hit(has_tlb, dconfig, dclock, a))
                if hit_row >= 0:
                    l1_store_hits += 1
                    d_now = l1_hit(dstamps, ddirty, hit_row, hit_way, True, l1_lru, d_now)
                elif hit_row == REPLAYED_HIT:
                    pass
                else:
                    dclock[0] = d_now
                    w, bus_free, l2bus_free = _access_slow(dlog, dtags, dstamps, ddirty, dconfig, dclock, dstats, a, sz,
                                                           True, commit, P, mshr, bus_free, l2bus_free, counters,
                                                           per_static, seg, psid)
                    d_now = dclock[0]
                    commit += w
                fw_n = remember_store(fw_addr, fw_size, fw_ready, fw_commit, fw_n, a, sz, store_std, commit)
            sb_ring[sb_pos & IDX] = commit
            sb_pos = sb_pos + 1 if sb_pos + 1 < sb_n else 0
            nstores += 1
            last_commit = commit
        br = sf[sid, F_S_BRANCH]
        if br != BR_NONE:
            n_branches += 1
            nxt = dyn_pc[li + 1] if li + 1 < n else (next_pc if next_pc >= 0 else pc + length)
            taken = nxt != pc + length
            mispredicted = False
            redirect = False
            bset = sf[sid, F_S_BSET] & IDX
            way = -1
            for w in range(btb_ways):
                if btb_tag[bset, w] == pc:
                    way = w
            if br == BR_COND:
                if way >= 0:
                    h = btb_hist[bset, way] & IDX
                    predict = pht[bset, way, h] >= 2
                    cnt = pht[bset, way, h]
                    pht[bset, way, h] = min(3, cnt + 1) if taken else max(0, cnt - 1)
                    btb_hist[bset, way] = ((h << 1) | (1 if taken else 0)) & ((1 << hist_bits) - 1)
                    btb_stamp[bset, way] = i
                else:
                    target = sf[sid, F_S_TARGET]
                    predict = target >= 0 and target < pc  # static: backward taken, forward not taken
                    redirect = predict  # a static taken prediction redirects fetch at decode
                    if taken:
                        way = btb_alloc(btb_tag, btb_stamp, bset, btb_ways, pc, i)
                        btb_hist[bset, way] = 1
                        for h in range(1 << hist_bits):
                            pht[bset, way, h] = 2
                mispredicted = predict != taken
            elif br == BR_RET:
                predicted_target = -1
                if rsb_top > 0:
                    rsb_top -= 1
                    predicted_target = rsb[rsb_top % rsb.shape[0]]
                mispredicted = predicted_target != nxt
            else:
                if br == BR_CALL:
                    rsb[rsb_top % rsb.shape[0]] = pc + length
                    rsb_top += 1
                if way >= 0 and btb_target[bset, way] == nxt:
                    btb_stamp[bset, way] = i
                elif br == BR_INDIRECT:
                    mispredicted = True
                else:
                    redirect = True  # direct target known at decode: a short redirect bubble
                if way < 0:
                    way = btb_alloc(btb_tag, btb_stamp, bset, btb_ways, pc, i)
            if way >= 0:
                btb_target[bset, way] = nxt if taken else btb_target[bset, way]
            if mispredicted:
                counters[seg, C_MISPREDICTS] += 1
                per_static[psid, S_MISPREDICTS] += 1
                restart = (branch_done if branch_done > 0 else inst_complete) + P[P_MISPREDICT]
                if restart > fe_ready:
                    fe_ready = restart
                dec_pos = 3
                fetch_restart = True
            elif taken:
                bubble = P[P_STATIC_REDIRECT] if redirect else P[P_TAKEN_BUBBLE]
                if rare is not None and redirect and fe_ready - (decode_time + 1 + bubble) < sv[V_ROOM_REDIRECT]:
                    sv[V_ROOM_REDIRECT] = fe_ready - (decode_time + 1 + bubble)  # rooms kept
                if decode_time + 1 + bubble > fe_ready:
                    fe_ready = decode_time + 1 + bubble
                dec_pos = 3
                fetch_restart = True

        # ---- RDTSC values, timeline, per-static sums ------------------------------------------
        if rare is not None:  # an RDTSC
            if nrdtsc < rdtsc_out.shape[0] and rdtsc_sid[sid] == 1:
                rdtsc_out[nrdtsc] = first_dispatch
                nrdtsc += 1
        n_insns += 1
        n_uops += nu
        per_static[psid, S_EXECUTIONS] += 1
        per_static[psid, S_UOPS] += nu
        per_static[psid, S_ISSUE_TO_RETIRE] += inst_retire - first_dispatch
        per_static[psid, S_DECODE_TO_RETIRE] += inst_retire - decode_time
        if inst_retire > max_retire:
            max_retire = inst_retire
        if rare is not None:  # a timeline
            if tl_first <= i < tl_first + timeline.shape[0]:
                row = timeline[i - tl_first]
                row[0] = i
                row[1] = sid
                row[2] = decode_time
                row[3] = first_alloc
                row[4] = first_dispatch
                row[5] = inst_complete
                row[6] = inst_retire
                cause = cause_disp if cause_disp > 0 else cause_alloc
                if fe_ready >= decode_time and decode_time > 0 and cause == 0 and stall_fetch > 0:
                    cause = 1
                row[7] = cause
        if i + 1 == seg_next:
            counters[seg, C_CYCLES] = max_retire - seg_start_retire
            _add_counts(counters, seg, n_insns, n_uops, n_groups, n_stall_decode, n_stall_dep, n_stall_port, n_loads,
                        n_stores, n_branches, n_dec0, n_dec1, n_dec2, n_port0, n_port1, n_port2, n_port3, n_port4)
            n_insns = n_uops = n_groups = n_stall_decode = n_stall_dep = n_stall_port = n_loads = n_stores = 0
            n_branches = n_dec0 = n_dec1 = n_dec2 = n_port0 = n_port1 = n_port2 = n_port3 = n_port4 = 0
            seg_start_retire = max_retire
            seg += 1
            seg_next = seg_end[seg] if seg < seg_end.shape[0] else -1

    if seg < counters.shape[0]:
        _add_counts(counters, seg, n_insns, n_uops, n_groups, n_stall_decode, n_stall_dep, n_stall_port, n_loads,
                    n_stores, n_branches, n_dec0, n_dec1, n_dec2, n_port0, n_port1, n_port2, n_port3, n_port4)
    dclock[0] = d_now
    add_l1_hits(dstats, l1_load_hits, l1_store_hits)
    sv[V_FLAGS_MASK] = flags_mask
    sv[V_FLAGS_RETIRE] = flags_retire
    sv[V_FP_TOP] = fp_top
    sv[V_RS_PENDING] = rs_pending
    sv[V_RS_TIME] = rs_time
    sv[V_BOUND0] = bound0
    sv[V_BOUND1] = bound1
    sv[V_NSTORES] = nstores
    sv[V_SB_POS] = sb_pos
    sv[V_LAST_COMMIT] = last_commit
    sv[V_LAST_STA_DONE] = last_sta_done
    sv[V_BUS_FREE] = bus_free
    sv[V_L2BUS_FREE] = l2bus_free
    sv[V_FW_N] = fw_n
    sv[V_RSB_TOP] = rsb_top
    sv[V_DEC_CYCLE] = dec_cycle
    sv[V_DEC_POS] = dec_pos
    sv[V_DEC_LIMIT] = dec_limit
    sv[V_FETCH_RESTART] = 1 if fetch_restart else 0
    sv[V_FE_READY] = fe_ready
    sv[V_LAST_ILINE] = last_iline
    sv[V_REN_CYCLE] = ren_cycle
    sv[V_RR_MASK] = rr_mask
    sv[V_RR_N] = rr_n
    sv[V_RR_GROUP] = rr_group
    sv[V_REN_COUNT] = ren_count
    sv[V_RET_CYCLE] = ret_cycle
    sv[V_RET_COUNT] = ret_count
    sv[V_U_GLOBAL] = u_global
    sv[V_ROB_POS] = rob_pos
    sv[V_Q_POS] = q_pos
    sv[V_SEG] = seg
    sv[V_SEG_START_RETIRE] = seg_start_retire
    sv[V_MAX_RETIRE] = max_retire
    sv[V_PREV_PC] = prev_pc
    sv[V_REP_SID] = rep_sid
    return max_retire


@uncounted
def _rep_settle(s_rep, sid, count, rep_next, mode):
    """A REP string run of `count` elements has ended: a run that was charged the fast rate
    while ECX might still reach 64 and ended shorter takes the rest of the loop's rate."""
    fast = (mode & (REP_CAPABLE | REP_FORWARD)) == REP_CAPABLE | REP_FORWARD
    if fast and 2 <= count < FAST_MIN_COUNT:
        rep_next += (count - 1) * max(0, s_rep[sid, R_ELEMENT] - s_rep[sid, R_FAST])
    return rep_next


@njit(cache=True, nogil=True, inline="always")
def _miss_latency(r, lvl, levels, start, P, mshr, bus_free, l2bus_free, ctr):
    """Extra cycles beyond an L1 hit for an access that L1 missed, with fill-buffer, backside-bus
    and front-side-bus occupancy. Returns (extra, bus_free, l2bus_free)."""
    # a fill buffer: wait for the oldest outstanding miss when all are busy
    k = 0
    for j in range(mshr.shape[0]):
        if mshr[j] < mshr[k]:
            k = j
    t = max(start, mshr[k])
    has_l2 = P[P_HAS_L2] == 1
    if has_l2:
        ctr[C_L2_ACCESSES] += 1
    if lvl == 1 and has_l2 and lvl < levels:
        t2 = max(t, l2bus_free)
        l2bus_free = t2 + P[P_L2_BUS]
        done = t2 + P[P_L2_LAT] - P[P_L1_LAT]
        mshr[k] = t2 + P[P_L2_BUS]
    else:
        if has_l2:
            ctr[C_L2_MISSES] += 1
        # the bus request goes out when the L2's tag lookup reports the miss, not after the L2's
        # data latency (p6_machine.toml [caches.l2_miss_path])
        t2 = t + (P[P_L2_MISS_DETECT] if has_l2 else 0)
        b = max(t2, bus_free)
        fills = memory_fills(r)
        wbs = memory_writebacks(r)
        fh = memory_fill_page_hits(r)
        wh = memory_writeback_page_hits(r)
        busy = ((fills - fh) * P[P_DRAM_LINE] + fh * P[P_DRAM_LINE_HIT]
                + (wbs - wh) * P[P_DRAM_WB] + wh * P[P_DRAM_WB_HIT])
        bus_free = b + busy
        ctr[C_DRAM_FILLS] += fills
        ctr[C_DRAM_WRITEBACKS] += wbs
        ctr[C_DRAM_BUS_CYCLES] += busy
        ctr[C_DRAM_PAGE_HITS] += fh
        ctr[C_DRAM_PAGE_MISSES] += fills - fh
        # the critical chunk comes on the open-page lead-off only if every line it waits for hit
        done = (b + (P[P_DRAM_LAT_HIT] if fh == fills else P[P_DRAM_LAT])) if fills > 0 else t2
        mshr[k] = b + busy
    return max(0, done - start), bus_free, l2bus_free


@njit(cache=True, nogil=True)
def warm(base, next_pc, dyn_sid, dyn_pc, mem_insn, mem_addr, mem_size, mem_write, seg_end,
         s_len, s_pc, s_dec, s_lcp, s_branch, s_target, s_fpdelta, s_zero, s_nuops, s_uop0, s_nsrc, s_src,
         s_ndst, s_dst, u_kind, u_ports, u_lat, u_unit, u_occ, s_rep,
         P, dtags, dstamps, ddirty, dconfig, dclock, dstats, itags, istamps, idirty, iconfig, iclock, istats,
         sv, reg_ready, reg_pmask, reg_pretire, reg_zeroed, rob_ring, rs_by_cycle, queue_ring, book, unit_free,
         sb_ring, mshr, fw_addr, fw_size, fw_ready, fw_commit, btb_tag, btb_stamp, btb_hist, btb_target, pht,
         rsb, iline_seen):
    """Instructions base .. base + len(dyn_sid) - 1 as a warm-up (CoreSession.warm): what simulate
    does to the caches, TLB, DRAM pages, L1I, BTB, pattern tables, return stack and x87 top, in its
    order (a REP string's later elements' accesses in turn; an instruction's loads, one per load
    uop, then its store; the fetch line before them), and nothing it times. The hierarchy is walked
    through service for every access, which leaves what simulate's inline L1-hit path leaves. The session drains the
    timing state after it (tests/test_warm_start.py: the same learned state as timing the chunk)."""
    n = dyn_sid.shape[0]
    btb_sets, btb_ways, hist_bits = P[P_BTB_SETS], P[P_BTB_WAYS], P[P_HIST_BITS]
    fp_top = sv[V_FP_TOP]
    rsb_top = sv[V_RSB_TOP]
    last_iline = sv[V_LAST_ILINE]
    prev_pc = sv[V_PREV_PC]
    rep_sid = sv[V_REP_SID]
    acc_next = 0
    for li in range(n):
        i = base + li
        sid = dyn_sid[li] & IDX
        pc = dyn_pc[li]
        length = s_len[sid]
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
            for q in range(acc, acc_end):
                service(dtags, dstamps, ddirty, dconfig, dclock, dstats, np.int64(mem_addr[q]), np.int64(mem_size[q]),
                        mem_write[q] != 0)
            continue
        iline = pc >> 5
        if iline != last_iline and iline_seen[iline & 15] != iline:
            if served_level(service(itags, istamps, idirty, iconfig, iclock, istats, pc, 1, False)) > 0:
                iline_seen[:] = -1
            iline_seen[iline & 15] = iline
        last_iline = iline
        is_store = False
        u0 = s_uop0[sid] & IDX
        for k in range(s_nuops[sid]):
            kind = u_kind[(u0 + k) & IDX]
            if kind == LOAD and acc < acc_end:
                while acc < acc_end and mem_write[acc & IDX]:
                    acc += 1
                if acc < acc_end:
                    service(dtags, dstamps, ddirty, dconfig, dclock, dstats, np.int64(mem_addr[acc & IDX]),
                            np.int64(mem_size[acc & IDX]), False)
                    acc += 1
            elif kind == STA:
                is_store = True
        if is_store:
            while acc < acc_end and not mem_write[acc & IDX]:
                acc += 1
            if acc < acc_end:
                service(dtags, dstamps, ddirty, dconfig, dclock, dstats, np.int64(mem_addr[acc & IDX]),
                        np.int64(mem_size[acc & IDX]), True)
        fp_top = (fp_top - s_fpdelta[sid]) & 7
        if s_rep[sid, R_KIND] != REP_NONE:
            rep_sid = sid
        br = s_branch[sid]
        if br != BR_NONE:
            nxt = dyn_pc[li + 1] if li + 1 < n else (next_pc if next_pc >= 0 else pc + length)
            _, _, rsb_top = _predict(br, pc, length, nxt, i, (s_pc[sid] % btb_sets) & IDX, s_target[sid], btb_tag,
                                     btb_stamp, btb_hist, btb_target, pht, rsb, rsb_top, btb_ways, hist_bits)
    sv[V_SEG] = segments_ended(seg_end, sv[V_SEG], base + n)
    sv[V_FP_TOP] = fp_top
    sv[V_RSB_TOP] = rsb_top
    sv[V_LAST_ILINE] = last_iline
    sv[V_PREV_PC] = prev_pc
    sv[V_REP_SID] = rep_sid
