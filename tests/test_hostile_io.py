"""Hostile input, issues 25 and 26: output writers, input files read by commands, the assembler's
cache and limits, Unicorn's memory, and messages. Every case: exit 2, one stderr line, no
traceback, bounded time and memory (the cases about hangs and memory run in a subprocess under an
address-space limit and a timeout). No case names a real system path as an output.
"""

from __future__ import annotations

import json
import time
import os
import stat
from pathlib import Path

import pytest

from tests.test_hostile import OK, cli, fails, one_error, own_cache  # noqa: F401  (own_cache: autouse fixture)


# -- every writer is the checked writer ---------------------------------------------------------
def _never(*a, **k):
    raise AssertionError("the work ran before the output path was checked")


@pytest.mark.parametrize("command", ["texture-loops", "conformance", "validate"])
def test_report_writers_refuse_a_fifo_a_folder_and_a_missing_folder_before_the_work(command, tmp_path, monkeypatch):
    from sim.studies import conformance, texture_loops, validation

    monkeypatch.setattr(texture_loops, "report", _never)
    monkeypatch.setattr(conformance, "run_family", _never)
    monkeypatch.setattr(validation, "run_family", _never)
    fifo = tmp_path / "fifo.md"
    os.mkfifo(fifo)
    line = fails(command, "--out", fifo)
    assert "not a regular file" in line and str(fifo) in line
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)  # still the FIFO
    folder = tmp_path / "dir"
    folder.mkdir()
    assert "is a folder" in fails(command, "--out", folder)
    assert os.listdir(folder) == []  # no temporary file left behind
    assert "does not exist" in fails(command, "--out", tmp_path / "no" / "r.md")


def test_report_writers_follow_the_umask_and_leave_no_temporary_file(tmp_path, monkeypatch):
    from sim.studies import conformance, texture_loops

    monkeypatch.setattr(texture_loops, "report", lambda cpus=None: "# texture\n")
    monkeypatch.setattr(conformance, "run_family", lambda fam, progress=None: ([], []))
    monkeypatch.setattr(conformance, "render", lambda results, method: "# conformance\n")
    old = os.umask(0o022)
    try:
        texture_loops.write_report(tmp_path / "t.md")
        conformance.write_report(tmp_path / "c.md", ("p6",))
    finally:
        os.umask(old)
    assert sorted(os.listdir(tmp_path)) == ["c.md", "t.md"]
    for name in ("t.md", "c.md"):
        assert stat.S_IMODE(os.stat(tmp_path / name).st_mode) == 0o644


def test_no_module_writes_a_file_except_through_the_checked_writer():
    """mkstemp/os.replace/write_text only in sim/output.py, the assembler cache (sim/guest/asm.py)
    and into private temporary folders (loop's wrapper, conformance's benchmark source)."""
    import re

    root = Path(__file__).resolve().parent.parent / "sim"
    allowed = {"output.py", "asm.py"}
    private_temp = {("guest", "loop_program.py"), ("studies", "conformance.py")}  # write_text into a TemporaryDirectory
    pattern = re.compile(r"mkstemp|os\.replace|open\([^)]*['\"][wa]b?['\"]")
    for path in root.rglob("*.py"):
        if path.name in allowed:
            continue
        text = path.read_text()
        assert not pattern.search(text), f"{path}: writes a file without sim.output"
        if "write_text(" in text or "write_bytes(" in text:
            assert (path.parent.name, path.name) in private_temp, f"{path}: writes a file without sim.output"


