"""Run kernels under Unicorn (i686): guest memory map, cdecl calls, budgets, faults, RDTSC, traces.

The emulator knows nothing about timing. A call returns the kernel's results and, when asked, the
native :class:`~sim.guest.trace.Trace` of what it executed. RDTSC is intercepted so that a timing model
can answer it (see :class:`RdtscEvent`).
"""

from __future__ import annotations

import ctypes
import mmap
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from capstone import CS_ARCH_X86, CS_MODE_32, Cs
from unicorn import (UC_ARCH_X86, UC_ERR_EXCEPTION, UC_ERR_FETCH_PROT, UC_ERR_FETCH_UNMAPPED, UC_ERR_INSN_INVALID, UC_ERR_NOMEM,
                     UC_ERR_READ_PROT, UC_ERR_READ_UNMAPPED, UC_ERR_WRITE_PROT, UC_ERR_WRITE_UNMAPPED, UC_HOOK_CODE,
                     UC_HOOK_INSN, UC_HOOK_INTR, UC_HOOK_MEM_INVALID, UC_HOOK_MEM_READ, UC_HOOK_MEM_WRITE,
                     UC_MEM_FETCH_PROT, UC_MEM_FETCH_UNMAPPED, UC_MEM_WRITE, UC_MEM_WRITE_PROT, UC_MEM_WRITE_UNMAPPED, UC_MODE_32, UC_PROT_ALL, UC_PROT_EXEC, UC_PROT_READ, UC_PROT_WRITE, Uc, UcError)
from unicorn import x86_const as X
from unicorn.unicorn_py3.unicorn import uclib

from sim.errors import ArgumentError, GuestFault, LoadError, RunawayKernel, UntranslatableCode
from sim.guest import asm
from sim.guest import elf
from sim.guest.cpu import GuestCpu
from sim.guest.kernels import EntryPoint, entry_points
from sim.guest.trace import CONTROL_WORD_WRITERS, NativeTracer, Trace

DEFAULT_BUDGET = 200_000_000  # instructions per call; 0 means unlimited
DEFAULT_ARENA = 64 << 20
# Unicorn's translated-code buffer. Its default is 1 GB of address space per engine (the validation
# run peaked at 18 GB virtual for 249 MB resident); a kernel's code is at most 12 MB, and a full
# buffer is only flushed and refilled, so 64 MB costs nothing measurable and lets a `ulimit -v` hold.
TCG_BUFFER = 64 << 20
NO_MEMORY = ("out of host memory (a limit of the machine or of `ulimit -v`) for a {what}; "
             "lower the workload (--budget, --repeat, the scene's size) or raise the limit")


def _reserve(nbytes: int, what: str) -> None:
    """Fail with MemoryError unless `nbytes` of address space can be had now. Unicorn cannot report
    a failed allocation of its code buffer: it prints its own message and exits the process."""
    try:
        probe = mmap.mmap(-1, nbytes, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS, prot=0)  # PROT_NONE: address space only
    except OSError:
        raise MemoryError(NO_MEMORY.format(what=what)) from None
    probe.close()
FPU_RESET_CW = 0x037F  # FNINIT state: all exceptions masked, 64-bit precision, round to nearest

_GPRS = {"eax": X.UC_X86_REG_EAX, "ebx": X.UC_X86_REG_EBX, "ecx": X.UC_X86_REG_ECX, "edx": X.UC_X86_REG_EDX,
         "esi": X.UC_X86_REG_ESI, "edi": X.UC_X86_REG_EDI, "ebp": X.UC_X86_REG_EBP}
_FAULTS = {
    UC_ERR_READ_UNMAPPED: "read of unmapped memory",
    UC_ERR_WRITE_UNMAPPED: "write to unmapped memory",
    UC_ERR_FETCH_UNMAPPED: "jump to unmapped memory",
    UC_ERR_READ_PROT: "read of protected memory",
    UC_ERR_WRITE_PROT: "write to read-only memory",
    UC_ERR_FETCH_PROT: "execution of non-executable memory",
    UC_ERR_INSN_INVALID: "invalid instruction",
}
_INTERRUPTS = {0: "divide error (#DE)", 1: "debug trap", 3: "breakpoint (INT3)", 4: "overflow (INTO)",
               5: "BOUND range exceeded", 6: "invalid opcode (#UD)", 13: "general protection fault (#GP)"}
