"""Hostile and careless input (issue 13): every case ends with exit status 2 and one literal line
on stderr naming the file, field or guest PC; nothing is half written; memory stays bounded.

Most cases run the CLI in-process (fast); the ones about memory, hangs and signals run it in a
subprocess under an address-space limit and a timeout, where a regression cannot take the test run
(or the shared machine) down. No case names a real system path as an output.
"""

from __future__ import annotations

import json
import os
import resource
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest
from click.testing import CliRunner

from sim.guest import asm
from conftest import cli_fails
from sim.cli import main

ROOT = Path(__file__).resolve().parent.parent
AS_LIMIT = 3 << 30  # the CLI needs ~1.5 GB of address space (numba, Unicorn); the bad cases wanted 5-14 GB

OK = ".intel_syntax noprefix\n.globl f\n# @entry f() -> 7\nf:\n    mov eax, 7\n    ret\n"


@pytest.fixture(autouse=True)
def own_cache(tmp_path, monkeypatch):
    """A private assembler cache per test (the damage tests must not touch the shared one)."""
    monkeypatch.setenv("RETROSIM_CACHE", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)


fails = cli_fails  # exit 2, one "retrosim: error:" line, no traceback (conftest)


def succeeds(*args):
    r = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    return r


def _limit_memory():
    resource.setrlimit(resource.RLIMIT_AS, (AS_LIMIT, AS_LIMIT))


def cli(*args, env=None, timeout=60, cwd=None) -> subprocess.CompletedProcess:
    """The CLI in a subprocess under AS_LIMIT of address space."""
    full_env = {**os.environ, "PYTHONPATH": str(ROOT), "NUMBA_NUM_THREADS": "1", **(env or {})}
    return subprocess.run([sys.executable, "-m", "sim.cli", *map(str, args)], capture_output=True, text=True,
                          env=full_env, timeout=timeout, preexec_fn=_limit_memory, cwd=cwd)


def one_error(proc: subprocess.CompletedProcess) -> str:
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    return lines[0]


# -- 0. output paths that destroy files ---------------------------------------------------------
def test_trace_refuses_to_replace_a_device_a_fifo_or_a_folder(write_kernel, tmp_path):
    src = write_kernel(OK, "k.S")
    # never /dev/null itself: a regression run as root would replace the system's device
    device = tmp_path / "null"
    try:
        os.mknod(device, stat.S_IFCHR | 0o666, os.makedev(1, 3))
    except PermissionError:
        device = None  # not root: the FIFO below is the same case
    if device is not None:
        assert "not a regular file" in fails("trace", src, "--out", device)
        assert stat.S_ISCHR(os.stat(device).st_mode)
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    assert "pipe" in fails("trace", src, "--out", fifo)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert "folder" in fails("trace", src, "--out", tmp_path)
    assert not list(tmp_path.glob(".*tmp*")) and not list(tmp_path.glob(".pipe*"))


def test_impossible_out_paths_fail_before_the_work(write_kernel):
    # a runaway kernel: if --out were checked after the run, the message would be about the budget
    src = write_kernel("1:  jmp 1b", "loop.S", entry="f", text=False, tail="\n")
    a_file = write_kernel(OK, "k.S")
    for out in (a_file / "t.npz", "/proc/retrosim-none/t.npz", "/proc/self/t.npz"):
        line = fails("trace", src, "--budget", "100000", "--out", out)
        assert f"--out {out}" in line and "budget" not in line
    line = fails("report", "zbuffer-small", "--out", a_file / "reports")
    assert "is a file" in line
    line = fails("report", "zbuffer-small", "--out", "/proc/self/reports")
    assert "/proc/self/reports" in line


def test_outputs_follow_the_umask(write_kernel, tmp_path):
    src = write_kernel(OK, "k.S")
    old = os.umask(0o022)
    try:
        succeeds("trace", src, "--out", tmp_path / "t.npz")
    finally:
        os.umask(old)
    assert stat.S_IMODE(os.stat(tmp_path / "t.npz").st_mode) == 0o644
    objects = list((tmp_path / "cache" / "asm").iterdir())
    assert objects and all(stat.S_IMODE(p.stat().st_mode) == 0o644 for p in objects)


