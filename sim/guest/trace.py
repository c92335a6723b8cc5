"""Native execution traces: the PC stream and every data memory access, recorded without Python.

Two numba ``cfunc`` callbacks are registered with Unicorn's C ``uc_hook_add`` (one UC_HOOK_CODE,
one UC_HOOK_MEM_READ|WRITE). They write into one preallocated uint64 buffer, so tracing costs a C
call per instruction and per access, never a Python frame. When the buffer is nearly full the code
hook stops the emulator *before* the instruction runs; the runner drains the buffer into a
:class:`Trace` and resumes at the same PC, so traces of any length are exact.

The x87 control word (its precision control sets FDIV/FSQRT latency) is known for every
instruction without a per-instruction register read: a third native hook, registered only on the
static PCs of the instructions that can change it (FLDCW, FNINIT, FRSTOR, FNSAVE, FLDENV, FNSTENV,
FXRSTOR: :data:`CONTROL_WORD_WRITERS`, found by the :class:`~sim.guest.emu.Machine`), marks a read as
pending; the code hook of the next instruction reads FPCW (the writer has run by then) and records
(instruction index, control word). Each run segment also starts with a read, so every chunk opens
with the control word in force.

Buffer layout (uint64 words)::

    [0] instructions recorded   [1] instruction capacity
    [2] accesses recorded       [3] access capacity
    [4] overflow flag (an access arrived with no room; must stay 0)
    [5] instruction limit for this run segment (at most the capacity)
    [6] control-word read pending   [7] control-word entries recorded   [8] their capacity
    [9] scratch word uc_reg_read writes FPCW into
    [10] address of uc_emu_stop     [11] address of uc_reg_read (the hooks call them; cacheable code)
    [HEADER : HEADER+icap]             executed PCs
    [HEADER+icap : HEADER+icap+2*acap] access pairs: addr | size << 32 | write << 40, instruction index
    [... : ... + 2*ccap]               control-word entries: instruction index, control word
"""

from __future__ import annotations

import ctypes
import os
from dataclasses import dataclass

import numpy as np
from llvmlite import ir
from numba import carray, cfunc, njit, types
from numba.extending import intrinsic
from unicorn import UC_HOOK_CODE, UC_HOOK_MEM_READ, UC_HOOK_MEM_WRITE, UC_MEM_WRITE
from unicorn import x86_const as X
from unicorn.unicorn_py3.unicorn import uclib

from sim import output
from sim.errors import LimitError

HEADER = 12
# Room kept for the accesses of one instruction (FSAVE/FRSTOR/PUSHA make many); the code hook stops
# the run before an instruction could overflow the access area.
ACCESS_SLACK = 256
_U64 = np.uint64
# Traces live in host memory (4 bytes per instruction, 10 per data access, more while they are
# joined), so one endless or enormous run must stop with a clear message instead of exhausting the
# machine. The limit is on the arrays held; raise it with this variable (megabytes).
TRACE_LIMIT_ENV = "RETROSIM_TRACE_MB"
DEFAULT_TRACE_LIMIT_MB = 2048


def trace_limit_bytes() -> int:
    raw = os.environ.get(TRACE_LIMIT_ENV, "")
    try:
        mb = int(raw) if raw.strip() else DEFAULT_TRACE_LIMIT_MB
    except ValueError:
        raise LimitError(f"{TRACE_LIMIT_ENV}={raw!r}: expected a whole number of megabytes") from None
    if mb < 1:
        raise LimitError(f"{TRACE_LIMIT_ENV}={raw!r}: must be at least 1 (megabytes)")
    return mb << 20


def check_trace_bytes(nbytes: int, instructions: int) -> None:
    """Refuse to hold more than the trace limit (see TRACE_LIMIT_ENV)."""
    limit = trace_limit_bytes()
    if nbytes > limit:
        raise LimitError(f"the trace passed {limit >> 20:,} MB of host memory after {instructions:,} instructions "
                         f"(limit {TRACE_LIMIT_ENV}={limit >> 20}; raise it, or lower --budget or --repeat)")

