"""Per-CPU instruction sets: kernels assemble for the chosen CPU, what a CPU lacks is refused with
one line naming the line, instruction and CPU, system instructions get an error of their own."""

import re
import subprocess
import sys

import pytest

from sim.guest.asm import assemble
from sim.cpus import presets
from sim.errors import RetrosimError
from sim.guest.isa import EXTENSIONS
from sim.timing.kernel import emulate, guest_cpu, time_emulation, time_kernel
from conftest import KERNELS

PRESETS = presets.available()
HEAD = ".intel_syntax noprefix\n.text\n.globl k\nk:\n"


@pytest.mark.parametrize("cpu", PRESETS)
def test_every_preset_declares_its_instruction_set(cpu):
    p = presets.load(cpu)
    assert set(p.raw["isa_extensions"]) <= set(EXTENSIONS)
    target = guest_cpu(cpu)
    assert target.march("gnu") and target.march("zig")


@pytest.mark.parametrize("cpu", PRESETS)
def test_shipped_kernels_are_plain_i686_and_assemble_for_every_preset(cpu):
    """Every shipped kernel assembles for every preset, except a micro-benchmark that declares
    `# @requires EXT` for an extension the CPU lacks: that one is refused, naming the CPU."""
    have = set(presets.load(cpu).raw["isa_extensions"])
    for src in sorted(KERNELS.rglob("*.S")):
        needs = set(re.findall(r"^# @requires (\w+)", src.read_text(), re.M))
        if needs <= have:
            assert assemble(src, "gnu", guest_cpu(cpu)).is_file()
        else:
            with pytest.raises(RetrosimError, match=f"not available on {cpu}"):
                assemble(src, "gnu", guest_cpu(cpu))
    article = [p for folder in ("zbuffer", "convert", "texture") for p in (KERNELS / folder).glob("*.S")]
    assert article and not any("@requires" in p.read_text() for p in article)  # the article kernels stay i686


def test_the_cache_key_includes_the_cpu(write_kernel):
    src = write_kernel("    nop\n", entry="k", tail="    ret\n")
    assert assemble(src, "gnu", guest_cpu("k6-233")) != assemble(src, "gnu", guest_cpu("pentium3-500")) != assemble(src, "gnu")


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
def test_what_the_cpu_lacks_is_refused_with_its_line(write_kernel, cpu, insn, message):
    src = write_kernel(f"    nop\n    {insn}\n", entry="k", tail="    ret\n")
    with pytest.raises(RetrosimError) as e:
        time_kernel(src, "k", cpu=cpu, repeat=1)
    assert str(e.value) == f"{src}:6: {message}"


def test_refusal_of_an_executed_encoding_the_assembler_cannot_see(write_kernel):
    # CMOVE EAX,ECX as bytes: assembles anywhere, refused when it executes on a K6
    src = write_kernel("    .byte 0x0f, 0x44, 0xc1\n", entry="k", tail="    ret\n")
    emu = emulate(src, "k", repeat=1)  # plain i686, like a scene's kernels
    time_emulation(emu, "pentium2-233")
    with pytest.raises(RetrosimError, match=r"pc 0x0040000\d \(k\+0x0\): cmove is not available on k6-233 "
                                            r"\(the K6 family has no CMOV\)"):
        time_emulation(emu, "k6-233")


@pytest.mark.parametrize("insn", ["cli", "sti", "hlt", "in al, dx", "out dx, al", "lgdt [esp]", "wbinvd",
                                  "invd", "mov cr0, eax", "sysenter"])
def test_system_instructions_get_their_own_error(write_kernel, insn):
    src = write_kernel(f"    {insn}\n", entry="k", tail="    ret\n")
    with pytest.raises(RetrosimError, match=r"k\+0x0\): .* is a privileged or system instruction"):
        time_kernel(src, "k", cpu="pentium2-233", repeat=1)


@pytest.mark.parametrize("insn", ["int 0x80", "rdpmc"])
def test_traps_stop_the_emulation_with_a_guest_fault(write_kernel, insn):
    src = write_kernel(f"    {insn}\n", entry="k", tail="    ret\n")
    with pytest.raises(RetrosimError, match="guest fault at 0x004000"):
        time_kernel(src, "k", cpu="pentium2-233", repeat=1)


def test_cli_refusal_is_one_line_exit_2(write_kernel):
    src = write_kernel("    cmove eax, ecx\n", entry="k", tail="    ret\n")
    out = subprocess.run([sys.executable, "-m", "sim.cli", "time", str(src), "--cpu", "k6-2-300"],
                         capture_output=True, text=True)
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == [
        f"retrosim: error: {src}:5: cmove is not available on k6-2-300 (the K6 family has no CMOV)"]


def test_mmx_assembles_for_a_cpu_that_has_it(write_kernel):
    # issue 8: with -march=i686 `movd mm0, eax` took mm0 for a symbol
    src = write_kernel("    movd mm0, eax\n    paddd mm0, mm0\n    movd eax, mm0\n    emms\n", entry="k", tail="    ret\n")
    r = time_kernel(src, "k", cpu="pentium2-233", repeat=1)
    assert r.last["instructions"] == 5


# -- every form of each extension the CPU has (register forms; GNU as names them for the CPU) -------
MMX = ("packssdw packsswb packuswb paddb paddw paddd paddsb paddsw paddusb paddusw pand pandn pcmpeqb pcmpeqw "
       "pcmpeqd pcmpgtb pcmpgtw pcmpgtd pmaddwd pmulhw pmullw por psllw pslld psllq psraw psrad psrlw psrld psrlq "
       "psubb psubw psubd psubsb psubsw psubusb psubusw punpckhbw punpckhwd punpckhdq punpcklbw punpcklwd "
       "punpckldq pxor movq").split()
