"""Locked read-modify-writes: what a LOCK-prefixed instruction, or XCHG with a memory operand,
costs on each family (issue 8).

XCHG with memory is locked whether or not it has the prefix (Intel SDM vol. 2, LOCK and XCHG: "The
XCHG instruction always asserts the LOCK# signal"). The cost is the lock, not the ALU work, so it is
one family rule stated in the machine table's [lock] section with its source, not a row per locked
form: InstLatX64 measures LOCK ADD [m8], [m16] and [m32] alike (the P6 and P54C dumps), and no
CPU here has a measurement of another locked form.

- P6: a cache lock. The P6 locks the line in its cache instead of the bus when the operand is cached
  and within one line (Intel SDM vol. 3, "Effects of a LOCK operation on internal processor
  caches"), so the cost is a fixed number of core clocks: 21 for LOCK ADD on the Pentium Pro 200,
  Pentium II 333, Celeron 300 and Pentium III 450 alike, whatever their bus ratio.
- P5 and K6: a bus lock. The Pentium asserts LOCK# on the bus even when the operand is cached (same
  SDM section); the K6 flushes the operand's line from its cache and runs locked bus cycles (AMD-K6
  data sheet 20695H, LOCK#). The cost is a number of bus clocks, charged in core clocks at the
  preset's bus ratio.

A LOCK-prefixed instruction takes its unlocked row (uops, units, latency) with the lock's reciprocal
throughput where it exceeds the row's; XCHG with memory takes the family's XCHG latency and throughput. What the model
assumes: the operand is cached (P6) and within one line; a line split (a bus lock on the P6 too), a
locked access that misses the cache, and the lock's hold on neighbouring memory accesses (the P6
drains its store buffer) are not modelled; on the P6 the hold is per mnemonic (sim/cpus/p6/lowering.py: p6_uops), so
two different locked instructions do not wait for each other. The K6 holds its decoder (vector
decode) and the P5 its pipes for the whole cost, so there every later instruction waits (each family
model's `rewrite` of the locked row, passed to :func:`locked_match`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from fractions import Fraction

from sim.guest.decode import InsnRecord
from sim.errors import RetrosimError
from sim.cpus.table import Match

KINDS = ("lock", "xchg")  # a LOCK-prefixed read-modify-write; XCHG with a memory operand


@dataclass(frozen=True)
class LockCost:
    """Core clocks of a locked instruction on one preset: latency and reciprocal throughput per kind."""

    latency: dict[str, float]
    throughput: dict[str, float]
    source: str

    def kind(self, rec: InsnRecord) -> str | None:
        """'xchg', 'lock' or None (not locked)."""
        if rec.mnemonic == "xchg" and rec.mem_operands:
            return "xchg"
        return "lock" if rec.lock else None


def whole_clocks(x: float) -> int:
    """Clocks from a figure: nearest integer, halves up."""
    return math.floor(x + 0.5)


def lock_cost(section: dict, where: str, model: str | None = None, ratio: Fraction | None = None) -> LockCost:
    """The [lock] section of a machine table for one preset. Either `core_clocks` (the P6: the same
    on every bus) or `bus_clocks` per model key (P5, K6: times the preset's bus ratio, rounded)."""
    try:
        if "core_clocks" in section:
            figures = section["core_clocks"]
            lat = {k: float(figures[k]["latency"]) for k in KINDS}
            thr = {k: float(figures[k]["throughput"]) for k in KINDS}
        else:
            figures = section["bus_clocks"][model]
            lat = {k: float(whole_clocks(figures[k] * ratio)) for k in KINDS}
            thr = dict(lat)
        return LockCost(lat, thr, section["source"])
    except (KeyError, TypeError) as e:
        raise RetrosimError(f"{where} [lock]: missing or bad field {e} (model {model!r})") from None


def locked_match(rec: InsnRecord, match: Match, cost: LockCost, rewrite=None) -> Match:
    """The match with the lock's cost when `rec` is locked, else `match` itself. The new row keeps
    the unlocked row's uops and units; its key names the lock ('lock add m32,r32'). `rewrite(row,
    kind, throughput, extra, fields)`: the family's own changes to the locked row's extra fields and
    timing fields (its model module defines it), in place."""
    kind = cost.kind(rec)
    if kind is None:
        return match
    row = match.row
    lat, thr = cost.latency[kind], cost.throughput[kind]
    if kind == "lock":
        # the lock holds the machine for the measured reciprocal throughput; a register or flags
        # result is ready when the unlocked row says (InstLatX64's LOCK ADD chain through memory, L,
        # equals its T: the chain waits for the lock, not for a longer result)
        lat, thr = row.latency, max(thr, row.throughput or 0)
    name = row.mnemonic if kind == "xchg" else f"lock {row.mnemonic}"
    extra = dict(row.extra)
    fields = {"latency": lat, "throughput": thr}
    if rewrite is not None:
        rewrite(row, kind, thr, extra, fields)
    locked = replace(row, mnemonic=name, source=f"{cost.source} (locked); unlocked row: {row.source}",
                     note=f"Locked: the machine table's [lock] rule replaces the row's timing. {row.note}".strip(),
                     estimated=row.estimated or (kind == "lock" and row.mnemonic != "add"),  # LOCK ADD is the measured form
                     extra=extra, **fields)
    asked = match.asked if kind == "xchg" else f"lock {match.asked}"
    return Match(locked, asked, match.precision)