# The hooks call these two Unicorn functions through addresses the tracer puts in the buffer's
# header (slots 10 and 11), not through ctypes objects: a compiled function that holds a ctypes
# function's address cannot be cached (the address changes with every process), and compiling the
# three hooks anew took most of a second at every start of retrosim.
_H_EMU_STOP = 10
_H_REG_READ = 11
_REG_FPCW = X.UC_X86_REG_FPCW


def _address(fn) -> int:
    return ctypes.cast(fn, ctypes.c_void_p).value


@intrinsic
def _call_emu_stop(typingctx, address, uc):
    """uc_emu_stop(uc) at `address` (uc_err uc_emu_stop(uc_engine *uc))."""
    def codegen(context, builder, signature, args):
        fnty = ir.FunctionType(ir.IntType(32), [ir.IntType(8).as_pointer()])
        builder.call(builder.inttoptr(args[0], fnty.as_pointer()), [args[1]])
        return context.get_dummy_value()
    return types.void(types.uint64, types.voidptr), codegen


@intrinsic
def _call_reg_read(typingctx, address, uc, regid, value):
    """uc_reg_read(uc, regid, value) at `address` (uc_err uc_reg_read(uc_engine *uc, int regid,
    void *value)); `value` is the target's address as an integer."""
    def codegen(context, builder, signature, args):
        i8p = ir.IntType(8).as_pointer()
        fnty = ir.FunctionType(ir.IntType(32), [i8p, ir.IntType(32), i8p])
        builder.call(builder.inttoptr(args[0], fnty.as_pointer()),
                     [args[1], builder.trunc(args[2], ir.IntType(32)), builder.inttoptr(args[3], i8p)])
        return context.get_dummy_value()
    return types.void(types.uint64, types.voidptr, types.int64, types.int64), codegen
FNINIT_CW = 0x037F  # the control word after FNINIT: 64-bit precision, round to nearest, exceptions masked
# capstone mnemonics of the instructions that write the control word (FSAVE/FNSAVE reinitialise the
# x87; FNSTENV masks the exceptions; the WAIT forms decode as WAIT followed by these)
CONTROL_WORD_WRITERS = frozenset({"fldcw", "fninit", "frstor", "fnsave", "fldenv", "fnstenv", "fxrstor"})
# control-word precision field (bits 8-9) -> precision index 0 = 24-bit, 1 = 53-bit, 2 = 64-bit;
# the reserved value 1 is read as 64-bit
PRECISION_OF_FIELD = (0, 2, 1, 2)
PRECISION_BITS = (24, 53, 64)


def precision_of(control_word) -> np.ndarray:
    """Precision index (0 = 24-bit, 1 = 53-bit, 2 = 64-bit) of control words."""
    return np.asarray(PRECISION_OF_FIELD, np.uint8)[(np.asarray(control_word, np.int64) >> 8) & 3]


@cfunc(types.void(types.voidptr, types.uint64, types.uint32, types.voidptr), cache=True)
def _on_code(uc, address, size, user_data):
    head = carray(user_data, HEADER, np.uint64)
    n, icap, m, acap = head[0], head[1], head[2], head[3]
    if n >= head[5] or m + ACCESS_SLACK > acap or head[7] >= head[8]:
        _call_emu_stop(head[_H_EMU_STOP], uc)  # this instruction has not run; it is recorded when the run resumes
        return
    buf = carray(user_data, HEADER + icap + 2 * acap + 2 * head[8], np.uint64)
    if head[6] != 0:  # a control-word writer ran just before: the word in force from here on
        _call_reg_read(head[_H_REG_READ], uc, np.int64(_REG_FPCW), np.int64(head[9:].ctypes.data))
        at = HEADER + icap + 2 * acap + 2 * head[7]
        buf[at] = n
        buf[at + 1] = head[9] & np.uint64(0xFFFF)
        head[7] = head[7] + 1
        head[6] = 0
    buf[HEADER + n] = address
    head[0] = n + 1


