"""Assemble i686 kernels (GNU as syntax, `.intel_syntax noprefix`) into ELF32 relocatable objects.

Two back ends produce the same bytes for the kernels in this repository (a test proves it):
- ``gnu``: binutils ``as --32`` (Debian/Ubuntu: ``apt-get install binutils``);
- ``zig``: clang's integrated assembler shipped in the ``ziglang`` wheel (``pip install '.[zig]'``).

Sources may be in Intel (``.intel_syntax noprefix``) or AT&T syntax: a file's own directive decides;
without one, ``syntax`` (or :func:`source_syntax` around a command) chooses, else it is detected where
unambiguous (``%`` register prefixes mean AT&T; ``ptr`` or bare register names mean Intel).

Objects are cached by content hash (source bytes, included files, assembler identity and flags) so a
scene that names ten kernels assembles each once per machine, and a stale object can never be used:
beside each object the files GNU as reported reading (--MD) are listed with their hashes and checked
on every hit; the zig back end reports none, so an include it could read unseen is refused. The
assembler runs under a time limit ($RETROSIM_ASM_SECONDS, 60 s) and a 1 GB memory limit.
"""

from __future__ import annotations

import functools
import hashlib
import os
import re
import shutil
import signal
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
from sim.inputfile import read_bounded
from sim.output import file_mode, temporary_file

CACHE_ENV = "RETROSIM_CACHE"
ASSEMBLER_ENV = "RETROSIM_ASSEMBLER"
# .include (assembly, scanned for its own includes) and .incbin (bytes): both are part of the object.
# Directives are case-insensitive and may follow a `;` or labels. This scan only forms the cache key;
# what the assembler really read (also an .include inside a macro, whose name is a macro argument)
# is recorded from its dependency output and checked on every cache hit (see _manifest).
_INCLUDE = re.compile(rb'(?:^|;)[ \t]*(?:[\w.$]+:[ \t]*)*\.(include|incbin)[ \t]+"([^"]+)"',
                      re.MULTILINE | re.IGNORECASE)
_ANY_INCLUDE = re.compile(rb'\.(?:include|incbin)\b', re.IGNORECASE)


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


def read_source(path: Path, what: str) -> bytes:
    """A kernel source or include file, refused with one line unless it is a regular file of at most
    MAX_SOURCE_BYTES. `what` names it in the message (`file` or `file:line: .include "x"`)."""
    return read_bounded(path, MAX_SOURCE_BYTES, "kernel source", AssemblerError, where=what)


# The checks an object passed before it was cached (the assembler's warnings that become errors:
# unclosed strings and comments). Raising it re-assembles every cached object once, so a source
# cached before a new check is checked too.
OBJECT_CHECKS = 2


def content_key(source: Path, asm: Assembler, march: str | None = None, depfile: bool = True) -> str:
    """Hash of everything the object depends on: the source, its .include files, the assembler
    and its flags (the CPU it assembles for included). `depfile`: the assembler reports what it
    read (checked on each cache hit); without it, an include the scan cannot follow is refused."""
    h = hashlib.sha256()
    h.update(repr((OBJECT_CHECKS, asm.name, asm.version, _with_march(asm.command, march)[1:])).encode())
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
        if not depfile:
            _refuse_unseen_includes(data, _shown(path, source))
        for m in _INCLUDE.finditer(data):
            line = data.count(b"\n", 0, m.start(2)) + 1
            kind, name = m.group(1).decode().lower(), m.group(2).decode(errors="replace")
            pending.append((path.parent / name, f'{_shown(path, source)}:{line}: .{kind} "{name}"', kind == "incbin"))
    return h.hexdigest()


def _refuse_unseen_includes(data: bytes, shown: str) -> None:
    """One line for an .include/.incbin the scan cannot follow (a name built from a macro's
    arguments, or written in a form it does not parse): its file could change unseen."""
    seen = {m.start(0) + m.group(0).lower().index(b"." + m.group(1).lower()) for m in _INCLUDE.finditer(data)}
    for m in _ANY_INCLUDE.finditer(data):
        start = data.rfind(b"\n", 0, m.start()) + 1
        before = data[start:m.start()]
        if m.start() in seen or b"#" in before or b"/*" in before:
            continue
        line = data.count(b"\n", 0, m.start()) + 1
        name = m.group(0).decode().lower()
        raise AssemblerError(f"{shown}:{line}: {name} whose file the assembler cache cannot see (a name "
                             f"from a macro argument?); with the zig back end write {name} \"file\" with a "
                             "literal name, or assemble with GNU as, which reports what it read")
    for m in _INCLUDE.finditer(data):
        if b"\\" in m.group(2):
            line = data.count(b"\n", 0, m.start(2)) + 1
            raise AssemblerError(f"{shown}:{line}: .{m.group(1).decode().lower()} of a name built from a macro "
                                 "argument: the zig back end cannot report the file it reads, so the assembler "
                                 "cache cannot see it; use a literal name, or GNU as")