# -- 1. a cache that verifies what it serves ----------------------------------------------------
def test_a_damaged_cached_object_is_rebuilt_not_served(write_kernel):
    src = write_kernel(OK, "k.S")
    obj = asm.assemble(src)
    data = bytearray(obj.read_bytes())
    at = data.find(bytes([0xB8, 7, 0, 0, 0]))  # mov eax, 7
    data[at + 1] = 42
    obj.write_bytes(bytes(data))
    assert json.loads(succeeds("run-kernel", src, "--json").stdout)["eax"] == 7
    obj.write_bytes(obj.read_bytes()[:100])  # truncated
    assert json.loads(succeeds("run-kernel", src, "--json").stdout)["eax"] == 7
    assert obj.with_name(obj.name + asm.DIGEST_SUFFIX).is_file()


def test_an_unwritable_cache_folder_is_one_line(write_kernel):
    src = write_kernel(OK, "k.S")
    line = fails("run-kernel", src, env={"RETROSIM_CACHE": "/proc/retrosim-none"})
    assert "RETROSIM_CACHE" in line and "/proc/retrosim-none" in line


def test_objects_of_kernels_rejected_for_size_leave_the_cache(write_kernel, tmp_path):
    src = write_kernel("    ret\n.data\n.space 13 << 20", "big.S", entry="f", text=False, tail="\n")
    line = fails("run-kernel", src)
    assert line.startswith(f"retrosim: error: {src}: code and data need")
    assert not list((tmp_path / "cache" / "asm").glob("*.o"))


# -- 3. messages are printed literally ----------------------------------------------------------
def test_square_brackets_survive_and_never_crash(write_kernel, tmp_path):
    folder = tmp_path / "br [bold]"
    folder.mkdir()
    src = write_kernel("    mov eax, dword ptr [ebx]\n    ret", "k.S", entry="f", text=False, tail="\n", folder=folder)
    line = fails("run-kernel", src)
    assert "dword ptr [ebx]" in line
    assert "[/]" in fails("run-kernel", src, "--entry", "[/]")
    assert "'[/]'" in fails("run-kernel", src, "--args", "[/]")
    assert "br [bold]/k.S" in line


# -- 4. bounded memory and no hangs -------------------------------------------------------------
def test_include_of_dev_zero_and_of_a_fifo(write_kernel, tmp_path):
    zero = write_kernel('.intel_syntax noprefix\n.include "/dev/zero"\n', "zero.S")
    line = one_error(cli("run-kernel", zero, timeout=60))
    assert f"{zero}:2:" in line and "/dev/zero" in line and "not a regular file" in line
    os.mkfifo(tmp_path / "pipe.inc")
    fifo = write_kernel('.intel_syntax noprefix\n.include "pipe.inc"\n', "fifo.S")
    assert "pipe.inc" in one_error(cli("run-kernel", fifo, timeout=30))  # never waits for a writer


def test_kernel_listing_skips_nothing_forever(tmp_path):
    folder = tmp_path / "kernels"
    folder.mkdir()
    (folder / "z.S").symlink_to("/dev/zero")
    line = one_error(cli("kernels", env={"RETROSIM_KERNELS": str(folder)}, timeout=60))
    assert "z.S" in line and "not a regular file" in line


def test_argument_buffers_are_checked_before_allocating(write_kernel):
    src = write_kernel(OK, "k.S")
    line = one_error(cli("run-kernel", src, "--args", "buf:u32:1000000000"))
    assert "does not fit in the workload arena" in line


def test_trace_memory_is_bounded_with_the_limit_named(write_kernel, tmp_path):
    src = write_kernel("1:  mov eax, [esp]\n    jmp 1b", "loop.S", entry="f", text=False, tail="\n")
    proc = cli("trace", src, "--budget", "0", "--out", tmp_path / "t.npz", env={"RETROSIM_TRACE_MB": "32"})
    line = one_error(proc)
    assert "RETROSIM_TRACE_MB=32" in line
    assert not (tmp_path / "t.npz").exists()
    line = one_error(cli("time", src, "--repeat", "1000000000", timeout=60))
    assert "--repeat" in line and "10,000" in line