# -- reports/baselines.json is read like every other input ---------------------------------------
def test_baselines_file_that_is_a_fifo_a_device_huge_or_deep(tmp_path, monkeypatch):
    from sim.scenes import baseline

    path = tmp_path / "baselines.json"
    monkeypatch.setattr(baseline, "BASELINE_FILE", path)
    os.mkfifo(path)  # would block `check` for ever
    assert "not a regular file" in fails("check", "zbuffer-small")
    path.unlink()
    path.symlink_to("/dev/zero")  # would grow without end
    assert "not a regular file" in fails("check", "zbuffer-small")
    path.unlink()
    with open(path, "wb") as f:  # sparse: 3 GB of size, no disk
        f.truncate(3 << 30)
    assert "more than the 16 MB" in fails("check", "zbuffer-small")
    path.write_text("[" * 100_000 + "]" * 100_000)
    line = fails("check", "zbuffer-small")
    assert str(path) in line and "nested too deeply" in line
    path.write_text('{"a": {"b": {"cycles": ' + "9" * 5000 + "}}}")
    assert str(path) in fails("check", "zbuffer-small")


# -- Unicorn under an address-space limit ---------------------------------------------------------
def run_limited(args, limit: int, timeout: int = 240, cwd=None):
    """The CLI in a subprocess under `limit` bytes of address space."""
    import resource
    import subprocess
    import sys

    from tests.test_hostile import ROOT

    def limit_memory():
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    env = {**os.environ, "PYTHONPATH": str(ROOT), "NUMBA_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, "-m", "sim.cli", *map(str, args)], capture_output=True, text=True,
                          env=env, timeout=timeout, preexec_fn=limit_memory, cwd=cwd)


def test_an_emulator_fits_in_a_gigabyte_of_address_space(write_kernel, tmp_path):
    """Unicorn's default code buffer alone is 1 GB of address space; ours is smaller."""
    src = write_kernel(OK, "k.S")
    proc = run_limited(["time", src, "--cpu", "pentium-133"], 1 << 30, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]


@pytest.mark.parametrize("command", [["loop", "BODY", "--cpu", "all"], ["validate", "--family", "p5", "--out", "v.md"]])
def test_emulators_past_a_ulimit_give_the_documented_line(command, tmp_path):
    (tmp_path / "body.s").write_text("add eax, ebx\n")
    args = [str(tmp_path / "body.s") if a == "BODY" else a for a in command]
    line = one_error(run_limited(args, 900 << 20, cwd=tmp_path))
    assert line.startswith("retrosim: error: out of host memory"), line
    assert not (tmp_path / "v.md").exists()


# -- the assembler cache sees every include; the assembler runs under limits ----------------------
INCLUDES = """.intel_syntax noprefix
.macro add_from f
.include "\\f"
.endm
.globl f
# @entry f() -> 7
f:
    nop; .include "a.inc"
    .INCLUDE "b.inc"
    add_from c.inc
    ret
"""


def test_an_edited_include_in_any_form_rebuilds_the_object(write_kernel, tmp_path):
    from sim.guest.emu import Machine

    src = write_kernel(INCLUDES, "inc.S")
    folder = Path(src).parent
    for name, line in (("a.inc", "mov eax, 1"), ("b.inc", "add eax, 2"), ("c.inc", "add eax, 4")):
        (folder / name).write_text(line + "\n")
    assert Machine.from_source(src, assembler="gnu").call("f").eax == 7
    for name, line, want in (("a.inc", "mov eax, 8", 14), ("b.inc", "add eax, 16", 28), ("c.inc", "add eax, 32", 56)):
        (folder / name).write_text(line + "\n")
        assert Machine.from_source(src, assembler="gnu").call("f").eax == want, name


def test_the_zig_back_end_refuses_an_include_it_cannot_report(write_kernel, tmp_path):
    from sim.guest import asm

    if "zig" not in asm.available_assemblers():
        pytest.skip("zig not installed")
    src = write_kernel(INCLUDES, "inc.S")
    for name in ("a.inc", "b.inc", "c.inc"):
        (Path(src).parent / name).write_text("nop\n")
    line = fails("time", src, "--assembler", "zig")
    assert f"{src}:3: .include" in line and "macro argument" in line