def _shown(path: Path, source: Path) -> str:
    return str(source) if path == source.resolve() else str(path)


# -- sources a client sent (retrosim serve) -------------------------------------------------------
# The command line assembles the user's own files, and .include/.incbin read whatever the user can read:
# that is the point of them. A body sent to the web app is another matter: whoever sent it must not
# read the server's files, by an error message that quotes a line or by timings that depend on its
# bytes. sim/guest/loop_body.py refuses every directive but an allow-list in such a body; here, as a second
# wall, no such source may name an include at all, an assembly that read any file but the source is
# refused without a word of it, and a message about another file is never shown.
_served: ContextVar[bool] = ContextVar("retrosim_served", default=False)


@contextmanager
def served_sources():
    """Assemble every source in this context as one a client sent (`retrosim serve`)."""
    token = _served.set(True)
    try:
        yield
    finally:
        _served.reset(token)


def serving() -> bool:
    """True inside :func:`served_sources`."""
    return _served.get()


_READ_ANOTHER_FILE = "the assembler read another file than the body; a body sent to the server may read none"


def _refuse_served_reads(text: bytes, source: Path) -> None:
    m = _ANY_INCLUDE.search(text)  # anywhere: in a macro's argument or a string too
    if m:
        line = text.count(b"\n", 0, m.start()) + 1
        raise AssemblerError(f"{source}:{line}: '{m.group(0).decode(errors='replace')}': a body sent to the server "
                             "may read no file (.include and .incbin are for your own files, on the command line)")


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
    """The first of :func:`diagnostics`, with how many more ("(+1 more)"): the command line's one line."""
    return format_diagnostics_of(diagnostics(stderr, source, output))


def format_diagnostics_of(lines: list[str]) -> str:
    return lines[0] + (f" (+{len(lines) - 1} more)" if len(lines) > 1 else "")


def diagnostics(stderr: str, source: Path, output: Path | None = None) -> list[str]:
    """Reduce assembler output to `file:line: message` lines (the first error first). A message from
    an included file keeps that file's name and line; the temporary object is never named (a user
    knows the source, not the cache). A served source (:func:`serving`) gets messages about its own
    lines only: a message about any other file could quote that file."""
    if output is not None:
        stderr = stderr.replace(str(output), str(source))
    own = {str(source), source_arg(source)}
    lines, foreign = [], 0
    for raw in stderr.splitlines():
        m = _GNU_MSG.match(raw) or _CLANG_MSG.match(raw)
        if m and "Warning" not in raw:
            if serving() and m["file"] not in own:
                foreign += 1
                continue
            name = str(source) if m["file"] in own else m["file"]
            lines.append(f"{name}:{m['line']}: {m['msg'].strip()}")
    if serving() and not lines:
        last = ([t for t in stderr.splitlines() if t.strip()] or [""])[-1]
        mine = next((last[len(o) + 2:] for o in own if last.startswith(f"{o}: ")), None)
        if mine and not foreign:  # a message about the body as a whole (`body: Error: ...`)
            return [f"{source}: {mine}"]
        return [f"{source}: the assembler failed on " + ("another file than the body (its messages are not shown: "
                "a body sent to the server may read no file)" if foreign else "the body without naming a line of it")]
    if not lines:
        text = [t for t in stderr.strip().splitlines() if t.strip()]
        last = text[-1] if text else "assembler failed without a message"
        # `as: file: message` or `/usr/bin/as: message`: the program's own name adds nothing
        last = re.sub(r"^\S*\bas: ", "", last)
        return [f"{source}: {last}" if not last.startswith(str(source)) else last]
    return lines


def _unterminated_string_line(text: bytes | str) -> int:
    """The line whose double quote is never closed (GNU as strings do not span lines; `#` starts a
    comment outside a string; a backslash escapes the next character)."""
    if isinstance(text, bytes):
        text = text.decode("utf-8", errors="replace")
    for number, line in enumerate(text.splitlines(), 1):
        inside = False
        escaped = False
        for ch in line:
            if escaped:
                escaped = False
            elif inside and ch == "\\":
                escaped = True
            elif ch == '"':
                inside = not inside
            elif ch == "#" and not inside:
                break
        if inside:
            return number
    return len(text.splitlines())


