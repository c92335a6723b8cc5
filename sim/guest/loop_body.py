"""A loop body's text read as a body: its lines, labels and shape, and what it may not hold.

Two shapes are accepted (sim/guest/loop_program.py wraps and runs each):

- a **loop**: the last instruction is a conditional jump (or LOOP/JECXZ, or a JMP) to a label on
  the first instruction; the body runs as written (its own counter must not run out first);
- a **block**: anything else; it is repeated back to back (unrolled, as uiCA's unrolled mode), so
  no loop counter or branch is added to what is timed.

Comments (`#`, `//` and, in Intel syntax, `;`), syntax detection and MASM forms are
sim/guest/body_source.py's; this module refuses what a body cannot be (placement directives, a
return or trap, a jump to no label of its own) and, for a body sent to `retrosim serve`, every
directive outside :data:`SERVED_DIRECTIVES` (the first of the two walls; sim/guest/asm.py holds
the second).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from sim.errors import ArgumentError, RetrosimError
from sim.guest import asm, isa
from sim.guest.body_source import COND as _COND, JUMP as _JUMP, LABEL as _LABEL, LABEL_RUN as _LABEL_RUN
from sim.guest.body_source import from_masm, strip_comment, syntax_of as _syntax_of
from sim.guest.cpu import GuestCpu

MAX_BODY_BYTES = 1 << 20      # a loop body is instructions only: 1 MB is far beyond any

_REGISTERS = {p + r for r in ("ax", "bx", "cx", "dx", "si", "di", "bp", "sp") for p in ("e", "")}
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

