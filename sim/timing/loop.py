"""Time a bare loop body or basic block, the way llvm-mca and uiCA take one.

The input is instructions only (Intel or AT&T syntax, comments `#`, `//` and, in Intel syntax, `;`).
Two shapes are accepted:

- a **loop**: the last instruction is a conditional jump (or LOOP/JECXZ, or a JMP) to a label on
  the first instruction; the body runs as written (its own counter must not run out first);
- a **block**: anything else; it is repeated back to back (unrolled, as uiCA's unrolled mode), so
  no loop counter or branch is added to what is timed.

The tool supplies everything a kernel would: the code around the body, register start values
(:data:`REG_DEFAULTS`, overridable), a stack, and a demand-zero data region: every data page the
body touches is mapped zero-filled on first use (Unicorn's unmapped-memory hook), up to
:data:`MAX_DATA_PAGES`. Addresses below :data:`NULL_LIMIT` are never mapped, so a null pointer faults.

Measurement: the body runs ``iterations`` times twice from the same registers (the first pass
warms caches and predictors). In the second pass the counters are cut where iteration
``iterations // 2`` and iteration ``iterations`` start; steady-state figures are the difference
divided by the iterations between (start-up cancels). The model is told that the body goes on
after the trace (to the next iteration's first instruction), so the last back-edge is taken and
nothing drains inside the window. An iteration starts where the PC reaches the first instruction
from another instruction: a REP string instruction first in the body repeats at its own PC once
per element, and its elements are one iteration. Any family's model from
:func:`sim.cpus.build.make_model` serves, as for `retrosim time`.
"""

from __future__ import annotations

import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from unicorn import UC_ERR_EXCEPTION, UC_HOOK_MEM_READ_UNMAPPED, UC_HOOK_MEM_WRITE_UNMAPPED, UC_PROT_READ, UC_PROT_WRITE, UcError
from unicorn import x86_const as X

from sim.guest import asm
from sim.guest.body_source import COND as _COND, JUMP as _JUMP, LABEL as _LABEL, LABEL_RUN as _LABEL_RUN
from sim.guest.body_source import MASM_ANON, from_masm, strip_comment, syntax_of as _syntax_of  # noqa: F401 (re-exported)
from sim.guest import elf
from sim.guest.cpu import GuestCpu
from sim.guest import isa
from sim.cpus.build import make_model
from sim.guest.decode import Decoder
from sim.guest.emu import X87_RUN_LIMIT_WORDS, X87_RUN_WORDS, Machine
from sim.errors import ArgumentError, AssemblerError, GuestFault, RetrosimError, UntranslatableCode
from sim.timing.kernel import TimingResult
from sim.guest.trace import NativeTracer, Trace

# Start values. Every register but ESP is a valid pointer (compilers use any of them as one):
# regions 4 MB apart in unmapped low memory (demand-zero, below the 64 MB that Socket 7 board
# caches cover), each shifted by a different multiple of 0x440 bytes so that streams fall in
# different cache sets (4 KB P6 ways, 16 KB K6 ways) and sectors, as real buffers would. The values
# are large, so `dec reg / jnz` loops run as long as needed, and distinct, so `cmp reg, reg / jne`
# loops do too. EDX is the smallest so that `div r32` by any other register cannot overflow (#DE);
# it is not shifted, so DL and DH start at 0 (byte-register steps stay still).
REG_DEFAULTS = {"eax": 0x02400000 + 6 * 0x440, "ebx": 0x01800000 + 3 * 0x440, "ecx": 0x02000000 + 5 * 0x440,
                "edx": 0x00C00000, "esi": 0x01000000, "edi": 0x01400000 + 2 * 0x440,
                "ebp": 0x01C00000 + 4 * 0x440}
NULL_LIMIT = 0x10000          # accesses below 64 KB are null-pointer bugs, not data
MAX_DATA_PAGES = 4096         # 16 MB of demand-zero data at most
MAX_INSTRUCTIONS = 5_000_000  # per pass: a body that needs more never reaches its back-edge
DEFAULT_ITERATIONS = 100
MAX_BODY_BYTES = 1 << 20      # a loop body is instructions only: 1 MB is far beyond any
MAX_ITERATIONS = 100_000      # -n: a loop of that many iterations traces in seconds
# A block is repeated, not looped: its wrapper holds -n + 1 copies, and assembling and decoding
# 20,000 one-instruction copies takes about 15 s (GNU as): 40,000 instructions is the most a wrapper may hold.
MAX_BLOCK_INSTRUCTIONS = 40_000
# Placement of the body's first instruction: ALIGN_SPAN bytes is the largest block any modelled
# front end cuts code into (32-byte L1I lines and P5/K6 fetch, 16-byte P6 fetch blocks), so the
# body's offset from an ALIGN_SPAN boundary decides everything alignment can change. The default
# puts it on such a boundary (the start of the code, as every release has done).
ALIGN_SPAN = 64
DEFAULT_ALIGN = ALIGN_SPAN
# --data: the caches' state when the measured pass starts. cold: what the warm-up pass left (reads
# allocate; a write allocates only if the preset's write policy does, so a P5 or a K6 without
# write allocation writes fresh memory through to the bus). warm: also every line the measured pass
# touches, read in, in address order, as far as it fits (llvm-mca's and uiCA's all-hits-L1 view).
# Cold is the default: it is what the chip does, and what every release has timed.
DATA_STATES = ("cold", "warm")
DEFAULT_DATA = "cold"
_STACK_TOP = elf.STACK_BASE + elf.STACK_SIZE - 4096  # room above ESP for [esp+k] reads

