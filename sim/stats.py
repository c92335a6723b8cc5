"""Exact statistics for reports: the same bytes on every machine.

numpy's reductions (sum, mean, ...) add in blocks whose size and order can follow the vector width
of the host CPU, so a mean over a large array may differ in its last bits between two machines, and a
report that prints all its digits (the JSON) would then not reproduce; Python's own ``sum`` of floats
changed its algorithm in 3.12. Every float statistic a committed report shows goes through here: the
values are added exactly, as integers (each float is an integer mantissa times a power of two), and
the exact result is rounded once. The answer is the float nearest the exact statistic, whatever the
order of the values, the CPU or the Python version.
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np

_HALF = 26  # a 53-bit mantissa in two parts, so int64 sums of up to 2^36 parts cannot overflow


def exact_sum(values) -> Fraction:
    """The exact sum of the finite float64 `values` (any array-like of numbers)."""
    x = np.asarray(values, dtype=np.float64).ravel()
    if not np.isfinite(x).all():
        raise ValueError("exact_sum takes finite values")
    m, e = np.frexp(x)  # x = m * 2^e exactly, 0.5 <= |m| < 1
    mant = np.ldexp(m, 53).astype(np.int64)  # exact: x = mant * 2^(e - 53)
    exps, where = np.unique(e, return_inverse=True)
    hi, lo = np.zeros(exps.size, np.int64), np.zeros(exps.size, np.int64)
    np.add.at(hi, where, mant >> _HALF)  # integer additions: exact in any order
    np.add.at(lo, where, mant & ((1 << _HALF) - 1))
    if not exps.size:
        return Fraction(0)
    base = int(exps.min()) - 53
    num = sum(((int(h) << _HALF) + int(l)) << (int(p) - 53 - base) for h, l, p in zip(hi, lo, exps))
    return Fraction(num) * Fraction(2) ** base


def mean(values, empty: float = 0.0) -> float:
    """The exact mean of `values`, correctly rounded (`empty` when there are none; inf or nan when a
    value is)."""
    x = np.asarray(values, dtype=np.float64).ravel()
    if not x.size:
        return empty
    if not np.isfinite(x).all():
        return math.fsum(x[~np.isfinite(x)].tolist())
    return float(exact_sum(x) / x.size)