def test_a_scene_too_big_for_host_memory_is_refused_by_validation(tmp_path):
    (tmp_path / "big.toml").write_text(
        '[scene]\nname = "big"\nwidth = 1024\nheight = 1024\n[geometry]\ngenerator = "random"\nseed = 1\n'
        'triangles = 2000\ndepth_complexity = 60.0\n[run]\nvariants = ["z32"]\ncpus = ["pentium2-233"]\n')
    line = one_error(cli("report", tmp_path / "big.toml", "--out", tmp_path / "out", timeout=120))
    assert "big.toml" in line and "geometry" in line and "RETROSIM_MAX_VISITS" in line
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


# -- 5. one line instead of a traceback ---------------------------------------------------------
@pytest.mark.parametrize("args, field", [
    ("buf:u32:-5", "COUNT"), ("buf:u8:10:-1", "FILL -1"), ("buf:u16:4:70000", "FILL 70000"),
    ("buf:u32:99999999999999999999", "arena"), ("1e40f", "out of range"), ("0x1FFFFFFFF", "32-bit"),
])
def test_bad_argument_values(write_kernel, args, field):
    src = write_kernel(OK, "k.S")
    line = fails("run-kernel", src, "--args", args)
    assert f"--args item 1 '{args}'" in line and field in line


@pytest.mark.parametrize("args, option", [
    (("bench", "--pixels", "0"), "--pixels"), (("bench", "--pixels", "-3"), "--pixels"),
    (("run-kernel", "k.S", "--budget", "-1"), "--budget -1: must be at least 0"),
    (("time", "k.S", "--repeat", "0"), "--repeat"),
])
def test_bad_option_values(write_kernel, args, option):
    write_kernel(OK, "k.S")
    assert option in fails(*args)


def test_binary_source_is_one_line(tmp_path):
    src = tmp_path / "bin.S"
    src.write_bytes(b".intel_syntax noprefix\n\xff\xfe\x00 mov eax, \xc3\xa9\x80\n")
    assert f"{src}:" in fails("run-kernel", src)
    echoed = tmp_path / "echo.S"  # the assembler echoes the bytes back in its message
    echoed.write_bytes(b'.intel_syntax noprefix\n.error "bad \xff\xfe here"\n')
    assert f"{echoed}:2: bad" in fails("run-kernel", echoed)


def test_damaged_baselines_file(tmp_path, monkeypatch):
    from sim.scenes import baseline

    path = tmp_path / "baselines.json"
    monkeypatch.setattr(baseline, "BASELINE_FILE", path)
    for content, expect in ((b'{"zbuffer-small": {', "not valid JSON"), (b"", "not valid JSON"),
                            (b"[1, 2]", "expected a JSON object"), (b'{"a": {"b": {"cycles": "x"}}}', "integer"),
                            (b"\xff\xfe{}", "not UTF-8")):
        path.write_bytes(content)
        line = fails("check", "zbuffer-small")
        assert str(path) in line and expect in line


# -- scenes ------------------------------------------------------------------------------------
SCENE = """[scene]
name = "{name}"
width = 32
height = 24
[geometry]
{geometry}
[run]
variants = ["z32"]
cpus = {cpus}
metrics = ["visibility", "depth_error"]
"""
RANDOM = 'generator = "random"\nseed = {seed}\ntriangles = 4\ndepth_complexity = 1.0'


def scene(folder: Path, name: str, geometry: str = RANDOM.format(seed=3), cpus='["pentium2-233"]') -> Path:
    path = folder / f"{name}.toml"
    path.write_text(SCENE.format(name=name, geometry=geometry, cpus=cpus))
    return path


def test_scene_field_errors(tmp_path):
    line = fails("report", scene(tmp_path, "neg", RANDOM.format(seed=-1)), "--out", tmp_path / "o")
    assert "neg.toml:" in line and "geometry.seed" in line
    twice = scene(tmp_path, "twice", cpus='["pentium2-233", "pentium2-233:edo"]')
    line = fails("report", twice, "--out", tmp_path / "o")
    assert "run.cpus[1]" in line and "repeats" in line
    huge = scene(tmp_path, "huge", 'generator = "triangles"\n[[geometry.triangle]]\n'
                 'xy = [[-1e300, 1], [1e300, 5], [9, 1e300]]\nz = [0.1, 0.2, 0.3]')
    line = fails("report", huge, "--out", tmp_path / "o")
    assert "geometry.triangle[0].xy" in line and "within" in line
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


