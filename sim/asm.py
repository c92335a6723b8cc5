"""Assemble i686 kernels (GNU as syntax, `.intel_syntax noprefix`) into ELF32 relocatable objects.

Two back ends produce the same bytes for the kernels in this repository (a test proves it):
- ``gnu``: binutils ``as --32`` (Debian/Ubuntu: ``apt-get install binutils``);
- ``zig``: clang's integrated assembler shipped in the ``ziglang`` wheel (``pip install '.[zig]'``).

Sources may be in Intel (``.intel_syntax noprefix``) or AT&T syntax: a file's own directive decides;
without one, ``syntax`` (or :func:`source_syntax` around a command) chooses, else it is detected where
unambiguous (``%`` register prefixes mean AT&T; ``ptr`` or bare register names mean Intel).

Objects are cached by content hash (source bytes, included files, assembler identity and flags) so a
scene that names ten kernels assembles each once per machine, and a stale object can never be used.
"""

from __future__ import annotations

import functools
import hashlib
import os
import re
import shutil
import subprocess
import sys
import tempfile
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from pathlib import Path

from .errors import AssemblerError, AssemblerMissing

CACHE_ENV = "RETROSIM_CACHE"
ASSEMBLER_ENV = "RETROSIM_ASSEMBLER"
_INCLUDE = re.compile(rb'^\s*\.include\s+"([^"]+)"', re.MULTILINE)


@dataclass(frozen=True)
class Assembler:
    name: str
    command: tuple[str, ...]  # argv prefix; the source and output paths are appended
    version: str

    def argv(self, source: Path, output: Path, extra: tuple[str, ...] = (), march: str | None = None) -> list[str]:
        # -I: `.include "x"` resolves next to the source, wherever the assembler is started
        return [*_with_march(self.command, march), *extra, "-I", str(source.parent), "-o", str(output), str(source)]


def _with_march(command: tuple[str, ...], march: str | None) -> tuple[str, ...]:
    """The command with its CPU flag (-march= / -mcpu=, i686 by default) set to `march`."""
    if march is None:
        return command
    return tuple(c.split("=", 1)[0] + "=" + march if c.startswith(("-march=", "-mcpu=")) else c for c in command)


def _first_line(argv: list[str]) -> str:
    out = subprocess.run(argv, capture_output=True, text=True, check=False)
    return (out.stdout or out.stderr).strip().splitlines()[0] if (out.stdout or out.stderr) else "?"


@functools.cache
def _gnu() -> Assembler | None:
    exe = shutil.which("as")
    if exe is None:
        return None
    return Assembler("gnu", (exe, "--32", "-march=i686"), _first_line([exe, "--version"]))


@functools.cache
def _zig() -> Assembler | None:
    try:
        import ziglang  # noqa: F401  (only its presence matters; it is run as a module)
    except ImportError:
        return None
    base = (sys.executable, "-m", "ziglang")
    # -x assembler: no C preprocessor, so '#' comments mean what they mean to GNU as.
    cmd = (*base, "cc", "-c", "-x", "assembler", "-target", "x86-linux-none", "-mcpu=i686")
    return Assembler("zig", cmd, "zig " + _first_line([*base, "version"]))


def available_assemblers() -> list[str]:
    return [a.name for a in (_gnu(), _zig()) if a is not None]


def get_assembler(name: str | None = None) -> Assembler:
    """The named back end, or (name None) $RETROSIM_ASSEMBLER, else GNU as, else zig."""
    name = name or os.environ.get(ASSEMBLER_ENV) or "auto"
    if name not in ("auto", "gnu", "zig"):
        raise AssemblerMissing(f"unknown assembler '{name}': choose 'gnu' or 'zig'")
    if name in ("auto", "gnu") and (asm := _gnu()) is not None:
        return asm
    if name in ("auto", "zig") and (asm := _zig()) is not None:
        return asm
    hint = {
        "gnu": "GNU as not found on PATH: install binutils (Debian/Ubuntu: apt-get install binutils)",
        "zig": "the zig assembler is not installed: pip install 'retrosim[zig]' (or pip install ziglang)",
    }
    if name == "auto":
        raise AssemblerMissing(f"{hint['gnu']}, or {hint['zig'].split(': ', 1)[1]}")
    raise AssemblerMissing(hint[name])


def cache_dir() -> Path:
    root = os.environ.get(CACHE_ENV)
    base = Path(root) if root else Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "retrosim"
    return base / "asm"


def _content_key(source: Path, asm: Assembler, march: str | None = None) -> str:
    """Hash of everything the object depends on: the source, its .include files, the assembler
    and its flags (the CPU it assembles for included)."""
    h = hashlib.sha256()
    h.update(repr((asm.name, asm.version, _with_march(asm.command, march)[1:])).encode())
    seen: set[Path] = set()
    pending = [source.resolve()]
    while pending:
        path = pending.pop()
        if path in seen:
            continue
        seen.add(path)
        try:
            data = path.read_bytes()
        except OSError:
            continue  # a missing include is reported by the assembler itself, with its line
        h.update(str(path.name).encode() + b"\0" + data)
        pending.extend(path.parent / m.decode() for m in _INCLUDE.findall(data))
    return h.hexdigest()


