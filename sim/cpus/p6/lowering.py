"""The P6's lowering rules: the uops of one instruction (kind, port, latency and the held unit
that reproduces a measured throughput), for the shared lowering (sim/cpus/lowering.py).

Throughput (:func:`p6_uops`). A row's reciprocal throughput is a measured fact the model must
reproduce. What the machine already charges is its "natural" throughput: the busiest port, the
rename/retire width, the microcode sequencer's rate, the taken-branch redirect of a branch and the
length-changing-prefix decode of an LCP instruction. When the row's throughput exceeds that, the
instruction's first compute uop (else its first uop) holds a non-pipelined resource for the row's
throughput: the next instruction of the same mnemonic using the same port waits for it (the
divider: DIV 37; FMUL 2; LOOP 8; EMMS 5.67; CMP 1.0), other instructions are not held. Fractions
are kept (the core counts the resource in hundredths of a cycle), so EMMS averages 5.67. A row
whose measured throughput another mechanism of the machine explains says so (`throughput_by`) and
holds nothing: CMP/TEST r,r and MOVD between MMX and integer registers (the register read stall).
"""

from __future__ import annotations

from dataclasses import dataclass

from sim.guest.decode import InsnRecord
from sim.cpus.lowering import BRANCH, COMPUTE, LOAD, OCC_SCALE, SIDE, STA, STD, port_mask
from sim.cpus.table import Match

_KIND_ORDER = {COMPUTE: 1, BRANCH: 1, LOAD: 0, STA: 2, STD: 3}  # load, then compute/branch, then store address, store data


@dataclass(frozen=True)
class P6Limits:
    """What the P6 machine charges an instruction's throughput without a held resource."""

    width: int = 3          # rename and retire uops per cycle
    msrom_rate: int = 3     # microcode sequencer uops per cycle
    taken_cycles: int = 2   # a taken branch: its decode cycle plus the redirect bubble
    lcp_cycles: int = 2     # an instruction with a length-changing prefix decodes alone, plus the penalty


def natural_throughput(rec: InsnRecord, row, kinds: list[int], ports: list[str], limits: P6Limits) -> float:
    """Reciprocal throughput the P6 machine gives the instruction without a held resource."""
    per_port: dict[int, int] = {}
    alu = 0
    for k, p in zip(kinds, ports):
        m = port_mask(p)
        if m and m & (m - 1) == 0:
            per_port[m] = per_port.get(m, 0) + 1
        if m & 3:
            alu += 1
    bound = max([len(kinds) / limits.width, alu / 2] + list(per_port.values()))
    if len(kinds) > 4 or row.decoder == "msrom":
        bound = max(bound, -(-len(kinds) // limits.msrom_rate))
    if rec.is_branch:
        bound = max(bound, limits.taken_cycles)
    if (rec.opsize_prefix and rec.imm_size == 2) or (rec.addrsize_prefix and rec.disp_size == 2):
        bound = max(bound, limits.lcp_cycles)
    return bound



def p6_uops(rec: InsnRecord, match: Match, load_latency: int, limits: P6Limits | None = None,
            units: dict | None = None) -> list[tuple[int, int, int, int, int]]:
    """[(kind, port mask, latency, resource, occupancy in hundredths)] for one P6 instruction.
    `units` maps (mnemonic, port mask) to a resource id (1, 2, ...) for the whole program."""
    row = match.row
    limits = limits or P6Limits()
    ports = list(row.ports) + ["p01"] * max(0, row.uops - len(row.ports))  # rows list one port per uop
    ports = [p.strip().lower() for p in ports[:row.uops]]
    kinds = [LOAD if p == "p2" else STA if p == "p3" else STD if p == "p4" else COMPUTE for p in ports]
    order = sorted(range(len(kinds)), key=lambda i: _KIND_ORDER[kinds[i]])
    kinds, ports = [kinds[i] for i in order], [ports[i] for i in order]
    if rec.is_branch:
        # the uop on port 1 (the jump unit) resolves the branch; otherwise the last compute uop
        idx = [i for i, p in enumerate(ports) if port_mask(p) == 2 and kinds[i] == COMPUTE]
        idx = idx or [i for i, k in enumerate(kinds) if k == COMPUTE][-1:]
        if idx:
            kinds[idx[0]] = BRANCH
    has_load = LOAD in kinds
    compute = [i for i, k in enumerate(kinds) if k in (COMPUTE, BRANCH)]
    if row.latency is None:
        work = len(compute)  # no register result: each compute uop 1 cycle, all on the chain
    else:
        work = int(round(row.latency - (load_latency if has_load else 0)))
        work = max(work, 0 if has_load else 1)
    chain_n = min(len(compute), max(work, 1 if BRANCH in kinds else 0))
    # uops the latency has no room for run beside the chain (never the branch): XCHG r,r's third
    # uop, POP's stack-pointer adder (POP r32 latency 3 = the load alone)
    side = [i for i in compute if kinds[i] != BRANCH][:len(compute) - chain_n]
    for i in side:
        kinds[i] = SIDE
    chain = [i for i in compute if i not in side]
    holder, occ = -1, 0
    # `throughput_by = "register_read"`: the machine's register read stall sets the measured rate
    # (p6_machine.toml [rob.register_read]), not a unit the instruction holds
    if row.throughput and not row.extra.get("throughput_by") and \
            row.throughput > natural_throughput(rec, row, kinds, ports, limits) + 1e-9:
        holder = compute[0] if compute else 0
        occ = int(round(row.throughput * OCC_SCALE))
    out = []
    for i, k in enumerate(kinds):
        if k in (COMPUTE, BRANCH):
            lat = max(1, work - (len(chain) - 1)) if i == chain[-1] else 1
        elif k == LOAD:
            lat = load_latency
        else:
            lat = 1
        mask = port_mask(ports[i])
        unit = 0
        if i == holder:
            key = (row.mnemonic, mask)
            if units is None:
                units = {}
            unit = units.setdefault(key, len(units) + 1)
        out.append((k, mask, lat, unit, occ if unit else 0))
    return out


def uops_rule(limits: P6Limits):
    """The `uops_for` rule of one lowering (sim/cpus/lowering.py: lower): :func:`p6_uops` with the
    machine's `limits`, numbering the held units over the whole program."""
    units: dict = {}

    def uops_for(rec, match, load_latency):
        return p6_uops(rec, match, load_latency, limits, units)
    return uops_for
