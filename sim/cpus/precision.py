"""x87 precision control in the timing models: one static instruction per precision it ran at.

FDIV, FSQRT and their relatives take a time set by the precision-control field of the x87 control
word in force (24, 53 or 64 bits), not by their operands; the trace carries that word for every
instruction (sim/guest/trace.py). A model's cores key everything on static instructions, so a
precision-dependent static that ran at several precisions becomes one static per precision: the
first precision it ran at keeps its id, the others get new ids appended after the decoder's
records (same record, same PC), and the dynamic index is rewritten to point at them. Lowering then
takes each static's row at its precision (:meth:`sim.cpus.table.Match.at_precision`), so the cores
need no per-instruction precision at all, and `retrosim explain` shows one row per precision
("fdiv st,st @24-bit").
"""

from __future__ import annotations

import numpy as np

from sim.guest.decode import InsnRecord
from sim.guest.trace import Trace
from sim.cpus.table import InstructionTable


def split_by_precision(records: list[InsnRecord], index: np.ndarray, trace: Trace, table: InstructionTable
                       ) -> tuple[list[InsnRecord], np.ndarray, list[int | None]]:
    """(records, dynamic index, precision per static: 0 = 24-bit, 1 = 53-bit, 2 = 64-bit, None where
    the static's row does not depend on precision or has no row; lowering reports a missing row)."""
    precisions: list[int | None] = [None] * len(records)
    dependent = []
    for s, rec in enumerate(records):
        match = table.lookup(rec.mnemonic, rec.signature) if rec.is_x87 else None
        if match is not None and match.row.precision_dependent:
            dependent.append(s)
    if not dependent:
        return records, index, precisions
    positions = np.flatnonzero(np.isin(index, dependent))
    sids = index[positions]
    prec = trace.precision_at(positions)
    records, index = list(records), index.copy()
    for s in dependent:
        mine = positions[sids == s]
        if mine.size == 0:
            continue
        at = prec[sids == s]
        first = int(at[0])
        precisions[s] = first
        for p in sorted(set(np.unique(at).tolist()) - {first}):
            index[mine[at == p]] = len(records)
            records.append(records[s])
            precisions.append(int(p))
    return records, index, precisions
