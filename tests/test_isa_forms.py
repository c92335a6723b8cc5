"""Issue 8: every user-mode instruction form GNU as accepts for a CPU times on that CPU's model.

The forms are tests/isa_forms.py (base IA-32 set and x87, every operand kind and size). For each of
the presets the issue names, each form GNU as accepts with the preset's -march either has a row in
its family's table, or is refused because the CPU lacks its extension, or is a system instruction;
then one generated kernel holding every non-branching form is emulated and timed through the full
model, so "times without error" is shown end to end, not only by a table lookup.
"""

from __future__ import annotations

import re
import shutil
import subprocess

import numpy as np
import pytest
from elftools.elf.elffile import ELFFile

from isa_forms import forms
from sim.guest import isa
from sim.guest.cpu import GuestCpu
from sim.cpus import presets
from sim.cpus.table import load_table
from sim.guest.decode import iter_decode
from sim.errors import RetrosimError
from sim.timing.kernel import emulate, time_emulation

AS = shutil.which("as")
# the P5 presets: a Pentium (P54C, -march=pentium) and a Pentium MMX (P55C, -march=pentium+mmx)
PRESETS = ["pentium-90", "pentium-mmx-233", "pentium-pro-200", "pentium2-233", "pentium3-500", "k6-233", "k6-2-300"]
# at most this many instructions complete per clock: two (U and V pipes) on the P5, three on the P6 (uops) and K6
WIDTH = {"p5": 2, "p6": 3, "k6": 3}

# Loading DS or SS (MOV sreg / POP sreg) is a system instruction here (sim/guest/isa.py), on every preset.
SYSTEM = {"pop es", "pop ds", "pop fs", "pop gs", "mov ds, cx", "mov ds, word ptr [esi]"}
# GNU as accepts FXSAVE/FXRSTOR for -march=pentiumpro and pentiumii, but CPUID.01H:EDX.FXSR is clear on
# the Pentium Pro and the Pentium II model 3 (sim/guest/isa.py): the model refuses them there.
REFUSED = {"pentium-pro-200": {"fxsave [esi]", "fxrstor [esi]"}, "pentium2-233": {"fxsave [esi]", "fxrstor [esi]"}}


