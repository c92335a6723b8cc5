"""AT&T syntax wherever a source is taken, and source-handling fixes (empty files, whole operands)."""

import numpy as np
import pytest
from click.testing import CliRunner

from sim.guest import asm
from sim.timing import loop
from sim.guest import loop_body
from sim.cli import main
from sim.cpus import presets
from sim.timing.kernel import time_kernel

INTEL_KERNEL = """# @entry sum(p, n) -> EAX
.text
.globl sum
sum:
    push esi
    mov esi, [esp+8]
    mov ecx, [esp+12]
    xor eax, eax
1:  add eax, dword ptr [esi]
    add esi, 4
    dec ecx
    jnz 1b
    pop esi
    ret
"""

ATT_KERNEL = """# @entry sum(p, n) -> EAX
.text
.globl sum
sum:
    pushl %esi
    movl 8(%esp), %esi
    movl 12(%esp), %ecx
    xorl %eax, %eax
1:  addl (%esi), %eax
    addl $4, %esi
    decl %ecx
    jnz 1b
    popl %esi
    ret
"""

# gcc -S output for `for (i = 0; i != n; i++) s += a[i];` and the same loop in Intel syntax
ATT_LOOP = ".L3:\n\tmovl\t(%esi,%eax,4), %edx\n\taddl\t%edx, %ecx\n\taddl\t$1, %eax\n\tcmpl\t%ebx, %eax\n\tjne\t.L3\n"
INTEL_LOOP = ".L3:\n\tmov\tedx, DWORD PTR [esi+eax*4]\n\tadd\tecx, edx\n\tadd\teax, 1\n\tcmp\teax, ebx\n\tjne\t.L3\n"


@pytest.mark.parametrize("text, expected", [
    (b"movl (%esi), %eax\n", "att"),
    (b"mov eax, [esi]\n", "intel"),
    (b"mov eax, 1\n", "intel"),
    (b"add eax, dword ptr [esi]\n", "intel"),
    (b".intel_syntax noprefix\nmov eax, 1\n", None),   # the file's own directive decides
    (b".att_syntax\nmovl %eax, %ebx\n", None),
    (b"nop\n", None),                                   # nothing to go by
])
def test_detect_syntax(text, expected):
    assert asm.detect_syntax(text) == expected


def test_same_loop_in_either_syntax_gives_identical_cycles():
    att = loop.time_body(ATT_LOOP, presets.available(), iterations=40)
    intel = loop.time_body(INTEL_LOOP, presets.available(), iterations=40)
    assert [r.per_iteration for r in att] == [r.per_iteration for r in intel]
    assert loop_body.parse_body(ATT_LOOP).syntax == "att" and loop_body.parse_body(INTEL_LOOP).syntax == "intel"


def test_same_kernel_in_either_syntax_gives_identical_cycles(tmp_path):
    paths = []
    for name, text in (("intel.S", INTEL_KERNEL), ("att.S", ATT_KERNEL)):
        (tmp_path / name).write_text(text)
        paths.append(tmp_path / name)
    for cpu in ("pentium2-233", "k6-233"):
        a, b = (time_kernel(p, "sum", setup=lambda m: [m.arena.put(np.ones(64, np.uint32)), 64], cpu=cpu)
                for p in paths)
        assert a.last == b.last


def test_explicit_syntax_option_for_kernels(tmp_path):
    # detection reads `mov eax, 7` as Intel; an explicit --syntax reaches the assembler of run-kernel
    src = tmp_path / "k.S"
    src.write_text("# @entry f() -> EAX\n.text\n.globl f\nf:\n    mov eax, 7\n    ret\n")
    for syntax in (None, "intel"):
        args = ["run-kernel", str(src), "--json"] + (["--syntax", syntax] if syntax else [])
        result = CliRunner().invoke(main, args)
        assert result.exit_code == 0 and '"eax": 7' in result.output
    result = CliRunner().invoke(main, ["run-kernel", str(src), "--syntax", "att"])
    assert result.exit_code == 2 and f"{src}:5:" in result.output  # AT&T cannot read Intel operands


@pytest.mark.parametrize("text", ["", "\n\n", "# only a comment\n"])
def test_empty_source_is_named_by_its_own_path(tmp_path, text):
    src = tmp_path / "empty.S"
    src.write_text(text)
    result = CliRunner().invoke(main, ["run-kernel", str(src)])
    assert result.exit_code == 2
    assert str(src) in result.output and ".cache" not in result.output and "asm/" not in result.output


def test_guest_fault_prints_whole_memory_operands(tmp_path):
    src = tmp_path / "fault.S"
    src.write_text(".intel_syntax noprefix\n.text\n# @entry f() -> EAX\n.globl f\nf:\n"
                   "    xor esi, esi\n    test byte ptr [esi], 1\n    ret\n")
    result = CliRunner().invoke(main, ["run-kernel", str(src)])
    assert result.exit_code == 2 and "test byte ptr [esi], 1" in result.output


def test_repository_stands_alone():
    # the design document ships with the repository and the README points to it; docs cite articles
    # by title, never by a path into the workspace the project was developed in
    root = __import__("pathlib").Path(__file__).resolve().parent.parent
    readme = (root / "README.md").read_text()
    assert "docs/ARCHITECTURE.md" in readme and (root / "docs" / "ARCHITECTURE.md").is_file()
    for path in [root / "README.md", *(root / "docs").rglob("*.md"), *(root / "scenes").glob("*.toml")]:
        text = path.read_text()
        assert "shared/" not in text and "seeds/" not in text, path
        assert "seed article" not in text.lower() and "seed z-buffer" not in text.lower(), path
