import functools
from pathlib import Path

import pytest
from click.testing import CliRunner

from sim.guest.emu import Machine

ROOT = Path(__file__).resolve().parent.parent
KERNELS = ROOT / "kernels"


@functools.cache
def _machine(relpath: str) -> Machine:
    return Machine.from_source(KERNELS / relpath)


@pytest.fixture
def machine():
    """machine('zbuffer/z32.S') -> a Machine with that kernel loaded and a fresh arena.
    Machines are shared across tests (assembling and mapping is the slow part); the arena is reset."""

    def get(relpath: str) -> Machine:
        m = _machine(relpath)
        m.arena.reset()
        m.reset_fpu()
        return m

    return get


RDTSC_KERNEL = """.intel_syntax noprefix
.text
# @entry timed(n) -> EAX = cycles measured by RDTSC around n dependent IMULs
.globl timed
timed:
    push ebx
    mov ecx, [esp+8]
    rdtsc
    mov ebx, eax
    mov eax, 3
1:  imul eax, eax
    dec ecx
    jnz 1b
    rdtsc
    sub eax, ebx
    pop ebx
    ret
"""


INTEL = ".intel_syntax noprefix\n"


@pytest.fixture
def write_kernel(tmp_path):
    """write_kernel(body, name="k.S", entry=None, *, text=True, tail="", folder=None) -> Path:
    the one way a test writes a tiny kernel. The file (in `folder`, default the test's tmp_path)
    holds `.intel_syntax noprefix`, `.text` (unless text=False), `.globl ENTRY` and `ENTRY:` when
    an entry is named, the body and `tail`; a body that starts with `.intel_syntax` is written as
    it is. Line numbers in messages count from that header."""

    def write(body: str, name: str = "k.S", entry: str | None = None, *, text: bool = True, tail: str = "",
              folder: Path | None = None) -> Path:
        path = (folder or tmp_path) / name
        if body.startswith(".intel_syntax"):
            path.write_text(body)
            return path
        head = INTEL + (".text\n" if text else "") + (f".globl {entry}\n{entry}:\n" if entry else "")
        path.write_text(head + body + tail)
        return path

    return write


def one_error_line(r) -> str:
    """A CLI result that failed as bad input should: exit 2, no exception but SystemExit, no
    traceback, and one stderr line starting "retrosim: error: ". Returns that line."""
    assert r.exit_code == 2, (r.exit_code, r.output, r.exception)
    assert isinstance(r.exception, SystemExit), r.exception
    assert "Traceback" not in r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith("retrosim: error: "), lines[0]
    return lines[0]


def cli_fails(*args, env=None) -> str:
    """Run the CLI in-process and require :func:`one_error_line` of it. Returns the line."""
    from sim.cli import main

    return one_error_line(CliRunner().invoke(main, [str(a) for a in args], env=env, catch_exceptions=True))