@pytest.mark.parametrize("xy", ["[[1, 1], [5, 5], [9, 9]]", "[[-50, -50], [-40, -50], [-45, -40]]",
                                "[[3.1, 3.1], [3.2, 3.1], [3.1, 3.2]]"])
def test_scenes_that_draw_nothing_report_zero_covered_pixels(tmp_path, xy):
    from sim.scenes.registry import load_scene, run_scene

    path = scene(tmp_path, "empty", f'generator = "triangles"\n[[geometry.triangle]]\nxy = {xy}\nz = [0.1, 0.2, 0.3]')
    result = run_scene(load_scene(path))
    assert result.pixels == 0
    assert result.accuracy["z32"].visibility["covered"] == 0
    assert result.accuracy["z32"].depth_error["pixels"] == 0


def test_a_failing_scene_keeps_the_finished_ones(tmp_path):
    good = scene(tmp_path, "good")
    bad = scene(tmp_path, "bad", RANDOM.format(seed=-1))
    out = tmp_path / "out"
    old = os.umask(0o022)
    try:
        r = CliRunner().invoke(main, ["report", str(good), str(bad), "--out", str(out)])
    finally:
        os.umask(old)
    assert stat.S_IMODE((out / "good.md").stat().st_mode) == 0o644
    assert r.exit_code == 2 and isinstance(r.exception, SystemExit)
    assert (out / "good.md").is_file() and (out / "good.json").is_file()
    assert not list(out.glob("bad.*"))
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith("retrosim: error: 1 of 2 scene(s) failed") and "bad.toml" in last


# -- 8. smaller ones -----------------------------------------------------------------------------
def test_a_source_named_like_an_option(write_kernel):
    write_kernel(OK, "-k.S")
    assert json.loads(succeeds("run-kernel", "--json", "--", "-k.S").stdout)["eax"] == 7


def test_an_error_in_an_included_file_names_that_file(write_kernel, tmp_path):
    (tmp_path / "inc.inc").write_text("\n\n    bogus eax\n")
    src = write_kernel('.intel_syntax noprefix\n.include "inc.inc"\n.globl f\nf:\n    ret\n', "k.S")
    line = fails("run-kernel", src)
    assert "inc.inc:3:" in line and "bogus" in line


def test_errors_name_the_source_not_the_cache_object(write_kernel, tmp_path):
    empty = tmp_path / "empty.S"
    empty.write_text("")
    line = fails("run-kernel", empty)
    assert f"{empty}:" in line and "cache" not in line
    undef = write_kernel("    call g\n    ret", "undef.S", entry="f", text=False, tail="\n")
    line = fails("run-kernel", undef)
    assert f"{undef}:" in line and "'g'" in line and "cache" not in line
    huge = write_kernel("    ret\n.space 1 << 30", "huge.S", entry="f", text=False, tail="\n")
    line = one_error(cli("run-kernel", huge, env={"RETROSIM_CACHE": str(tmp_path / "cache")}))
    assert f"{huge}:" in line and "MB" in line and "cache" not in line
    assert not list((tmp_path / "cache" / "asm").glob("*.o")) and not list((tmp_path / "cache" / "asm").glob(".tmp*"))


def test_execute_and_software_interrupt_faults_name_the_right_thing(write_kernel):
    nx = write_kernel("    lea eax, [dat]\n    jmp eax\n.data\ndat: .byte 0x90", "nx.S", entry="f", text=False, tail="\n")
    line = fails("run-kernel", nx)
    assert "execution of non-executable memory" in line and "0x00401000" in line and "read" not in line
    i80 = write_kernel("    nop\n    int 0x80\n    ret", "i80.S", entry="f", text=False, tail="\n")
    line = fails("run-kernel", i80)
    assert "0x00400001 (f+0x1): int 0x80" in line


