"""Hostile and careless input to `retrosim loop` (issues 25 and 26): every refusal is one stderr line
with exit 2 and no traceback, in bounded time; warnings are one stderr line each; ISA refusals say
what `retrosim time` says for the same instruction on the same CPU."""

from __future__ import annotations

import re
import time

import pytest
from click.testing import CliRunner

from sim.cli import main


@pytest.fixture(autouse=True)
def own_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("RETROSIM_CACHE", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)


def run(args, stdin=None):
    started = time.monotonic()
    r = CliRunner().invoke(main, [str(a) for a in args], input=stdin, catch_exceptions=True)
    r.seconds = time.monotonic() - started
    return r


def fails(args, stdin=None, seconds=60) -> str:
    """Exit 2, no exception but SystemExit, one stderr line, within `seconds`. Returns the line."""
    r = run(args, stdin)
    assert r.exit_code == 2, (r.exit_code, r.output, r.exception)
    assert isinstance(r.exception, SystemExit), r.exception
    assert "Traceback" not in r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith("retrosim: error: "), lines[0]
    assert r.seconds < seconds, r.seconds
    return lines[0][len("retrosim: error: "):]


def loop_fails(body: str, *args, **kw) -> str:
    return fails(["loop", "-", "--brief", *args], body, **kw)


def time_message(write_kernel, insn: str, cpu: str) -> str:
    """What `retrosim time` says of `insn` on `cpu`, without its location."""
    src = write_kernel(f"    mov esi, esp\n    sub esi, 1024\n    and esi, -16\n    {insn}\n    ret\n", entry="f")
    return re.sub(r"^.*?: (pc \S+ \(\S+\): )?", "", fails(["time", src, "-c", cpu]), count=1)


# -- the CPU's instruction set, exactly as `time` checks it ----------------------------------
@pytest.mark.parametrize("insn, cpu, says", [
    ("addps xmm0, xmm1", "pentium2-233", "no SSE"),
    ("paddb mm0, mm1", "pentium-pro-200", "no MMX"),
    ("fxsave [esi]", "pentium-pro-200", "no FXSAVE"),
    ("paddq mm0, mm1", "pentium3-500", "no SSE2"),
    ("cli", "pentium2-233", "privileged or system instruction"),
    ("in al, dx", "pentium2-233", "privileged or system instruction"),
    ("mov cr0, eax", "pentium2-233", "privileged or system instruction"),
    ("lgdt [esi]", "pentium2-233", "privileged or system instruction"),
    ("hlt", "pentium2-233", "privileged or system instruction"),
])
def test_loop_refuses_what_time_refuses(write_kernel, insn, cpu, says):
    expected = time_message(write_kernel, insn, cpu)
    assert says in expected
    got = loop_fails(f"mov esi, esp\nsub esi, 1024\nand esi, -16\n{insn}\n", "-c", cpu)
    assert got.startswith("<stdin>")
    assert "no timing row" not in got
    assert re.sub(r"^.*?: (pc \S+ \(\S+\): )?", "", got, count=1) == expected


def test_multi_byte_nop_refused_on_p5():
    got = loop_fails("l: nop dword ptr [eax]\ndec ecx\njnz l\n", "-c", "pentium-133")
    assert got.startswith("<stdin>:1:") and "nop" in got


def test_cpus_without_the_extension_are_listed_not_timed():
    r = run(["loop", "-", "--brief", "-c", "pentium-pro-200,pentium3-500"], "l: fxsave [esi]\ndec ecx\njnz l\n")
    assert r.exit_code == 0, r.output
    assert "not timed (no FXSAVE/FXRSTOR): pentium-pro-200" in r.output
    assert "pentium3-500" in r.output
