"""Decode guest x86 code once per static PC into immutable instruction records.

The timing models (P5, P6, K6) never look at raw bytes or at capstone objects:
they key their tables on :class:`InsnRecord`.  Everything here is derived once
per *static* PC (see :class:`Decoder`), so the dynamic trace only carries an
index into the record list.

Conventions
-----------
* 32-bit protected mode (``CS_MODE_32``), Intel syntax, capstone 5.
* ``regs_read`` / ``regs_written`` hold explicit *and* implicit register
  accesses, merged so each full register appears at most once with the widest
  part touched (``al`` + ``ah`` becomes ``ax``).  EFLAGS and EIP are *not*
  listed: flags are described precisely by ``flags_read`` / ``flags_written``
  and the PC is never a data dependency in our models.
* Registers of a memory operand's address (base, index, explicit segment) are
  reads, whether the operand is loaded or stored.
* ``fpcw`` and ``mxcsr`` are pseudo-registers capstone does not model; we add
  them so FLDCW / LDMXCSR serialisation can be seen by the models.
* x87 stack registers are named ``st0``..``st7`` relative to TOP *at the
  moment of access*: sources before any push, destinations of pushing loads
  after the push (FLD writes ``st0``), destinations of popping ops before the
  pop (FADDP st(1),st writes ``st1``).  ``fpu_stack_delta`` tells a model how
  TOP moves (+1 push, -1 pop) so it can map names onto physical slots.
* Flags use the vocabulary ``CF PF AF ZF SF OF DF IF TF``.  Written = modified,
  set, reset or left undefined; ``flags_undefined`` is the undefined subset.

Signature vocabulary (``InsnRecord.signature``)
-----------------------------------------------
Comma-separated operand tokens in Intel operand order, ``''`` when there are
no explicit operands:

==========================  ===================================================
``r8 r16 r32``              general register (by operand width)
``cl``                      CL as the count of a shift/rotate/SHLD/SHRD (not CL as
                            their destination: ROL CL,1 is ``r8,1``)
``dx``                      DX as the port of IN/OUT/INS/OUTS
``ax``                      AX as the destination of FNSTSW
``sreg cr dr``              segment / control / debug register
``mm xmm``                  MMX / SSE register
``st``                      x87 ST(0) in its fixed position (FADD ST,m32fp)
``sti``                     x87 ST(i) selected by ModRM (i may be 0)
``i8 i16 i32``              immediate, by *encoded* size (``83 /0 ib`` is i8)
``1``                       the implicit count of the D0/D1 shift forms
``rel8 rel16 rel32``        relative branch displacement
``m8 .. m128``              memory operand by access width in bits
                            (``m48``: far pointer of LDS.., LGDT/SIDT operand)
``m32fp m64fp m80fp``       x87 real memory operand
``m16int m32int m64int``    x87 integer memory operand
``m80bcd``                  x87 packed BCD memory operand
``mNbyte``                  other widths in bytes (``m28byte`` FNSTENV,
                            ``m108byte`` FNSAVE, ``m512byte`` FXSAVE)
``m``                       address only, no access (LEA, multi-byte NOP)
==========================  ===================================================

Examples: BSR ECX,EAX ``r32,r32``; SHRD EDX,EAX,CL ``r32,r32,cl``;
MOV [EAX],BX ``m16,r16``; FADD DWORD PTR [EAX] ``st,m32fp``;
FADD ST(1),ST ``sti,st``; FLD QWORD PTR [EAX] ``m64fp``; RET ``''``.

Capstone 5 quirks patched here (all found by inspection, see tests)
-------------------------------------------------------------------
* x87: ``insn.eflags`` is a union with ``fpu_flags``, and FSTP ST(i) / FNSTSW
  / FNSTCW lack the ``fpu`` group, so reading eflags gives garbage (FLD
  "modifies CF").  Capstone's x87 operand access and implicit registers are
  also unreliable: FSTP/FST/FISTP m report the memory as *read*, FRSTOR as
  written, FNSAVE has size 4, FADD ST(0),ST(i) omits ST(0), FCOMIP omits
  ST(0) and reports no EFLAGS writes, FCMOVcc reads/writes the wrong operand.
  All x87 instructions (opcodes D8-DF and WAIT) are therefore described by the
  ``_X87`` table from the encoding; only the mnemonic and the memory
  addressing come from capstone.  EFLAGS: FCOMI/FCOMIP/FUCOMI/FUCOMIP write
  ZF,PF,CF and clear OF,SF,AF; FCMOVcc reads its condition; no other x87
  instruction touches EFLAGS.
* Stores reported as loads: MOVD/MOVQ/MOVUPS/MOVNTPS/MOVNTQ/MOVHPS/MOVLPS to
  memory, STMXCSR.  Any ``mov*`` whose first operand is memory is a pure write.
* CMPXCHG: destination reported read-only and the accumulator write missing;
  CMPXCHG8B memory reported read-only.  CMOVcc: old destination not read.
* CDQ / CWD report EAX / AX as written.  RDPMC writes "rax"/"rdx".
* Implicit register gaps: XLATB (al, ebx + a load), AAA/AAS/DAA/DAS/AAM/AAD,
  ENTER (ebp), PUSH sreg, POP sreg, LCALL, RETF, INT, IRET (esp).  Every
  stack instruction gets ``esp`` read+written and its stack traffic in
  ``implicit_mem``.
* Flags: CMC, RCL, RCR don't report reading CF; LAHF/PUSHF report no reads;
  INTO doesn't read OF; AAA/AAS/DAA/DAS don't read AF/CF; F3-prefixed SSE
  (MOVSS, ...) falsely "tests DF"; PREFETCHW claims to modify every flag;
  shifts/rotates: OF is defined only for a count of 1.
* 0x67 string ops / LOOP list implicit esi/edi/ecx instead of si/di/cx.
* Operands with access 0 (CL of SHLD/SHRD, PUSH sreg, CMPSD under REPNE,
  INS/OUTS memory) are fixed to their real access.
* LEA, multi-byte NOP and INVLPG memory operands don't access memory
  (``access ''``, size 0, token ``m``); NOP's address registers are not read.
* LOOP/LOOPE/LOOPNE lack the ``jump`` group (JECXZ has it): added.
* Group ``sse`` is added for any sse1/sse2/... group, ``fpu`` for all x87.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable, Iterator

import capstone
import numpy as np
from numba import njit
from capstone import x86_const as X

__all__ = [
    "DecodeError",
    "Decoder",
    "InsnRecord",
    "MAX_INSN_LEN",
    "MemOperand",
    "Operand",
    "RegRef",
    "decode_block",
    "decode_one",
    "iter_decode",
    "reg_ref",
]

MAX_INSN_LEN = 15  # architectural limit; we never need more bytes than this

FLAG_NAMES = ("CF", "PF", "AF", "ZF", "SF", "OF", "DF", "IF", "TF")
_ARITH_FLAGS = frozenset({"CF", "PF", "AF", "ZF", "SF", "OF"})
_ALL_FLAGS = frozenset(FLAG_NAMES)


class DecodeError(ValueError):
    """The bytes at a PC do not form a (complete) instruction."""


# --------------------------------------------------------------------------
# Registers
# --------------------------------------------------------------------------

# Bit mask of the architectural bits a part covers (bit0 = bits 0-7,
# bit1 = bits 8-15, bits 2-3 = bits 16-31).  Partial-register stall models
# compare masks: a read stalls if it needs bits the last writer didn't write.
_PART_MASK = {"low8": 0x1, "high8": 0x2, "word": 0x3, "dword": 0xF, "full": 0xF}


@dataclass(frozen=True, slots=True)
class RegRef:
    """One architectural register access, with partial-register info."""

    name: str  # as written: 'al', 'ah', 'ax', 'eax', 'st0', 'mm0', 'fpsw', ...
    full: str  # containing register: 'eax' for al/ah/ax/eax; itself otherwise
    part: str  # 'low8' | 'high8' | 'word' | 'dword' | 'full' (non-GPRs)

    @property
    def mask(self) -> int:
        """Bytes of ``full`` covered (see ``_PART_MASK``)."""
        return _PART_MASK[self.part]

    @property
    def kind(self) -> str:
        """'gpr' | 'sreg' | 'st' | 'mm' | 'xmm' | 'cr' | 'dr' | 'fpu' | 'other'."""
        return _REG_KIND.get(self.full, "other")

    @property
    def is_partial(self) -> bool:
        """An 8- or 16-bit piece of a 32-bit general register."""
        return self.part in ("low8", "high8", "word")


def _build_reg_tables() -> tuple[dict[str, RegRef], dict[str, str]]:
    regs: dict[str, RegRef] = {}
    kind: dict[str, str] = {}

    def add(ref: RegRef, k: str) -> None:
        regs[ref.name] = ref
        kind[ref.full] = k

    for x in "abcd":
        full = f"e{x}x"
        add(RegRef(f"{x}l", full, "low8"), "gpr")
        add(RegRef(f"{x}h", full, "high8"), "gpr")
        add(RegRef(f"{x}x", full, "word"), "gpr")
        add(RegRef(full, full, "dword"), "gpr")
    for x in ("si", "di", "bp", "sp"):
        add(RegRef(x, "e" + x, "word"), "gpr")
        add(RegRef("e" + x, "e" + x, "dword"), "gpr")
    for name in ("es", "cs", "ss", "ds", "fs", "gs"):
        add(RegRef(name, name, "full"), "sreg")
    for i in range(8):
        for prefix, k in (("st", "st"), ("mm", "mm"), ("xmm", "xmm"), ("cr", "cr"), ("dr", "dr")):
            add(RegRef(f"{prefix}{i}", f"{prefix}{i}", "full"), k)
    for name in ("fpsw", "fpcw"):
        add(RegRef(name, name, "full"), "fpu")
    add(RegRef("mxcsr", "mxcsr", "full"), "other")
    return regs, kind


_REGS, _REG_KIND = _build_reg_tables()
# (full, mask) -> RegRef, to turn a merged mask back into a register name.
_BY_MASK = {(r.full, r.mask): r for r in _REGS.values()}

# Capstone spellings that differ from ours.  The 64-bit names show up in
# 32-bit mode for RDPMC.
_ALIASES = {f"st({i})": f"st{i}" for i in range(8)}
_ALIASES.update({f"r{x}": f"e{x}" for x in ("ax", "bx", "cx", "dx", "si", "di", "bp", "sp")})
_NOT_DATA_REGS = frozenset({"eflags", "eip", "ip", "rip"})


def reg_ref(name: str) -> RegRef:
    """RegRef for a register name (capstone or our spelling)."""
    name = _ALIASES.get(name, name)
    ref = _REGS.get(name)
    return ref if ref is not None else RegRef(name, name, "full")


def _merge_regs(refs: Iterable[RegRef]) -> tuple[RegRef, ...]:
    """One entry per full register, widened to cover every part touched."""
    masks: dict[str, int] = {}
    for r in refs:
        masks[r.full] = masks.get(r.full, 0) | r.mask
    out = []
    for full, mask in masks.items():
        ref = _BY_MASK.get((full, mask))
        out.append(ref if ref is not None else RegRef(full, full, "full"))
    return tuple(out)


# --------------------------------------------------------------------------
# Operands and records
# --------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class MemOperand:
    base: str | None
    index: str | None
    scale: int
    disp: int
    segment: str | None  # explicit segment (override or ES of string ops); None = default
    size: int  # bytes accessed; 0 for address-only operands (LEA)


@dataclass(frozen=True, slots=True)
class Operand:
    kind: str  # 'reg' | 'imm' | 'mem'
    size: int  # bytes (effective width: the imm8 of '83 /0 ib' has size 4)
    access: str  # 'r' | 'w' | 'rw' | '' (immediates and address-only memory)
    reg: RegRef | None = None
    imm: int | None = None
    mem: MemOperand | None = None


_BRANCH_GROUPS = frozenset({"jump", "call", "ret", "iret", "int"})
_COND_BRANCHES = frozenset(
    "ja jae jb jbe je jg jge jl jle jne jno jnp jns jo jp js "
    "jcxz jecxz loop loope loopne".split()
)
_ZERO_IDIOMS = frozenset({"xor", "sub", "pxor", "xorps", "psubb", "psubw", "psubd", "psubq"})


@dataclass(frozen=True, slots=True)
class InsnRecord:
    pc: int
    length: int
    raw: bytes
    mnemonic: str  # capstone's, lower case, without rep/lock words
    op_str: str  # capstone's Intel-syntax operand text
    prefixes: tuple[int, ...]  # legacy prefix bytes in encoding order
    opsize_prefix: bool
    addrsize_prefix: bool
    rep: str | None  # 'rep' (F3) | 'repe' (F3 on CMPS/SCAS) | 'repne' (F2); string ops only
    opcode: bytes  # after prefixes, incl. 0F escape; 3DNow! = 0F 0F + suffix byte
    escape_0f: bool
    modrm: int | None
    operands: tuple[Operand, ...]
    regs_read: tuple[RegRef, ...]
    regs_written: tuple[RegRef, ...]
    flags_read: frozenset[str]
    flags_written: frozenset[str]
    flags_undefined: frozenset[str]
    groups: frozenset[str]
    signature: str
    # -- additions beyond the core API --
    lock: bool = False
    implicit_mem: str = ""  # memory traffic not visible as an operand (stack, XLAT): 'r'|'w'|'rw'|''
    fpu_stack_delta: int = 0  # x87 TOP movement: +1 push, -1 pop, -2 FCOMPP
    disp_size: int = 0  # encoded displacement bytes
    imm_size: int = 0  # encoded immediate bytes (0 for the implicit '1' of D1 /4)

    # ---- control flow ----
    @property
    def is_branch(self) -> bool:
        return bool(self.groups & _BRANCH_GROUPS)

    @property
    def is_conditional_branch(self) -> bool:
        return self.mnemonic in _COND_BRANCHES

    @property
    def is_relative_branch(self) -> bool:
        return "branch_relative" in self.groups

    @property
    def branch_target(self) -> int | None:
        """Static target of a relative branch (capstone resolves it), else None."""
        if not self.is_relative_branch:
            return None
        return next((op.imm for op in self.operands if op.kind == "imm"), None)

    @property
    def fallthrough(self) -> int:
        return self.pc + self.length

    # ---- memory ----
    @property
    def mem_operands(self) -> tuple[Operand, ...]:
        return tuple(op for op in self.operands if op.kind == "mem")

    @property
    def memory_operand(self) -> MemOperand | None:
        return next((op.mem for op in self.operands if op.kind == "mem"), None)

    @property
    def reads_memory(self) -> bool:
        return "r" in self.implicit_mem or any("r" in op.access for op in self.mem_operands)

    @property
    def writes_memory(self) -> bool:
        return "w" in self.implicit_mem or any("w" in op.access for op in self.mem_operands)

    @property
    def segment_override(self) -> str | None:
        for p in reversed(self.prefixes):
            if p in _SEG_PREFIX:
                return _SEG_PREFIX[p]
        return None

    # ---- partial registers / flags (P6 stall models) ----
    @property
    def partial_reads(self) -> tuple[RegRef, ...]:
        return tuple(r for r in self.regs_read if r.is_partial)

    @property
    def partial_writes(self) -> tuple[RegRef, ...]:
        return tuple(r for r in self.regs_written if r.is_partial)

    @property
    def writes_partial(self) -> frozenset[str]:
        """Full GPRs that receive an 8/16-bit write (later wider reads may stall)."""
        return frozenset(r.full for r in self.partial_writes)

    @property
    def reads_partial(self) -> frozenset[str]:
        return frozenset(r.full for r in self.partial_reads)

    @property
    def uses_partial_register(self) -> bool:
        return bool(self.partial_reads or self.partial_writes)

    @property
    def full_regs_read(self) -> frozenset[str]:
        return frozenset(r.full for r in self.regs_read)

    @property
    def full_regs_written(self) -> frozenset[str]:
        return frozenset(r.full for r in self.regs_written)

    @property
    def writes_partial_flags(self) -> bool:
        """Writes some but not all of the six arithmetic flags (INC, SAHF, BT...)."""
        w = self.flags_written & _ARITH_FLAGS
        return bool(w) and w != _ARITH_FLAGS

    @property
    def is_zero_idiom(self) -> bool:
        """XOR/SUB r,r style clear: P6 uses it to avoid partial-register stalls."""
        ops = self.operands
        return (
            self.mnemonic in _ZERO_IDIOMS
            and len(ops) == 2
            and ops[0].kind == ops[1].kind == "reg"
            and ops[0].reg == ops[1].reg
        )

    @property
    def is_x87(self) -> bool:
        return "fpu" in self.groups

    @property
    def is_mmx(self) -> bool:
        return "mmx" in self.groups or "3dnow" in self.groups


# --------------------------------------------------------------------------
# Static tables
# --------------------------------------------------------------------------

_SEG_PREFIX = {0x26: "es", 0x2E: "cs", 0x36: "ss", 0x3E: "ds", 0x64: "fs", 0x65: "gs"}
_LEGACY_PREFIXES = frozenset({0x66, 0x67, 0xF0, 0xF2, 0xF3, *_SEG_PREFIX})
# Words capstone glues onto the mnemonic for prefixes we report separately.
_PREFIX_WORDS = frozenset(
    "lock rep repe repz repne repnz data16 addr16 bnd notrack xacquire xrelease".split()
)
_STRING_OPS = frozenset(
    f"{base}{suffix}" for base in ("movs", "cmps", "scas", "lods", "stos", "ins", "outs") for suffix in "bwd"
)
_SHIFTS = frozenset("rol ror rcl rcr shl sal shr sar shld shrd".split())
_PORT_IO = frozenset({"in", "out"}) | frozenset(m for m in _STRING_OPS if m[:3] in ("ins", "out"))
_LOOPS = frozenset({"loop", "loope", "loopne"})

_ACCESS = {0: "", capstone.CS_AC_READ: "r", capstone.CS_AC_WRITE: "w",
           capstone.CS_AC_READ | capstone.CS_AC_WRITE: "rw"}


def _flag_bit_tables() -> tuple[dict[int, str], dict[int, str], dict[int, str]]:
    """Map capstone X86_EFLAGS_<ACTION>_<FLAG> bits to our flag names."""
    read, written, undefined = {}, {}, {}
    for const in dir(X):
        if not const.startswith("X86_EFLAGS_"):
            continue
        action, flag = const.split("_")[2:4]
        if flag not in _ALL_FLAGS:  # NT, RF, AC, '0F' ... are outside our vocabulary
            continue
        bit = getattr(X, const)
        if action == "TEST":
            read[bit] = flag
        else:  # MODIFY, SET, RESET, UNDEFINED, PRIOR (restored) all write
            written[bit] = flag
            if action == "UNDEFINED":
                undefined[bit] = flag
    return read, written, undefined


_EFL_READ, _EFL_WRITTEN, _EFL_UNDEF = _flag_bit_tables()


def _bits_to_flags(value: int, table: dict[int, str]) -> frozenset[str]:
    return frozenset(flag for bit, flag in table.items() if value & bit)


@dataclass(frozen=True)
class _Fix:
    """Corrections for one mnemonic on top of capstone's detail."""

    read: tuple[str, ...] = ()  # extra implicit register reads ('<acc>' = al/ax/eax by op size)
    write: tuple[str, ...] = ()
    drop_write: tuple[str, ...] = ()
    access: tuple[str | None, ...] = ()  # per-operand access override (None keeps)
    flags_read: frozenset[str] = frozenset()
    flags_none: bool = False  # capstone's eflags are garbage: touches no flags
    mem: str = ""  # implicit memory access
    mem_size: tuple[int, int] | None = None  # corrected memory size: (32-bit, 16-bit opsize)


