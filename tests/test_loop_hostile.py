"""Hostile and careless input to `retrosim loop` (issues 25 and 26): every refusal is one stderr line
with exit 2 and no traceback, in bounded time; warnings are one stderr line each; ISA refusals say
what `retrosim time` says for the same instruction on the same CPU."""

from __future__ import annotations

import json
import re
import time

import pytest
from click.testing import CliRunner

from conftest import one_error_line
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
    line = one_error_line(r)
    assert r.seconds < seconds, r.seconds
    return line[len("retrosim: error: "):]


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
    ("rdmsr", "pentium2-233", "privileged or system instruction"),  # issue 31: it had "no timing row"
    ("rdmsr", "k6-2-300", "privileged or system instruction"),
    ("wrmsr", "pentium-mmx-233", "privileged or system instruction"),
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


# -- arguments and input --------------------------------------------------------------------
@pytest.mark.parametrize("args, says", [
    (["--reg", "ecx=0x1FFFFFFFF"], "32 bits"),
    (["--reg", "ecx=-0x80000001"], "32 bits"),
    (["--timeline", "-1"], "--timeline -1"),
    (["--cpu", ",,,"], "names no CPU"),
    (["-n", "1000000000"], "100,000"),
    (["-n", "3"], "from 4"),
])
def test_bad_arguments_are_refused(args, says):
    assert says in loop_fails("l: nop\ndec ecx\njnz l\n", *args, seconds=20)


def test_register_values_keep_32_bits():
    r = run(["loop", "-", "--brief", "--json", "--reg", "ecx=-1", "--reg", "edx=0xFFFFFFFF"], "l: nop\ndec ecx\njnz l\n")
    assert r.exit_code == 0, r.output
    assert '"ecx": "0xffffffff"' in r.output and '"edx": "0xffffffff"' in r.output


def test_a_directory_is_named_as_one(tmp_path):
    assert "is a directory" in fails(["loop", tmp_path])


@pytest.mark.parametrize("data, says", [
    (b"nop\n\xff\n", "byte 4 (0xff)"),
    (bytes(range(256)) * 120_000, "more than 1 MB"),
])
def test_stdin_bytes_are_bounded_and_checked(data, says):
    assert says in fails(["loop", "-"], data, seconds=20)


def test_a_huge_block_is_refused_up_front_naming_the_wrapper():
    got = loop_fails("add eax, 1\n", "-n", "50000", seconds=10)
    assert "block" in got and "-n " in got and "<stdin> has" not in got
    got = loop_fails("mov eax, 0" + "+0" * 1500 + "\n", "-n", "9000", seconds=10)
    assert "wrapper generated around <stdin>" in got and "16 MB" in got


# -- what a body may hold ------------------------------------------------------------------
@pytest.mark.parametrize("body, says", [
    (".data\nnop\n", "<stdin>:1: '.data': a section directive"),
    (".end\nnop\n", "<stdin>:1: '.end'"),
    ("nop\n.section .rodata\n", "<stdin>:2: '.section .rodata'"),
    (".code16\nadd ax, bx\n", "<stdin>:1: '.code16': 16-bit code"),
    (".code64\nadd rax, rbx\n", "<stdin>:1: '.code64': 64-bit code"),
    ("nop\n.rept 2\n", "<stdin>:2: '.rept' is never closed"),
    ("nop\n.endr\n", "<stdin>:2: '.endr' closes nothing"),
    ("ecx: add ecx, 1\n", "<stdin>:1: 'ecx' is a register"),
    ("ptr: nop\n", "<stdin>:1: 'ptr' is a register or operand keyword"),
    ("word: add eax, 1\n", "<stdin>:1: 'word'"),
])
def test_body_directives_and_labels_get_user_facing_messages(body, says):
    got = loop_fails(body, "-n", "8", seconds=20)
    assert got.startswith(says), got
    assert "retrosim_" not in got


def test_harness_names_never_leak():
    got = loop_fails('nop\n.ascii "x\n', "-n", "8", seconds=20)
    assert "retrosim_" not in got


