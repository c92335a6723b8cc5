"""Per-CPU instruction sets: which extension an instruction needs, what each preset has, and how a
kernel is assembled for a preset.

A preset (sim/cpus/presets/*.toml) declares ``isa_extensions`` (from the vocabulary below) and the
assembler's CPU names: ``gnu_march`` (GNU as ``-march=``) and ``zig_mcpu`` (clang ``-mcpu=``). The
guest stages see them as a :class:`sim.guest.cpu.GuestCpu`, resolved from the preset by the caller.
The base set of every modelled family is i586 (CPUID, CMPXCHG8B, RDTSC; Intel SDM vol. 2,
"CPUID: Feature Information"); the extensions on top of it are:

- ``cmov``   CMOVcc (CPUID.01H:EDX.CMOV; Pentium Pro and later; no K6 has it)
- ``fcmov``  FCMOVcc and FCOMI/FCOMIP/FUCOMI/FUCOMIP (present when CMOV and FPU are; Intel SDM
             vol. 2, FCMOVcc and FCOMI "IA-32 Architecture Compatibility")
- ``mmx``    MMX (Pentium MMX, Pentium II and later, every K6)
- ``sse``    SSE with its MMX-register additions, PREFETCHh, SFENCE, MOVNTQ, MASKMOVQ (Pentium III)
- ``3dnow``  3DNow!, FEMMS, PREFETCH/PREFETCHW (AMD "3DNow! Technology Manual" 21928; K6-2, K6-III)
- ``sse2``   SSE2 and the later SIMD sets (SSE3 adds the x87 FISTTP): the Pentium 4 and later, so no
             modelled CPU has it; listed so that their encodings are refused, not left without a row
- ``nopl``   the multi-byte NOP 0F 1F /0 (Intel SDM vol. 2 NOP: processors with CPUID family 6,
             i.e. every P6; not the family-5 P5 and K6, where GNU as refuses it too)
- ``fxsr``   FXSAVE/FXRSTOR (CPUID.01H:EDX bit 24 FXSR: set on the Pentium II model 5 and later P6
             cores, clear on the Pentium Pro, the Pentium II model 3 and every K6 and P5; InstLatX64
             CPUID dumps GenuineIntel0000617, 0633, 0651, 0660, AuthenticAMD0000562)

PAUSE (F3 90) needs nothing: it is REP NOP, which every IA-32 processor before the Pentium 4
executes as a NOP (Intel SDM vol. 2, PAUSE), although capstone files it under SSE2.

Privileged and system instructions (HLT, CLI/STI, IN/OUT, LGDT, ...) are never part of a user
kernel: they fault at CPL 3, so no user-mode timing exists for them.
"""

from __future__ import annotations

from sim.errors import RetrosimError
from sim.guest.cpu import GuestCpu
from sim.guest.decode import InsnRecord

EXTENSIONS = ("cmov", "fcmov", "mmx", "sse", "3dnow", "fxsr", "sse2", "nopl")

# MMX-register instructions that came with SSE (Intel SDM vol. 1, "SSE 64-bit SIMD integer
# instructions") and the SSE cacheability instructions; capstone files the former under 'mmx'.
_SSE_MMX = frozenset("pavgb pavgw pextrw pinsrw pmaxsw pmaxub pminsw pminub pmovmskb pmulhuw psadbw "
                     "pshufw maskmovq movntq sfence prefetchnta prefetcht0 prefetcht1 prefetcht2".split())
_SSE_UNGROUPED = frozenset({"cvtss2si"})  # SSE instructions capstone 5 puts in no group
_3DNOW = frozenset({"femms", "prefetch", "prefetchw"})
_FCMOV = frozenset({"fcomi", "fcompi", "fucomi", "fucompi"})
_FXSR = frozenset({"fxsave", "fxrstor"})
_NO_EXTENSION = frozenset({"pause"})  # REP NOP: a NOP before the Pentium 4 (module docstring)
_SSE2_GROUPS = frozenset({"sse2", "sse3", "ssse3", "sse41", "sse42", "sse4a"})
_SSE3_X87 = frozenset({"fisttp"})  # an x87 opcode (DB /1, DD /1, DF /1) that came with SSE3
# SSE2 instructions whose names look like MMX or SSE ones (Intel SDM vol. 1, "SSE2 64-bit and
# 128-bit SIMD integer instructions"): PADDQ/PSUBQ/PMULUDQ also take MMX registers, but only on
# SSE2 processors. For assembler messages, where only the mnemonic is known.
_SSE2_NAMES = frozenset("paddq psubq pmuludq pshufd pshufhw pshuflw pslldq psrldq punpcklqdq punpckhqdq "
                        "movdqa movdqu movq2dq movdq2q maskmovdqu movntdq movnti movntpd lfence mfence "
                        "clflush".split())