def _unclosed_comment_line(text: bytes | str) -> int:
    """The line where a /* comment opens that is never closed (outside strings and # comments)."""
    if isinstance(text, bytes):
        text = text.decode("utf-8", errors="replace")
    line, opened, i, n = 1, 0, 0, len(text)
    in_string = in_line_comment = in_block = escaped = False
    while i < n:
        ch = text[i]
        if ch == "\n":
            line += 1
            in_string = in_line_comment = escaped = False  # GNU as strings and # comments end with the line
        elif in_block:
            if text.startswith("*/", i):
                in_block, i = False, i + 1
        elif in_line_comment:
            pass
        elif in_string:
            if escaped:
                escaped = False
            elif ch == "\\":
                escaped = True
            elif ch == '"':
                in_string = False
        elif ch == '"':
            in_string = True
        elif ch == "#":
            in_line_comment = True
        elif text.startswith("/*", i):
            in_block, opened, i = True, line, i + 1
        i += 1
    return opened or line


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


# The assembler runs under a time and a memory limit: `.rept 100000000` wants 3.6 GB, an empty one
# runs for a minute, and an .include of a pipe waits for ever. A kernel assembles in well under a second.
ASM_SECONDS_ENV = "RETROSIM_ASM_SECONDS"
ASM_SECONDS = 60
ASM_MEMORY = 1 << 30
# GNU as says so; clang (zig) crashes with a signal and prints a crash report instead
_OUT_OF_MEMORY = re.compile(rb"out of memory|memory exhausted|cannot allocate|can't allocate|OutOfMemory|bad_alloc"
                            rb"|command failed (?:with exit code 1[3-9][0-9]|due to signal)", re.IGNORECASE)


def _limit_assembler() -> None:  # runs in the assembler's child process, before exec
    import resource

    for kind, limit in ((resource.RLIMIT_FSIZE, MAX_OBJECT_BYTES), (resource.RLIMIT_AS, ASM_MEMORY)):
        for current in resource.getrlimit(kind):  # never above a limit already set (`ulimit -v`)
            if current != resource.RLIM_INFINITY:
                limit = min(limit, current)
        resource.setrlimit(kind, (limit, limit))


def assembler_seconds() -> float:
    raw = os.environ.get(ASM_SECONDS_ENV)
    if raw is None:
        return ASM_SECONDS
    try:
        value = float(raw)
    except ValueError:
        value = float("nan")
    if not 0 < value <= 3600:
        raise AssemblerError(f"${ASM_SECONDS_ENV}={raw!r}: must be a number of seconds above 0 and at most 3600")
    return value


def _run_assembler(argv: list[str], source: Path) -> tuple[int, bytes]:
    """(exit status, stderr) of the assembler, run in its own process group so that a time-out or
    an interrupt stops it and anything it started."""
    seconds = assembler_seconds()
    proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            preexec_fn=_limit_assembler, start_new_session=True)
    try:
        _, err = proc.communicate(timeout=seconds)
    except subprocess.TimeoutExpired:
        _kill(proc)
        raise AssemblerError(f"{source}: the assembler ran past {seconds:g} s and was stopped (a huge or nested "
                             f".rept, or an .include of a pipe?); ${ASM_SECONDS_ENV} sets the limit") from None
    except BaseException:  # Ctrl-C, SIGTERM: never leave the assembler running
        _kill(proc)
        raise
    return proc.returncode, err


def _kill(proc: subprocess.Popen) -> None:
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.communicate()


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _verified(target: Path) -> bool:
    """True when the cached object matches the digest stored beside it and every file the
    assembler read for it (listed below the digest) is unchanged. A damaged, truncated or
    unreadable entry (or one without a digest) is removed, so it is rebuilt."""
    digest = target.with_name(target.name + DIGEST_SUFFIX)
    try:
        first, *deps = digest.read_text(encoding="utf-8", errors="surrogateescape").splitlines()
        ok = first.strip() == _digest(target.read_bytes()) and all(_unchanged(line) for line in deps)
    except (OSError, UnicodeDecodeError, ValueError):
        ok = False
    if not ok:
        evict(target)
    return ok


def _read_files(target: Path) -> int:
    """How many files besides the source the assembler read for a cached object (its manifest lines)."""
    try:
        return len(target.with_name(target.name + DIGEST_SUFFIX).read_text(
            encoding="utf-8", errors="surrogateescape").splitlines()) - 1
    except OSError:
        return 1  # unreadable now: count it as reading something, so a served body is refused


def _unchanged(line: str) -> bool:
    """A manifest line `sha256 path`: does the file still hold those bytes?"""
    want, path = line.split(" ", 1)
    try:
        return _digest(read_source(Path(path), path)) == want
    except AssemblerError:  # gone, or now a pipe or too big: rebuild, and the assembler says what is wrong
        return False