def test_a_label_named_like_a_mnemonic_is_renamed_only_as_a_label():
    """A block's copies get their own labels; `add:` must not turn the ADD mnemonics into `add__r0`."""
    r = run(["loop", "-", "--brief", "--json", "-n", "8"], "add: add eax, 1\nadc ebx, 0\njz add\nadd ecx, 2\n")
    assert r.exit_code == 0, (r.output, r.exception)
    assert '"instructions_per_iteration": 4' in r.output


def test_a_macro_in_a_block_is_defined_once():
    r = run(["loop", "-", "--brief", "--json", "-n", "8"], ".macro twice r\nadd \\r, 1\nadd \\r, 1\n.endm\ntwice eax\n")
    assert r.exit_code == 0, (r.output, r.exception)
    assert '"instructions_per_iteration": 2' in r.output


def test_a_hash_inside_a_string_is_not_a_comment():
    from sim.guest.body_source import strip_comment

    assert strip_comment('mov eax, "#"  # comment', "intel") == 'mov eax, "#"'
    assert strip_comment(".ascii \"a#b\" ; c", "intel") == '.ascii "a#b"'
    assert strip_comment("mov al, '#'  ; c", "intel") == "mov al, '#'"
    assert strip_comment("movb $'#, %al # c", "att") == "movb $'#, %al"
    got = loop_fails('mov eax, "#"\n', "-n", "8", seconds=20)
    assert "'#'" in got and "unbalanced" not in got


def test_a_loop_striding_through_memory_runs_only_the_iterations_asked():
    """Each iteration touches a new page: the tracer must stop at -n iterations, not run a whole
    buffer (65,536 instructions, 16,384 pages) first and hit the 16 MB data limit."""
    r = run(["loop", "-", "--brief", "--json", "-n", "10"], "l: mov eax, [ebx]\nadd ebx, 4096\ndec ecx\njnz l\n")
    assert r.exit_code == 0, (r.output, r.exception)
    assert r.seconds < 30
    assert '"measured_iterations": 5' in r.output


def test_output_fits_the_terminal_and_p5_tables_name_their_cpu():
    import os
    import subprocess
    import sys

    body = "l: add eax, ebx\nadd esi, 1\nimul edi, edi\ndec ecx\njnz l\n"
    r = subprocess.run([sys.executable, "-m", "sim.cli", "loop", "-", "-c", "pentium-133,pentium2-233", "-n", "20",
                        "--timeline", "6", "--detail"], input=body, capture_output=True, text=True, timeout=300,
                       env={**os.environ, "COLUMNS": "60"})
    assert r.returncode == 0, r.stderr
    out = r.stdout.splitlines()
    start = next(i for i, line in enumerate(out) if line.startswith("timeline on pentium2-233"))
    chart = [line for line in out[start + 1:] if line.rstrip().endswith(("]", "ecx", "ebx", "1", "edi", "0x400000"))]
    assert len(chart) >= 20
    assert max(len(line) for line in chart) <= 60
    assert any(line.startswith("pentium-133: per instruction") for line in out)


# -- warnings: one stderr line each ---------------------------------------------------------
def warnings_of(r) -> list[str]:
    return [line for line in r.stderr.splitlines() if line.startswith("retrosim: warning: ")]


def test_forced_syntax_contradicting_the_body_is_warned():
    r = run(["loop", "-", "--brief", "--syntax", "intel", "-n", "8"], "l: mov %eax, %ebx\ndec %ecx\njnz l\n")
    assert r.exit_code == 0, (r.output, r.exception)
    w, = warnings_of(r)
    assert "--syntax intel" in w and "AT&T" in w
    r = run(["loop", "-", "--brief", "--syntax", "intel", "-n", "8"], "l: mov eax, ebx\ndec ecx\njnz l\n")
    assert r.exit_code == 0 and not warnings_of(r)


