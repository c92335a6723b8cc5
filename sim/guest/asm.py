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
import signal
import stat
import subprocess
import sys
import tempfile
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from pathlib import Path

from sim.errors import AssemblerError, AssemblerMissing
from sim.guest.cpu import GuestCpu
from sim.guest.cpu import require as require_cpu
from sim.guest.elf import CODE_BASE, CODE_LIMIT
from sim.output import file_mode, temporary_file

CACHE_ENV = "RETROSIM_CACHE"
ASSEMBLER_ENV = "RETROSIM_ASSEMBLER"
# .include (assembly, scanned for its own includes) and .incbin (bytes): both are part of the object
_INCLUDE = re.compile(rb'^\s*(?:[\w.$]+:\s*)*\.(include|incbin)\s+"([^"]+)"', re.MULTILINE)


@dataclass(frozen=True)
class Assembler:
    name: str
    command: tuple[str, ...]  # argv prefix; the source and output paths are appended
    version: str

    def argv(self, source: Path, output: Path, extra: tuple[str, ...] = (), march: str | None = None) -> list[str]:
        # -I: `.include "x"` resolves next to the source, wherever the assembler is started
        return [*_with_march(self.command, march), *extra, "-I", str(source.parent), "-o", str(output),
                source_arg(source)]


def _with_march(command: tuple[str, ...], march: str | None) -> tuple[str, ...]:
    """The command with its CPU flag (-march= / -mcpu=, i686 by default) set to `march`."""
    if march is None:
        return command
    return tuple(c.split("=", 1)[0] + "=" + march if c.startswith(("-march=", "-mcpu=")) else c for c in command)


def source_arg(source: Path) -> str:
    """The source as an argument: a name starting with '-' (`-k.S`) would be read as an option."""
    text = str(source)
    return os.path.join(".", text) if text.startswith("-") else text


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


# Sources and includes are hashed before the assembler runs, so they are read here first: in chunks,
# only regular files (a FIFO would block, /dev/zero never ends), and at most this many bytes each.
MAX_SOURCE_BYTES = 16 << 20
_CHUNK = 1 << 16


def read_source(path: Path, what: str) -> bytes:
    """A kernel source or include file, refused with one line unless it is a regular file of at most
    MAX_SOURCE_BYTES. `what` names it in the message (`file` or `file:line: .include "x"`)."""
    try:
        # O_NONBLOCK: opening a FIFO for reading must not wait for a writer
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as e:
        raise AssemblerError(f"{what}: cannot read {path}: {e.strerror or e}") from None
    with os.fdopen(fd, "rb") as f:
        st = os.fstat(f.fileno())
        if not stat.S_ISREG(st.st_mode):
            raise AssemblerError(f"{what}: {path} is not a regular file (a device, pipe or folder)")
        if st.st_size > MAX_SOURCE_BYTES:
            raise AssemblerError(f"{what}: {path} has {st.st_size:,} bytes, more than the "
                                 f"{MAX_SOURCE_BYTES >> 20} MB a kernel source may have")
        chunks, total = [], 0
        while chunk := f.read(_CHUNK):
            total += len(chunk)
            if total > MAX_SOURCE_BYTES:  # it grew while being read
                raise AssemblerError(f"{what}: {path} has more than {MAX_SOURCE_BYTES >> 20} MB")
            chunks.append(chunk)
    return b"".join(chunks)


def _content_key(source: Path, asm: Assembler, march: str | None = None) -> str:
    """Hash of everything the object depends on: the source, its .include files, the assembler
    and its flags (the CPU it assembles for included)."""
    h = hashlib.sha256()
    h.update(repr((asm.name, asm.version, _with_march(asm.command, march)[1:])).encode())
    seen: set[Path] = set()
    pending: list[tuple[Path, str, bool]] = [(source.resolve(), str(source), False)]  # (path, name, binary)
    while pending:
        path, what, binary = pending.pop()
        if path in seen:
            continue
        seen.add(path)
        if not path.exists() and path != source.resolve():
            continue  # a missing include is reported by the assembler itself, with its line
        data = read_source(path, what)
        h.update(str(path.name).encode() + b"\0" + data)
        if binary:
            continue  # .incbin data: not scanned for directives
        for m in _INCLUDE.finditer(data):
            line = data.count(b"\n", 0, m.start(2)) + 1
            kind, name = m.group(1).decode(), m.group(2).decode(errors="replace")
            pending.append((path.parent / name, f'{_shown(path, source)}:{line}: .{kind} "{name}"', kind == "incbin"))
    return h.hexdigest()


