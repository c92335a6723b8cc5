"""What the emulator (Unicorn 2.1) cannot run is refused with one error, before it can crash the process."""

from __future__ import annotations

import subprocess
import sys

import pytest

from sim.guest.emu import _UNTRANSLATABLE_RUN, _x87_run_start

FXCH1, FADD_TO_ST1, NOP = b"\xd9\xc9", b"\xdc\xc1", b"\x90"


@pytest.mark.parametrize("pad", [0, 1])  # the run found at either byte alignment
def test_a_long_run_of_x87_register_forms_is_found_where_it_starts(pad):
    code = b"\x8b\x06" + NOP * pad + (FXCH1 + FADD_TO_ST1) * 101 + b"\xc3"
    assert _x87_run_start(code) == (2 + pad, 202)


def test_runs_up_to_the_limit_or_broken_by_another_instruction_are_not():
    assert _x87_run_start(FXCH1 * _UNTRANSLATABLE_RUN) is None
    assert _x87_run_start((FXCH1 * 150 + NOP) * 4) is None
    assert _x87_run_start(b"\xd8\xc1" * 400) is None  # FADD ST,ST(1): translated fine at any length


def _loop(body: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sim.cli", "loop", "-", "--cpu", "pentium2-233"], input=body,
                          capture_output=True, text=True, timeout=120)


def test_a_block_of_fxch_is_refused_with_one_line_instead_of_crashing():
    """Three FXCH, repeated as a block 101 times, crashed the process with SIGSEGV in Unicorn."""
    r = _loop("fxch st(1)\nfxch st(2)\nfxch st(3)\n")
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "303 x87 register-stack instructions in a row" in lines[0]
    assert "<stdin>" in lines[0] and "retrosim_" not in lines[0]


def test_the_limit_is_below_what_crashes():
    """200 FXCH in a row (the most allowed) run: the limit keeps a margin under the crash (~235)."""
    script = ("from sim.guest.emu import Machine; from sim.guest import elf; import numpy as np, tempfile, pathlib\n"
              "d = pathlib.Path(tempfile.mkdtemp()); s = d / 'k.S'\n"
              "s.write_text('.intel_syntax noprefix\\n.globl f\\n# @entry f() -> eax\\nf:\\n'"
              " + 'fxch st(1)\\n' * 200 + 'ret\\n')\n"
              "m = Machine.from_source(s); m.call('f'); print('ran')\n")
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "ran" in r.stdout, r.stderr