_REGISTERS = {p + r for r in ("ax", "bx", "cx", "dx", "si", "di", "bp", "sp") for p in ("e", "")}
_REP_PREFIXES = {"rep", "repe", "repz", "repne", "repnz"}
_PREFIXES = _REP_PREFIXES | {"lock", "data16", "addr16", "data32", "addr32", "cs", "ds", "es", "fs", "gs", "ss"}
# Directives a body may not hold: the harness places it in .text, in 32-bit code, and ends it itself.
_PLACEMENT_DIRECTIVES = {".data": "a section directive", ".bss": "a section directive", ".section": "a section directive",
                         ".text": "a section directive", ".previous": "a section directive",
                         ".pushsection": "a section directive", ".popsection": "a section directive",
                         ".subsection": "a section directive", ".org": "an .org",
                         ".end": ".end", ".code16": "16-bit code", ".code16gcc": "16-bit code", ".code64": "64-bit code"}
# Intel-syntax names GNU as reads as registers or operand keywords, never as a label
_INTEL_RESERVED = ({p + r for r in ("ax", "bx", "cx", "dx", "si", "di", "bp", "sp") for p in ("e", "")}
                   | {r + x for r in "abcd" for x in "lh"} | {"cs", "ds", "es", "fs", "gs", "ss", "st"}
                   | {f"{k}{i}" for k in ("mm", "xmm", "cr", "dr", "tr") for i in range(8)}
                   | {"byte", "word", "dword", "fword", "qword", "tbyte", "oword", "xmmword", "ptr", "offset",
                      "short", "near", "far", "flat"})
# A body sent to `retrosim serve` (sim.guest.asm.serving) may use these directives and no other: data,
# alignment, repetition, macros, conditions, symbols and syntax. An allow-list, because GNU as has many
# directives that read a file (.include, .incbin) or name one (.file, .loc, .stabs ...), and a new
# binutils may add more; none of these reads or names a file.
SERVED_DIRECTIVES = frozenset(
    ".byte .word .short .hword .value .long .int .quad .octa .2byte .4byte .8byte .single .float .double .tfloat "
    ".dc .dc.b .dc.w .dc.l .dc.s .dc.d .dc.x .ascii .asciz .string .sleb128 .uleb128 "
    ".fill .skip .space .zero .nop .nops .align .balign .balignw .balignl .p2align .p2alignw .p2alignl "
    ".rept .endr .irp .irpc .macro .endm .exitm .purgem .noaltmacro "
    ".if .ifdef .ifndef .ifnotdef .ifb .ifnb .ifc .ifnc .ifeq .ifeqs .ifne .ifnes .ifge .ifgt .ifle .iflt "
    ".else .elseif .endif .set .equ .equiv .eqv .local .globl .global .type .size "
    ".intel_syntax .att_syntax .arch .code32 .err .error .warning .print".split())
_FILE_DIRECTIVES = {".include": "reads a file", ".incbin": "reads a file", ".file": "names a file",
                    ".appfile": "names a file", ".line": "names a file's line", ".appline": "names a file's line",
                    ".loc": "names a file's line", ".stabs": "names a file", ".stabn": "names a file",
                    ".stabd": "names a file", ".cv_file": "names a file", ".ident": "adds text to the object"}
_OPENERS = (".rept", ".irp", ".irpc", ".macro", ".if")
_CLOSERS = {".endr": (".rept", ".irp", ".irpc"), ".endm": (".macro",), ".endif": (".if",)}
_LEAVES = {"ret", "retl", "retn", "retf", "iret", "iretd", "int", "int3", "into", "hlt", "sysenter", "syscall"}
# those that are system instructions (sim/guest/isa.py): refused as such, as `retrosim time` does
_SYSTEM_LEAVES = {"retf", "iret", "iretd", "int", "int1", "int3", "into", "hlt", "sysenter", "sysexit", "syscall",
                  "sysret", "ljmp", "lcall"}


@dataclass
class Body:
    """A parsed loop body: its lines (user line number, text without comments) and shape."""

    name: str                      # file name for messages (or <stdin>)
    syntax: str                    # 'intel' or 'att'
    lines: list[tuple[int, str]]   # every line kept, comments removed
    labels: set[str]               # labels the body defines
    head_labels: set[str]          # labels on the first instruction
    instructions: int              # static instruction count
    loop: bool                     # ends with a conditional jump to its first instruction
    macros: list[tuple[int, str]] = field(default_factory=list)  # .macro ... .endm, assembled once before the body
    warnings: list[str] = field(default_factory=list)  # one line each, for stderr


def _statements(line: str, where: str) -> list[str]:
    """A served body's line cut at GNU as's statement separator `;` (outside strings and character
    constants). A `;` inside a string or character constant is refused: passed to a macro, it would
    start a statement of its own where the macro uses the argument."""
    out, start, i = [], 0, 0
    while i < len(line):
        ch = line[i]
        if ch in "\"'":
            m = re.compile(r'"(?:[^"\\]|\\.)*"?').match(line, i) if ch == '"' else None
            end = m.end() if m else min(i + 3 if line[i + 2:i + 3] == "'" else i + 2, len(line))
            if ";" in line[i:end]:
                raise RetrosimError(f"{where}: a ';' inside a string or character constant: a body sent to the "
                                    "server may not hold one (a macro argument would make it a statement)")
            i = end
            continue
        if ch == ";":
            out.append(line[start:i])
            start = i + 1
        i += 1
    return out + [line[start:]]


def check_served_line(line: str, where: str) -> None:
    """Refuse, in a body sent to `retrosim serve`, any directive not in SERVED_DIRECTIVES (first of
    all those that read or name a host file) and any statement whose name a macro argument makes."""
    for statement in _statements(line, where):
        rest = _LABEL_RUN.sub("", statement).strip()
        word = rest.split(None, 1)[0].lower() if rest else ""
        if "\\" in word or "&" in word:
            raise RetrosimError(f"{where}: '{word}': in a body sent to the server a macro argument may not be an "
                                "instruction's or directive's name")
        if word.startswith(".") and word not in SERVED_DIRECTIVES:
            if word in _FILE_DIRECTIVES:
                raise RetrosimError(f"{where}: '{word}' {_FILE_DIRECTIVES[word]}: a body sent to the server may read "
                                    "or name no file (it is for your own files, with `retrosim loop FILE`)")
            raise RetrosimError(f"{where}: '{word}' is not a directive a body sent to the server may use (these are: "
                                f"{' '.join(sorted(SERVED_DIRECTIVES))})")


