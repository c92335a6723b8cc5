"""Per-CPU instruction sets: kernels assemble for the chosen CPU, what a CPU lacks is refused with
one line naming the line, instruction and CPU, system instructions get an error of their own."""

import subprocess
import sys

import pytest

from sim.asm import assemble
from sim.cpus import presets
from sim.errors import RetrosimError
from sim.isa import EXTENSIONS, march
from sim.timing import emulate, time_emulation, time_kernel
from conftest import KERNELS

PRESETS = presets.available()
HEAD = ".intel_syntax noprefix\n.text\n.globl k\nk:\n"


def kernel(tmp_path, body: str, name="k.S"):
    src = tmp_path / name
    src.write_text(HEAD + body + "    ret\n")
    return src


@pytest.mark.parametrize("cpu", PRESETS)
def test_every_preset_declares_its_instruction_set(cpu):
    p = presets.load(cpu)
    assert set(p.raw["isa_extensions"]) <= set(EXTENSIONS)
    assert march(p, "gnu") and march(p, "zig")


@pytest.mark.parametrize("cpu", PRESETS)
def test_shipped_kernels_are_plain_i686_and_assemble_for_every_preset(cpu):
    for src in sorted(KERNELS.rglob("*.S")):
        assert assemble(src, "gnu", cpu).is_file()


def test_the_cache_key_includes_the_cpu(tmp_path):
    src = kernel(tmp_path, "    nop\n")
    assert assemble(src, "gnu", "k6-233") != assemble(src, "gnu", "pentium3-500") != assemble(src, "gnu")


# (preset, instruction, what the message must say) -- the CPUID feature bits of each CPU
# (InstLatX64 dumps named by each preset's isa_source)
REFUSED = [
    ("k6-2-300", "cmove eax, ecx", "cmove is not available on k6-2-300 (the K6 family has no CMOV)"),
    ("k6-233", "fcmovb st, st(1)", "fcmovb is not available on k6-233 (the K6 family has no FCMOV/FCOMI)"),
    ("k6-3-450", "fcomi st, st(1)", "fcomi is not available on k6-3-450 (the K6 family has no FCMOV/FCOMI)"),
    ("pentium2-233", "addps xmm0, xmm1", "addps is not available on pentium2-233 (pentium2-233 has no SSE)"),
    ("pentium-pro-200", "paddw mm0, mm1", "paddw is not available on pentium-pro-200 (pentium-pro-200 has no MMX)"),
    ("pentium3-500", "pfadd mm0, mm1", "pfadd is not available on pentium3-500 (the P6 family has no 3DNow!)"),
    ("k6-233", "pfadd mm0, mm1", "pfadd is not available on k6-233 (k6-233 has no 3DNow!)"),
    ("k6-2-300", "pshufw mm0, mm1, 3", "pshufw is not available on k6-2-300 (the K6 family has no SSE)"),
]


@pytest.mark.parametrize("cpu,insn,message", REFUSED)
def test_what_the_cpu_lacks_is_refused_with_its_line(tmp_path, cpu, insn, message):
    src = kernel(tmp_path, f"    nop\n    {insn}\n")
    with pytest.raises(RetrosimError) as e:
        time_kernel(src, "k", cpu=cpu, repeat=1)
    assert str(e.value) == f"{src}:6: {message}"


def test_refusal_of_an_executed_encoding_the_assembler_cannot_see(tmp_path):
    # CMOVE EAX,ECX as bytes: assembles anywhere, refused when it executes on a K6
    src = kernel(tmp_path, "    .byte 0x0f, 0x44, 0xc1\n")
    emu = emulate(src, "k", repeat=1)  # plain i686, like a scene's kernels
    time_emulation(emu, "pentium2-233")
    with pytest.raises(RetrosimError, match=r"pc 0x0040000\d \(k\+0x0\): cmove is not available on k6-233 "
                                            r"\(the K6 family has no CMOV\)"):
        time_emulation(emu, "k6-233")


@pytest.mark.parametrize("insn", ["cli", "sti", "hlt", "in al, dx", "out dx, al", "lgdt [esp]", "wbinvd",
                                  "invd", "mov cr0, eax", "sysenter"])
def test_system_instructions_get_their_own_error(tmp_path, insn):
    src = kernel(tmp_path, f"    {insn}\n")
    with pytest.raises(RetrosimError, match=r"k\+0x0\): .* is a privileged or system instruction"):
        time_kernel(src, "k", cpu="pentium2-233", repeat=1)


@pytest.mark.parametrize("insn", ["int 0x80", "rdpmc"])
def test_traps_stop_the_emulation_with_a_guest_fault(tmp_path, insn):
    src = kernel(tmp_path, f"    {insn}\n")
    with pytest.raises(RetrosimError, match="guest fault at 0x004000"):
        time_kernel(src, "k", cpu="pentium2-233", repeat=1)


def test_cli_refusal_is_one_line_exit_2(tmp_path):
    src = kernel(tmp_path, "    cmove eax, ecx\n")
    out = subprocess.run([sys.executable, "-m", "sim.cli", "time", str(src), "--cpu", "k6-2-300"],
                         capture_output=True, text=True)
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == [
        f"retrosim: error: {src}:5: cmove is not available on k6-2-300 (the K6 family has no CMOV)"]


def test_mmx_assembles_for_a_cpu_that_has_it(tmp_path):
    # issue 8: with -march=i686 `movd mm0, eax` took mm0 for a symbol
    src = kernel(tmp_path, "    movd mm0, eax\n    paddd mm0, mm0\n    movd eax, mm0\n    emms\n")
    r = time_kernel(src, "k", cpu="pentium2-233", repeat=1)
    assert r.last["instructions"] == 5
