"""Functional references for the kernels: what each kernel must compute, written in numpy.

These model the instructions' architectural semantics (including BSR on zero and SHRD by zero),
not the intent, so a test can demand bit-exact agreement with Unicorn and with host silicon. The
"ideal" helpers (:func:`fp16z_encode`, :func:`fp16z_decode`) give the format without hazards.
"""

from __future__ import annotations

import numpy as np
from numba import njit

U32 = 0xFFFFFFFF


def msb_index(z: np.ndarray) -> np.ndarray:
    """Index of the highest set bit of each uint32 (what BSR returns); -1 for zero."""
    z = np.asarray(z, dtype=np.uint32)
    _, exp = np.frexp(z.astype(np.float64))  # exact: every uint32 is a float64
    return np.where(z == 0, -1, exp - 1).astype(np.int64)


def fp16z_convert(z, edx_in=0, ecx_in=0) -> tuple[np.ndarray, np.ndarray]:
    """BSR ECX,EAX / SHRD EDX,EAX,CL / SHRD EDX,ECX,21 with EAX=z; returns (EDX, ECX) afterwards.

    - BSR with a zero source leaves ECX unchanged (Intel: "undefined", AMD and every Intel part
      measured: unchanged) and the count CL is then whatever ECX held;
    - SHRD with a count of 0 (CL & 31 == 0, i.e. z == 1) leaves EDX unchanged;
    - the 16-bit float is DX; EDX's upper half holds the exponent's higher bits (zero unless
      ECX >= 32, which only a zero input with a large preset ECX gives).
    """
    # uint32 arithmetic throughout; numpy defines shifts by >= 32 as 0, which makes SHRD by 0
    # (count 0: EDX >> 0 | EAX << 32) come out as "EDX unchanged" with no special case.
    z = np.asarray(z, dtype=np.uint32)
    _, exp = np.frexp(z.astype(np.float64))  # exact: every uint32 is a float64
    ecx = (exp - 1).astype(np.uint32)
    if np.any(zero := z == 0):
        ecx[zero] = np.broadcast_to(np.asarray(ecx_in, dtype=np.uint32), z.shape)[zero]
    count = ecx & np.uint32(31)
    edx = np.asarray(edx_in, dtype=np.uint32) >> count
    edx |= z << (np.uint32(32) - count)
    edx >>= np.uint32(21)
    edx |= ecx << np.uint32(11)
    return edx, ecx


def fp16z_encode(z) -> np.ndarray:
    """The 16-bit float of each depth with EDX and ECX cleared first (the hazard-free format)."""
    return (fp16z_convert(z, 0, 0)[0] & 0xFFFF).astype(np.uint16)


def fp16z_decode(h) -> np.ndarray:
    """The smallest 32-bit depth whose encoding is h (the lower end of h's interval)."""
    h = np.asarray(h, dtype=np.uint32)
    e = (h >> 11).astype(np.int64)
    m = (h & 0x7FF).astype(np.int64)
    top = np.int64(1) << e
    mant = np.where(e >= 11, m << np.maximum(e - 11, 0), m >> np.maximum(11 - e, 0))
    return (top | mant).astype(np.uint32)


def interpolate_u32(z: int, dz: int, count: int) -> np.ndarray:
    """z, z+dz, ... as a 32-bit register holds them (wrapping modulo 2^32)."""
    k = np.arange(count, dtype=np.uint64)
    return ((np.uint64(z & U32) + k * np.uint64(dz & U32)) & np.uint64(U32)).astype(np.uint32)


def _depth_test(zbuf, fbuf, depth, colour) -> int:
    """Strictly-nearer test and write, vectorised (the pixels of one span are distinct)."""
    passed = depth < zbuf
    zbuf[passed] = depth[passed]
    fbuf[passed] = colour & 0xFFFF
    return int(np.count_nonzero(passed))


def z32_span(zbuf: np.ndarray, fbuf: np.ndarray, z: int, dz: int, colour: int) -> int:
    return _depth_test(zbuf, fbuf, interpolate_u32(z, dz, zbuf.size), colour)


def z16_span(zbuf: np.ndarray, fbuf: np.ndarray, z: int, dz: int, colour: int) -> int:
    return _depth_test(zbuf, fbuf, (interpolate_u32(z, dz, zbuf.size) >> 16).astype(np.uint16), colour)


@njit(cache=True)
def _fp16z_span(zbuf, fbuf, z, dz, colour, edx, ecx):
    written = 0
    for i in range(zbuf.size):
        if z != 0:
            e = 0
            while (z >> (e + 1)) != 0:
                e += 1
            ecx = e
        c = ecx & 31
        if c != 0:
            edx = ((edx >> c) | (z << (32 - c))) & 0xFFFFFFFF
        edx = ((edx >> 21) | (ecx << 11)) & 0xFFFFFFFF
        if (edx & 0xFFFF) < zbuf[i]:
            zbuf[i] = edx & 0xFFFF
            edx = (edx & 0xFFFF0000) | (colour & 0xFFFF)  # MOV DX, colour keeps EDX's top half
            fbuf[i] = colour & 0xFFFF
            written += 1
        z = (z + dz) & 0xFFFFFFFF
    return written, edx, ecx