def parse_body(text: str, name: str = "<stdin>", syntax: str | None = None, cpu: GuestCpu | None = None) -> Body:
    """Split the body into lines and find its shape. `cpu` names the CPU in the refusal of a system
    instruction (as `retrosim time` words it). Macro definitions are kept apart (assembled once,
    before the body, which a block repeats). A body sent to the server (asm.serving()) is held to
    SERVED_DIRECTIVES. A UTF-8 byte-order mark before the first line is not part of it."""
    text = text.removeprefix("\ufeff")  # an editor's byte-order mark, not a character of the first label
    syntax, warnings = _syntax_of(text, syntax)
    served = asm.serving()
    lines, labels, head, order, macros, nesting = [], set(), set(), [], [], []
    for number, raw in enumerate(text.splitlines(), 1):
        line = strip_comment(raw, syntax)
        if served:
            check_served_line(line, f"{name}:{number}")
        if syntax == "intel":
            line = from_masm(line)
        rest = line
        while (m := _LABEL.match(rest)):
            if syntax == "intel" and m.group(1).lower() in _INTEL_RESERVED:
                raise RetrosimError(f"{name}:{number}: '{m.group(1)}' is a register or operand keyword in Intel "
                                    "syntax and cannot be a label: rename it")
            labels.add(m.group(1))
            if not order:
                head.add(m.group(1))
            rest = rest[m.end():]
        rest = rest.strip()
        word = rest.split(None, 1)[0].lower() if rest else ""
        if word in _PLACEMENT_DIRECTIVES:
            raise RetrosimError(f"{name}:{number}: '{rest}': {_PLACEMENT_DIRECTIVES[word]} cannot be part of a loop "
                                "body (the harness places it in 32-bit .text and ends it itself)")
        if word.startswith(_OPENERS):
            nesting.append((number, word))
        elif word in _CLOSERS or word.startswith(".else"):
            if word in _CLOSERS and (not nesting or not nesting[-1][1].startswith(_CLOSERS[word])):
                raise RetrosimError(f"{name}:{number}: '{word}' closes nothing")
            if word in _CLOSERS:
                opened = nesting.pop()
                if opened[1] == ".macro" and not nesting:  # a definition ends: assembled once, before the body
                    macros.append((number, line))
                    continue
        in_macro = any(w == ".macro" for _, w in nesting)
        if rest and not rest.startswith(".") and not in_macro:
            order.append((number, rest))
        if line.strip():
            (macros if in_macro else lines).append((number, line))
    if nesting:
        number, word = nesting[-1]
        raise RetrosimError(f"{name}:{number}: '{word}' is never closed in the body")
    if not order:
        raise RetrosimError(f"{name}: no instructions in the body")
    for number, insn in order:  # static check: every jump target must be a label of the body
        words = insn.replace(",", " ").split()
        op = words[0].lower()
        if op in _SYSTEM_LEAVES:
            raise isa.system_refusal(f"{name}:{number}", " ".join(insn.split()), cpu)
        if op in _LEAVES:
            raise RetrosimError(f"{name}:{number}: '{insn}' leaves the body (a loop body cannot return or trap)")
        if _JUMP.match(op) and len(words) == 2 and words[1].lower() not in _REGISTERS and re.fullmatch(r"[A-Za-z_.$][\w.$@]*|\d+[bf]", words[1]):
            target = words[1]
            local = re.fullmatch(r"(\d+)[bf]", target)
            if (local.group(1) if local else target) not in labels:
                raise RetrosimError(f"{name}:{number}: '{insn}' jumps to '{target}', which is not a label of the body")
    last = order[-1][1].replace(",", " ").split()
    target = last[1] if len(last) == 2 else ""
    target = target[:-1] if re.fullmatch(r"\d+b", target) else target
    # a conditional jump back to the first instruction (or an unconditional one: the harness stops
    # by counting iterations, so an endless loop is fine) makes the body a loop
    loop = bool(_COND.match(last[0].lower()) or last[0].lower() in ("jmp", "jmpl")) and target in head
    return Body(name, syntax, lines, labels, head, len(order), loop, macros, warnings)


def _rename(line: str, labels: set[str], suffix: str) -> str:
    """Give a repeated copy its own labels (numeric local labels need no renaming): in label
    definitions and operands, never in the mnemonic or its prefixes (a label may be called `add`)."""
    named = [x for x in labels if not x.isdigit()]
    if not named:
        return line
    run = _LABEL_RUN.match(line).end()
    head, rest = line[:run], line[run:]
    prefixes = "" if rest.lstrip().startswith(".") else r"(?:(?:" + "|".join(sorted(_PREFIXES)) + r")\s+)*"
    words = re.match(r"\s*" + prefixes + r"\S*", rest, re.IGNORECASE)
    mnemonic, operands = rest[:words.end()], rest[words.end():]
    for lab in sorted(named, key=len, reverse=True):
        pattern = rf"(?<![\w.$@%]){re.escape(lab)}(?![\w.$@])"
        head = re.sub(pattern, lab + suffix, head)
        operands = re.sub(pattern, lab + suffix, operands)
    return head + mnemonic + operands