def _shown(path: Path, source: Path) -> str:
    return str(source) if path == source.resolve() else str(path)


# -- source syntax (Intel or AT&T) ---------------------------------------------------------------
SYNTAXES = ("intel", "att")
_syntax: ContextVar[str | None] = ContextVar("retrosim_syntax", default=None)
_DIRECTIVE = re.compile(rb"^\s*\.(intel|att)_syntax\b", re.MULTILINE)
_ATT_REG = re.compile(rb"%(?:e?[abcd]x|[abcd][lh]|e?[sd]i|e?[sb]p|st|mm\d|xmm\d|[cdefgs]s)\b")
_INTEL_HINT = re.compile(rb"\bptr\b|(?<![%\w.$])(?:e[abcd]x|e[sd]i|e[sb]p|[abcd][lh])\b", re.IGNORECASE)


@contextmanager
def use_syntax(syntax: str | None) -> None:
    """Set the syntax of every later assembly in this context (a command's --syntax)."""
    _syntax.set(syntax)


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


def format_diagnostics(stderr: str, source: Path, output: Path | None = None) -> str:
    """Reduce assembler output to `file:line: message` lines (the first error first). A message from
    an included file keeps that file's name and line; the temporary object is never named (a user
    knows the source, not the cache)."""
    if output is not None:
        stderr = stderr.replace(str(output), str(source))
    own = {str(source), source_arg(source)}
    lines = []
    for raw in stderr.splitlines():
        m = _GNU_MSG.match(raw) or _CLANG_MSG.match(raw)
        if m and "Warning" not in raw:
            name = str(source) if m["file"] in own else m["file"]
            lines.append(f"{name}:{m['line']}: {m['msg'].strip()}")
    if not lines:
        text = [t for t in stderr.strip().splitlines() if t.strip()]
        last = text[-1] if text else "assembler failed without a message"
        # `as: file: message` or `/usr/bin/as: message`: the program's own name adds nothing
        last = re.sub(r"^\S*\bas: ", "", last)
        return f"{source}: {last}" if not last.startswith(str(source)) else last
    extra = f" (+{len(lines) - 1} more)" if len(lines) > 1 else ""
    return lines[0] + extra


_UNSUPPORTED = re.compile(r"^(?P<where>.*?:\d+): `(?P<mnemonic>[^']+)' is not supported on `[^']+'(?P<rest>.*)$")


def _for_cpu(message: str, cpu) -> str:
    """GNU as's "`cmove' is not supported on `k6'" in the preset's terms (see sim/guest/isa.py)."""
    m = _UNSUPPORTED.match(message)
    if cpu is None or m is None:
        return message
    from sim.guest.isa import mnemonic_extension, why_missing

    name = m["mnemonic"]
    ext = mnemonic_extension(name)
    why = f" ({why_missing(cpu, ext)})" if ext else ""
    return f"{m['where']}: {name} is not available on {cpu.name}{why}{m['rest']}"


# The guest map reserves 12 MB for code and data (sim.guest.elf.CODE_LIMIT): an object much larger than
# that can never load, so the assembler is stopped (RLIMIT_FSIZE) before a `.space 1<<30` fills the disk.
MAX_OBJECT_BYTES = 64 << 20
DIGEST_SUFFIX = ".sha256"


