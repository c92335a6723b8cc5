"""Reading a file a user names: one bounded reader for kernel sources and their includes, TOML
inputs and the baselines file; and :func:`files_hash`, what a set of the package's own files holds.

Only a regular file is read (a FIFO would block, /dev/zero never ends), opened without waiting
for a writer, its size checked on the open file itself and again while reading (it may grow), so
no input makes retrosim hang or read gigabytes. Every refusal is one error naming the file.
"""

from __future__ import annotations

import hashlib
import os
import stat
from collections.abc import Iterable
from pathlib import Path

from sim.errors import RetrosimError

_CHUNK = 1 << 20


def read_bounded(path: str | os.PathLike, max_bytes: int, kind: str, error: type[Exception] = RetrosimError,
                 where: str | None = None) -> bytes:
    """The bytes of the regular file `path`, at most `max_bytes` of them. `kind` names the input in
    messages ("kernel source", "scene file"); `where` is the message's prefix (default the path;
    `file:line: .include "x"` for an included file)."""
    path = Path(path)
    where = str(path) if where is None else where
    named = "" if where == str(path) else f" {path}"  # the path once, not twice
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))  # opening a FIFO must not wait
    except OSError as e:
        raise error(f"{where}: cannot read {kind}{named}: {e.strerror or e}") from None
    too_big = f"more than the {max_bytes >> 20} MB a {kind} may have"
    st = os.fstat(fd)  # before fdopen, which refuses a folder with an error naming only the descriptor
    if not stat.S_ISREG(st.st_mode):
        os.close(fd)
        raise error(f"{where}:{named} not a regular file (a device, pipe or folder)")
    with os.fdopen(fd, "rb") as f:
        if st.st_size > max_bytes:
            raise error(f"{where}:{named} {st.st_size:,} bytes, {too_big}")
        chunks, total = [], 0
        while chunk := f.read(min(_CHUNK, max_bytes + 1 - total)):
            total += len(chunk)
            if total > max_bytes:  # it grew while being read
                raise error(f"{where}:{named} {too_big}")
            chunks.append(chunk)
    return b"".join(chunks)


def files_hash(paths: Iterable[Path], root: Path) -> str:
    """SHA-256 of files by their path relative to `root` and their content, in path order: what a
    cached result computed from them (a sweep point, a compiled copy of a core) must match."""
    h = hashlib.sha256()
    for path in sorted(paths):
        h.update(path.relative_to(root).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()