@cfunc(types.void(types.voidptr, types.uint64, types.uint32, types.voidptr), cache=True)
def _on_control_word_writer(uc, address, size, user_data):
    head = carray(user_data, HEADER, np.uint64)
    head[6] = 1  # read FPCW before the next instruction, once this one has run


@cfunc(types.void(types.voidptr, types.int32, types.uint64, types.int32, types.int64, types.voidptr), cache=True)
def _on_access(uc, kind, address, size, value, user_data):
    head = carray(user_data, HEADER, np.uint64)
    n, icap, m, acap = head[0], head[1], head[2], head[3]
    if m >= acap:
        head[4] = 1
        return
    buf = carray(user_data, HEADER + icap + 2 * acap, np.uint64)
    at = HEADER + icap + 2 * m
    write = np.uint64(1) if kind == UC_MEM_WRITE else np.uint64(0)
    buf[at] = (address & np.uint64(0xFFFFFFFF)) | (np.uint64(size) << np.uint64(32)) | (write << np.uint64(40))
    buf[at + 1] = n - 1  # the access belongs to the instruction recorded last
    head[2] = m + 1


@dataclass(frozen=True)
class Trace:
    """A dynamic trace of one guest run.

    Invariants (checked by :meth:`validate`):
    - ``pc`` (uint32) lists executed instruction addresses in execution order, one per instruction
      (each iteration of a REP string instruction counts as one execution);
    - ``mem_addr`` (uint32), ``mem_size`` (uint8, bytes), ``mem_write`` (bool) and ``mem_insn``
      (uint32) have one entry per data access in program order; instruction fetches are not accesses;
    - ``mem_insn[k]`` is the index in ``pc`` of the instruction that made access k: non-decreasing,
      and below ``len(pc)``;
    - ``cw_at`` (uint32) and ``cw_value`` (uint16), one entry each per x87 control-word reading:
      from instruction ``cw_at[j]`` on, the control word is ``cw_value[j]`` (until the next entry);
      ``cw_at`` is non-decreasing, below ``len(pc)``, and starts at 0 when there are instructions.
      A trace made without them (an .npz from before they existed, a hand-built trace) is taken
      to run in the FNINIT state, control word 0x037F.
    """

    pc: np.ndarray
    mem_addr: np.ndarray
    mem_size: np.ndarray
    mem_write: np.ndarray
    mem_insn: np.ndarray
    cw_at: np.ndarray | None = None
    cw_value: np.ndarray | None = None

    def __post_init__(self):
        if self.cw_at is None or self.cw_value is None:
            n = 1 if self.pc.size else 0
            object.__setattr__(self, "cw_at", np.zeros(n, np.uint32))
            object.__setattr__(self, "cw_value", np.full(n, FNINIT_CW, np.uint16))

    def control_word_at(self, positions) -> np.ndarray:
        """The control word in force at each instruction index in `positions`."""
        j = np.searchsorted(self.cw_at, np.asarray(positions, np.int64), side="right") - 1
        return self.cw_value[np.maximum(j, 0)]

    def precision_at(self, positions) -> np.ndarray:
        """Precision index (0 = 24-bit, 1 = 53-bit, 2 = 64-bit) in force at each instruction index."""
        return precision_of(self.control_word_at(positions))

    def head(self, n: int) -> Trace:
        """The first `n` instructions and their accesses."""
        return self.part(0, n)

    def part(self, start: int, stop: int) -> Trace:
        """Instructions start .. stop - 1 as a trace of their own (accesses counted from `start`,
        opening with the control word in force at `start`): a chunk, as a streamed run sees it."""
        stop = min(stop, self.pc.size)
        m0, m1 = (int(x) for x in np.searchsorted(self.mem_insn, [start, stop], side="left"))
        if stop <= start:  # no instruction: no control word either
            cw_at, cw_value = np.zeros(0, np.uint32), np.zeros(0, np.uint16)
        else:
            j0 = max(0, int(np.searchsorted(self.cw_at, start, side="right")) - 1)
            later = slice(j0 + 1, max(j0 + 1, int(np.searchsorted(self.cw_at, stop, side="left"))))
            cw_at = np.concatenate([[0], self.cw_at[later] - start]).astype(np.uint32)
            cw_value = np.concatenate([self.cw_value[j0:j0 + 1], self.cw_value[later]]).astype(np.uint16)
        return Trace(self.pc[start:stop], self.mem_addr[m0:m1], self.mem_size[m0:m1], self.mem_write[m0:m1],
                     self.mem_insn[m0:m1] if start == 0 else (self.mem_insn[m0:m1] - start).astype(np.uint32),
                     cw_at, cw_value)

    @property
    def instructions(self) -> int:
        return int(self.pc.size)

    @property
    def accesses(self) -> int:
        return int(self.mem_addr.size)

    @property
    def reads(self) -> int:
        return int(self.accesses - np.count_nonzero(self.mem_write))

    @property
    def writes(self) -> int:
        return int(np.count_nonzero(self.mem_write))

    def validate(self) -> None:
        n = self.mem_addr.size
        expect = {"pc": np.uint32, "mem_addr": np.uint32, "mem_size": np.uint8, "mem_write": np.bool_, "mem_insn": np.uint32,
                  "cw_at": np.uint32, "cw_value": np.uint16}
        for name, dtype in expect.items():
            arr = getattr(self, name)
            if arr.dtype != dtype or arr.ndim != 1:
                raise ValueError(f"trace field {name}: expected 1-D {np.dtype(dtype)}, got {arr.ndim}-D {arr.dtype}")
            if name not in ("pc", "cw_at", "cw_value") and arr.size != n:
                raise ValueError(f"trace field {name}: {arr.size} entries, mem_addr has {n}")
        if self.cw_value.size != self.cw_at.size:
            raise ValueError(f"trace field cw_value: {self.cw_value.size} entries, cw_at has {self.cw_at.size}")
        if self.pc.size:
            if self.cw_at.size == 0 or int(self.cw_at[0]) != 0:
                raise ValueError("trace field cw_at: the control word at the first instruction is missing")
            if np.any(np.diff(self.cw_at.astype(np.int64)) < 0) or int(self.cw_at[-1]) >= self.pc.size:
                raise ValueError("trace field cw_at: not in program order, or past the end of pc")
        elif self.cw_at.size:
            raise ValueError("trace field cw_at: control words of a trace without instructions")
        if n:
            if not _non_decreasing(self.mem_insn):
                raise ValueError("trace field mem_insn: not in program order")
            if int(self.mem_insn[-1]) >= self.pc.size:
                raise ValueError("trace field mem_insn: names an instruction past the end of pc")
            if not self.mem_size.all():
                raise ValueError("trace field mem_size: zero-byte access")

    @property
    def nbytes(self) -> int:
        return sum(getattr(self, k).nbytes for k in _FIELDS)

    def save(self, path: str | os.PathLike) -> None:
        """Write the trace as .npz, atomically (an interrupted write leaves any old file intact;
        a device, FIFO or folder at `path` is refused, see sim.output)."""
        with output.atomic_output(path, "--out", suffix=".npz") as f:
            np.savez_compressed(f, **{k: getattr(self, k) for k in _FIELDS})

    @classmethod
    def load(cls, path: str | os.PathLike) -> Trace:
        with np.load(path) as data:
            trace = cls(**{k: data[k] for k in _FIELDS if k in data.files or k not in _OPTIONAL})
        trace.validate()
        return trace

    @classmethod
    def concatenate(cls, parts: list[Trace]) -> Trace:
        """One trace from consecutive parts. Empties `parts` as it copies them, so memory peaks at
        the whole trace plus one part, not twice the trace."""
        if not parts:
            return cls.empty()
        if len(parts) == 1:
            return parts.pop()  # traces are immutable by convention: no copy
        sizes = [(p.pc.size, p.mem_addr.size, p.cw_at.size) for p in parts]
        n, m, c = (sum(s[k] for s in sizes) for k in range(3))
        out = cls(np.empty(n, np.uint32), np.empty(m, np.uint32), np.empty(m, np.uint8), np.empty(m, np.bool_),
                  np.empty(m, np.uint32), np.empty(c, np.uint32), np.empty(c, np.uint16))
        i = j = q = 0
        parts.reverse()
        while parts:
            p = parts.pop()
            out.pc[i:i + p.pc.size] = p.pc
            k = p.mem_addr.size
            out.mem_addr[j:j + k] = p.mem_addr
            out.mem_size[j:j + k] = p.mem_size
            out.mem_write[j:j + k] = p.mem_write
            out.mem_insn[j:j + k] = p.mem_insn + np.uint32(i)
            out.cw_at[q:q + p.cw_at.size] = p.cw_at + np.uint32(i)
            out.cw_value[q:q + p.cw_at.size] = p.cw_value
            i, j, q = i + p.pc.size, j + k, q + p.cw_at.size
        return out

    @classmethod
    def empty(cls) -> Trace:
        return cls(np.zeros(0, np.uint32), np.zeros(0, np.uint32), np.zeros(0, np.uint8),
                   np.zeros(0, np.bool_), np.zeros(0, np.uint32))