def placement(align: int = DEFAULT_ALIGN, offset: int = 0) -> int:
    """Bytes from an ALIGN_SPAN-byte boundary to the body's first instruction for ``--align N
    --offset K``: the least aligned address that is a multiple of N (a multiple of N and of no
    larger power of two, what `.p2align` may give a function's loop), then K bytes further."""
    if align not in [1 << k for k in range(ALIGN_SPAN.bit_length())]:
        raise ArgumentError(f"--align {align}: must be a power of two from 1 to {ALIGN_SPAN}")
    if not 0 <= offset < align:
        raise ArgumentError(f"--offset {offset}: must be from 0 to {align - 1} (less than --align {align})")
    return (align % ALIGN_SPAN) + offset


def wrapper_source(body: Body, copies: int, pad: int = 0) -> tuple[str, list[int]]:
    """The assembled file and, per generated line, the user's line number (0 for ours). The body
    starts `pad` bytes after an ALIGN_SPAN-byte boundary (the bytes before it are INT3, never run)."""
    out: list[tuple[str, int]] = []
    add = lambda text, n=0: out.append((text, n))  # noqa: E731
    add(".intel_syntax noprefix" if body.syntax == "intel" else ".att_syntax prefix")
    add(".text")
    for n, line in body.macros:
        add(line, n)
    add(f".balign {ALIGN_SPAN}")
    if pad:
        add(f".fill {pad}, 1, 0xcc")
    add(".globl retrosim_loop")
    add("retrosim_loop:")
    if body.loop:
        first = True
        for n, line in body.lines:
            rest = _LABEL_RUN.sub("", line).strip()
            if first and rest and not rest.startswith("."):
                add("retrosim_iter_0:")  # the first instruction: where each iteration starts
                first = False
            add(line, n)
    else:
        for j in range(copies):
            add(f"retrosim_iter_{j}:")
            for n, line in body.lines:
                add(_rename(line, body.labels, f"__r{j}"), n)
    add("retrosim_exit:")
    add("nop")
    return "\n".join(t for t, _ in out) + "\n", [n for _, n in out]


@dataclass
class LoopRun:
    """The traced passes of a body: one trace (warm pass then measured pass) and the cut points."""

    body: Body
    machine: Machine = field(repr=False)
    trace: Trace = field(repr=False)
    cuts: list[int]        # end of warm pass, start of iteration n1, start of iteration n2 (measured pass)
    measured: int          # iterations between the last two cuts
    iteration_length: int  # instructions in the first measured iteration (for the timeline)
    next_pc: int = -1      # where the body goes after the trace's last instruction (its back-edge's target)
    address: int = 0       # the body's first instruction

    @property
    def alignment(self) -> int:
        """The largest power of two (up to ALIGN_SPAN) the body's address is a multiple of."""
        return min(ALIGN_SPAN, self.address & -self.address) if self.address else ALIGN_SPAN


class _DemandZero:
    """Maps zero-filled pages where the body touches unmapped data, within a page budget."""

    def __init__(self, machine: Machine):
        self.machine, self.pages = machine, 0
        machine.uc.hook_add(UC_HOOK_MEM_READ_UNMAPPED | UC_HOOK_MEM_WRITE_UNMAPPED, self._on_unmapped)

    def _on_unmapped(self, uc, kind, address, size, value, user_data):
        first, last = address & ~(elf.PAGE - 1), (address + max(size, 1) - 1) & ~(elf.PAGE - 1)
        if first < NULL_LIMIT or self.pages >= MAX_DATA_PAGES:
            return False
        for page in range(first, last + elf.PAGE, elf.PAGE):
            try:
                uc.mem_map(page, elf.PAGE, UC_PROT_READ | UC_PROT_WRITE)
                self.pages += 1
            except UcError:
                pass  # already mapped (an access straddling into a mapped page)
        self.machine._fault = None  # the Machine's own hook saw it first; it is handled now
        return True


def _truncate(trace: Trace, n: int) -> Trace:
    return trace.head(n)


def _user_line(body: Body, lines: list[int], message: str, generated: Path, wrapper: str | None = None) -> str:
    """An assembler message about the generated file, on the user's line (or naming `wrapper`)."""
    m = re.match(rf"^{re.escape(str(generated))}:(\d+): (.*)$", message)
    if not m:
        if wrapper and re.match(rf"^{re.escape(str(generated))}: {re.escape(str(generated))} has ", message):
            # a limit on the file as a whole: the wrapper's, not the user's file's
            return message.replace(f"{generated}: {generated}", wrapper)
        return message.replace(str(generated), body.name)
    k = int(m.group(1)) - 1
    # a harness line (a label of ours) that fails was broken by the user line before it (an open
    # string or expression): the message names that line and none of the harness's names
    n = next((lines[j] for j in range(min(k, len(lines) - 1), -1, -1) if lines[j]), 0)
    text = re.sub(r"`?'?retrosim_\w+:?'?`?", "the next line the harness adds", m.group(2)) if not lines[k] else m.group(2)
    return f"{body.name}:{n}: {text}" if n else f"{body.name}: {text}"


def read_body(source: str, stdin) -> tuple[str, str]:
    """The body's text and its name for messages, from FILE or - (standard input, binary): at most
    MAX_BODY_BYTES, UTF-8 (a bad byte is refused with its offset)."""
    if source == "-":
        data, name = stdin.read(MAX_BODY_BYTES + 1), "<stdin>"
    else:
        path, name = Path(source), source
        if path.is_dir():
            raise ArgumentError(f"{source}: is a directory, not a file with a loop body")
        if not path.exists():
            raise ArgumentError(f"{source}: no such file")
        if not path.is_file():
            raise ArgumentError(f"{source}: not a regular file")
        try:
            with path.open("rb") as f:
                data = f.read(MAX_BODY_BYTES + 1)
        except OSError as e:
            raise ArgumentError(f"{source}: cannot be read ({e.strerror})") from None
    if len(data) > MAX_BODY_BYTES:
        raise ArgumentError(f"{name}: more than {MAX_BODY_BYTES >> 20} MB; a loop body is instructions only")
    try:
        return data.decode("utf-8"), name
    except UnicodeDecodeError as e:
        raise ArgumentError(f"{name}: byte {e.start} ({data[e.start]:#04x}) is not UTF-8 text") from None