_F = frozenset
_FIXES: dict[str, _Fix] = {
    "cdq": _Fix(drop_write=("eax",)),
    "cwd": _Fix(drop_write=("ax",)),
    "cmpxchg": _Fix(read=("<acc>",), write=("<acc>",), access=("rw", None)),
    "cmpxchg8b": _Fix(access=("rw",)),
    "bound": _Fix(access=("r", None)),
    "arpl": _Fix(access=("rw", None)),
    "xlatb": _Fix(read=("al", "ebx"), write=("al",), mem="r"),
    "aaa": _Fix(read=("al", "ah"), write=("al", "ah"), flags_read=_F({"AF"})),
    "aas": _Fix(read=("al", "ah"), write=("al", "ah"), flags_read=_F({"AF"})),
    "daa": _Fix(read=("al",), write=("al",), flags_read=_F({"AF", "CF"})),
    "das": _Fix(read=("al",), write=("al",), flags_read=_F({"AF", "CF"})),
    "aam": _Fix(read=("al",), write=("al", "ah")),
    "aad": _Fix(read=("al", "ah"), write=("al", "ah")),
    "enter": _Fix(read=("ebp",), write=("ebp",)),
    "lds": _Fix(write=("ds",), mem_size=(6, 4)),
    "les": _Fix(write=("es",), mem_size=(6, 4)),
    "lfs": _Fix(write=("fs",), mem_size=(6, 4)),
    "lgs": _Fix(write=("gs",), mem_size=(6, 4)),
    "lss": _Fix(write=("ss",), mem_size=(6, 4)),
    "ldmxcsr": _Fix(write=("mxcsr",)),
    "stmxcsr": _Fix(read=("mxcsr",), access=("w",)),
    "fxsave": _Fix(access=("w",), mem_size=(512, 512)),
    "fxrstor": _Fix(access=("r",), mem_size=(512, 512)),
    "maskmovq": _Fix(mem="w"),
    "maskmovdqu": _Fix(mem="w"),
    "cmc": _Fix(flags_read=_F({"CF"})),
    # capstone marks the destination of ROL/ROR/RCL/RCR and SETcc read-only: a memory destination
    # is written too (issue 20: the K6 lowering gave such stores no store op)
    "rol": _Fix(access=("rw", None)),
    "ror": _Fix(access=("rw", None)),
    "rcl": _Fix(flags_read=_F({"CF"}), access=("rw", None)),
    "rcr": _Fix(flags_read=_F({"CF"}), access=("rw", None)),
    **{f"set{cc}": _Fix(access=("w",)) for cc in "o no b ae e ne be a s ns p np l ge le g".split()},
    "lahf": _Fix(flags_read=_F({"SF", "ZF", "AF", "PF", "CF"})),
    "pushf": _Fix(flags_read=_ALL_FLAGS),
    "pushfd": _Fix(flags_read=_ALL_FLAGS),
    "into": _Fix(flags_read=_F({"OF"})),
    **{m: _Fix(flags_none=True) for m in ("prefetch", "prefetchw", "prefetchnta",
                                          "prefetcht0", "prefetcht1", "prefetcht2")},
}

