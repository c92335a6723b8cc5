"""Kernel call arguments written as text (`--args`, sweep specs' [[sweep.kernels]] args): integers,
32-bit floats and buffers allocated in the workload arena, parsed into a call's values.

Item forms: ``12``, ``-3``, ``0x1F`` (a 32-bit stack slot), ``1.5f`` (a 32-bit float), and
``buf:TYPE:COUNT[:FILL]`` (a buffer of COUNT elements of TYPE, passed by address). Every problem is
one ArgumentError naming the item.
"""

from __future__ import annotations

import math

import numpy as np

from sim.errors import ArgumentError

_DTYPES = {"u8": np.uint8, "u16": np.uint16, "u32": np.uint32, "i8": np.int8, "i16": np.int16, "i32": np.int32,
           "f32": np.float32, "f64": np.float64}
ARGS_HELP = ("comma-separated cdecl arguments: integers (12, -3, 0x1F), 32-bit floats (1.5f), or buffers "
             "allocated in the workload arena and passed by address: buf:TYPE:COUNT[:FILL] with TYPE one of "
             + ", ".join(_DTYPES))


def _f32(text: str, what: str, field: str | None = None) -> np.float32:
    """A 32-bit float, refusing finite values that overflow it (1e40 would silently become inf).
    `field`: the buffer field the text is ("FILL"); None for a float argument (1.5f)."""
    try:
        value = float(text)
    except ValueError:
        if field is None:
            raise ArgumentError(f"{what}: '{text}' before the 'f' is not a decimal float (as in 1.5f)") from None
        raise ArgumentError(f"{what}: {field} must be a decimal float for f32, got '{text}'") from None
    with np.errstate(over="ignore"):
        single = np.float32(value)
    if math.isfinite(value) and not math.isfinite(single):
        raise ArgumentError(f"{what}: {value:g} is out of range for a 32-bit float (largest {np.finfo(np.float32).max:g})")
    return single


def _buffer(item: str, what: str, machine) -> tuple[np.ndarray, np.dtype, int]:
    """Check a buf:TYPE:COUNT[:FILL] item completely (sizes before allocating anything)."""
    parts = item.split(":")
    if len(parts) not in (3, 4) or parts[1] not in _DTYPES:
        raise ArgumentError(f"{what}: expected buf:TYPE:COUNT[:FILL], TYPE one of {', '.join(_DTYPES)}")
    dtype = np.dtype(_DTYPES[parts[1]])
    try:
        count = int(parts[2], 0)
    except ValueError:
        raise ArgumentError(f"{what}: COUNT must be a whole number") from None
    left = machine.arena.size - machine.arena.used
    if count < 0:
        raise ArgumentError(f"{what}: COUNT must not be negative")
    if count * dtype.itemsize > left:
        raise ArgumentError(f"{what}: {count:,} x {dtype.itemsize} bytes does not fit in the workload arena "
                            f"({left:,} of {machine.arena.size:,} bytes left)")
    fill = 0
    if len(parts) == 4:
        if dtype.kind == "f":
            if dtype == np.float32:
                fill = _f32(parts[3], what, "FILL")
            else:
                try:
                    fill = float(parts[3])
                except ValueError:
                    raise ArgumentError(f"{what}: FILL must be a decimal float for {parts[1]}, got '{parts[3]}'") from None
        else:
            try:
                fill = int(parts[3], 0)
            except ValueError:
                raise ArgumentError(f"{what}: FILL must be a whole number for {parts[1]}") from None
            info = np.iinfo(dtype)
            if not info.min <= fill <= info.max:
                raise ArgumentError(f"{what}: FILL {fill} is out of range for {parts[1]} ({info.min}..{info.max})")
    return np.full(count, fill, dtype=dtype), dtype, count


def parse_args(text: str | None, machine) -> tuple[list, list[tuple[str, int, np.dtype, int]]]:
    """Parse --args; buffers are allocated in the machine's arena. Returns (values, buffers)."""
    values, buffers = [], []
    for i, item in enumerate(a.strip() for a in (text or "").split(",") if a.strip()):
        what = f"--args item {i + 1} '{item}'"
        if item.startswith("buf:"):
            data, dtype, count = _buffer(item, what, machine)
            address = machine.arena.put(data)
            buffers.append((item, address, dtype, count))
            values.append(address)
        elif item.lower().endswith("f") and not item.lower().startswith(("0x", "-0x")):
            values.append(_f32(item[:-1], what))
        else:
            try:
                value = int(item, 0)
            except ValueError:
                raise ArgumentError(f"{what}: not an integer, float (1.5f) or buf:TYPE:COUNT") from None
            if not -(1 << 31) <= value < (1 << 32):
                raise ArgumentError(f"{what}: does not fit in a 32-bit stack slot")
            values.append(value)
    return values, buffers