def test_sigterm_during_assembly_leaves_no_temporary_file(write_kernel, tmp_path):
    src = write_kernel(".rept 3000000\n    add eax, 1\n.endr\n    ret", "slow.S", entry="f", text=False, tail="\n")
    cache = tmp_path / "cache"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "NUMBA_NUM_THREADS": "1", "RETROSIM_CACHE": str(cache)}
    proc = subprocess.Popen([sys.executable, "-m", "sim.cli", "run-kernel", str(src)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 30
    while not list((cache / "asm").glob(".tmp-*")) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.01)
    time.sleep(0.3)  # well inside the assembler's run (it takes seconds)
    assert proc.poll() is None, "the assembler finished before the test could interrupt it"
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 128 + signal.SIGTERM, (out, err)
    assert not list((cache / "asm").iterdir())


def test_includes_are_hashed_with_a_size_limit_and_incbin_counts(write_kernel, tmp_path):
    sparse = tmp_path / "big.inc"
    with open(sparse, "wb") as f:
        f.truncate(1 << 30)  # 1 GB, sparse: reading it whole is what must not happen
    src = write_kernel('.intel_syntax noprefix\n# a comment\n.include "big.inc"\n', "k.S")
    line = one_error(cli("run-kernel", src))
    assert f"{src}:3:" in line and "big.inc" in line and "MB" in line
    src = write_kernel('.intel_syntax noprefix\n.globl f\nf:\n    mov eax, [d]\n    ret\n'
                 '.data\nd: .incbin "d.bin"\n', "bin.S", entry="f", text=False, tail="\n")
    (tmp_path / "d.bin").write_bytes(bytes([1, 0, 0, 0]))
    assert json.loads(succeeds("run-kernel", src, "--json").stdout)["eax"] == 1
    (tmp_path / "d.bin").write_bytes(bytes([2, 0, 0, 0]))  # the object depends on it: not served stale
    assert json.loads(succeeds("run-kernel", src, "--json").stdout)["eax"] == 2
    (tmp_path / "d.bin").unlink()
    (tmp_path / "d.bin").symlink_to("/dev/zero")
    assert "not a regular file" in one_error(cli("run-kernel", src, env={"RETROSIM_CACHE": str(tmp_path / "cache")}))


def test_sigterm_during_a_trace_save_leaves_no_temporary_file(write_kernel, tmp_path):
    # ~8 M instructions: saving (compressing) the trace takes a good fraction of a second
    src = write_kernel("    mov ecx, 2000000\n1:  mov eax, [esp]\n    dec ecx\n    jnz 1b\n    ret", "loop.S", entry="f", text=False, tail="\n")
    out = tmp_path / "out"
    out.mkdir()
    env = {**os.environ, "PYTHONPATH": str(ROOT), "NUMBA_NUM_THREADS": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "sim.cli", "trace", str(src), "--out", str(out / "t.npz")],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 60
    while not list(out.glob(".t.npz*")) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.005)
    assert proc.poll() is None, "the trace was saved before the test could interrupt it"
    proc.send_signal(signal.SIGTERM)
    out_text, err = proc.communicate(timeout=30)
    assert proc.returncode == 128 + signal.SIGTERM, (out_text, err)
    assert not list(out.iterdir())


def test_a_scene_name_with_markup_is_shown_literally(tmp_path):
    path = scene(tmp_path, "x[bold]y")
    r = succeeds("report", path, "--out", tmp_path / "out")
    assert "x[bold]y" in r.stdout and (tmp_path / "out" / "x[bold]y.md").is_file()


def test_timing_memory_is_bounded_with_the_limit_named(write_kernel):
    src = write_kernel("    mov ecx, 200000\n1:  dec ecx\n    jnz 1b\n    ret", "cnt.S", entry="f", text=False, tail="\n")
    # explain picks its timeline from the whole trace, so the model holds it all
    line = fails("explain", src, env={"RETROSIM_MODEL_MB": "10"})  # 2 x 400,002 instructions x 90 bytes > 10 MB
    assert "RETROSIM_MODEL_MB=10" in line and "800,004 instructions" in line  # 2 calls (--repeat 2)
    # time streams the trace through the model (sim/timing/stream.py): nothing grows with its length
    r = cli("time", src, "--json", env={"RETROSIM_MODEL_MB": "10"})
    assert r.returncode == 0, r.stderr[-2000:]


def test_scene_files_that_are_not_text_files(tmp_path):
    (tmp_path / "z.toml").symlink_to("/dev/zero")
    assert "z.toml: not a regular file" in fails("report", tmp_path / "z.toml", "--out", tmp_path / "o")
    with open(tmp_path / "big.toml", "wb") as f:
        f.truncate(1 << 30)
    assert "big.toml: 1,073,741,824 bytes" in one_error(cli("report", tmp_path / "big.toml", "--out", tmp_path / "o"))