# Stack instructions: they all read and write ESP; value = stack memory traffic.
_STACK_MEM = {
    **dict.fromkeys(("push", "pushal", "pushaw", "pushf", "pushfd", "call", "lcall",
                     "enter", "int", "int3", "into"), "w"),
    **dict.fromkeys(("pop", "popal", "popaw", "popf", "popfd", "ret", "retf",
                     "leave", "iret", "iretd"), "r"),
}

# Memory operands that only name an address.
_ADDRESS_ONLY = frozenset({"lea", "nop", "invlpg"})

# 16-bit addressing (0x67) changes the implicit pointer/counter registers.
_ADDR16 = {"esi": "si", "edi": "di", "ecx": "cx"}

_GPR_TOKEN = {1: "r8", 2: "r16", 4: "r32"}
_REG_TOKEN = {"sreg": "sreg", "cr": "cr", "dr": "dr", "mm": "mm", "xmm": "xmm", "st": "sti", "fpu": "fpu"}
_MEM_BITS = {1: 8, 2: 16, 4: 32, 6: 48, 8: 64, 10: 80, 16: 128}


# --------------------------------------------------------------------------
# x87: described entirely by this table (capstone's detail is unreliable)
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class _X87:
    """How one x87 mnemonic uses its operands.

    form -- arrangement of explicit operands:
        'arith'  mem: st,m (st rw)  | D8 reg: st,sti (st rw) | DC/DE reg: sti,st (sti rw)
        'cmp'    st,m or st,sti, both read
        'cmov'   st,sti (st rw: conditional move keeps old value)
        'src'    one read operand (m or sti)
        'dst'    one written operand (m, sti, or AX for FNSTSW)
        'xch'    sti rw (plus implicit st0)
        'tag'    sti written (FFREE only touches the tag)
        'none'   no explicit operand
    """

    form: str
    mtype: str = ""  # memory token suffix: 'fp' | 'int' | 'bcd' | '' (raw bytes)
    reads: tuple[str, ...] = ()
    writes: tuple[str, ...] = ()
    delta: int = 0  # fpu_stack_delta
    fpsw: bool = True  # writes the status word (condition codes / TOP / exceptions)
    mem_size: tuple[int, int] | None = None  # (32-bit opsize, 16-bit opsize) override