def test_x87_stack_growth_is_warned():
    r = run(["loop", "-", "--brief", "-n", "8"], "l: fld dword ptr [esi]\ndec ecx\njnz l\n")
    assert r.exit_code == 0, (r.output, r.exception)
    w, = warnings_of(r)
    assert "pushes 1 more x87 register" in w and "overflows" in w
    r = run(["loop", "-", "--brief", "-n", "8"], "l: fld dword ptr [esi]\nfstp dword ptr [edi]\ndec ecx\njnz l\n")
    assert r.exit_code == 0 and not warnings_of(r)


# -- MASM/TASM listings paste as printed (README) -------------------------------------------
def test_masm_hex_and_anonymous_labels():
    from sim.guest import body_source, loop_body
    from sim.timing import loop

    assert body_source.from_masm("@@: add eax, 0FFh") == "1986: add eax, 0x0FF"
    assert body_source.from_masm("jnz @B") == "jnz 1986b" and body_source.from_masm("jmp @f") == "jmp 1986f"
    # only numeric tokens: registers and symbols ending in h stay as they are, and strings too
    for same in ("mov al, bh", "mov eax, abh", "call x1h", '.ascii "0FFh"'):
        assert body_source.from_masm(same) == same
    masm = "@@:  add eax, 0FFh   ; a listing's comment\n     and ebx, 0ffffh\n     dec ecx\n     jnz @b\n"
    gnu = "l: add eax, 0xff\n and ebx, 0xffff\n dec ecx\n jnz l\n"
    a, = loop.time_body(masm, ["pentium2-233"], iterations=20)
    b, = loop.time_body(gnu, ["pentium2-233"], iterations=20)
    assert loop_body.parse_body(masm).loop
    assert a.per_iteration == b.per_iteration


# -- an unterminated string: GNU as only warns and swallows the rest of the file ---------------
def test_an_unclosed_string_is_refused_at_its_line():
    line = loop_fails('l: add eax, 1\n.byte 1,"\ndec ecx\njnz l\n')
    assert line.startswith("<stdin>:2:") and "string is not closed" in line, line


@pytest.mark.parametrize("body, line", [('nop\n.ascii "a\\"b # c"\n.ascii "x\nret\n', 3),
                                        ('nop # a " in a comment\n.ascii "q\nret\n', 2)])
def test_the_open_quote_is_found_past_escapes_and_comments(body, line, write_kernel):
    src = write_kernel(body, entry="f")
    got = fails(["time", src])
    # write_kernel's header (.intel_syntax, .text, .globl f, f:) comes first: 4 lines
    assert got.startswith(f"{src}:{line + 4}: a string is not closed"), got


# -- an unclosed /* comment: GNU as only warns and assembles nothing after it ----------------------
def test_an_unclosed_block_comment_is_refused_at_its_line():
    line = loop_fails("l: add eax, 1 /* closed */\n  add ebx, 2 /* never closed\ndec ecx\njnz l\n")
    assert line.startswith("<stdin>:2:") and "comment is not closed" in line, line


@pytest.mark.parametrize("body, line", [('nop\n.ascii "/*"\nnop # /* in a comment\nnop /* open\nret\n', 4),
                                        ("nop /* a\nblock */ nop\n/* open\nret\n", 3)])
def test_the_open_comment_is_found_past_strings_and_closed_comments(body, line, write_kernel):
    src = write_kernel(body, entry="f")
    got = fails(["time", src])
    assert got.startswith(f"{src}:{line + 4}: a comment is not closed"), got  # 4 header lines, as above


def test_a_byte_order_mark_before_the_first_label_is_not_part_of_it(tmp_path):
    # issue 31: an editor's UTF-8 BOM made `top:` another label, and the back-edge "jumped to a label
    # not in the body"; it is not part of the text, so the loop times as without it
    body = "top:\n  add eax, 1\n  dec edx\n  jnz top\n"
    path = tmp_path / "bom.S"
    path.write_bytes(b"\xef\xbb\xbf" + body.encode())
    with_bom = run(["loop", path, "--json", "-c", "pentium2-233"])
    without = run(["loop", "-", "--json", "-c", "pentium2-233"], body)
    assert with_bom.exit_code == 0, with_bom.output
    assert json.loads(with_bom.output)["results"] == json.loads(without.output)["results"]
