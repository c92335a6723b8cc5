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


def power(base: float, exponents) -> np.ndarray:
    """base ** exponents elementwise (base > 0), as float64 of the exponents' shape."""
    b = decimal.Decimal(float(base))
    e = np.asarray(exponents, dtype=np.float64)
    out = [float(_CONTEXT.power(b, decimal.Decimal(x))) for x in e.ravel().tolist()]
    return np.array(out, dtype=np.float64).reshape(e.shape)


def exp(x: float) -> float:
    """e ** x for one float."""
    return float(_CONTEXT.exp(decimal.Decimal(float(x))))
