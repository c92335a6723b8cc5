"""Reading a TOML file a user or the package gives: one bounded loader for scenes, sweep specs,
validation case files and the CPU and memory presets.

A TOML input is text of modest size: the loader never reads a device, a pipe or a sparse giant
whole (it checks the file's type and size before reading), and every problem is one error whose
message names the file, with a line where TOML gives one:
``scenes/a.toml:12: TOML syntax error: Expected '=' after a key in a key/value pair (column 11)``.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from sim.errors import RetrosimError
from sim.inputfile import read_bounded

MAX_TOML_BYTES = 64 << 20  # the largest inputs are scenes with many explicit triangles (~6 MB for 65535)
# shared documents (read_toml's `shared`): path -> ((inode, mtime_ns, size), (text, document))
_SHARED: dict[Path, tuple[tuple[int, int, int], tuple[str, dict]]] = {}


def read_toml(path: str | Path, what: str = "TOML file", error: type[Exception] = RetrosimError,
              max_bytes: int = MAX_TOML_BYTES, shared: bool = False) -> tuple[str, dict]:
    """(text, parsed document) of the TOML file `path`; `what` names it in the messages ("scene
    file", "sweep spec"), `error` is the exception class raised.

    `shared`: the document is parsed once while the file is unchanged (its inode, modification time and
    size) and the same dict is returned to every caller, which must not change it. The CPU and
    memory presets are read so: every machine a scene's claims re-time reads them again, and
    parsing them was 4 % of the sort scene's time."""
    path = Path(path)
    if shared:
        try:
            st = path.stat()
        except OSError:
            st = None  # read_bounded says what is wrong
        if st is not None:
            stamp = (st.st_ino, st.st_mtime_ns, st.st_size)
            hit = _SHARED.get(path)
            if hit is not None and hit[0] == stamp:
                return hit[1]
            got = read_toml(path, what, error, max_bytes)
            _SHARED[path] = (stamp, got)
            return got
    raw = read_bounded(path, max_bytes, what, error)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise error(f"{path}: not UTF-8 text ({e.reason} at byte {e.start})") from None
    try:
        return text, tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise error(syntax_message(path, text, e)) from None


def syntax_message(path: Path, text: str, e: tomllib.TOMLDecodeError) -> str:
    """`file:line: TOML syntax error: problem (column n)`: tomllib's position moved to the front."""
    msg = str(e)
    m = re.search(r"\s*\(at line (\d+), column (\d+)\)\s*$", msg)
    if m:
        return f"{path}:{m.group(1)}: TOML syntax error: {msg[:m.start()]} (column {m.group(2)})"
    m = re.search(r"\s*\(at end of document\)\s*$", msg)
    if m:
        line = text.count("\n") + (0 if text.endswith("\n") else 1)
        return f"{path}:{max(line, 1)}: TOML syntax error: {msg[:m.start()]} (at end of document)"
    return f"{path}: TOML syntax error: {msg}"
