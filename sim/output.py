"""Every file retrosim writes goes through here: one check of the output path, one atomic writer.

Why: writing to a temporary file and renaming it over the target is atomic, but a rename replaces
*whatever* is at the target, so `--out /dev/null` run as root would replace the system's /dev/null
with a regular file. Targets must therefore be a regular file or nothing; and the check runs before
the work (a report that takes a minute must not fail at the end because its folder is read-only).
Files are created following the umask, like any other program's output (mkstemp alone gives 0600).

Symbolic links: every writer writes *through* them, as a plain `open(path, "w")` would. A link at the
target is kept and the file it points to is replaced (atomically, from a temporary file beside that
file); renaming over the link itself would turn it into a regular file and leave its target unwritten.
The target the link points to is held to the same rule: a regular file or nothing.
"""

from __future__ import annotations

import contextlib
import os
import signal
import stat
import tempfile
from pathlib import Path
from typing import Iterator

from sim.errors import OutputError


@contextlib.contextmanager
def temporary_file(folder: str | os.PathLike, prefix: str, suffix: str = "") -> Iterator[Path]:
    """A new empty file in `folder` (mode 0600 until the caller publishes it), removed on exit
    unless it was renamed away. SIGINT/SIGTERM are held while it is created, so an interrupt can
    never land between its creation and the `finally` that removes it."""
    held = {signal.SIGINT, signal.SIGTERM}
    path = None
    old = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        try:
            fd, name = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=folder)
            path = Path(name)  # known before any held signal can be delivered
            os.close(fd)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)
        yield path
    finally:
        if path is not None and os.path.lexists(path):
            os.unlink(path)


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def file_mode() -> int:
    """The mode a new file gets from open(): 0o666 minus the umask."""
    return 0o666 & ~_umask()


def _reason(e: OSError) -> str:
    return e.strerror or str(e)


def file_path(given: str, what: str = "output") -> Path:
    """A file name as typed: refused when empty or ending in "/" (a folder meant; Path() would drop
    the "/" and the file would take the folder's name)."""
    if not given or given.endswith(("/", os.sep)):
        raise OutputError(f"{what} {given!r}: " + ("names a folder, not a file; give the file's name" if given
                                                  else "no file name"))
    return Path(given)


def check_output_file(path: str | os.PathLike, what: str = "output") -> Path:
    """Refuse, with one line, a target that is not a regular file or whose folder cannot take a new
    file. Returns the path. Does not create anything that stays behind."""
    path = file_path(path, what) if isinstance(path, str) else Path(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        st = None
    except NotADirectoryError:
        raise OutputError(f"{what} {path}: a parent of this path is a file, not a folder") from None
    except OSError as e:
        raise OutputError(f"{what} {path}: {_reason(e)}") from None
    if st is not None and not stat.S_ISREG(st.st_mode):
        kind = "a folder" if stat.S_ISDIR(st.st_mode) else "a device, pipe or socket"
        raise OutputError(f"{what} {path}: is {kind}, not a regular file; refusing to replace it")
    target = Path(os.path.realpath(path)) if os.path.islink(path) else path  # written through (see above)
    check_output_dir(target.parent if str(target.parent) else Path("."), what, create=False, for_file=path)
    return path


def check_output_dir(folder: str | os.PathLike, what: str = "output", create: bool = True,
                     for_file: Path | None = None) -> Path:
    """Make sure `folder` exists (creating it when `create`) and can take a new file: probe by
    creating and removing a temporary file, which is what the writer will do."""
    folder = Path(folder)
    label = f"{what} {for_file if for_file is not None else folder}"
    try:
        st = os.stat(folder)
    except FileNotFoundError:
        if not create:
            raise OutputError(f"{label}: folder {folder} does not exist") from None
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise OutputError(f"{label}: cannot create folder {folder}: {_reason(e)}") from None
        st = os.stat(folder)
    except NotADirectoryError:
        raise OutputError(f"{label}: a parent of {folder} is a file, not a folder") from None
    except OSError as e:
        raise OutputError(f"{label}: {_reason(e)}") from None
    if not stat.S_ISDIR(st.st_mode):
        raise OutputError(f"{label}: {folder} is not a folder")
    try:
        fd, probe = tempfile.mkstemp(prefix=".retrosim-probe-", dir=folder)
    except OSError as e:
        raise OutputError(f"{label}: cannot write in {folder}: {_reason(e)}") from None
    os.close(fd)
    os.unlink(probe)
    return folder


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike, what: str = "output", suffix: str = "") -> Iterator:
    """Yield a binary file object; on success it replaces `path` atomically (an interrupted or
    failed write leaves any old file intact and no temporary file behind)."""
    path = check_output_file(path, what)
    if path.is_symlink():  # write through it: the file it points to is the one replaced
        path = check_output_file(Path(os.path.realpath(path)), what)
    folder = path.parent if str(path.parent) else Path(".")
    try:
        with temporary_file(folder, f".{path.name}.", suffix or ".tmp") as tmp:
            with open(tmp, "wb") as f:
                yield f
            os.chmod(tmp, file_mode())
            # re-check just before the rename: something may have appeared at the target meanwhile
            check_output_file(path, what)
            os.replace(tmp, path)
    except OSError as e:
        raise OutputError(f"{what} {path}: {_reason(e)}") from None


def atomic_write(path: str | os.PathLike, data: bytes, what: str = "output") -> None:
    with atomic_output(path, what) as f:
        f.write(data)