def _limit_output_size() -> None:  # runs in the assembler's child process, before exec
    import resource

    resource.setrlimit(resource.RLIMIT_FSIZE, (MAX_OBJECT_BYTES, MAX_OBJECT_BYTES))


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _verified(target: Path) -> bool:
    """True when the cached object matches the digest stored beside it. A damaged, truncated or
    unreadable entry (or one without a digest) is removed, so it is rebuilt."""
    digest = target.with_name(target.name + DIGEST_SUFFIX)
    try:
        ok = digest.read_text(encoding="ascii").strip() == _digest(target.read_bytes())
    except (OSError, UnicodeDecodeError):
        ok = False
    if not ok:
        evict(target)
    return ok


def evict(target: str | os.PathLike) -> None:
    """Remove a cached object and its digest (a damaged entry, or an object that cannot load)."""
    target = Path(target)
    for p in (target, target.with_name(target.name + DIGEST_SUFFIX)):
        try:
            p.unlink()
        except FileNotFoundError:
            pass
        except OSError:
            pass  # a read-only cache: the digest check will keep refusing the entry


def _prepare_cache(out_dir: Path) -> None:
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".probe-", dir=out_dir)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise AssemblerError(f"assembler cache {out_dir}: not writable ({e.strerror or e}); set {CACHE_ENV} "
                             "to a writable folder") from None


def assemble(source: str | os.PathLike, assembler: str | None = None, cpu: GuestCpu | None = None,
             syntax: str | None = None) -> Path:
    """Assemble `source` and return the path of its cached ELF32 object (verified against its
    digest). `cpu`: the kernel is then assembled for that CPU's instruction set, with the
    assembler's name for it (default: plain i686). `syntax`: 'intel' or 'att' for a source without
    its own directive (default: source_syntax(), else detected)."""
    source = Path(source)
    if not source.exists():
        raise AssemblerError(f"{source}: no such kernel source file")
    asm = get_assembler(assembler)
    text = read_source(source, str(source))  # refuses devices, pipes and oversized files
    if not text.strip():
        raise AssemblerError(f"{source}: empty source file (no instructions to assemble)")
    flags = _syntax_flags(asm, syntax or _syntax.get() or detect_syntax(text))
    cpu = require_cpu(cpu)
    march = cpu.march(asm.name) if cpu is not None else None
    key = _content_key(source, asm, march) + "-".join(("", *flags))  # also checks every include
    key = hashlib.sha256(key.encode()).hexdigest() if flags else key
    out_dir = cache_dir()
    target = out_dir / f"{source.stem}-{asm.name}-{march or 'i686'}-{key[:20]}.o"
    if target.is_file() and _verified(target):
        return target
    _prepare_cache(out_dir)
    with temporary_file(out_dir, ".tmp-", ".o") as tmp, temporary_file(out_dir, ".tmp-", ".sha256") as digest_tmp:
        proc = subprocess.run(asm.argv(source, tmp, flags, march), capture_output=True, check=False,
                              preexec_fn=_limit_output_size)
        if proc.returncode != 0:
            if proc.returncode == -signal.SIGXFSZ or (tmp.exists() and tmp.stat().st_size >= MAX_OBJECT_BYTES):
                raise AssemblerError(f"{source}: the object passed {MAX_OBJECT_BYTES >> 20} MB and was stopped "
                                     f"(the guest map holds {(CODE_LIMIT - CODE_BASE) >> 20} MB of code and data; "
                                     "a huge .space or .fill?)")
            # a binary or non-UTF-8 source is echoed back in the messages: never fail on decoding them
            raise AssemblerError(_for_cpu(format_diagnostics(proc.stderr.decode("utf-8", errors="replace"), source, tmp),
                                          cpu))
        data = tmp.read_bytes()
        os.chmod(tmp, file_mode())
        digest_tmp.write_text(_digest(data) + "\n", encoding="ascii")
        os.chmod(digest_tmp, file_mode())
        # digest first, then the object: a reader that finds the object finds its digest
        os.replace(digest_tmp, target.with_name(target.name + DIGEST_SUFFIX))
        os.replace(tmp, target)  # atomic: a concurrent or interrupted run never sees half an object
    return target
