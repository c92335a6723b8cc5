"""The kernel catalogue: .S files under kernels/ and the entry points they declare.

A kernel source declares each cdecl entry point in a structured comment, so the harness can list
kernels and check argument counts without parsing assembly:

    # @entry fp16z_span(zbuf, fbuf, count, z, dz, colour) -> pixels written

A description too long for one line continues on the comment lines right below it (up to a line
that is not a `#` comment, an empty comment, or the next `@` tag):

    # @entry div_window(n) -> per iteration: DIV r32 (20 clocks on X), then
    # 16 independent ADD r32,i8 and DEC/JNZ

The names are documentation; the count is enforced by :meth:`sim.guest.emu.Machine.call`.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

KERNELS_ENV = "RETROSIM_KERNELS"
_CONTINUATION = re.compile(r"^\s*#(?!\s*@)\s*(?P<text>\S.*?)\s*$")
_ENTRY = re.compile(r"^\s*#\s*@entry\s+(?P<name>[A-Za-z_.$][\w.$]*)\s*\((?P<args>[^)]*)\)\s*(?:->\s*(?P<ret>.*?))?\s*$")


@dataclass(frozen=True)
class EntryPoint:
    name: str
    args: tuple[str, ...]
    returns: str
    line: int

    def signature(self, returns: bool = True) -> str:
        ret = f" -> {self.returns}" if self.returns and returns else ""
        return f"{self.name}({', '.join(self.args)}){ret}"


def kernels_root() -> Path:
    env = os.environ.get(KERNELS_ENV)
    return Path(env) if env else Path(__file__).resolve().parents[2] / "kernels"


def entry_points(source: str | os.PathLike) -> dict[str, EntryPoint]:
    """The entry points a source file declares with `# @entry` comments, in file order."""
    from sim.guest.asm import read_source  # regular files of bounded size only (a symlink to /dev/zero never ends)

    found: dict[str, EntryPoint] = {}
    lines = read_source(Path(source), str(source)).decode("utf-8", errors="replace").splitlines()
    for lineno, line in enumerate(lines, 1):
        m = _ENTRY.match(line)
        if m:
            args = tuple(a.strip() for a in m["args"].split(",") if a.strip())
            text = [m["ret"] or ""]
            for more in lines[lineno:]:
                c = _CONTINUATION.match(more)
                if not c:
                    break
                text.append(c["text"])
            found[m["name"]] = EntryPoint(m["name"], args, _join(text), lineno)
    return found


def _join(parts: list[str]) -> str:
    """Continuation lines joined into one description; a line that starts a new sentence (capital
    letter after a line without closing punctuation) is set off with a semicolon."""
    out = ""
    for part in filter(None, parts):
        if out and part[:1].isupper() and out[-1] not in ".;:,":
            out += ";"
        out = f"{out} {part}" if out else part
    return out


def catalogue(root: Path | None = None) -> dict[Path, dict[str, EntryPoint]]:
    """Every kernel source under `root` (default: the repository's kernels/), sorted by path."""
    root = root or kernels_root()
    return {p: entry_points(p) for p in sorted(root.rglob("*.S"))}


def resolve(name: str | os.PathLike) -> Path:
    """A kernel given as a path, or as a path relative to kernels/ (with or without .S)."""
    p = Path(name)
    candidates = [p, kernels_root() / p, kernels_root() / p.with_suffix(".S")]
    for c in candidates:
        if c.is_file():
            return c
    return p  # let the caller report the missing file with the name the user gave