# System instructions that capstone does not put in its 'privilege' group but that a user-mode
# kernel may not run: port I/O (IOPL 0 under every OS of the period), software interrupts and
# fast system calls (they leave the kernel's code), segment/descriptor loads.
# RDMSR is here by name: Capstone does not put it in its privilege group, but it faults at CPL 3 as
# WRMSR does ("RDMSR/WRMSR: #GP(0) if the current privilege level is not 0", Intel SDM vol. 2).
_SYSTEM = frozenset("in out insb insw insd outsb outsw outsd int int1 int3 into iret iretd sysenter sysexit "
                    "syscall sysret lldt sldt ltr str lmsw smsw lar lsl verr verw arpl clts ud2 ud0 ud1 "
                    "lcall ljmp retf rdmsr".split())

# What a family lacks, in words, for the refusal message.
_WHY = {
    "cmov": "has no CMOV",
    "fcmov": "has no FCMOV/FCOMI",
    "mmx": "has no MMX",
    "sse": "has no SSE",
    "3dnow": "has no 3DNow!",
    "fxsr": "has no FXSAVE/FXRSTOR (CPUID FXSR)",
    "sse2": "has no SSE2 or later SIMD extension",
    "nopl": "has no multi-byte NOP (0F 1F)",
}


class IsaError(RetrosimError):
    """A kernel uses an instruction its CPU preset does not have, or a system instruction."""


def required_extension(mnemonic: str, groups: frozenset[str] | set[str]) -> str | None:
    """The extension an instruction needs beyond i586, or None."""
    if mnemonic in _NO_EXTENSION:
        return None
    if mnemonic in _FXSR:
        return "fxsr"
    if mnemonic in _SSE3_X87 or groups & _SSE2_GROUPS:
        return "sse2"
    if mnemonic in _SSE_MMX or mnemonic in _SSE_UNGROUPED or any(g.startswith("sse") for g in groups):
        return "sse"
    if mnemonic in _3DNOW or "3dnow" in groups:
        return "3dnow"
    if mnemonic in _FCMOV or mnemonic.startswith("fcmov"):
        return "fcmov"
    if "cmov" in groups:
        return "cmov"
    if "mmx" in groups:
        return "mmx"
    return None


_3DNOW_NAMES = frozenset({"pavgusb", "pmulhrw", "pswapd"})


def mnemonic_extension(name: str) -> str | None:
    """The extension a mnemonic belongs to, from its name alone (for assembler messages, where
    there is no decoded instruction): the families' naming conventions."""
    name = name.lower()
    if name in _NO_EXTENSION:
        return None
    if name.startswith("fcmov") or name in _FCMOV:
        return "fcmov"
    if name.startswith("cmov"):
        return "cmov"
    if name in _3DNOW or name in _3DNOW_NAMES or name.startswith(("pf", "pi2f")):
        return "3dnow"
    if name in _FXSR:
        return "fxsr"
    if name in _SSE3_X87 or name in _SSE2_NAMES or (name.endswith("pd") and name not in _3DNOW_NAMES):
        return "sse2"
    if name in _SSE_MMX or name.endswith(("ps", "ss")) or name in ("ldmxcsr", "stmxcsr"):
        return "sse"
    if name in ("emms", "movd", "movq") or name.startswith("p"):
        return "mmx"
    return None


def is_system(rec: InsnRecord) -> bool:
    return "privilege" in rec.groups or rec.mnemonic in _SYSTEM


def record_extension(rec: InsnRecord) -> str | None:
    """The extension a decoded instruction needs (:func:`required_extension`, plus what only the
    encoding tells: NOP with the 0F escape is the multi-byte NOP)."""
    if rec.mnemonic == "nop" and rec.escape_0f:
        return "nopl"
    return required_extension(rec.mnemonic, rec.groups)


def why_missing(cpu: GuestCpu, ext: str) -> str:
    """Why `cpu` refuses `ext`. When no CPU of its family has it (``family_lacks``, from the
    family's record: this layer does not read sim.cpus), the refusal names the family
    (``family_name``), else the preset."""
    if ext in cpu.family_lacks:
        return f"{cpu.family_name} {_WHY[ext]}"
    return f"{cpu.name} {_WHY[ext]}"


def system_refusal(where: str, text: str, cpu: GuestCpu | None) -> IsaError:
    """The refusal of a privileged or system instruction (`text`) on `cpu`."""
    on = f" on {cpu.name}" if cpu is not None else ""
    return IsaError(f"{where}: {text} is a privileged or system instruction; a user-mode kernel cannot "
                    f"execute it{on} (it faults at CPL 3), so it has no timing")


def check_record(rec: InsnRecord, cpu: GuestCpu, where) -> None:
    """Raise IsaError if `rec` may not run on `cpu` (a system instruction or a missing extension).
    `where`: the location for the message, or a callable making it (only called on an error)."""
    if not is_system(rec) and record_extension(rec) in (None, *cpu.extensions):
        return
    where = where() if callable(where) else where
    text = f"{rec.mnemonic} {rec.op_str}".strip()
    if is_system(rec):
        raise system_refusal(where, text, cpu)
    ext = record_extension(rec)
    if ext is not None and ext not in cpu.extensions:
        raise IsaError(f"{where}: {rec.mnemonic} is not available on {cpu.name} ({why_missing(cpu, ext)})")