def test_an_include_of_a_fifo_inside_a_macro_is_stopped_by_the_time_limit(write_kernel, tmp_path):
    src = write_kernel(INCLUDES.replace('nop; .include "a.inc"\n    .INCLUDE "b.inc"\n', "")
                       .replace("add_from c.inc", "add_from p.fifo"), "fifo.S")
    os.mkfifo(Path(src).parent / "p.fifo")
    line = one_error(cli("time", src, env={"RETROSIM_ASM_SECONDS": "3"}, timeout=60, cwd=tmp_path))
    assert line == (f"retrosim: error: {src}: the assembler ran past 3 s and was stopped (a huge or nested .rept, "
                    "or an .include of a pipe?); $RETROSIM_ASM_SECONDS sets the limit")


REPT = ".intel_syntax noprefix\n.globl f\n# @entry f() -> 7\nf:\n{body}\n    ret\n"


@pytest.mark.parametrize("assembler", ["gnu", "zig"])
@pytest.mark.parametrize("body", [".rept 100000000\nnop\n.endr",  # 3.6 GB unbounded
                                  ".rept 100000000\n.endr",  # a minute unbounded
                                  ".rept 10000\n.rept 10000\nnop\n.endr\n.endr"])
def test_huge_rept_is_stopped_by_the_assembler_limits(assembler, body, write_kernel, tmp_path):
    from sim.guest import asm

    if assembler not in asm.available_assemblers():
        pytest.skip(f"{assembler} not installed")
    src = write_kernel(REPT.format(body=body), "rept.S")
    start = time.monotonic()
    proc = cli("time", src, "--assembler", assembler, env={"RETROSIM_ASM_SECONDS": "10"}, timeout=90, cwd=tmp_path)
    assert time.monotonic() - start < 60
    if proc.returncode == 0 and assembler == "zig" and ".rept 100000000\n.endr" in body:
        return  # clang expands an empty .rept in no time
    line = one_error(proc)
    assert line.startswith(f"retrosim: error: {src}: the "), line
    assert "memory limit" in line or "ran past 10 s" in line or "object passed" in line, line


def test_a_bad_assembler_time_limit_is_one_line(write_kernel):
    src = write_kernel(OK, "k.S")
    assert "RETROSIM_ASM_SECONDS" in fails("time", src, env={"RETROSIM_ASM_SECONDS": "nan"})


# -- messages -------------------------------------------------------------------------------------
def test_a_loop_fault_names_the_file_once(tmp_path):
    body = tmp_path / "nullptr.s"
    body.write_text("mov eax, [0]\n")
    line = fails("loop", body)
    assert line.count("nullptr.s") == 1 and "guest fault" in line, line


@pytest.mark.parametrize("args, expect", [
    ("buf:f32:256:0x40000000", "FILL must be a decimal float for f32, got '0x40000000'"),
    ("buf:f64:4:zz", "FILL must be a decimal float for f64, got 'zz'"),
    ("1.5xf", "'1.5x' before the 'f' is not a decimal float"),
])
def test_float_fills_and_arguments_say_float(args, expect, write_kernel):
    line = fails("run-kernel", write_kernel(OK, "k.S"), "--args", args)
    assert expect in line and "not a number" not in line


JUMP = ".intel_syntax noprefix\n.globl f\n# @entry f() -> 7\nf:\n    {insn}\n    ret\n"


@pytest.mark.parametrize("insn", ["jmp 0x12345678", "call 0x400"])
def test_a_jump_to_a_bare_address_is_a_guest_fault_there(insn, write_kernel):
    line = fails("time", write_kernel(JUMP.format(insn=insn), "j.S"))
    assert "undefined symbol" not in line
    assert "outside the kernel's code" in line and ("0x12345678" in line or "0x00000400" in line), line