_RDTSC_CB = ctypes.CFUNCTYPE(ctypes.c_uint32, ctypes.c_void_p, ctypes.c_void_p)
_disasm = Cs(CS_ARCH_X86, CS_MODE_32)


@dataclass(frozen=True)
class RdtscEvent:
    """An RDTSC the guest executed: where, and how many instructions of this call ran before it
    (None when the call is not traced). A timing model answers with the simulated cycle count."""

    pc: int
    instructions: int | None


RdtscSource = Callable[[RdtscEvent], int]


@dataclass(frozen=True)
class CallResult:
    entry: str
    eax: int
    edx: int
    trace: Trace | None

    @property
    def edx_eax(self) -> int:
        return (self.edx << 32) | self.eax

    @property
    def instructions(self) -> int | None:
        return None if self.trace is None else self.trace.instructions


def arg_word(value, index: int) -> int:
    """One cdecl stack slot: ints (signed or unsigned, 32-bit) and 32-bit floats."""
    if isinstance(value, (bool, np.bool_)):
        raise ArgumentError(f"argument {index}: booleans are ambiguous; pass 0 or 1")
    if isinstance(value, (int, np.integer)):
        v = int(value)
        if not -(1 << 31) <= v < (1 << 32):
            raise ArgumentError(f"argument {index}: {v} does not fit in 32 bits")
        return v & 0xFFFFFFFF
    if isinstance(value, (float, np.float32)):
        return struct.unpack("<I", struct.pack("<f", float(value)))[0]
    raise ArgumentError(f"argument {index}: cannot pass {type(value).__name__} {value!r} in a 32-bit stack slot")


class Arena:
    """The workload region: one linear block with bump allocation, so buffer addresses (and cache
    behaviour) depend only on the order and size of allocations."""

    def __init__(self, uc: Uc, base: int, size: int):
        self.uc, self.base, self.size, self.top = uc, base, size, base

    def alloc(self, nbytes: int, align: int = 64) -> int:
        at = elf.align_up(self.top, align)
        if at + nbytes > self.base + self.size:
            raise ArgumentError(f"workload arena full: {nbytes} bytes requested, "
                                f"{self.base + self.size - at} of {self.size} left")
        self.top = at + nbytes
        return at

    def put(self, array: np.ndarray, align: int = 64) -> int:
        data = np.ascontiguousarray(array).tobytes()
        at = self.alloc(len(data), align)
        self.uc.mem_write(at, data)
        return at

    def get(self, address: int, dtype, count: int) -> np.ndarray:
        dtype = np.dtype(dtype)
        return np.frombuffer(bytes(self.uc.mem_read(address, dtype.itemsize * count)), dtype=dtype).copy()

    def reset(self) -> None:
        """Free everything and zero what was used, so the next workload starts from the same state."""
        used = elf.page_up(self.top - self.base)
        if used:
            self.uc.mem_write(self.base, bytes(used))
        self.top = self.base

    @property
    def used(self) -> int:
        return self.top - self.base


# x87 register-stack forms that Unicorn 2.1 cannot translate in long unbroken runs: about 235 of
# them back to back (with no other instruction between) crash the process while translating one
# block (measured: 230 FXCH ST(1) run, 240 crash; the same with FADD ST(1),ST). Any other instruction
# between them avoids it. The second bytes, per first byte: D9 C8-CF FXCH; DC C0-CF, E0-FF the
# arithmetic ST(i),ST forms; DD C0-D7 FFREE, FXCH4, FST ST(i); DF C8-CF FXCH7.
_UNTRANSLATABLE_RUN = 200
X87_RUN_WORDS = "x87 register-stack instructions in a row (FXCH, FST ST(i), FFREE, FADD ST(i),ST and the like)"
X87_RUN_LIMIT_WORDS = (f"the emulator (Unicorn 2.1) crashes translating about 235 of them in a row, so more than "
                       f"{_UNTRANSLATABLE_RUN} are refused: put another instruction among them")
_X87_RUN_FORMS = {0xD9: range(0xC8, 0xD0), 0xDC: [*range(0xC0, 0xD0), *range(0xE0, 0x100)],
                  0xDD: range(0xC0, 0xD8), 0xDF: range(0xC8, 0xD0)}