def parse_regs(items) -> dict[str, int]:
    regs = dict(REG_DEFAULTS)
    for item in items or ():
        name, _, value = item.partition("=")
        name = name.strip().lower()
        if name not in REG_DEFAULTS or not value.strip():
            raise ArgumentError(f"--reg {item}: expected R=V with R one of {', '.join(REG_DEFAULTS)}")
        try:
            number = int(value, 0)
        except ValueError:
            raise ArgumentError(f"--reg {item}: '{value}' is not an integer") from None
        if not -(1 << 31) <= number < 1 << 32:
            raise ArgumentError(f"--reg {item}: {name} holds 32 bits (from -0x80000000 to 0xFFFFFFFF)")
        regs[name] = number & 0xFFFFFFFF
    return regs


def check_iterations(body: Body, iterations: int) -> None:
    """Refuse an iteration count outside what the harness can do in bounded time and memory."""
    if not 4 <= iterations <= MAX_ITERATIONS:
        raise ArgumentError(f"--iterations {iterations}: must be from 4 to {MAX_ITERATIONS:,}")
    size = sum(len(line) + 1 for _, line in body.lines) * (1 if body.loop else iterations + 1)
    if size > asm.MAX_SOURCE_BYTES:
        raise ArgumentError(f"--iterations {iterations}: the wrapper generated around {body.name} would have "
                            f"{size:,} bytes, more than the {asm.MAX_SOURCE_BYTES >> 20} MB a source may have")
    total = (iterations + 1) * body.instructions
    if not body.loop and total > MAX_BLOCK_INSTRUCTIONS:
        most = MAX_BLOCK_INSTRUCTIONS // body.instructions - 1
        raise ArgumentError(f"--iterations {iterations}: {body.name} is a block (no back-edge), so it is repeated "
                            f"{iterations + 1:,} times, {total:,} instructions to assemble; the limit is "
                            f"{MAX_BLOCK_INSTRUCTIONS:,}: use -n {most} or less (at least 4), or end the body with "
                            "a jump back to its first instruction")


def _assemble(body: Body, copies: int, pad: int, assembler: str | None, cpu: GuestCpu | None) -> Machine:
    """The body's wrapper (`copies` copies of a block), assembled and loaded. Messages name the
    user's lines; a limit the wrapper exceeds names the wrapper, not the user's file."""
    text, lines = wrapper_source(body, copies, pad)
    with tempfile.TemporaryDirectory(prefix="retrosim-loop-") as tmp:
        path = Path(tmp) / "loop.S"
        path.write_text(text)
        wrapper = f"the wrapper generated around {body.name}" + (f" ({copies:,} copies)" if copies > 1 else "")
        try:
            return Machine.from_source(path, assembler=assembler, cpu=cpu)
        except AssemblerError as e:
            raise AssemblerError(_user_line(body, lines, str(e), path, wrapper)) from None
        except UntranslatableCode as e:
            raise UntranslatableCode(f"{body.name}: {wrapper} holds {e.count} {X87_RUN_WORDS}; {X87_RUN_LIMIT_WORDS}"
                                     + (" (or time it as a loop ending in a jump back to its start)" if copies > 1 else ""),
                                     e.offset, e.count) from None
        except RetrosimError as e:
            raise RetrosimError(_user_line(body, lines, str(e), path, wrapper)) from None


def run_body(body: Body, iterations: int = DEFAULT_ITERATIONS, regs: dict[str, int] | None = None,
             assembler: str | None = None, cpu: GuestCpu | None = None, align: int = DEFAULT_ALIGN,
             offset: int = 0) -> LoopRun:
    """Assemble the body in its wrapper (for `cpu`'s instruction set, if given; placed as
    :func:`placement` says) and trace the warm and the measured pass."""
    check_iterations(body, iterations)
    regs = regs or dict(REG_DEFAULTS)
    n1, n2 = iterations // 2, iterations
    pad = placement(align, offset)
    # a block is first assembled once: its errors are then the user's lines, once each
    for copies in ((n2 + 1,) if body.loop else (1, n2 + 1)):
        machine = _assemble(body, copies, pad, assembler, cpu)
    machine.image.path = Path(body.name)
    _DemandZero(machine)
    starts = [machine.symbol(f"retrosim_iter_{j}") for j in range(1 if body.loop else n2 + 1)]
    exit_pc = machine.symbol("retrosim_exit")
    lo = machine.symbol("retrosim_loop")
    if lo % ALIGN_SPAN != pad:  # the loader must keep the section's alignment
        raise RetrosimError(f"{body.name}: the body was placed at {lo:#x}, not {pad} bytes past a "
                            f"{ALIGN_SPAN}-byte boundary")
    rep_first = machine.disassemble(starts[0]).split()[0].lower() in _REP_PREFIXES
    passes = [_pass(machine, body, regs, starts, exit_pc, lo, n2, rep_first) for _ in range(2)]
    warm, (meas, marks, next_pc) = passes[0][0], passes[1]
    cuts = [warm.instructions, warm.instructions + marks[n1], warm.instructions + marks[n2]]
    return LoopRun(body, machine, Trace.concatenate([warm, meas]), cuts, n2 - n1, marks[n1 + 1] - marks[n1],
                   next_pc, starts[0])