# -- source syntax (Intel or AT&T) ---------------------------------------------------------------
SYNTAXES = ("intel", "att")
_syntax: ContextVar[str | None] = ContextVar("retrosim_syntax", default=None)
_DIRECTIVE = re.compile(rb"^\s*\.(intel|att)_syntax\b", re.MULTILINE)
_ATT_REG = re.compile(rb"%(?:e?[abcd]x|[abcd][lh]|e?[sd]i|e?[sb]p|st|mm\d|xmm\d|[cdefgs]s)\b")
_INTEL_HINT = re.compile(rb"\bptr\b|(?<![%\w.$])(?:e[abcd]x|e[sd]i|e[sb]p|[abcd][lh])\b", re.IGNORECASE)


@contextmanager
def source_syntax(syntax: str | None):
    """Assemble every source without its own syntax directive as `syntax` (the CLI's --syntax)."""
    token = _syntax.set(syntax)
    try:
        yield
    finally:
        _syntax.reset(token)


def detect_syntax(text: bytes) -> str | None:
    """'att' or 'intel' when the text says so unambiguously, else None. A `.intel_syntax` or
    `.att_syntax` directive is the file's own choice: None (the assembler follows it)."""
    if _DIRECTIVE.search(text):
        return None
    att, intel = bool(_ATT_REG.search(text)), bool(_INTEL_HINT.search(text))
    return "att" if att and not intel else "intel" if intel and not att else None


def _syntax_flags(asm: Assembler, syntax: str | None) -> tuple[str, ...]:
    """Command-line flags that set the starting syntax (a directive in the file still overrides)."""
    if syntax not in (None, *SYNTAXES):
        raise AssemblerError(f"unknown syntax '{syntax}': choose one of {', '.join(SYNTAXES)}")
    if syntax == "intel":
        return ("-msyntax=intel", "-mnaked-reg") if asm.name == "gnu" else ("-mllvm", "-x86-asm-syntax=intel")
    if syntax == "att":
        return ("-msyntax=att",) if asm.name == "gnu" else ()
    return ()


_GNU_MSG = re.compile(r"^(?P<file>[^:\n]+):(?P<line>\d+): (?:Error|Warning|Fatal error): (?P<msg>.*)$")
_CLANG_MSG = re.compile(r"^(?P<file>[^:\n]+):(?P<line>\d+):\d+: (?:error|fatal error): (?P<msg>.*)$")


def format_diagnostics(stderr: str, source: Path) -> str:
    """Reduce assembler output to `file:line: message` lines (the first error first)."""
    lines = []
    for raw in stderr.splitlines():
        m = _GNU_MSG.match(raw) or _CLANG_MSG.match(raw)
        if m and "Warning" not in raw:
            lines.append(f"{source}:{m['line']}: {m['msg'].strip()}")
    if not lines:
        text = stderr.strip().splitlines()
        return f"{source}: {text[-1] if text else 'assembler failed without a message'}"
    extra = f" (+{len(lines) - 1} more)" if len(lines) > 1 else ""
    return lines[0] + extra


_UNSUPPORTED = re.compile(r"^(?P<where>.*?:\d+): `(?P<mnemonic>[^']+)' is not supported on `[^']+'(?P<rest>.*)$")


def _for_cpu(message: str, cpu) -> str:
    """GNU as's "`cmove' is not supported on `k6'" in the preset's terms (see sim/isa.py)."""
    m = _UNSUPPORTED.match(message)
    if cpu is None or m is None:
        return message
    from .isa import mnemonic_extension, why_missing

    name = m["mnemonic"]
    ext = mnemonic_extension(name)
    why = f" ({why_missing(cpu, ext)})" if ext else ""
    return f"{m['where']}: {name} is not available on {cpu.name}{why}{m['rest']}"


def assemble(source: str | os.PathLike, assembler: str | None = None, cpu: str | None = None,
             syntax: str | None = None) -> Path:
    """Assemble `source` and return the path of its cached ELF32 object. `cpu`: a CPU preset
    name; the kernel is then assembled for that CPU's instruction set (default: plain i686).
    `syntax`: 'intel' or 'att' for a source without its own directive (default: source_syntax(),
    else detected)."""
    source = Path(source)
    if not source.is_file():
        raise AssemblerError(f"{source}: no such kernel source file")
    asm = get_assembler(assembler)
    text = source.read_bytes()
    if not text.strip():
        raise AssemblerError(f"{source}: empty source file (no instructions to assemble)")
    flags = _syntax_flags(asm, syntax or _syntax.get() or detect_syntax(text))
    preset = march = None
    if cpu is not None:
        from .cpus import presets
        from .isa import march as isa_march

        preset = presets.load(cpu)
        march = isa_march(preset, asm.name)
    key = _content_key(source, asm, march) + "-".join(("", *flags))
    key = hashlib.sha256(key.encode()).hexdigest() if flags else key
    out_dir = cache_dir()
    target = out_dir / f"{source.stem}-{asm.name}-{march or 'i686'}-{key[:20]}.o"
    if target.is_file():
        return target
    out_dir.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".o", dir=out_dir)
    os.close(fd)
    try:
        proc = subprocess.run(asm.argv(source, Path(tmp), flags, march), capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            raise AssemblerError(_for_cpu(format_diagnostics(proc.stderr, source), preset))
        os.replace(tmp, target)  # atomic: a concurrent or interrupted run never sees half an object
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return target