_FIELDS = ("pc", "mem_addr", "mem_size", "mem_write", "mem_insn", "cw_at", "cw_value")
_OPTIONAL = ("cw_at", "cw_value")  # absent from traces saved before they existed


@njit(cache=True, nogil=True)
def _non_decreasing(a) -> bool:
    """Whether `a` never decreases (checked in one pass: np.diff of a widened copy held two more
    arrays of the trace's size)."""
    for k in range(1, a.shape[0]):
        if a[k] < a[k - 1]:
            return False
    return True


class NativeTracer:
    """Owns the trace buffer and the two native hooks on one Unicorn engine."""

    def __init__(self, uc, instruction_capacity: int = 1 << 20, access_capacity: int = 1 << 20,
                 control_word_pcs=(), control_word_capacity: int = 1 << 12):
        """`control_word_pcs`: static PCs of the instructions that write the x87 control word
        (the machine finds them: :meth:`sim.guest.emu.Machine.control_word_pcs`)."""
        self.uc = uc
        self.icap = int(instruction_capacity)
        self.acap = int(access_capacity) + ACCESS_SLACK
        self.ccap = int(control_word_capacity)
        self.cw_pcs = sorted(set(int(p) for p in control_word_pcs))
        self.buffer = np.zeros(HEADER + self.icap + 2 * self.acap + 2 * self.ccap, dtype=np.uint64)
        self.buffer[1], self.buffer[3], self.buffer[5] = self.icap, self.acap, self.icap
        self.buffer[6], self.buffer[8] = 1, self.ccap  # the first instruction reads the control word
        self.buffer[_H_EMU_STOP] = _address(uclib.uc_emu_stop)  # what the hooks call (see _H_EMU_STOP)
        self.buffer[_H_REG_READ] = _address(uclib.uc_reg_read)
        self._handles: list[ctypes.c_size_t] = []
        self.recorded = 0  # instructions recorded since the last reset (all drained chunks)
        self.held_bytes = 0  # bytes of the drained chunks (bounded by trace_limit_bytes)
        self._parts: list[Trace] = []
        self.active = False
        # a streamed run (sim/timing/stream.py) hands each validated chunk to `sink` instead of holding it
        self.sink = None

    def attach(self) -> None:
        if self.active:
            return
        ptr = ctypes.c_void_p(self.buffer.ctypes.data)
        # the writers' hooks come after the code hook: Unicorn calls hooks in the order added, so at
        # a writer that follows another the code hook first reads the first writer's word
        hooks = [(UC_HOOK_CODE, _on_code, 1, 0), (UC_HOOK_MEM_READ | UC_HOOK_MEM_WRITE, _on_access, 1, 0)]
        hooks += [(UC_HOOK_CODE, _on_control_word_writer, pc, pc) for pc in self.cw_pcs]
        for kind, fn, begin, end in hooks:
            handle = ctypes.c_size_t()
            err = uclib.uc_hook_add(self.uc._uch, ctypes.byref(handle), kind, ctypes.c_void_p(fn.address), ptr,
                                    ctypes.c_uint64(begin), ctypes.c_uint64(end))
            if err:
                raise RuntimeError(f"uc_hook_add failed with Unicorn error {err}")
            self._handles.append(handle)
        self.uc.ctl_flush_tb()  # blocks translated before the hooks existed would run uninstrumented
        self.active = True

    def detach(self) -> None:
        for handle in self._handles:
            uclib.uc_hook_del(self.uc._uch, handle)
        self._handles.clear()
        self.uc.ctl_flush_tb()  # and blocks translated with them would keep calling them
        self.active = False

    def limit(self, instructions: int) -> None:
        """Stop the next run segment after at most `instructions` more recorded instructions."""
        self.buffer[5] = max(0, min(self.icap, int(instructions)))

    def drain(self) -> None:
        """Move the buffer's contents into an immutable chunk and empty the buffer."""
        b = self.buffer
        if b[4]:
            raise RuntimeError("native trace lost memory accesses (buffer overflow)")
        n, m = int(b[0]), int(b[2])
        if self.sink is None:
            self.held_bytes += 4 * n + 10 * m + 6 * int(b[7])
        try:
            check_trace_bytes(self.held_bytes, self.recorded + n)
        except LimitError:
            b[0] = b[2] = b[7] = 0  # drop everything held: the run is abandoned
            b[6] = 1
            self._parts.clear()
            self.recorded = self.held_bytes = 0
            raise
        pcs = b[HEADER:HEADER + n].astype(np.uint32)
        pairs = b[HEADER + self.icap:HEADER + self.icap + 2 * m].reshape(m, 2)
        packed = pairs[:, 0]
        at = HEADER + self.icap + 2 * self.acap
        words = b[at:at + 2 * int(b[7])].reshape(-1, 2)
        chunk = Trace(
            pc=pcs,
            mem_addr=(packed & _U64(0xFFFFFFFF)).astype(np.uint32),
            mem_size=((packed >> _U64(32)) & _U64(0xFF)).astype(np.uint8),
            mem_write=((packed >> _U64(40)) & _U64(1)).astype(np.bool_),
            mem_insn=pairs[:, 1].astype(np.uint32),
            cw_at=words[:, 0].astype(np.uint32) if n else np.zeros(0, np.uint32),
            cw_value=words[:, 1].astype(np.uint16) if n else np.zeros(0, np.uint16),
        )
        self.recorded += n
        b[0] = b[2] = b[7] = 0
        b[6] = 1  # the next chunk opens with the control word in force
        if self.sink is None:
            self._parts.append(chunk)
        elif n:
            chunk.validate()
            self.sink(chunk)

    def executed_pcs(self) -> np.ndarray:
        """The PCs recorded since the last take and not yet handed to a sink (a faulted run's last
        instructions: the ISA check looks at them before the fault is reported)."""
        b = self.buffer
        pending = b[HEADER:HEADER + int(b[0])].astype(np.uint32)
        return np.concatenate([*(p.pc for p in self._parts), pending]) if self._parts else pending

    def take(self) -> Trace:
        """The whole trace since the last take, as one validated :class:`Trace`."""
        self.drain()
        trace = Trace.concatenate(self._parts)
        self._parts.clear()
        self.recorded = self.held_bytes = 0
        trace.validate()
        return trace