def _pass(machine: Machine, body: Body, regs: dict[str, int], starts: list[int], exit_pc: int, lo: int,
          iterations: int, rep_first: bool = False) -> tuple[Trace, list[int], int]:
    """Run from the body's start with `regs` until `iterations` iterations are complete; return the
    trace up to the start of the next one, the index where each iteration starts and the PC of the
    next iteration's first instruction (what follows the trace)."""
    uc = machine.uc
    for name, value in regs.items():
        machine.set_reg(name, value)
    uc.reg_write(X.UC_X86_REG_ESP, _STACK_TOP)
    machine.reset_fpu()
    tracer = NativeTracer(uc, instruction_capacity=1 << 16, access_capacity=1 << 17,
                          control_word_pcs=machine.control_word_pcs())
    tracer.attach()
    pc = starts[0]
    # Run no further than the iterations still needed can take (from the instructions per iteration
    # seen so far), so a body that touches a new page per iteration maps only the pages `iterations`
    # iterations touch, not a whole trace buffer's worth; before the first iteration completes, the
    # budget grows fourfold per segment.
    budget = 1024
    try:
        while True:
            tracer.limit(min(tracer.icap, budget, MAX_INSTRUCTIONS - tracer.recorded))
            machine._fault = machine._interrupt = None
            try:
                uc.emu_start(pc, exit_pc)
            except UcError as e:
                raise _fault(machine, body, machine._describe_fault(e.errno), lo, exit_pc) from None
            if machine._interrupt is not None:
                raise _fault(machine, body, machine._describe_fault(UC_ERR_EXCEPTION), lo, exit_pc)
            tracer.drain()
            pc = machine.reg("eip")
            trace = Trace.concatenate(list(tracer._parts))
            marks = _marks(trace.pc, starts, body.loop, rep_first)
            if len(marks) > iterations:
                break
            done = len(marks) - 1  # complete iterations so far
            if done >= 1:
                per = (marks[-1] - marks[0]) / done
                budget = int((iterations + 1 - done) * per) + 16
            else:
                budget *= 4
            outside = np.flatnonzero((trace.pc < lo) | (trace.pc >= exit_pc))
            if outside.size:
                k = int(outside[0])
                src = machine.disassemble(int(trace.pc[k - 1])) if k else "?"
                raise RetrosimError(f"{body.name}: the body branches out of itself: '{src}' went to "
                                    f"{int(trace.pc[k]):#010x}")
            if pc == exit_pc:
                if body.loop:
                    raise RetrosimError(
                        f"{body.name}: the loop left through its back-edge after {max(len(marks) - 1, 1)} "
                        f"iteration(s), {iterations} needed: give its counter a larger start value with --reg "
                        f"(defaults: {', '.join(f'{k}={v:#x}' for k, v in REG_DEFAULTS.items())})")
                raise RetrosimError(f"{body.name}: the block skipped some of its own copies (a forward jump out of it)")
            if tracer.recorded >= MAX_INSTRUCTIONS:
                done = len(marks) - 1
                if done >= 1:  # it does iterate: the iterations asked for are too many for its length
                    per = (marks[-1] - marks[0]) / done
                    raise RetrosimError(
                        f"{body.name}: {iterations} iterations of the body need more than {MAX_INSTRUCTIONS:,} "
                        f"instructions per pass: it reached its back-edge {done} times, {per:,.0f} instructions "
                        f"per iteration (fewer --iterations, at most about {max(int(MAX_INSTRUCTIONS / per) - 1, 1):,}; "
                        "or a shorter inner loop or REP count: set its register with --reg)")
                raise RetrosimError(f"{body.name}: the body never reached its back-edge {iterations} times in "
                                    f"{MAX_INSTRUCTIONS:,} instructions (an inner loop or REP count too long? "
                                    "set its register with --reg)")
    finally:
        tracer.detach()
    cut = marks[iterations]
    next_pc = int(trace.pc[cut])
    trace = _truncate(trace, cut)
    outside = np.flatnonzero((trace.pc < lo) | (trace.pc >= exit_pc))
    if outside.size:
        k = int(outside[0])
        raise RetrosimError(f"{body.name}: the body branches out of itself: "
                            f"'{machine.disassemble(int(trace.pc[k - 1]))}' went to {int(trace.pc[k]):#010x}")
    return trace, marks[:iterations + 1], next_pc


def _marks(pc: np.ndarray, starts: list[int], loop: bool, rep_first: bool = False) -> list[int]:
    """Where each iteration (loop) or copy (block) starts in the pass's PC stream."""
    if loop:
        at = pc == starts[0]
        if rep_first:
            # a REP string instruction appears once per element at the same PC: an iteration starts
            # at its first element only (a one-instruction `l: loop l` still starts one per pass)
            at[1:] &= pc[:-1] != starts[0]
        return np.flatnonzero(at).tolist()
    first = []
    for s in starts:
        hit = np.flatnonzero(pc == s)
        if not hit.size:
            break
        first.append(int(hit[0]))
    return first


def _fault(machine: Machine, body: Body, fault: GuestFault, lo: int, hi: int) -> RetrosimError:
    if not lo <= fault.pc <= hi:  # a computed jump left the body and landed on no code
        return RetrosimError(f"{body.name}: the body branches out of itself: a jump went to {fault.pc:#010x}")
    msg = str(fault).removeprefix(f"{body.name}: ")  # the machine's fault names the file already: once is enough
    msg = msg.replace(" (retrosim_loop+", " (body+").replace(" (retrosim_iter_0+", " (body+")
    msg = re.sub(r" \(retrosim_\w+\+0x[0-9a-f]+\)", "", msg)
    if fault.address is not None and fault.address < NULL_LIMIT and lo <= fault.pc < hi:
        msg += " (below 64 KB: a null pointer; set the register with --reg)"
    elif fault.address is not None and lo <= fault.pc < hi:
        msg += f" (more than {MAX_DATA_PAGES * elf.PAGE >> 20} MB of data touched, or a protected page)"
    return RetrosimError(f"{body.name}: {msg}")