def fp16z_span(zbuf, fbuf, z: int, dz: int, colour: int, edx_in: int = 0, ecx_in: int = 0) -> tuple[int, int, int]:
    """The kernel's exact per-pixel semantics, EDX/ECX carried from pixel to pixel as the kernel
    carries them; returns (pixels written, EDX, ECX) at the end."""
    return _fp16z_span(zbuf, fbuf, np.int64(z & U32), np.int64(dz & U32), np.int64(colour),
                       np.int64(edx_in & U32), np.int64(ecx_in & U32))


def _fp16t_table() -> np.ndarray:
    """kernels/*/fp16t.S's table: entry b (the top byte of z, 1..255) = ((e - 1) << 11) | (e - 11)
    with e = 24 + msb(b): the shift count in the low 5 bits (the only bits of CL that SHR uses) and
    the exponent minus one already in bits 11..15; entry 0 = 0 (z = 0 shifts by 0 and adds 0)."""
    b = np.arange(256, dtype=np.int64)
    e = 24 + msb_index(b)
    return np.where(b == 0, 0, ((e - 1) << 11) | (e - 11)).astype(np.uint32)


FP16T_TABLE = _fp16t_table()
FP16T_TABLE.setflags(write=False)


def fp16t_convert(z) -> np.ndarray:
    """The BSR-free conversion of kernels/*/fp16t.S, step by step (uint32 arithmetic):
    top byte b = z >> 24; t = FP16T_TABLE[b]; EDX = (z >> (t & 31)) + (t & ~31). For z < 2^24
    (b = 0, z != 0) z is first shifted left by 8 k bits until its top byte is non-zero and 8k << 11
    is subtracted at the end; z = 0 gives 0. Returns the 16-bit floats (uint16); equal to
    :func:`fp16z_encode` for every uint32 (tests/test_fp16t.py checks all 2^32)."""
    z = np.asarray(z, dtype=np.uint32)
    shape, z = z.shape, z.ravel()
    top = z >> np.uint32(24)
    corr = None
    if z.size and z.min() < (1 << 24):  # the kernel's rarely taken path
        small = np.flatnonzero(top == 0)
        small = small[z[small] != 0]
        z = z.copy()
        corr = np.zeros(z.shape, np.uint32)
        while small.size:  # at most three rounds
            z[small] <<= np.uint32(8)
            corr[small] += np.uint32(8 << 11)
            top[small] = z[small] >> np.uint32(24)
            small = small[top[small] == 0]
    t = FP16T_TABLE.take(top, mode="wrap")  # top < 256: "wrap" only skips the bounds check
    edx = z >> (t & np.uint32(31))
    edx += t & np.uint32(0xFFFFFFE0)
    if corr is not None:
        edx -= corr
    return edx.astype(np.uint16).reshape(shape)


def fp16t_span(zbuf: np.ndarray, fbuf: np.ndarray, z: int, dz: int, colour: int) -> int:
    """kernels/zbuffer/fp16t.S: fp16z's span without its hazards (every pixel's conversion is
    fp16z_encode of its depth, nothing carries from pixel to pixel); returns the pixels written."""
    return _depth_test(zbuf, fbuf, fp16t_convert(interpolate_u32(z, dz, zbuf.size)), colour)


def x87_extended_available() -> bool:
    """True when numpy's longdouble is the x87 80-bit format (64-bit mantissa), as on x86 Linux."""
    return np.finfo(np.longdouble).nmant == 63


def zf32_span(zbuf: np.ndarray, fbuf: np.ndarray, z: float, dz: float, colour: int) -> int:
    """x87 at 64-bit precision: z accumulates in extended precision (one rounding per FADD), is
    compared exactly with the stored float, and stored rounded to nearest single."""
    if not x87_extended_available():
        raise RuntimeError("the zf32 reference needs numpy.longdouble to be the x87 80-bit format")
    if zbuf.size == 0:
        return 0
    steps = np.full(zbuf.size, np.longdouble(np.float32(dz)), dtype=np.longdouble)
    steps[0] = np.longdouble(np.float32(z))
    depth = np.cumsum(steps)  # sequential adds, each rounded to 64 bits, like the FADD chain
    passed = depth < zbuf.astype(np.longdouble)  # NaN compares false: unordered fails, as in the kernel
    with np.errstate(over="ignore"):  # FST rounds an out-of-range value to infinity, as here
        zbuf[passed] = depth[passed].astype(np.float32)
    fbuf[passed] = colour & 0xFFFF
    return int(np.count_nonzero(passed))