def test_an_instruction_the_cpu_lacks_is_refused_before_the_fault_it_causes(write_kernel):
    # FXSAVE [esp] writes the FPU control word over the return address: the RET then jumps to 0x37f
    src = write_kernel(JUMP.format(insn="fxsave [esp]"), "fx.S")
    for command in ("time", "explain"):
        line = fails(command, src, "--cpu", "pentium-pro-200")
        assert "fxsave is not available on pentium-pro-200" in line, line
    assert "guest fault" in fails("time", src, "--cpu", "pentium3-500")  # it has FXSR: the fault is the error


@pytest.mark.parametrize("command", [["time"], ["explain"], ["run-kernel"], ["report"]])
def test_a_folder_given_as_an_input_file_is_named_in_the_error(command, tmp_path):
    # a folder opens read-only; the reader must refuse it by name ("x.S: not a regular file"), not
    # let Python's fdopen say "3: Is a directory" (its descriptor number)
    folder = tmp_path / ("scene.toml" if command == ["report"] else "kernel.S")
    folder.mkdir()
    line = fails(*command, str(folder))
    assert line.startswith(f"retrosim: error: {folder}: ") and "not a regular file" in line, line


def test_an_include_of_a_folder_is_named_in_the_error(write_kernel, tmp_path):
    (tmp_path / "inc").mkdir()
    src = write_kernel(f'.include "{tmp_path / "inc"}"\nret\n', entry="f")
    line = fails("time", src)
    assert str(tmp_path / "inc") in line and "not a regular file" in line, line


# -- issue 31: symbolic links and `--html -` -------------------------------------------------------
LOOP_BODY = "top:\n  add eax, 1\n  dec edx\n  jnz top\n"


@pytest.mark.parametrize("command", ["loop", "explain"])
def test_html_through_a_symlink_writes_its_target_and_keeps_the_link(command, tmp_path):
    # the rule for every checked writer (sim/output.py): write through a link, as open() would
    target = tmp_path / "mine" / "view.html"
    target.parent.mkdir()
    target.write_text("old")
    link = tmp_path / "link.html"
    link.symlink_to(target)
    args = (["loop", "-", "-c", "pentium2-233"] if command == "loop" else
            ["explain", "convert/fp16z.S", "--entry", "fp16z_convert_array", "--args", "buf:u32:16:7,buf:u32:16,16,0,0"])
    from click.testing import CliRunner
    from sim.cli import main

    r = CliRunner().invoke(main, [*args, "--html", str(link)], input=LOOP_BODY)
    assert r.exit_code == 0, r.output
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert target.read_text().startswith("<!DOCTYPE html>")
    assert sorted(p.name for p in target.parent.iterdir()) == ["view.html"]  # no temporary file left


def test_every_writer_writes_through_a_symlink_and_refuses_one_to_a_device(tmp_path):
    from sim import output
    from sim.errors import OutputError

    target = tmp_path / "real.txt"
    target.write_text("old")
    link = tmp_path / "link.txt"
    link.symlink_to(target)
    output.atomic_write(link, b"new")
    assert link.is_symlink() and target.read_text() == "new"
    dangling = tmp_path / "dangling.txt"
    dangling.symlink_to(tmp_path / "not-yet.txt")
    output.atomic_write(dangling, b"made")
    assert dangling.is_symlink() and (tmp_path / "not-yet.txt").read_text() == "made"
    device = tmp_path / "null.txt"
    device.symlink_to("/dev/null")
    with pytest.raises(OutputError, match="not a regular file"):
        output.atomic_write(device, b"x")
    loop_link = tmp_path / "loop.txt"
    loop_link.symlink_to(loop_link)
    with pytest.raises(OutputError, match="loop.txt"):
        output.atomic_write(loop_link, b"x")


def test_html_dash_is_refused_not_a_file_named_dash(tmp_path, monkeypatch):
    from click.testing import CliRunner
    from sim.cli import main

    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(main, ["loop", "-", "-c", "pentium2-233", "--html", "-"], input=LOOP_BODY)
    assert r.exit_code == 2 and "--html -: the page is written to a file" in r.output
    assert not (tmp_path / "-").exists()