# -- timing ---------------------------------------------------------------------------------
@dataclass
class LoopTiming:
    cpu: str                         # the preset, or the machine label with its overrides
    memory: str
    iterations: int                  # measured iterations (between the two cuts)
    per_iteration: dict[str, float]  # every counter divided by the measured iterations
    result: TimingResult = field(repr=False)  # for views.explain_rows / timeline_rows
    address: int = 0                 # where the body's first instruction was placed
    alignment: int = 0               # the largest power of two (up to ALIGN_SPAN) dividing it
    warnings: list[str] = field(default_factory=list)  # about the body's run (one line each)
    data: str = DEFAULT_DATA         # the caches' state at the measured pass (DATA_STATES)
    write_policy: str | None = None  # when the write policy decides the result: one line saying so

    @property
    def cycles_per_iteration(self) -> float:
        return self.per_iteration["cycles"]

    @property
    def uops_per_iteration(self) -> float:
        return self.per_iteration["uops"]


def time_run(run: LoopRun, cpu: str, memory: str | None = None, timeline_iterations: int = 3,
             data: str = DEFAULT_DATA) -> LoopTiming:
    """Time a traced body on one CPU (a preset or a machine label such as
    ``k6-233{write_allocate.mode=full}``; any family make_model knows), with the caches `data`
    (DATA_STATES) when the measured pass starts."""
    if data not in DATA_STATES:
        raise ArgumentError(f"--data {data}: choose {' or '.join(DATA_STATES)}")
    model = make_model(cpu, memory)
    span = min(256, run.iteration_length * max(0, timeline_iterations))
    core_run = _run_model(model, run, (run.cuts[1], span), data)
    calls = [core_run.segment(k) for k in range(len(run.cuts))]
    per = {k: round(v / run.measured, 4) for k, v in calls[-1].items()}
    result = TimingResult(cpu, model.dram.name, "loop", Path(run.body.name), 1, calls, model, core_run, run.trace)
    return LoopTiming(cpu, model.dram.name, run.measured, per, result, run.address, run.alignment,
                      x87_warnings(run), data, write_policy_line(model, cpu, per, data))


def _run_model(model, run: LoopRun, timeline: tuple[int, int], data: str = DEFAULT_DATA):
    """`model.run` on the loop's trace, except that the body does not end after the trace: it goes on
    to `run.next_pc` (the back-edge is taken). A run that ended there would take the last back-edge
    as falling through, a mispredict the loop never has, inside the measured window. With warm data
    the warm-up pass is fed first, then the lines of the measured pass are read into the caches
    (Hierarchy.prefill), then the measured pass is fed: the core's own state runs on unbroken."""
    decoder = Decoder(run.machine.image.fetch)
    session_type = type(model.session(decoder, list(run.cuts), run.cuts[1]))
    session = session_type(model, decoder, list(run.cuts), timeline, run.cuts[1])
    if data == "warm":
        warm_end = run.cuts[0]
        session.feed(run.trace.head(warm_end), int(run.trace.pc[warm_end]))
        measured = run.trace.part(warm_end, run.trace.instructions)
        model.dside.prefill(measured.mem_addr, measured.mem_size)
        session.feed(measured, run.next_pc)
    else:
        session.feed(run.trace, run.next_pc)
    return session.finish()


# How to make write misses allocate on a preset whose write policy does not (the K6's is the
# [write_allocate] mode of its preset; the P5 never allocates on a write miss: Intel SDM vol. 3A sec. 11.3)
_WRITE_ALLOCATE_FIX = {"k6": "; --set write_allocate.mode=full makes write misses allocate (a K6 whose BIOS programs WHCR)"}


def write_policy_line(model, cpu: str, per: dict[str, float], data: str) -> str | None:
    """One line when the preset's write policy decides the result: stores in the measured
    iterations miss the L1 data cache and the L1 does not allocate every write miss (P5: never;
    K6 presets: per their write_allocate mode), so each goes to the bus and the loop waits on the
    write buffer. None otherwise (no such store, or warm data)."""
    from sim.memory.cache import ALLOC_ALWAYS

    misses = per.get("l1d_store_misses", 0)
    if data == "warm" or not misses or model.dside.geometries[0].allocate_id == ALLOC_ALWAYS:
        return None
    what = {0: "does not allocate a line on a write miss", 2: "allocates on a write miss only to the page of the "
            "last line fill or a present sector"}[model.dside.geometries[0].allocate_id]
    return (f"{cpu}: the write policy decides this result: {misses:g} store(s) per iteration miss L1 and go to the "
            f"bus (its L1 data cache {what}); --data warm times them as L1 hits"
            f"{_WRITE_ALLOCATE_FIX.get(model.family, '')}")


def x87_warnings(run: LoopRun) -> list[str]:
    """A warning when the body leaves the x87 stack deeper or shallower after each iteration: the
    eight-register stack then overflows (or underflows) within a few iterations on real hardware, a
    stack fault (Intel SDM vol. 1, "x87 FPU stack overflow or underflow": #IS, NaN results when
    masked), so the timing describes no real run. Unicorn does not fault, so the trace cannot tell."""
    window = run.trace.pc[run.cuts[1]:run.cuts[2]]
    pcs, counts = np.unique(window, return_counts=True)
    records, _ = Decoder(run.machine.image.fetch).decode_trace(pcs)
    delta = {rec.pc: rec.fpu_stack_delta for rec in records}
    net = sum(int(delta.get(int(pc), 0)) * int(n) for pc, n in zip(pcs, counts)) / run.measured
    if not net:
        return []
    what = f"pushes {net:g} more x87 register(s) than it pops" if net > 0 else f"pops {-net:g} more x87 register(s) than it pushes"
    return [f"{run.body.name}: each iteration {what}: the 8-register x87 stack {'overflows' if net > 0 else 'underflows'} "
            "within 8 iterations on real hardware (a stack fault), so this timing describes no real run"]