_ST0, _ST1 = ("st0",), ("st0", "st1")
_ALL_ST = tuple(f"st{i}" for i in range(8))
_X87_TABLE: dict[str, _X87] = {
    **{m: _X87("arith", "fp") for m in ("fadd", "fsub", "fsubr", "fmul", "fdiv", "fdivr")},
    **{m: _X87("arith", delta=-1) for m in ("faddp", "fsubp", "fsubrp", "fmulp", "fdivp", "fdivrp")},
    **{m: _X87("arith", "int") for m in ("fiadd", "fisub", "fisubr", "fimul", "fidiv", "fidivr")},
    "fcom": _X87("cmp", "fp"),
    "fcomp": _X87("cmp", "fp", delta=-1),
    "ficom": _X87("cmp", "int"),
    "ficomp": _X87("cmp", "int", delta=-1),
    "fucom": _X87("cmp"),
    "fucomp": _X87("cmp", delta=-1),
    "fcomi": _X87("cmp"),
    "fucomi": _X87("cmp"),
    "fcompi": _X87("cmp", delta=-1),
    "fucompi": _X87("cmp", delta=-1),
    "fcompp": _X87("none", reads=_ST1, delta=-2),
    "fucompp": _X87("none", reads=_ST1, delta=-2),
    "ftst": _X87("none", reads=_ST0),
    "fxam": _X87("none", reads=_ST0),
    **{m: _X87("cmov") for m in ("fcmovb", "fcmove", "fcmovbe", "fcmovu",
                                 "fcmovnb", "fcmovne", "fcmovnbe", "fcmovnu")},
    "fld": _X87("src", "fp", writes=_ST0, delta=1),
    "fild": _X87("src", "int", writes=_ST0, delta=1),
    "fbld": _X87("src", "bcd", writes=_ST0, delta=1),
    **{m: _X87("none", writes=_ST0, delta=1) for m in ("fld1", "fldz", "fldpi", "fldl2e",
                                                     "fldl2t", "fldlg2", "fldln2")},
    "fst": _X87("dst", "fp", reads=_ST0),
    "fstp": _X87("dst", "fp", reads=_ST0, delta=-1),
    "fstpnce": _X87("dst", "fp", reads=_ST0, delta=-1),  # D9 D8+i alias of FSTP ST(i)
    "fist": _X87("dst", "int", reads=_ST0),
    "fistp": _X87("dst", "int", reads=_ST0, delta=-1),
    "fisttp": _X87("dst", "int", reads=_ST0, delta=-1),
    "fbstp": _X87("dst", "bcd", reads=_ST0, delta=-1),
    "fxch": _X87("xch", reads=_ST0, writes=_ST0),
    **{m: _X87("none", reads=_ST0, writes=_ST0) for m in ("fchs", "fabs", "fsqrt", "frndint",
                                                        "f2xm1", "fsin", "fcos")},
    **{m: _X87("none", reads=_ST1, writes=_ST0) for m in ("fscale", "fprem", "fprem1")},
    **{m: _X87("none", reads=_ST1, writes=("st1",), delta=-1) for m in ("fpatan", "fyl2x", "fyl2xp1")},
    **{m: _X87("none", reads=_ST0, writes=_ST1, delta=1) for m in ("fsincos", "fptan", "fxtract")},
    "ffree": _X87("tag", fpsw=False),
    "ffreep": _X87("tag", delta=-1),
    "fincstp": _X87("none", delta=-1),
    "fdecstp": _X87("none", delta=1),
    "fldcw": _X87("src", writes=("fpcw",), fpsw=False),
    "fnstcw": _X87("dst", reads=("fpcw",), fpsw=False),
    "fnstsw": _X87("dst", reads=("fpsw",), fpsw=False),
    "fldenv": _X87("src", writes=("fpcw",), mem_size=(28, 14)),
    "fnstenv": _X87("dst", reads=("fpcw", "fpsw"), writes=("fpcw",), fpsw=False, mem_size=(28, 14)),
    "frstor": _X87("src", writes=("fpcw",) + _ALL_ST, mem_size=(108, 94)),
    "fnsave": _X87("dst", reads=("fpcw", "fpsw") + _ALL_ST, writes=("fpcw",), mem_size=(108, 94)),
    "fninit": _X87("none", writes=("fpcw",)),
    "fnclex": _X87("none"),
    **{m: _X87("none", fpsw=False) for m in ("fnop", "wait", "fsetpm", "feni8087_nop", "fdisi8087_nop")},
}

