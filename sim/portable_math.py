"""Elementary functions whose results do not depend on the host CPU, for generating scene data.

numpy's vectorised exp, log and power take a different code path on a CPU with AVX-512 than on one
without, and the two disagree in the last bit for some inputs (``2.0 ** u`` over 100,000 uniform
exponents gives different bytes with ``NPY_DISABLE_CPU_FEATURES=X86_V4``). A scene whose geometry
is built from such values then draws slightly different triangles on another machine, and its error
statistics no longer reproduce. These functions compute in Python's ``decimal`` (a software
implementation: the same digits everywhere) with 17 more digits than a double holds, then round
once to the nearest float.
"""

from __future__ import annotations

import decimal

import numpy as np

_CONTEXT = decimal.Context(prec=34)


def _each(values, fn) -> np.ndarray:
    """fn (a decimal function) of every value, rounded once to float64, in the values' shape."""
    v = np.asarray(values, dtype=np.float64)
    return np.array([float(fn(decimal.Decimal(t))) for t in v.ravel().tolist()], dtype=np.float64).reshape(v.shape)


def power(base: float, exponents) -> np.ndarray:
    """base ** exponents elementwise (base > 0), as float64 of the exponents' shape."""
    b = decimal.Decimal(float(base))
    return _each(exponents, lambda e: _CONTEXT.power(b, e))


def exp(x: float) -> float:
    """e ** x for one float."""
    return float(_each(x, _CONTEXT.exp))


def exp_array(x) -> np.ndarray:
    """e ** x elementwise, as float64 of x's shape (Generator.lognormal's exp, made portable:
    ``exp_array(rng.normal(m, s, n))`` draws what ``rng.lognormal(m, s, n)`` draws, but every
    value is rounded once from 34 digits instead of by the host libm's exp)."""
    return _each(x, _CONTEXT.exp)


def geomspace(start: float, stop: float, num: int) -> np.ndarray:
    """num points from start to stop (both > 0), equally spaced on a log scale, ends exact: what
    np.geomspace gives, with the powers computed by `power` instead of the host's vector log/exp."""
    if num == 1:
        return np.array([float(start)])
    steps = np.arange(num, dtype=np.float64) / (num - 1)
    out = float(start) * power(float(stop) / float(start), steps)
    out[0], out[-1] = start, stop
    return out


# pi/2 split Cody-Waite style into three parts of 33 bits each (the leading ones exact in a double
# with room for a 20-bit multiple), so x - k*pi/2 is formed without cancellation for |k| < 2**20
_PIO2_HI = 1.57079632673412561417e+00
_PIO2_MID = 6.07710050630396597660e-11
_PIO2_LO = 2.02226624879595063154e-21
# Taylor coefficients (-1)^n / (2n+1)! and (-1)^n / (2n)!: on |r| <= pi/4 the first omitted terms
# are below 1e-24, far under a double's last bit
_SIN = tuple((-1) ** n / float(np.prod(np.arange(1, 2 * n + 2, dtype=np.float64))) for n in range(1, 11))
_COS = tuple((-1) ** n / float(np.prod(np.arange(1, 2 * n + 1, dtype=np.float64))) for n in range(1, 12))


def sin_cos(x) -> tuple[np.ndarray, np.ndarray]:
    """(sin x, cos x) elementwise for |x| < 2**20 (scene angles), as float64 of x's shape.

    numpy's vectorised sin and cos take another code path (and give other last bits) on a CPU with
    AVX-512 than on one without; this uses only IEEE multiply, add and rint, which round the same
    on every x86-64 CPU, so the bytes are the same everywhere (within about 1 ulp of the true
    values)."""
    v = np.asarray(x, dtype=np.float64)
    if v.size and not np.all(np.abs(v) < 2.0 ** 20):
        raise ValueError("sin_cos: an angle out of range (|x| must be below 2**20)")
    k = np.rint(v * (2.0 / np.pi))
    r = ((v - k * _PIO2_HI) - k * _PIO2_MID) - k * _PIO2_LO
    r2 = r * r
    s = np.zeros_like(r)
    for c in reversed(_SIN):
        s = (s + c) * r2
    s = r + r * s
    c = np.zeros_like(r)
    for a in reversed(_COS):
        c = (c + a) * r2
    c = 1.0 + c
    q = k.astype(np.int64) & 3
    sin = np.choose(q, [s, c, -s, -c])
    cos = np.choose(q, [c, -s, -c, s])
    return sin, cos


def unit_vectors(angles) -> np.ndarray:
    """(cos a, sin a) along a new last axis: the unit vectors at the given angles, portably."""
    sin, cos = sin_cos(angles)
    return np.stack([cos, sin], axis=-1)