# What an instruction-set extension is called in "not timed (no MMX): ..." (sim/guest/isa.py names).
EXTENSION_NAMES = {"cmov": "CMOV", "fcmov": "FCMOV/FCOMI", "mmx": "MMX", "sse": "SSE", "3dnow": "3DNow!",
                   "fxsr": "FXSAVE/FXRSTOR", "sse2": "SSE2", "nopl": "multi-byte NOP"}


def required_extensions(run: LoopRun) -> set[str]:
    """The instruction-set extensions the executed body uses (sim/guest/isa.py)."""
    records, _ = Decoder(run.machine.image.fetch).decode_trace(np.unique(run.trace.pc))
    return {ext for rec in records if (ext := isa.record_extension(rec))}


def time_body(text: str, cpus: list[str], name: str = "<stdin>", syntax: str | None = None,
              iterations: int = DEFAULT_ITERATIONS, regs: dict[str, int] | None = None,
              assembler: str | None = None, timeline_iterations: int = 3, memory: str | None = None,
              align: int = DEFAULT_ALIGN, offset: int = 0, data: str = DEFAULT_DATA) -> list[LoopTiming]:
    """Time the body on every CPU in `cpus` (presets or machine labels); a CPU without an
    instruction the body uses is an error."""
    timings, _ = time_body_where_possible(text, cpus, name, syntax, iterations, regs, assembler,
                                          timeline_iterations, memory, align, offset, skip=False, data=data)
    return timings


def time_body_where_possible(text: str, cpus: list[str], name: str = "<stdin>", syntax: str | None = None,
                             iterations: int = DEFAULT_ITERATIONS, regs: dict[str, int] | None = None,
                             assembler: str | None = None, timeline_iterations: int = 3,
                             memory: str | None = None, align: int = DEFAULT_ALIGN, offset: int = 0,
                             skip: bool = True, data: str = DEFAULT_DATA) -> tuple[list[LoopTiming], dict[str, list[str]]]:
    """Time the body on the CPUs in `cpus` that have every instruction it uses; return the timings
    and the others by what they lack ({"MMX": [cpu, ...]}). With no CPU able to run it (or
    `skip` false and one CPU unable), the first refusal is the error."""
    from sim.cpus import presets
    from sim.cpus.overrides import split_label

    placement(align, offset)  # a bad --align / --offset (or --data) fails before any emulation
    if data not in DATA_STATES:
        raise ArgumentError(f"--data {data}: choose {' or '.join(DATA_STATES)}")
    if not cpus:
        raise ArgumentError("no CPU to time the body on")
    bases = {}
    for c in cpus:  # an unknown preset fails before any emulation
        base, _ = split_label(c)
        if base not in presets.available():
            raise ArgumentError(f"unknown CPU preset '{base}' (choose one of: {', '.join(presets.available())})")
        bases[c] = base
    targets = {c: GuestCpu.from_preset(presets.load(bases[c])) for c in cpus}  # each preset read once
    body = parse_body(text, name, syntax, targets[cpus[0]])

    def isa_key(c):
        t = targets[c]
        return (t.gnu_march, t.zig_mcpu, t.emulator_cpu)

    # one emulation per instruction set: the body assembles for each CPU's own (MMX, 3DNow!, SSE)
    # and runs on the Unicorn CPU model that has it; an assembler that refuses an instruction for
    # one of them is kept as that set's answer
    runs: dict[tuple, LoopRun | RetrosimError] = {}
    for c in cpus:
        key = isa_key(c)
        if key not in runs:
            try:
                runs[key] = run_body(body, iterations, regs, assembler, cpu=targets[c], align=align, offset=offset)
            except (AssemblerError, isa.IsaError) as e:
                runs[key] = e
    done = [r for r in runs.values() if isinstance(r, LoopRun)]
    if not done:
        raise next(iter(runs.values()))
    records = {id(r): Decoder(r.machine.image.fetch).decode_trace(np.unique(r.trace.pc))[0] for r in done}
    for run in done:  # a system instruction has no timing on any CPU (as `retrosim time` refuses it)
        for rec in records[id(run)]:
            if isa.is_system(rec):
                raise isa.system_refusal(_where(run, rec.pc), f"{rec.mnemonic} {rec.op_str}".strip(), targets[cpus[0]])
    out, missing, refusals = [], {}, []
    for c in cpus:
        run = runs[isa_key(c)]
        if not isinstance(run, LoopRun):
            refusals.append(run)
            lacks = sorted(required_extensions(done[0]) - targets[c].extensions, key=isa.EXTENSIONS.index)
            if skip and lacks:  # the assembler refused what the body needs for this CPU
                missing.setdefault(", ".join(EXTENSION_NAMES[x] for x in lacks), []).append(c)
                continue
            raise run  # refused for another reason than an extension the body uses
        try:  # assembled (an assembler may accept more than the CPU has): the CPU must have it all
            for rec in records[id(run)]:
                isa.check_record(rec, targets[c], lambda rec=rec, run=run: _where(run, rec.pc))
        except isa.IsaError as e:
            if not skip:
                raise
            refusals.append(e)
            lacks = sorted(required_extensions(run) - targets[c].extensions, key=isa.EXTENSIONS.index)
            missing.setdefault(", ".join(EXTENSION_NAMES[x] for x in lacks), []).append(c)
            continue
        out.append(time_run(run, c, memory, timeline_iterations=timeline_iterations, data=data))
    if not out:  # no CPU could run it: the refusal `retrosim time` gives on the first one
        raise refusals[0]
    return out, missing


def _where(run: LoopRun, pc: int) -> str:
    """Where an instruction of the body is, as `retrosim time` says it (`file: pc ADDRESS (entry+k)`)."""
    return f"{run.body.name}: pc {pc:#010x} (body+{pc - run.address:#x})"