# The only x87 instructions that touch EFLAGS (P6 additions).
_X87_FLAGS_WRITTEN = dict.fromkeys(("fcomi", "fcompi", "fucomi", "fucompi"), _ARITH_FLAGS)
_X87_FLAGS_READ = {
    "fcmovb": _F({"CF"}), "fcmovnb": _F({"CF"}),
    "fcmove": _F({"ZF"}), "fcmovne": _F({"ZF"}),
    "fcmovbe": _F({"CF", "ZF"}), "fcmovnbe": _F({"CF", "ZF"}),
    "fcmovu": _F({"PF"}), "fcmovnu": _F({"PF"}),
}


# --------------------------------------------------------------------------
# Decoding
# --------------------------------------------------------------------------

_md: capstone.Cs | None = None


def _disassembler() -> capstone.Cs:
    global _md
    if _md is None:
        md = capstone.Cs(capstone.CS_ARCH_X86, capstone.CS_MODE_32)
        md.syntax = capstone.CS_OPT_SYNTAX_INTEL
        md.detail = True
        _md = md
    return _md


def _split_prefixes(raw: bytes) -> tuple[int, ...]:
    n = 0
    while n < len(raw) - 1 and raw[n] in _LEGACY_PREFIXES:
        n += 1
    return tuple(raw[:n])


def _opcode_bytes(raw: bytes, start: int) -> bytes:
    if raw[start] != 0x0F:
        return raw[start : start + 1]
    second = raw[start + 1]
    if second in (0x38, 0x3A):  # three-byte opcode maps
        return raw[start : start + 3]
    if second == 0x0F:  # 3DNow!: the real opcode is the trailing suffix byte
        return raw[start : start + 2] + raw[-1:]
    return raw[start : start + 2]