def _dependencies(depfile: Path, source: Path) -> list[Path]:
    """The files GNU as read (its --MD output, `obj: file file ...`), without the source itself."""
    text = depfile.read_text(encoding="utf-8", errors="surrogateescape").replace("\\\n", " ")
    _, _, names = text.partition(": ")
    paths = [Path(os.path.abspath(n.replace("\\ ", " "))) for n in re.split(r"(?<!\\)\s+", names) if n]
    own = Path(os.path.abspath(source))
    return sorted({p for p in paths if p != own})


def _manifest(deps: list[Path], source: Path) -> str:
    """One `sha256 path` line per file the assembler read, read with the same guards as a source."""
    lines = []
    for p in deps:
        if "\n" in str(p):
            raise AssemblerError(f"{source}: includes a file whose name has a line break: {p!r}")
        lines.append(f"{_digest(read_source(p, f'{source}: included file'))} {p}")
    return "".join(line + "\n" for line in lines)


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
    if serving():
        _refuse_served_reads(text, source)
    flags = _syntax_flags(asm, syntax or _syntax.get() or detect_syntax(text))
    cpu = require_cpu(cpu)
    march = cpu.march(asm.name) if cpu is not None else None
    depfile = asm.name == "gnu"  # GNU as reports the files it read (--MD); zig does not
    key = content_key(source, asm, march, depfile) + "-".join(("", *flags))  # also checks every include
    key = hashlib.sha256(key.encode()).hexdigest() if flags else key
    out_dir = cache_dir()
    target = out_dir / f"{source.stem}-{asm.name}-{march or 'i686'}-{key[:20]}.o"
    if target.is_file() and _verified(target):
        if serving() and _read_files(target):  # (a served body assembles into a cache of its own: belt and braces)
            raise AssemblerError(f"{source}: {_READ_ANOTHER_FILE}")
        return target
    _prepare_cache(out_dir)
    with (temporary_file(out_dir, ".tmp-", ".o") as tmp, temporary_file(out_dir, ".tmp-", ".sha256") as digest_tmp,
          temporary_file(out_dir, ".tmp-", ".d") as deps_tmp):
        extra = (*flags, "--MD", str(deps_tmp)) if depfile else flags
        returncode, stderr = _run_assembler(asm.argv(source, tmp, extra, march), source)
        if returncode != 0:
            if returncode == -signal.SIGXFSZ or (tmp.exists() and tmp.stat().st_size >= MAX_OBJECT_BYTES):
                raise AssemblerError(f"{source}: the object passed {MAX_OBJECT_BYTES >> 20} MB and was stopped "
                                     f"(the guest map holds {(CODE_LIMIT - CODE_BASE) >> 20} MB of code and data; "
                                     "a huge .space or .fill?)")
            if returncode < 0 or _OUT_OF_MEMORY.search(stderr):
                raise AssemblerError(f"{source}: the assembler passed its {ASM_MEMORY >> 20} MB memory limit and was "
                                     "stopped (a huge or nested .rept or .irp?)")
            # a binary or non-UTF-8 source is echoed back in the messages: never fail on decoding them
            found = diagnostics(stderr.decode("utf-8", errors="replace"), source, tmp)
            raise AssemblerError(_for_cpu(format_diagnostics_of(found), cpu), tuple(_for_cpu(m, cpu) for m in found))
        if b"end of file in string" in stderr:
            # GNU as only warns, closes the string at the end of the file and swallows every line after
            # it into one symbol name: refuse it where the quote opened
            raise AssemblerError(f"{source}:{_unterminated_string_line(text)}: a string is not closed "
                                 "(no matching '\"')")
        if b"end of file in comment" in stderr:
            # the same: GNU as only warns, and every line after the /* is silently not assembled
            raise AssemblerError(f"{source}:{_unclosed_comment_line(text)}: a comment is not closed "
                                 "(no matching '*/')")
        deps = _dependencies(deps_tmp, source) if depfile else []
        if serving() and deps:  # what it read is never shown, nor timed
            raise AssemblerError(f"{source}: {_READ_ANOTHER_FILE}")
        manifest = _manifest(deps, source)
        data = tmp.read_bytes()
        os.chmod(tmp, file_mode())
        digest_tmp.write_text(_digest(data) + "\n" + manifest, encoding="utf-8", errors="surrogateescape")
        os.chmod(digest_tmp, file_mode())
        # digest first, then the object: a reader that finds the object finds its digest
        os.replace(digest_tmp, target.with_name(target.name + DIGEST_SUFFIX))
        os.replace(tmp, target)  # atomic: a concurrent or interrupted run never sees half an object
    return target