MMX_EXTRA = ["movd mm0, eax", "movd eax, mm1", "psllq mm0, 3", "psrlq mm1, 2", "psraw mm2, 1", "emms"]
SSE = ("addps addss subps subss mulps mulss divps divss maxps maxss minps minss sqrtps sqrtss rcpps rcpss rsqrtps "
       "rsqrtss andps andnps orps xorps unpcklps unpckhps movaps movups movss movhlps comiss ucomiss").split()
SSE_EXTRA = ["pavgb mm0, mm1", "pavgw mm0, mm1", "pmaxsw mm0, mm1", "pmaxub mm0, mm1", "pminsw mm0, mm1",
             "pminub mm0, mm1", "pmulhuw mm0, mm1", "psadbw mm0, mm1", "pshufw mm0, mm1, 3", "pmovmskb eax, mm1",
             "shufps xmm0, xmm1, 3", "cmpps xmm0, xmm1, 1", "cmpss xmm0, xmm1, 1", "cvtpi2ps xmm0, mm1",
             "cvtps2pi mm0, xmm1", "cvttps2pi mm0, xmm1", "movmskps eax, xmm1", "sfence", "emms"]
NOW3 = ("pfadd pfsub pfsubr pfmul pfacc pfcmpeq pfcmpge pfcmpgt pfmax pfmin pfrcp pfrcpit1 pfrcpit2 pfrsqrt "
        "pfrsqit1 pf2id pi2fd pavgusb pmulhrw").split()


def extension_kernel(exts) -> str:
    lines = []
    if "mmx" in exts:  # register and memory-source forms ([esp]: the stack is mapped and 8-aligned enough)
        lines += [f"{m} mm0, mm1" for m in MMX] + [f"{m} mm0, [esp]" for m in MMX] + MMX_EXTRA
    if "sse" in exts:
        lines += [f"{m} xmm0, xmm1" for m in SSE] + SSE_EXTRA
    if "3dnow" in exts:
        lines += [f"{m} mm0, mm1" for m in NOW3] + [f"{m} mm0, [esp]" for m in NOW3] + ["femms"]
    return "".join(f"    {l}\n" for l in lines)


@pytest.mark.parametrize("cpu", PRESETS)
def test_every_extension_form_times_on_the_cpu_that_has_it(write_kernel, cpu):
    exts = set(presets.load(cpu).raw["isa_extensions"])
    body = extension_kernel(exts)
    if not body:
        pytest.skip(f"{cpu} has no SIMD extension")
    r = time_kernel(write_kernel(body, entry="k", tail="    ret\n"), "k", cpu=cpu, repeat=1)
    assert r.last["instructions"] == body.count("\n") + 1


# -- costs that follow the values ---------------------------------------------------------------------
REP = HEAD.replace("k:\n", "k:\n    push edi\n    mov edi, [esp+8]\n    mov ecx, [esp+12]\n    xor eax, eax\n") + \
    "    rep stosd\n    pop edi\n    ret\n"


@pytest.mark.parametrize("cpu", ["pentium2-233", "k6-2-300"])
def test_rep_cost_follows_ecx(tmp_path, cpu):
    # InstLatX64 measures REP STOSD as a bandwidth: a fixed cost per element (the table's rep stosd row)
    import numpy as np

    src = tmp_path / "rep.S"
    src.write_text(REP)
    cyc = [time_kernel(src, "k", lambda m, n=n: [m.arena.put(np.zeros(n, np.uint32)), n], cpu=cpu,
                       repeat=2).last["cycles"] for n in (1000, 2000, 3000)]
    per_element = (cyc[1] - cyc[0]) / 1000
    assert per_element >= 0.5  # at most two stores per clock on either family
    assert abs((cyc[2] - cyc[1]) - (cyc[1] - cyc[0])) <= 10  # linear in ECX


def test_div_cost_follows_the_operand_size(write_kernel):
    # InstLatX64 Deschutes: DIV r8 ~19, r16 23, r32 39 clocks (p6.toml div rows)
    cyc = {}
    for reg, clear in (("cl", "mov ah, 0"), ("cx", "xor edx, edx"), ("ecx", "xor edx, edx")):
        body = "    mov ecx, 3\n    xor edx, edx\n    mov eax, 100\n" + f"    div {reg}\n    {clear}\n" * 20
        cyc[reg] = time_kernel(write_kernel(body, f"div_{reg}.S", entry="k", tail="    ret\n"), "k", cpu="pentium2-233", repeat=2).last["cycles"]
    assert cyc["cl"] < cyc["cx"] < cyc["ecx"]
    assert (cyc["ecx"] - cyc["cx"]) / 20 == pytest.approx(39 - 23, abs=2)


def test_refusal_names_the_line_with_the_zig_assembler_too(write_kernel):
    # clang assembles CMOV for -mcpu=k6_2 without complaint; the refusal still names the line
    from sim.guest.asm import available_assemblers

    if "zig" not in available_assemblers():
        pytest.skip("zig assembler not installed")
    src = write_kernel("    cmove eax, ecx\n", entry="k", tail="    ret\n")
    with pytest.raises(RetrosimError, match=r"k\.S:5: cmove is not available on k6-2-300"):
        time_kernel(src, "k", cpu="k6-2-300", repeat=1, assembler="zig")