def _mem_token(size: int, mtype: str = "") -> str:
    if size == 0:
        return "m"
    if size in _MEM_BITS:
        return f"m{_MEM_BITS[size]}{mtype}"
    return f"m{size}byte"


class _Builder:
    """Accumulates operands/regs for one instruction; keeps decode_one short."""

    def __init__(self) -> None:
        self.operands: list[Operand] = []
        self.tokens: list[str] = []
        self.reads: list[RegRef] = []
        self.writes: list[RegRef] = []

    def add(self, op: Operand, token: str) -> None:
        self.operands.append(op)
        self.tokens.append(token)
        if op.kind == "reg":
            if "r" in op.access:
                self.reads.append(op.reg)
            if "w" in op.access:
                self.writes.append(op.reg)

    def add_address_regs(self, mem: MemOperand) -> None:
        self.reads.extend(reg_ref(r) for r in (mem.base, mem.index, mem.segment) if r)


def _cs_mem(insn, op, size: int) -> MemOperand:
    m = op.mem
    name = insn.reg_name
    return MemOperand(
        base=reg_ref(name(m.base)).name if m.base else None,
        index=reg_ref(name(m.index)).name if m.index else None,
        scale=m.scale,
        disp=m.disp,
        segment=name(m.segment) if m.segment else None,
        size=size,
    )


def _generic_operands(
    insn, b: _Builder, mnemonic: str, groups: frozenset[str], fix: _Fix | None, opsize16: bool
) -> None:
    """Operands of a non-x87 instruction from capstone, with access fixes."""
    n_imm = sum(op.type == X.X86_OP_IMM for op in insn.operands)
    for pos, op in enumerate(insn.operands):
        access = _ACCESS[op.access & 3]
        if fix and pos < len(fix.access) and fix.access[pos] is not None:
            access = fix.access[pos]
        elif pos == 0 and op.type == X.X86_OP_MEM and mnemonic.startswith("mov"):
            access = "w"  # stores capstone reports as loads (MOVQ m64,mm ...)
        elif pos == 0 and "cmov" in groups:
            access = "rw"  # CMOVcc keeps the old value when the condition fails
        elif access == "":
            if op.type == X.X86_OP_REG:
                access = "r"
            elif op.type == X.X86_OP_MEM:
                access = "w" if mnemonic.startswith("ins") else "r"

        if op.type == X.X86_OP_REG:
            ref = reg_ref(insn.reg_name(op.reg))
            if ref.kind == "gpr":
                token = _GPR_TOKEN.get(op.size, "r32")
                # only the COUNT of a shift/rotate/SHLD/SHRD is 'cl' (its last operand); CL as the
                # destination of ROL CL,1 or SHL CL,CL is an ordinary 8-bit register
                if ref.name == "cl" and mnemonic in _SHIFTS and 0 < pos == len(insn.operands) - 1:
                    token = "cl"
                elif ref.name == "dx" and mnemonic in _PORT_IO:
                    token = "dx"
            else:
                token = _REG_TOKEN.get(ref.kind, ref.name)
            b.add(Operand("reg", op.size, access, reg=ref), token)
        elif op.type == X.X86_OP_IMM:
            if "branch_relative" in groups:
                token = f"rel{insn.imm_size * 8}"
            elif n_imm > 1:  # ENTER iw,ib; far pointers: use operand widths
                size = (2, 1)[pos] if mnemonic == "enter" else op.size
                token = f"i{size * 8}"
            elif insn.imm_size == 0:
                token = "1"  # D0/D1 shift-by-one: the 1 is not encoded
            else:
                token = f"i{insn.imm_size * 8}"
            b.add(Operand("imm", op.size, "", imm=op.imm), token)
        else:
            size = op.size
            if fix and fix.mem_size is not None:
                size = fix.mem_size[1 if opsize16 else 0]
            if mnemonic in _ADDRESS_ONLY:
                access, size = "", 0
            mem = _cs_mem(insn, op, size)
            b.add(Operand("mem", size, access, mem=mem), _mem_token(size))
            if mnemonic != "nop":  # multi-byte NOP has no real inputs
                b.add_address_regs(mem)


def _x87_operands(insn, b: _Builder, spec: _X87, opcode0: int, modrm: int | None, opsize16: bool) -> None:
    """Operands of an x87 instruction from the encoding and the _X87 table."""
    cs_mem = next((op for op in insn.operands if op.type == X.X86_OP_MEM), None)

    def st(access: str, fixed: bool = False) -> tuple[Operand, str]:
        ref = _REGS["st0"] if fixed else _REGS[f"st{modrm & 7}"]
        return Operand("reg", 10, access, reg=ref), "st" if fixed else "sti"

    def mem(access: str) -> tuple[Operand, str]:
        size = cs_mem.size
        if spec.mem_size:
            size = spec.mem_size[1 if opsize16 else 0]
        m = _cs_mem(insn, cs_mem, size)
        b.add_address_regs(m)
        return Operand("mem", size, access, mem=m), _mem_token(size, spec.mtype)

    form = spec.form
    if form in ("arith", "cmp"):
        dst_access = "rw" if form == "arith" else "r"
        if cs_mem is not None:
            pair = [st(dst_access, fixed=True), mem("r")]
        elif form == "arith" and opcode0 != 0xD8:  # DC/DE: ST(i) is the destination
            pair = [st(dst_access), st("r", fixed=True)]
        else:
            pair = [st(dst_access, fixed=True), st("r")]
        for op, token in pair:
            b.add(op, token)
    elif form == "cmov":
        b.add(*st("rw", fixed=True))
        b.add(*st("r"))
    elif form in ("src", "dst"):
        access = "r" if form == "src" else "w"
        if cs_mem is not None:
            b.add(*mem(access))
        elif spec is _X87_TABLE["fnstsw"]:  # FNSTSW AX
            b.add(Operand("reg", 2, "w", reg=_REGS["ax"]), "ax")
        else:
            b.add(*st(access))
    elif form == "xch":
        b.add(*st("rw"))
    elif form == "tag":
        b.add(*st("w"))
    b.reads.extend(_REGS[r] for r in spec.reads)
    b.writes.extend(_REGS[r] for r in spec.writes)
    if spec.fpsw:
        b.writes.append(_REGS["fpsw"])


