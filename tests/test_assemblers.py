"""GNU as and the zig (clang) assembler produce byte-identical code for every kernel we ship."""

import pytest
from elftools.elf.elffile import ELFFile

from sim.guest import asm
from sim.guest.kernels import catalogue

BOTH = {"gnu", "zig"} <= set(asm.available_assemblers())
KERNELS = sorted(catalogue())


def text_and_relocations(obj):
    with open(obj, "rb") as f:
        e = ELFFile(f)
        text = e.get_section_by_name(".text").data()
        rel = e.get_section_by_name(".rel.text")
        relocs = sorted((r["r_offset"], r["r_info_type"]) for r in rel.iter_relocations()) if rel else []
    return text, relocs


def test_the_repository_has_kernels():
    assert len(KERNELS) >= 5


@pytest.mark.skipif(not BOTH, reason="needs both GNU as and the ziglang package (pip install '.[zig]')")
@pytest.mark.parametrize("source", KERNELS, ids=lambda p: p.parent.name + "/" + p.name)
def test_gnu_and_zig_produce_identical_text(source):
    gnu = text_and_relocations(asm.assemble(source, "gnu"))
    zig = text_and_relocations(asm.assemble(source, "zig"))
    assert gnu[0] == zig[0], f"{source}: .text differs between GNU as and zig"
    assert gnu[1] == zig[1], f"{source}: relocations differ"


@pytest.mark.skipif(not BOTH, reason="needs both assemblers")
def test_zig_errors_are_file_line_message(tmp_path):
    src = tmp_path / "bad.S"
    src.write_text(".intel_syntax noprefix\n.text\nf:\n  frobnicate eax\n")
    with pytest.raises(asm.AssemblerError, match=rf"^{src}:4: .*frobnicate"):
        asm.assemble(src, "zig")