def _x87_run_start(code: bytes, limit: int = _UNTRANSLATABLE_RUN) -> tuple[int, int] | None:
    """(offset, length) of the first run of more than `limit` back-to-back two-byte x87 forms of
    _X87_RUN_FORMS in `code`, or None. A byte scan (both alignments): real code holds no such run by
    accident, and the scan costs microseconds where a disassembly of a large wrapper costs seconds."""
    b = np.frombuffer(code, dtype=np.uint8)
    if len(b) < 2 * (limit + 1):
        return None
    hit = np.zeros(len(b) - 1, dtype=bool)
    for first, seconds in _X87_RUN_FORMS.items():
        second = np.zeros(256, dtype=bool)
        second[list(seconds)] = True
        hit |= (b[:-1] == first) & second[b[1:]]
    for parity in (0, 1):
        h = hit[parity::2].astype(np.int8)
        edges = np.flatnonzero(np.diff(np.concatenate(([0], h, [0]))))
        starts, ends = edges[::2], edges[1::2]
        long = np.flatnonzero(ends - starts > limit)
        if long.size:
            k = long[0]
            return parity + 2 * int(starts[k]), int(ends[k] - starts[k])
    return None


class Machine:
    """One guest: a loaded kernel object, a stack, an arena, and the Unicorn engine that runs them."""

    def __init__(self, image: elf.GuestImage, entries: dict[str, EntryPoint] | None = None,
                 arena_size: int = DEFAULT_ARENA, rdtsc: RdtscSource | None = None,
                 emulator_cpu: str | None = None):
        self.image = image
        self.entries = entries or {}
        self.rdtsc = rdtsc
        arena_size = elf.page_up(arena_size)
        # everything the engine maps below: code buffer, arena, stack, code and data, and a margin
        _reserve(TCG_BUFFER + arena_size + elf.STACK_SIZE + elf.CODE_LIMIT + (64 << 20), "guest emulator")
        self.uc = uc = Uc(UC_ARCH_X86, UC_MODE_32)
        uc.ctl_set_tcg_buffer_size(TCG_BUFFER)
        try:
            self._map(image, arena_size, emulator_cpu)
        except UcError as e:
            if e.errno == UC_ERR_NOMEM:
                raise MemoryError(NO_MEMORY.format(what="guest emulator")) from None
            raise
        self.arena = Arena(uc, elf.ARENA_BASE, arena_size)
        run = _x87_run_start(bytes(image.code[1]))
        if run is not None:
            raise UntranslatableCode(f"{image.path}: the code at {self.where(image.code[0] + run[0])} holds {run[1]} "
                                     f"{X87_RUN_WORDS}; {X87_RUN_LIMIT_WORDS}", *run)
        self.reset_fpu()
        self._fault: tuple[str, int] | None = None
        self._interrupt: int | None = None
        uc.hook_add(UC_HOOK_MEM_INVALID, self._on_invalid)
        uc.hook_add(UC_HOOK_INTR, self._on_interrupt)
        self._tracer: NativeTracer | None = None
        # called with the PCs a traced run executed before a guest fault, before the fault is raised:
        # an instruction the CPU lacks (the ISA check) is the cause to report, not what it broke later
        self.before_fault: Callable[[np.ndarray], None] | None = None
        # instructions per trace chunk (the tracer's buffer); a streamed run asks for smaller ones
        self.trace_chunk = 1 << 20
        self._rdtsc_cb = _RDTSC_CB(self._on_rdtsc)  # keep a reference: Unicorn holds only the pointer
        handle = ctypes.c_size_t()
        uclib.uc_hook_add(uc._uch, ctypes.byref(handle), UC_HOOK_INSN, ctypes.cast(self._rdtsc_cb, ctypes.c_void_p),
                          None, ctypes.c_uint64(1), ctypes.c_uint64(0), X.UC_X86_INS_RDTSC)

    def _map(self, image: elf.GuestImage, arena_size: int, emulator_cpu: str | None) -> None:
        uc = self.uc
        if emulator_cpu:  # a Unicorn CPU model (e.g. ATHLON: the default one has no 3DNow!)
            uc.ctl_set_cpu_model(getattr(X, f"UC_CPU_X86_{emulator_cpu}"))
        uc.mem_map(elf.EXIT_ADDR, elf.PAGE, UC_PROT_READ | UC_PROT_EXEC)
        uc.mem_write(elf.EXIT_ADDR, b"\xf4")  # HLT: never executed, the run stops on reaching it
        for base, blob, prot in ((image.code[0], image.code[1], UC_PROT_READ | UC_PROT_EXEC),
                                 (image.data[0], image.data[1], UC_PROT_READ | UC_PROT_WRITE)):
            if blob:
                uc.mem_map(base, elf.page_up(len(blob)), prot)
                uc.mem_write(base, bytes(blob))
        uc.mem_map(elf.STACK_BASE, elf.STACK_SIZE, UC_PROT_READ | UC_PROT_WRITE)
        uc.mem_map(elf.ARENA_BASE, arena_size, UC_PROT_ALL)

    @classmethod
    def from_source(cls, source: str | Path, assembler: str | None = None, cpu: GuestCpu | None = None,
                    **kwargs) -> Machine:
        """`cpu`: assemble for that CPU's instruction set (default plain i686), and emulate with the
        Unicorn CPU model it names (`emulator_cpu`), if any."""
        obj = asm.assemble(source, assembler, cpu)
        if cpu is not None and "emulator_cpu" not in kwargs:
            kwargs["emulator_cpu"] = cpu.emulator_cpu
        try:
            image = elf.load_object(obj, source)
        except LoadError:
            asm.evict(obj)  # an object that cannot load is useless in the cache (and may be large)
            raise
        return cls(image, entry_points(source), **kwargs)

    # -- state -------------------------------------------------------------------------------
    def reset_fpu(self) -> None:
        """Put the x87 in its FNINIT state. Unicorn starts with control word 0x0000, which would
        silently mean 24-bit precision and unmasked exceptions."""
        self.uc.reg_write(X.UC_X86_REG_FPCW, FPU_RESET_CW)
        self.uc.reg_write(X.UC_X86_REG_FPSW, 0)
        self.uc.reg_write(X.UC_X86_REG_FPTAG, 0xFFFF)

    def control_word_pcs(self) -> list[int]:
        """Static PCs of the instructions that write the x87 control word (FLDCW, FNINIT, FRSTOR...:
        trace.CONTROL_WORD_WRITERS), from a linear sweep of the code section that skips bytes it
        cannot decode. The tracer hooks only these; an extra PC (data that decodes as a writer)
        costs one redundant control-word read, never a wrong one."""
        if not hasattr(self, "_cw_pcs"):
            base, blob = self.image.code
            sweep = Cs(CS_ARCH_X86, CS_MODE_32)
            sweep.skipdata = True
            self._cw_pcs = [insn.address for insn in sweep.disasm(bytes(blob), base)
                            if insn.mnemonic in CONTROL_WORD_WRITERS] if blob else []
        return self._cw_pcs

    def reg(self, name: str) -> int:
        return self.uc.reg_read(_GPRS[name] if name in _GPRS else getattr(X, f"UC_X86_REG_{name.upper()}"))

    def set_reg(self, name: str, value: int) -> None:
        self.uc.reg_write(_GPRS[name] if name in _GPRS else getattr(X, f"UC_X86_REG_{name.upper()}"), value)

    def symbol(self, name: str) -> int:
        return self.image.symbol(name)

    def where(self, pc: int) -> str:
        """`symbol+offset` for a guest PC, for error messages."""
        best = None
        for name, addr in self.image.symbols.items():
            if addr <= pc and (best is None or addr > best[1]):
                best = (name, addr)
        if self.image.section_of(pc) is None:
            base, code = self.image.code
            if not base <= pc < base + len(code):  # the guest runs where no kernel code is: say so
                return f"{pc:#010x} (outside the kernel's code: a jump or call to a bare address?)"
            return f"{pc:#010x}"
        if best is None:
            return f"{pc:#010x}"
        return f"{pc:#010x} ({best[0]}+{pc - best[1]:#x})"

    # -- hooks (Python, but only on rare events) -----------------------------------------------
    def _on_invalid(self, uc, kind, address, size, value, user_data):
        if kind in (UC_MEM_WRITE_UNMAPPED, UC_MEM_WRITE_PROT):
            self._fault = ("write", address)
        elif kind in (UC_MEM_FETCH_UNMAPPED, UC_MEM_FETCH_PROT):
            self._fault = ("execute", address)  # an instruction fetch, not a data read
        else:
            self._fault = ("read", address)
        return False

    def _on_interrupt(self, uc, intno, user_data):
        self._interrupt = intno
        uc.emu_stop()

    def _on_rdtsc(self, uc_handle, user_data) -> int:
        pc = self.uc.reg_read(X.UC_X86_REG_EIP)
        tr = self._tracer
        # the code hook has already recorded this RDTSC itself: count only what ran before it
        done = tr.recorded + int(tr.buffer[0]) - 1 if tr is not None and tr.active else None
        value = self.rdtsc(RdtscEvent(pc, done)) if self.rdtsc else (done or 0)
        self.uc.reg_write(X.UC_X86_REG_EAX, value & 0xFFFFFFFF)
        self.uc.reg_write(X.UC_X86_REG_EDX, (value >> 32) & 0xFFFFFFFF)
        return 1  # skip Unicorn's own RDTSC (host-time based, hence not deterministic)

    # -- calls -------------------------------------------------------------------------------
    def call(self, entry: str, *args, budget: int = DEFAULT_BUDGET, trace: bool | str = False,
             regs: dict[str, int] | None = None, on_chunk=None) -> CallResult:
        """Call a cdecl entry point. `trace`: False, True (native), or "python" (Python hooks, for
        comparison only). `regs` preloads registers (e.g. to study an uninitialised EDX).
        `on_chunk` (native traces): called with each chunk of the trace, in order, as the run
        records it (at most `trace_chunk` instructions each); the call's result then holds no trace."""
        declared = self.entries.get(entry)
        if declared is not None and len(args) != len(declared.args):
            raise ArgumentError(f"{self.image.path}:{declared.line}: {declared.signature(returns=False)} takes "
                                f"{len(declared.args)} argument(s), {len(args)} given")
        start = self.symbol(entry)
        words = [arg_word(a, i) for i, a in enumerate(args)]
        esp = elf.STACK_BASE + elf.STACK_SIZE - 64 - 4 * len(words)
        self.uc.mem_write(esp, struct.pack(f"<{1 + len(words)}I", elf.EXIT_ADDR, *words))
        self.uc.reg_write(X.UC_X86_REG_ESP, esp)
        for name, value in (regs or {}).items():
            self.set_reg(name, value & 0xFFFFFFFF)
        if trace == "python":
            result = self._run_python_traced(start, budget)
        elif trace:
            result = self._run_traced(start, budget, on_chunk)
        else:
            self._run_segment(start, budget)
            self._check_finished(budget)
            result = None
        return CallResult(entry, self.reg("eax"), self.reg("edx"), result)

    def _run_segment(self, pc: int, count: int = 0) -> None:
        self._fault = self._interrupt = None
        try:
            self.uc.emu_start(pc, elf.EXIT_ADDR, 0, count)
        except UcError as e:
            raise self._describe_fault(e.errno) from None
        if self._interrupt is not None:
            raise self._describe_fault(UC_ERR_EXCEPTION)

    def _check_finished(self, budget: int) -> None:
        pc = self.reg("eip")
        if pc != elf.EXIT_ADDR:
            raise RunawayKernel(f"{self.image.path}: kernel ran past its budget of {budget:,} instructions; stopped at "
                                f"{self.where(pc)}: {self.disassemble(pc)} (raise --budget if it is not a hang)", pc)

    def _run_traced(self, start: int, budget: int, on_chunk=None) -> Trace | None:
        if self._tracer is None:
            self._tracer = NativeTracer(self.uc, instruction_capacity=self.trace_chunk,
                                        control_word_pcs=self.control_word_pcs())
        tr = self._tracer
        tr.sink = on_chunk
        tr.attach()
        pc = start
        try:
            while pc != elf.EXIT_ADDR:
                if budget and tr.recorded >= budget:
                    self._check_finished(budget)
                tr.limit(budget - tr.recorded if budget else tr.icap)
                try:
                    self._run_segment(pc)
                except GuestFault:
                    if self.before_fault is not None:
                        # the instructions that completed (the last one recorded is the one that
                        # faulted: its fault is the error), in the kernel's code (a jump to nowhere
                        # is recorded at its target)
                        pcs = tr.executed_pcs()[:-1]
                        base, code = self.image.code
                        self.before_fault(pcs[(pcs >= base) & (pcs < base + len(code))])
                    raise
                tr.drain()
                pc = self.reg("eip")
            if on_chunk is not None:
                tr.drain()
                return None
            return tr.take()
        finally:
            tr.detach()
            tr.sink = None
            tr.take()  # drop a partial trace left by a fault

    def _run_python_traced(self, start: int, budget: int) -> Trace:
        pcs: list[int] = []
        accesses: list[tuple[int, int, bool, int]] = []
        words: list[tuple[int, int]] = []

        def on_code(uc, address, size, _):
            cw = uc.reg_read(X.UC_X86_REG_FPCW)  # before this instruction: the word in force for it
            if not words or words[-1][1] != cw:
                words.append((len(pcs), cw))
            pcs.append(address)

        def on_access(uc, kind, address, size, value, _):
            accesses.append((address, size, kind == UC_MEM_WRITE, len(pcs) - 1))

        hooks = [self.uc.hook_add(UC_HOOK_CODE, on_code),
                 self.uc.hook_add(UC_HOOK_MEM_READ | UC_HOOK_MEM_WRITE, on_access)]
        self.uc.ctl_flush_tb()  # see NativeTracer.attach
        try:
            self._run_segment(start, budget)
            self._check_finished(budget)
        finally:
            for h in hooks:
                self.uc.hook_del(h)
            self.uc.ctl_flush_tb()
        acc = np.array(accesses, dtype=np.int64).reshape(-1, 4)
        cw = np.array(words, dtype=np.int64).reshape(-1, 2)
        return Trace(np.array(pcs, dtype=np.uint32), acc[:, 0].astype(np.uint32), acc[:, 1].astype(np.uint8),
                     acc[:, 2].astype(np.bool_), acc[:, 3].astype(np.uint32), cw[:, 0].astype(np.uint32),
                     cw[:, 1].astype(np.uint16))

    # -- errors ------------------------------------------------------------------------------
    def disassemble(self, pc: int) -> str:
        try:
            code = bytes(self.uc.mem_read(pc, 16))
        except UcError:
            return "<unmapped>"
        for insn in _disasm.disasm(code, pc, 1):
            return f"{insn.mnemonic} {insn.op_str}".strip()
        return f"<undecodable: {code[:4].hex(' ')}>"

    def _trap_pc(self, pc: int, intno: int) -> int:
        """The PC of the instruction that raised interrupt `intno`. Traps (INT n, INT3, INTO, INT1)
        leave EIP after the instruction; faults (#DE, #UD, #GP...) leave it on the instruction."""
        for length, pattern in ((2, bytes([0xCD, intno & 0xFF])), (1, {3: b"\xcc", 4: b"\xce", 1: b"\xf1"}.get(intno))):
            if pattern is None or pc < length:
                continue
            try:
                if bytes(self.uc.mem_read(pc - length, length)) == pattern:
                    return pc - length
            except UcError:
                pass
        return pc

    def _describe_fault(self, errno: int) -> GuestFault:
        """The fault as one line that starts with the kernel's source file."""
        fault = self._fault_of(errno)
        fault.args = (f"{self.image.path}: {fault.args[0]}",)
        return fault

    def _fault_of(self, errno: int) -> GuestFault:
        pc = self.reg("eip")
        if errno == UC_ERR_EXCEPTION and self._interrupt is not None:
            pc = self._trap_pc(pc, self._interrupt)
            what = _INTERRUPTS.get(self._interrupt, f"interrupt {self._interrupt:#x}" if self._interrupt >= 32
                                   else f"CPU exception {self._interrupt}")
            if self._interrupt >= 32:
                what += " (software interrupt: there is no operating system in the guest)"
            return GuestFault(f"guest fault at {self.where(pc)}: {self.disassemble(pc)}: {what}", pc)
        where = f"{self.where(pc)}: {self.disassemble(pc)}"
        what = _FAULTS.get(errno, f"Unicorn error {errno}")
        if self._fault is not None and self._fault[0] == "execute" or errno in (UC_ERR_FETCH_UNMAPPED, UC_ERR_FETCH_PROT):
            address = self._fault[1] if self._fault is not None else pc
            what = _FAULTS[UC_ERR_FETCH_PROT if errno == UC_ERR_FETCH_PROT else UC_ERR_FETCH_UNMAPPED]
            return GuestFault(f"guest fault: {what} at {self.where(address)} (an instruction fetch)", address, address)
        if self._fault is not None:
            kind, address = self._fault
            return GuestFault(f"guest fault at {where}: {kind} of unmapped or protected address {address:#010x}",
                              pc, address)
        return GuestFault(f"guest fault at {where}: {what}", pc)