def _group_names(insn) -> frozenset[str]:
    return frozenset(insn.group_name(g) for g in insn.groups)


def _strip_prefix_words(mnemonic: str) -> str:
    words = mnemonic.split()
    while len(words) > 1 and words[0] in _PREFIX_WORDS:
        words.pop(0)
    return " ".join(words)


def decode_one(code: bytes, pc: int) -> InsnRecord:
    """Decode the first instruction of ``code`` located at address ``pc``.

    Raises :class:`DecodeError` (a ``ValueError``) naming the PC and bytes if
    ``code`` does not start with a complete, valid instruction.
    """
    pc = int(pc)  # numpy scalars from traces must not leak into records
    code = bytes(code[:MAX_INSN_LEN])
    insn = next(_disassembler().disasm(code, pc, count=1), None)
    if insn is None:
        raise DecodeError(f"cannot decode instruction at pc={pc:#010x}: bytes [{code.hex(' ')}]")

    raw = bytes(insn.bytes)
    prefixes = _split_prefixes(raw)
    opcode = _opcode_bytes(raw, len(prefixes))
    modrm = raw[insn.modrm_offset] if insn.modrm_offset else None
    mnemonic = _strip_prefix_words(insn.mnemonic)
    opsize16 = 0x66 in prefixes
    addr16 = 0x67 in prefixes
    groups = set(_group_names(insn))
    b = _Builder()

    # Every decodable D8-DF encoding is in _X87_TABLE (tests enumerate them).
    x87 = _X87_TABLE.get(mnemonic) if (0xD8 <= opcode[0] <= 0xDF or mnemonic == "wait") else None
    if x87 is not None:
        _x87_operands(insn, b, x87, opcode[0], modrm, opsize16)
        groups.add("fpu")
        flags_read = _X87_FLAGS_READ.get(mnemonic, frozenset())
        flags_written = _X87_FLAGS_WRITTEN.get(mnemonic, frozenset())
        flags_undefined: frozenset[str] = frozenset()
        implicit_mem, stack_delta = "", x87.delta
    else:
        fix = _FIXES.get(mnemonic)
        _generic_operands(insn, b, mnemonic, frozenset(groups), fix, opsize16)
        _add_implicit_regs(insn, b, mnemonic, fix, addr16)
        flags_read, flags_written, flags_undefined = _generic_flags(insn, b, mnemonic, fix)
        implicit_mem = _STACK_MEM.get(mnemonic, "") or (fix.mem if fix else "")
        stack_delta = 0
        if mnemonic in _LOOPS:
            groups.add("jump")  # JECXZ has it, LOOP doesn't
    if any(g.startswith(("sse", "ssse")) for g in groups):
        groups.add("sse")

    rep = None
    if mnemonic in _STRING_OPS:
        last = next((p for p in reversed(prefixes) if p in (0xF2, 0xF3)), None)
        rep = {0xF3: "rep", 0xF2: "repne", None: None}[last]
        if rep == "rep" and mnemonic[:4] in ("cmps", "scas"):
            rep = "repe"  # F3 on CMPS/SCAS repeats while equal (Intel SDM vol. 2, REP/REPE/REPZ)

    return InsnRecord(
        pc=pc,
        length=insn.size,
        raw=raw,
        mnemonic=mnemonic,
        op_str=insn.op_str,
        prefixes=prefixes,
        opsize_prefix=opsize16,
        addrsize_prefix=addr16,
        rep=rep,
        opcode=opcode,
        escape_0f=opcode[0] == 0x0F,
        modrm=modrm,
        operands=tuple(b.operands),
        regs_read=_merge_regs(b.reads),
        regs_written=_merge_regs(b.writes),
        flags_read=frozenset(flags_read),
        flags_written=frozenset(flags_written),
        flags_undefined=frozenset(flags_undefined),
        groups=frozenset(groups),
        signature=",".join(b.tokens),
        lock=0xF0 in prefixes,
        implicit_mem=implicit_mem,
        fpu_stack_delta=stack_delta,
        disp_size=insn.disp_size,
        imm_size=_encoded_imm_size(insn, mnemonic),
    )


def _encoded_imm_size(insn, mnemonic: str) -> int:
    # capstone reports garbage (18) for the ptr16:32 of far JMP/CALL and only
    # the last immediate of ENTER; count those from the operands instead.
    imms = [op for op in insn.operands if op.type == X.X86_OP_IMM]
    if len(imms) <= 1:
        return insn.imm_size
    return 3 if mnemonic == "enter" else sum(op.size for op in imms)


def _add_implicit_regs(insn, b: _Builder, mnemonic: str, fix: _Fix | None, addr16: bool) -> None:
    """Capstone's implicit registers plus the _FIXES / stack / 0x67 corrections."""

    def names(ids) -> list[str]:
        out = []
        for r in ids:
            n = _ALIASES.get(insn.reg_name(r), insn.reg_name(r))
            if n in _NOT_DATA_REGS:
                continue
            if addr16 and (mnemonic in _STRING_OPS or mnemonic in _LOOPS):
                n = _ADDR16.get(n, n)
            out.append(n)
        return out

    reads, writes = names(insn.regs_read), names(insn.regs_write)
    if fix:
        acc = {1: "al", 2: "ax"}.get(insn.operands[0].size if insn.operands else 4, "eax")
        reads += [acc if r == "<acc>" else r for r in fix.read]
        writes += [acc if r == "<acc>" else r for r in fix.write]
        writes = [w for w in writes if w not in fix.drop_write]
    if mnemonic in _STACK_MEM:
        reads.append("esp")
        writes.append("esp")
    b.reads.extend(reg_ref(r) for r in reads)
    b.writes.extend(reg_ref(r) for r in writes)


