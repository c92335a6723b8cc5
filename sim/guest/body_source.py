"""Body text before it is a body: comments, syntax, MASM forms, and whole compiler output cut into regions.

`retrosim loop` takes a bare loop body, or a whole `gcc -S` / `clang -S` file or function (Intel or
AT&T syntax). :func:`regions` decides which, and cuts the second into the regions to time:

- with `# LLVM-MCA-BEGIN [name]` / `# LLVM-MCA-END` markers (llvm-mca's, which Compiler Explorer
  sends with whole compiler output), each marked region, named as marked;
- else every innermost loop: a conditional jump back to a label of the text (a back-edge) with no
  other back-edge between the label and the jump. None found is one error.

A text is whole output when it has markers, a section directive, a function frame directive
(`.cfi_startproc`), or a return: a bare body has none of these. A region's text keeps the file's
line numbers (the other lines are blank), so every later message names the file's line; nothing
outside the region reaches the assembler (a body sent to the server is checked after the cut, so
directives outside its region are dropped, never passed on). Inside a region, unwind and debug
annotations (`.cfi_*`, `.loc`, `.file`, `.ident`) are dropped too: they make no code, and name files.
A jump from inside the region to a label outside it is retargeted to the next instruction: it is
timed as a not-taken exit (an early `return` of a search loop), and a note says so.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from sim.errors import ArgumentError, RetrosimError
from sim.guest import asm

LABEL = re.compile(r"^\s*([A-Za-z_.$][\w.$@]*|\d+)\s*:(?!:)")
LABEL_RUN = re.compile(r"^(?:\s*(?:[A-Za-z_.$][\w.$@]*|\d+)\s*:(?!:))*")
COND = re.compile(r"^(j(?!mp)[a-z]+|loop[a-z]*|jn?e?cxz)$")
JUMP = re.compile(r"^(j[a-z]+|loop[a-z]*|call[lw]?|ljmp|lcall)$")
_TARGET = re.compile(r"[A-Za-z_.$][\w.$@]*|\d+[bf]")
_MARKER = re.compile(r"^\s*(?:#|//|;)\s*LLVM-MCA-(BEGIN|END)\b\s*(\S*)\s*$")
# signs that a text is a file or function, not a bare body
_SECTIONS = {".text", ".data", ".bss", ".section", ".previous", ".pushsection", ".popsection", ".cfi_startproc"}
_RETURNS = {"ret", "retl", "retn"}
# annotations a compiler puts between instructions: no code, dropped from a region
_ANNOTATIONS = re.compile(r"^\.(cfi_\w+|loc|loc_mark_labels|file|ident)$")
# a region's exits are retargeted to numeric local labels from here (one number per exit)
FALL_THROUGH_LABEL = 7900


def strip_comment(line: str, syntax: str) -> str:
    """Remove `//`, `#` and (Intel) `;` comments, but not inside a string ("a#b") or a character
    constant ('#', GNU as's '#). In GNU as `;` separates statements, so a MASM listing's
    `; comment` would be assembled as code without this."""
    marks = ("//", "#") + ((";",) if syntax == "intel" else ())
    i = 0
    while i < len(line):
        ch = line[i]
        if ch == '"':
            m = re.compile(r'"(?:[^"\\]|\\.)*"?').match(line, i)
            i = m.end()
            continue
        if ch == "'":
            i += 3 if line[i + 2:i + 3] == "'" else 2
            continue
        if line.startswith(marks, i):
            return line[:i].rstrip()
        i += 1
    return line.rstrip()


_STRING = re.compile(r'"(?:[^"\\]|\\.)*"?|\'.\'?')
_MASM_HEX = re.compile(r"(?<![\w.$@])([0-9][0-9A-Fa-f]*)[hH](?![\w.$@])")
_MASM_ANON_LABEL = re.compile(r"^(\s*)@@\s*:")
_MASM_ANON_REF = re.compile(r"(?<![\w.$@])@([bBfF])(?![\w.$@])")
MASM_ANON = "1986"  # the GNU numeric local label that stands for MASM's @@ (1986b = @b, 1986f = @f)


def from_masm(line: str) -> str:
    """The era's MASM/TASM forms in GNU as terms, outside strings: hex numbers `0FFh` -> `0x0FF`
    (numeric tokens only: they start with a digit, so a label `bh` or a register is untouched)
    and anonymous labels `@@:`, `@b`, `@f` -> the numeric local label MASM_ANON (`1986:`, `1986b`, `1986f`)."""
    line = _MASM_ANON_LABEL.sub(lambda m: f"{m.group(1)}{MASM_ANON}:", line)
    out, last = [], 0
    for m in _STRING.finditer(line):
        out.append(line[last:m.start()])
        out.append(m.group(0))
        last = m.end()
    out.append(line[last:])
    for i in range(0, len(out), 2):  # the parts outside strings
        part = _MASM_HEX.sub(lambda m: "0x" + m.group(1), out[i])
        out[i] = _MASM_ANON_REF.sub(lambda m: MASM_ANON + m.group(1).lower(), part)
    return "".join(out)


def syntax_of(text: str, syntax: str | None) -> tuple[str, list[str]]:
    """The text's syntax and a warning when a forced --syntax contradicts what the text says."""
    m = re.search(r"^\s*\.(intel|att)_syntax", text, re.MULTILINE)
    detected = m.group(1) if m else asm.detect_syntax(text.encode())
    if syntax:
        if syntax not in asm.SYNTAXES:
            raise ArgumentError(f"--syntax {syntax}: choose intel or att")
        if detected and detected != syntax:
            names = {"intel": "Intel", "att": "AT&T"}
            return syntax, [f"--syntax {syntax}: the body looks like {names[detected]} syntax; it is read as "
                            f"{names[syntax]} (operand order {'destination first' if syntax == 'intel' else 'source first'})"]
        return syntax, []
    return detected or "intel", []


@dataclass
class Region:
    """One part of a whole file to time: its name, the file's lines it took, and its text (the file's
    line count, every other line blank)."""

    name: str
    first: int                 # first and last line of the file it took (1-based, inclusive)
    last: int
    text: str
    notes: list[str] = field(default_factory=list)  # one line each: exits timed as not taken

    @property
    def lines(self) -> str:
        return f"lines {self.first}-{self.last}"


@dataclass
class _Line:
    labels: list[str]
    statement: str   # without labels and comments ('' for none)
    word: str        # the statement's first word, lower case

    @property
    def instruction(self) -> bool:
        return bool(self.word) and not self.word.startswith(".")


def _read(text: str, syntax: str) -> list[_Line]:
    out = []
    for raw in text.splitlines():
        line = strip_comment(raw, syntax)
        if syntax == "intel":
            line = from_masm(line)
        labels = []
        while (m := LABEL.match(line)):
            labels.append(m.group(1))
            line = line[m.end():]
        statement = line.strip()
        out.append(_Line(labels, statement, statement.split(None, 1)[0].lower() if statement else ""))
    return out


def _jump_target(line: _Line) -> str | None:
    """The label a direct jump (or LOOP, JECXZ) names, else None (no jump, or an indirect one)."""
    words = line.statement.replace(",", " ").split()
    if line.word and JUMP.match(line.word) and not line.word.startswith(("call", "lcall")) \
            and len(words) == 2 and _TARGET.fullmatch(words[1]):
        return words[1]
    return None


def _definition(lines: list[_Line], target: str, at: int) -> int | None:
    """The index of the line defining `target` as seen from line `at` (numeric `Nb`/`Nf`: the
    nearest definition before / after)."""
    local = re.fullmatch(r"(\d+)([bf])", target)
    if local:
        n, way = local.groups()
        span = range(at, -1, -1) if way == "b" else range(at + 1, len(lines))
        return next((k for k in span if n in lines[k].labels), None)
    return next((k for k, line in enumerate(lines) if target in line.labels), None)


def _marked(raw_lines: list[str], name: str) -> list[tuple[str, int, int]]:
    """(name, first, last line index) of each LLVM-MCA-BEGIN/END region."""
    out, open_ = [], None
    for k, raw in enumerate(raw_lines):
        m = _MARKER.match(raw)
        if not m:
            continue
        if m.group(1) == "BEGIN":
            if open_ is not None:
                raise RetrosimError(f"{name}:{k + 1}: LLVM-MCA-BEGIN inside the region begun on line {open_[1] + 1}")
            open_ = (m.group(2) or f"region {len(out) + 1}", k)
        else:
            if open_ is None:
                raise RetrosimError(f"{name}:{k + 1}: LLVM-MCA-END without an LLVM-MCA-BEGIN before it")
            out.append((open_[0], open_[1] + 1, k - 1))
            open_ = None
    if open_ is not None:
        raise RetrosimError(f"{name}:{open_[1] + 1}: LLVM-MCA-BEGIN is never ended (no LLVM-MCA-END after it)")
    return out


def _innermost_loops(lines: list[_Line]) -> list[tuple[str, int, int]]:
    """(label, first, last line index) of each innermost loop: a conditional jump back to a label."""
    edges = []
    for k, line in enumerate(lines):
        target = _jump_target(line) if COND.match(line.word) else None
        head = _definition(lines, target, k) if target else None
        if head is not None and head <= k:
            edges.append((target, head, k))
    return [(t, a, b) for t, a, b in edges
            if not any((a2, b2) != (a, b) and a <= a2 and b2 <= b for _, a2, b2 in edges)]


def is_whole(text: str, syntax: str) -> bool:
    """Whether the text is compiler output (or a function) to cut, not a bare body."""
    if any(_MARKER.match(raw) for raw in text.splitlines()):
        return True
    return any(line.word in _SECTIONS or line.word in _RETURNS for line in _read(text, syntax))


def regions(text: str, name: str, syntax: str | None = None) -> list[Region] | None:
    """The regions of a whole file or function to time, in file order; None for a bare body (timed
    as it is). `syntax`: --syntax, if given."""
    text = text.removeprefix("\ufeff")
    syntax, _ = syntax_of(text, syntax)
    if not is_whole(text, syntax):
        return None
    raw_lines = text.splitlines()
    lines = _read(text, syntax)
    marked = _marked(raw_lines, name)
    if marked:
        spans = marked
    else:
        spans = [(f"loop {label}", a, b) for label, a, b in _innermost_loops(lines)]
        if not spans:
            raise RetrosimError(_no_loop(lines, name))
    out = []
    for title, a, b in spans:  # a marked region's lines: from its first to its last label or statement
        used = [k for k in range(a, b + 1) if lines[k].labels or lines[k].statement]
        out.append(_region(raw_lines, lines, title, used[0] if used else a, used[-1] if used else b, name, syntax))
    return out


def _no_loop(lines: list[_Line], name: str) -> str:
    """The error for a whole file or function without a loop: the line that made it one, and what to do."""
    k, line = next((k, line) for k, line in enumerate(lines) if line.word in _SECTIONS or line.word in _RETURNS)
    what = "a section directive" if line.word in _SECTIONS else "leaves the body (a return)"
    return (f"{name}:{k + 1}: '{' '.join(line.statement.split())}': {what}, so this is a whole file or function, "
            "not a loop body, and no loop was found in it (no conditional jump back to a label of the text): mark "
            "the code to time with '# LLVM-MCA-BEGIN name' and '# LLVM-MCA-END' lines, or give the loop body alone")


def _region(raw_lines: list[str], lines: list[_Line], title: str, a: int, b: int, name: str,
            syntax: str) -> Region:
    out = [""] * (len(raw_lines) + 1)  # one spare line after the file: a last exit's landing
    inside = set().union(*(set(lines[k].labels) for k in range(a, b + 1))) if b >= a else set()
    notes, pending = [], []
    for k in range(a, b + 1):
        line = lines[k]
        prefix = "".join(f"{n}: " for n in pending)  # the exits before land here
        pending = []
        if _ANNOTATIONS.match(line.word):
            out[k] = prefix + "".join(f"{x}: " for x in line.labels)
            continue
        text = raw_lines[k]
        target = _jump_target(line)
        where = _definition(lines, target, k) if target else None
        local = bool(re.fullmatch(r"\d+[bf]", target or ""))
        if target and not (where is not None and a <= where <= b and (local or target in inside)):
            number = FALL_THROUGH_LABEL + len(notes)
            pending.append(number)
            statement = re.sub(rf"(?<![\w.$@]){re.escape(target)}(?![\w.$@])", f"{number}f", line.statement,
                               count=1)
            text = "".join(f"{x}: " for x in line.labels) + "\t" + statement
            notes.append(f"{name}:{k + 1}: '{' '.join(line.statement.split())}' leaves the region (to '{target}'): "
                         "timed as not taken")
        out[k] = prefix + text
    if pending:
        out[b + 1] = "".join(f"{n}:" for n in pending)
    # the file's syntax (directive or detected) goes on a spare line: the region's own text may be
    # too short to tell, and it must be read as the file is
    spare = next((k for k in list(range(b + 2, len(out))) + list(range(a - 1, -1, -1)) if not out[k]), None)
    if spare is not None:
        out[spare] = ".intel_syntax noprefix" if syntax == "intel" else ".att_syntax prefix"
    while out and not out[-1]:
        out.pop()
    return Region(title, a + 1, b + 1, "\n".join(out) + "\n", notes)