def assemble_each(lines: list[str], march: str | None, tmp_path) -> dict[str, list]:
    """{line: [InsnRecord, ...]} for the lines GNU as accepts with `march` (None: no -march, every
    extension); a rejected line is dropped and the rest assembled again."""
    lines = list(lines)
    for _ in range(6):
        src = ".intel_syntax noprefix\n.text\n" + "".join(f"L{i}:\n{line}\n1:\n" for i, line in enumerate(lines))
        src += f"L{len(lines)}:\n"
        (tmp_path / "f.S").write_text(src)
        cmd = [AS, "--32", *([f"-march={march}"] if march else []), "-o", str(tmp_path / "f.o"), str(tmp_path / "f.S")]
        out = subprocess.run(cmd, capture_output=True, text=True)
        if out.returncode == 0:
            break
        bad = {(int(n) - 4) // 3 for n in re.findall(r"f\.S:(\d+): Error", out.stderr)}
        assert bad, out.stderr
        lines = [line for i, line in enumerate(lines) if i not in bad]
    else:
        pytest.fail(f"GNU as kept rejecting lines for -march={march}")
    with open(tmp_path / "f.o", "rb") as f:
        elf = ELFFile(f)
        text = elf.get_section_by_name(".text").data()
        symbols = list(elf.get_section_by_name(".symtab").iter_symbols())
    at = {s.name: s["st_value"] for s in symbols}
    # a register name GNU as does not know for this CPU becomes an undefined symbol (-march=pentiumpro:
    # 'movd mm0, eax' is MOV [mm0], EAX): such a line is not the form it names, so it counts as refused
    undefined = {s.name for s in symbols if s.name and s["st_shndx"] == "SHN_UNDEF"}
    offs = [at[f"L{i}"] for i in range(len(lines) + 1)]
    return {line: list(iter_decode(text[offs[i]:offs[i + 1]], 0x400000 + offs[i])) for i, line in enumerate(lines)
            if not undefined & set(re.findall(r"\w+", line))}


def classify(records, preset, table) -> str:
    """'row' | 'refused' | 'system' | 'missing: ...' for the records of one form."""
    kinds = set()
    for rec in records:
        if isa.is_system(rec):
            kinds.add("system")
            continue
        try:
            isa.check_record(rec, GuestCpu.from_preset(preset), "form")
        except isa.IsaError:
            kinds.add("refused")
            continue
        mnemonic = f"{rec.rep} {rec.mnemonic}" if rec.rep else rec.mnemonic
        kinds.add("row" if table.lookup(mnemonic, rec.signature) else f"missing: {mnemonic} {rec.signature}")
    assert len(kinds) == 1, kinds
    return kinds.pop()


@pytest.fixture(scope="module")
def assembled(tmp_path_factory):
    if AS is None:
        pytest.skip("GNU binutils (as) not available")
    cache = {}

    def get(cpu):
        """The forms GNU as accepts for the preset `cpu` (None: with no -march, every extension)."""
        if cpu not in cache:
            march = GuestCpu.from_preset(presets.load(cpu)).march("gnu") if cpu else None
            cache[cpu] = assemble_each(forms(), march, tmp_path_factory.mktemp(cpu or "all"))
        return cache[cpu]

    return get


@pytest.mark.parametrize("cpu", PRESETS)
def test_every_form_gnu_as_accepts_has_a_row_or_is_refused(assembled, cpu):
    preset = presets.load(cpu)
    table = load_table(preset.family)
    accepted = assembled(cpu)
    assert len(accepted) > 700  # the list is the whole base set and x87: most of it assembles everywhere
    kinds = {line: classify(recs, preset, table) for line, recs in accepted.items()}
    assert [f"{line} -> {k}" for line, k in kinds.items() if k.startswith("missing")] == []
    assert {line for line, k in kinds.items() if k == "system"} == SYSTEM
    assert {line for line, k in kinds.items() if k == "refused"} == REFUSED.get(cpu, set())


# No source says what a K6 or a Pentium does with DF C0+i (FFREEP, which AMD documents from the Athlon
# on and Intel leaves undocumented): it is neither timed nor refused there; GNU as refuses it for
# -march=k6, k6_2, pentium and pentium+mmx.
UNKNOWN_ON = {cpu: {"ffreep st(1)"} for cpu in ("k6-233", "k6-2-300", "pentium-90", "pentium-mmx-233")}


@pytest.mark.parametrize("cpu", PRESETS)
def test_what_gnu_as_refuses_for_the_cpu_is_refused_when_its_bytes_run(assembled, cpu):
    # the bytes of a form assembled with no -march (every extension), executed on a CPU without it
    preset = presets.load(cpu)
    table = load_table(preset.family)
    accepted = assembled(cpu)
    lacking = {line: recs for line, recs in assembled(None).items() if line not in accepted}
    assert lacking  # every one of these CPUs lacks something GNU as knows (SSE2's MOVNTI at least)
    kinds = {line: classify(recs, preset, table) for line, recs in lacking.items()}
    assert {line for line, k in kinds.items() if k != "refused"} == UNKNOWN_ON.get(cpu, set())


def test_the_probe_sees_both_shift_operand_roles(assembled):
    # a shift whose destination is CL must find the r8 rows (it once asked for 'rol cl,1')
    accepted = assembled("pentium2-233")
    assert [r.signature for r in accepted["rol cl, 1"]] == ["r8,1"]
    assert [r.signature for r in accepted["shl cl, cl"]] == ["r8,cl"]
    assert [(r.rep, r.mnemonic) for r in accepted["repe scasb"]] == [("repe", "scasb")]
    assert [(r.rep, r.mnemonic) for r in accepted["repne cmpsd"]] == [("repne", "cmpsd")]


# -- end to end: one kernel holding every non-branching form, per preset ---------------------------------

# Before every form: a known machine state, so each form runs with valid operands (ESI and EBX point
# into the buffer, EDI 512 bytes further, a small ECX for REP, EDX:EAX = 100 so DIV/IDIV by CL, CX, ECX
# (3) or by the buffer (0x03030303...) cannot overflow, EBP a stack frame for ENTER/LEAVE, an empty
# x87 stack with every exception masked).
RESET = """    mov esp, dword ptr [saved_esp]
    mov esi, dword ptr [buffer]
    mov ebx, esi
    lea edi, [esi+512]
    lea ebp, [esp-256]
    mov eax, 100
    xor edx, edx
    mov ecx, 3
    fninit
"""
# Forms that need their operands prepared as well (only these touch the buffer before the form).
FILL = "    mov dword ptr [esi], 0x03030303\n    mov dword ptr [esi+4], 0x03030303\n"
PREPARE = {
    **{f"{op} {m}": FILL for op in ("div", "idiv") for m in ("byte ptr [esi]", "word ptr [esi]", "dword ptr [esi]")},
    "bound ecx, qword ptr [esi]": FILL + "    mov ecx, 0x03030303\n",
    "bound cx, dword ptr [esi]": FILL + "    mov ecx, 0x03030303\n",
    "fldcw word ptr [esi]": "    mov word ptr [esi], 0x037F\n",          # the FNINIT control word
    "ldmxcsr dword ptr [esi]": "    mov dword ptr [esi], 0x1F80\n",      # the reset MXCSR
    "fldenv [esi]": "    fnstenv [esi]\n",
    "frstor [esi]": "    fnsave [esi]\n",
    "fxrstor [esi]": "    fxsave [esi]\n",
    "popfd": "    pushfd\n", "popfw": "    pushfw\n", "popad": "    pushad\n", "popaw": "    pushaw\n",
}
# Forms the emulator cannot run although the CPU can: Unicorn's flat protected mode has null segment
# selectors, and loading a segment register (LDS, LES, LFS, LGS, LSS) breaks its stack addressing
# (measured: a later PUSH or ENTER faults at 0xffxx, ESP cut to 16 bits). Their rows are checked by
# the lookup test above.
NOT_EMULATED = re.compile(r"^l[defgs]s ")


def end_to_end_kernel(lines: list[str]) -> str:
    body = []
    for line in lines:
        body.append(RESET + PREPARE.get(line, "") + "    " + line.replace("ds:[0x1000]", "ds:[scratch]") + "\n")
    return (".intel_syntax noprefix\n.text\n.globl k\nk:\n    push ebx\n    push esi\n    push edi\n    push ebp\n"
            "    mov dword ptr [saved_esp], esp\n    mov eax, dword ptr [esp+20]\n    add eax, 1024\n"
            "    mov dword ptr [buffer], eax\n" + "".join(body) +
            "    mov esp, dword ptr [saved_esp]\n    fninit\n    cld\n    pop ebp\n    pop edi\n    pop esi\n"
            "    pop ebx\n    ret\n.bss\n.p2align 4\nsaved_esp: .long 0\nbuffer: .long 0\nscratch: .long 0\n")


@pytest.mark.parametrize("cpu", PRESETS)
def test_one_kernel_with_every_non_branching_form_times_end_to_end(assembled, tmp_path, cpu):
    preset = presets.load(cpu)
    table = load_table(preset.family)
    accepted = assembled(cpu)
    lines = [line for line, recs in accepted.items()
             if classify(recs, preset, table) == "row" and not any(r.is_branch for r in recs)
             and not NOT_EMULATED.match(line)]
    assert len(lines) > 650
    src = tmp_path / "forms.S"
    src.write_text(end_to_end_kernel(lines))
    emu = emulate(src, "k", lambda m: [m.arena.put(np.full(4096, 3, np.uint8))], repeat=1, isa_cpu=cpu)
    result = time_emulation(emu, cpu)
    assert result.last["cycles"] > result.last["instructions"] / WIDTH[preset.family]
    # every form was executed and timed: its decoded records are among the run's instructions
    executed, _ = emu.decoder().decode_trace(emu.trace.pc)
    ran = {(r.rep, r.mnemonic, r.signature) for r in executed}
    expected = {(r.rep, r.mnemonic, r.signature) for line in lines for r in accepted[line]}
    assert expected - ran == set()


def test_a_form_the_cpu_lacks_stops_the_end_to_end_kernel(tmp_path):
    # the same harness with FXSAVE on a Pentium II model 3 (no FXSR): refused, naming the CPU
    src = tmp_path / "fx.S"
    src.write_text(end_to_end_kernel(["fxsave [esi]"]))
    emu = emulate(src, "k", lambda m: [m.arena.put(np.full(4096, 3, np.uint8))], repeat=1)
    time_emulation(emu, "pentium3-500")
    with pytest.raises(RetrosimError, match=r"fxsave is not available on pentium2-233 \(pentium2-233 has no "
                                            r"FXSAVE/FXRSTOR"):
        time_emulation(emu, "pentium2-233")