def _generic_flags(insn, b: _Builder, mnemonic: str, fix: _Fix | None):
    """(read, written, undefined) EFLAGS sets from capstone, with corrections."""
    if fix and fix.flags_none:
        return frozenset(), frozenset(), frozenset()
    eflags = insn.eflags
    read = set(_bits_to_flags(eflags, _EFL_READ))
    written = set(_bits_to_flags(eflags, _EFL_WRITTEN))
    undefined = set(_bits_to_flags(eflags, _EFL_UNDEF))
    if fix:
        read |= fix.flags_read
    if mnemonic not in _STRING_OPS and mnemonic not in ("pushf", "pushfd"):
        read.discard("DF")  # capstone: F3-prefixed SSE (MOVSS) "tests DF"
    if mnemonic in _SHIFTS and "OF" in written:
        # OF is defined only for a count of 1 (D1 /x or an explicit imm 1).
        count = b.operands[-1] if b.operands else None
        if count is not None and count.kind == "imm" and count.imm == 1:
            undefined.discard("OF")
        else:
            undefined.add("OF")
    return frozenset(read), frozenset(written), frozenset(undefined)


def decode_block(code: bytes, pc: int) -> list[InsnRecord]:
    """Decode ``code`` linearly from ``pc`` to its end (raises on bad bytes)."""
    return list(iter_decode(code, pc))


def iter_decode(code: bytes, pc: int) -> Iterator[InsnRecord]:
    """Lazily decode ``code`` linearly from ``pc``."""
    offset = 0
    while offset < len(code):
        rec = decode_one(code[offset : offset + MAX_INSN_LEN], pc + offset)
        yield rec
        offset += rec.length


# --------------------------------------------------------------------------
# Per-static-PC cache
# --------------------------------------------------------------------------

# Records shared by every Decoder in the process, keyed by the bytes fetched and the PC (a record
# is a pure function of both, and immutable): a scene's many emulations of one kernel (the sort
# scene's hundreds of runs, each a new Emulation with its own Decoder) decode each instruction once.
_SHARED: dict[tuple[bytes, int], InsnRecord] = {}
_SHARED_MAX = 1 << 14  # records kept (a few hundred per kernel, about 1 KB each); past it the memo starts again


def _decode_shared(code: bytes, pc: int) -> InsnRecord:
    key = (code, pc)
    rec = _SHARED.get(key)
    if rec is None:
        if len(_SHARED) >= _SHARED_MAX:
            _SHARED.clear()
        rec = _SHARED[key] = decode_one(code, pc)
    return rec



@njit(cache=True, nogil=True)
def _index_by_first_appearance(pcs, lo, span):
    """(distinct PCs in order of first appearance, int32 index of each pc into them)."""
    slot_of = np.full(span, -1, np.int32)
    firsts = np.empty(min(span, pcs.size), np.int64)
    index = np.empty(pcs.size, np.int32)
    k = 0
    for i in range(pcs.size):
        off = np.int64(pcs[i]) - lo
        slot = slot_of[off]
        if slot < 0:
            slot = k
            slot_of[off] = k
            firsts[k] = pcs[i]
            k += 1
        index[i] = slot
    return firsts[:k], index


# a resumable timing decodes the calls before the last and the last call apart (sim.timing.kernel
# Emulation.parts), and every re-timing of the emulation asks for both again
TRACES_KEPT = 2


class Decoder:
    """Decodes each static PC once.

    ``fetch(addr, n)`` returns up to ``n`` bytes of guest code at ``addr``
    (fewer near the end of a region).  Code is assumed not to be modified
    after it was first decoded; call :meth:`invalidate` if it is.
    """

    def __init__(self, fetch: Callable[[int, int], bytes]):
        self._fetch = fetch
        self._cache: dict[int, InsnRecord] = {}
        # (pcs, records, index) of the last TRACES_KEPT decode_trace calls, the most recent last
        self._traces: list[tuple] = []

    def __len__(self) -> int:
        return len(self._cache)

    def __contains__(self, pc: int) -> bool:
        return int(pc) in self._cache

    def at(self, pc: int) -> InsnRecord:
        pc = int(pc)
        rec = self._cache.get(pc)
        if rec is None:
            rec = _decode_shared(self._fetch(pc, MAX_INSN_LEN), pc)
            self._cache[pc] = rec
        return rec

    def invalidate(self, start: int | None = None, end: int | None = None) -> None:
        """Forget records overlapping [start, end) (everything by default)."""
        self._traces = []
        if start is None:
            self._cache.clear()
            return
        end = start + 1 if end is None else end
        stale = [pc for pc, r in self._cache.items() if pc < end and pc + r.length > start]
        for pc in stale:
            del self._cache[pc]

    def decode_trace(self, pcs: np.ndarray) -> tuple[list[InsnRecord], np.ndarray]:
        """Records for a dynamic PC stream, decoding only its distinct PCs.

        Returns ``(records, index)``: one record per distinct PC in order of
        first appearance, and an int32 array with ``records[index[i]].pc ==
        pcs[i]``.  Vectorised: Python only loops over the distinct PCs.
        Asked again for one of the last :data:`TRACES_KEPT` arrays (a trace is
        never modified), it returns the same index: callers must not write to it.
        """
        for k, kept in enumerate(self._traces):
            if kept[0] is pcs:
                self._traces.append(self._traces.pop(k))
                return list(kept[1]), kept[2]
        records, index = self._decode_trace(pcs)
        self._traces = (self._traces + [(pcs, records, index)])[-TRACES_KEPT:]
        return list(records), index

    def _decode_trace(self, pcs) -> tuple[list[InsnRecord], np.ndarray]:
        pcs = np.asarray(pcs)
        if pcs.ndim != 1:
            raise ValueError(f"pcs must be 1-D, got shape {pcs.shape}")
        if pcs.size and pcs.dtype.kind not in "ui":
            raise TypeError(f"pcs must be an integer array, got {pcs.dtype}")
        if pcs.size == 0:
            return [], np.empty(0, dtype=np.int32)

        lo, hi = int(pcs.min()), int(pcs.max())
        if hi - lo < (1 << 22):
            # Code is compact: one compiled pass over a dense slot table (no sort).
            firsts, index = _index_by_first_appearance(pcs, lo, hi - lo + 1)
            return [self.at(int(pc)) for pc in firsts], index
        uniq, first, inverse = np.unique(pcs, return_index=True, return_inverse=True)
        if len(uniq) > np.iinfo(np.int32).max:
            raise ValueError("too many distinct PCs for an int32 index")
        order = np.argsort(first, kind="stable")  # sorted-unique slot -> appearance order
        rank = np.empty(len(order), dtype=np.int32)
        rank[order] = np.arange(len(order), dtype=np.int32)
        index = rank[inverse.reshape(-1)]
        records = [self.at(int(pc)) for pc in uniq[order]]
        return records, index
