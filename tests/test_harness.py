"""Assembler, loader and runner: clear errors for bad input, exact traces, x87 reset state, RDTSC."""

import numpy as np
import pytest

from sim.guest import asm
from sim.guest import elf
from sim.guest.emu import Machine, RdtscEvent
from sim.errors import (
    ArgumentError, AssemblerError, AssemblerMissing, GuestFault, LoadError, RunawayKernel, UnknownSymbol,
)
from sim.guest.trace import Trace


# -- assembler -------------------------------------------------------------------------------
def test_assembler_error_is_file_line_message(write_kernel):
    src = write_kernel(".globl f\nf:\n  mov eax, 1\n  frobnicate eax\n  ret\n")
    with pytest.raises(AssemblerError) as e:
        asm.assemble(src)
    assert str(e.value).startswith(f"{src}:6: ")
    assert "frobnicate" in str(e.value)


def test_assembler_cache_is_keyed_on_content(write_kernel, tmp_path, monkeypatch):
    monkeypatch.setenv(asm.CACHE_ENV, str(tmp_path / "cache"))
    src = write_kernel(".globl f\nf:\n  mov eax, 1\n  ret\n")
    first = asm.assemble(src)
    assert asm.assemble(src) == first  # cached
    src.write_text(src.read_text().replace("mov eax, 1", "mov eax, 2"))
    second = asm.assemble(src)
    assert second != first and first.exists()
    assert Machine(elf.load_object(second)).call("f").eax == 2


def test_included_file_changes_the_cache_key(write_kernel, tmp_path, monkeypatch):
    monkeypatch.setenv(asm.CACHE_ENV, str(tmp_path / "cache"))
    (tmp_path / "value.inc").write_text(".set VALUE, 5\n")
    src = write_kernel('.include "value.inc"\n.globl f\nf:\n  mov eax, VALUE\n  ret\n')
    a = asm.assemble(src)
    (tmp_path / "value.inc").write_text(".set VALUE, 6\n")
    b = asm.assemble(src)
    assert a != b


def test_missing_source_and_unknown_assembler(tmp_path):
    with pytest.raises(AssemblerError, match="no such kernel source"):
        asm.assemble(tmp_path / "nope.S")
    with pytest.raises(AssemblerMissing, match="choose 'gnu' or 'zig'"):
        asm.get_assembler("nasm")


def test_missing_gnu_as_says_how_to_get_it(monkeypatch):
    monkeypatch.setattr(asm, "_gnu", lambda: None)
    monkeypatch.setattr(asm, "_zig", lambda: None)
    with pytest.raises(AssemblerMissing, match="binutils.*ziglang"):
        asm.get_assembler()


# -- loader ----------------------------------------------------------------------------------
def test_relocations_are_applied(write_kernel):
    src = write_kernel("""
.globl f
f:
    mov eax, [table+4]          # R_386_32 with an addend
    call helper                 # R_386_PC32 (to a global: GNU as emits a relocation)
    add eax, [value]            # R_386_32 into .data
    ret
.globl helper
helper:
    add eax, 100
    ret
.section .rodata
table: .long 1, 20, 300
.data
value: .long 4000
.bss
scratch: .space 64
""")
    m = Machine.from_source(src)
    assert m.call("f").eax == 20 + 100 + 4000
    img = m.image
    assert set(img.sections) >= {".text", ".rodata", ".data", ".bss"}
    assert img.sections[".text"].address == elf.CODE_BASE
    assert img.sections[".data"].address % elf.PAGE == 0 or img.sections[".rodata"].address % elf.PAGE == 0
    assert img.symbol("helper") > img.symbol("f")


def test_unknown_relocation_type_is_an_error(write_kernel):
    src = write_kernel(".globl f\nf:\n  mov eax, OFFSET sym@GOTOFF\n  ret\nsym: .long 0\n")
    with pytest.raises(LoadError, match="relocation type 9 to .sym. is not supported"):
        Machine.from_source(src)


def test_undefined_symbol_is_an_error(write_kernel):
    src = write_kernel(".globl f\nf:\n  call elsewhere\n  ret\n")
    with pytest.raises(LoadError, match="undefined symbol 'elsewhere'"):
        Machine.from_source(src)


def test_not_an_elf_object(tmp_path):
    bad = tmp_path / "x.o"
    bad.write_bytes(b"not an elf at all")
    with pytest.raises(LoadError, match="not a valid ELF"):
        elf.load_object(bad)


# -- runner ----------------------------------------------------------------------------------
def test_unknown_entry_lists_known_symbols(machine):
    m = machine("zbuffer/z32.S")
    with pytest.raises(UnknownSymbol, match="no symbol 'z33_span'.*z32_span"):
        m.call("z33_span")


def test_wrong_argument_count_names_the_declaration(machine):
    m = machine("zbuffer/z32.S")
    with pytest.raises(ArgumentError, match=r"z32\.S:\d+: z32_span\(zbuf, fbuf, count, z, dz, colour\).*takes 6 argument\(s\), 2 given"):
        m.call("z32_span", 1, 2)


@pytest.mark.parametrize("bad", [1 << 32, -(1 << 31) - 1, "7", None, 1 + 2j, True])
def test_bad_argument_values(machine, bad):
    m = machine("convert/fp16z.S")
    with pytest.raises(ArgumentError, match="argument 0"):
        m.call("fp16z_convert", bad)


def test_unmapped_read_names_pc_instruction_and_address(write_kernel):
    src = write_kernel(".globl f\nf:\n  mov eax, 0x20000000\n  mov eax, [eax+8]\n  ret\n")
    m = Machine.from_source(src)
    with pytest.raises(GuestFault) as e:
        m.call("f")
    msg = str(e.value)
    assert e.value.pc == m.symbol("f") + 5
    assert e.value.address == 0x20000008
    assert "f+0x5" in msg and "mov eax, dword ptr [eax + 8]" in msg and "0x20000008" in msg


def test_write_to_code_is_a_fault(write_kernel):
    src = write_kernel(".globl f\nf:\n  mov dword ptr [f], 0\n  ret\n")
    m = Machine.from_source(src)
    with pytest.raises(GuestFault, match="write of unmapped or protected address 0x00400000"):
        m.call("f")


def test_invalid_opcode_and_divide_error(write_kernel):
    src = write_kernel(".globl f, g\nf:\n  ud2\n  ret\ng:\n  xor ecx, ecx\n  div ecx\n  ret\n")
    m = Machine.from_source(src)
    with pytest.raises(GuestFault, match=r"f\+0x0\): ud2"):
        m.call("f")
    with pytest.raises(GuestFault, match=r"g\+0x2\): div ecx: divide error"):
        m.call("g")


@pytest.mark.parametrize("traced", [False, True])
def test_runaway_kernel_stops_at_budget(write_kernel, traced):
    src = write_kernel(".globl f\nf:\n  xor eax, eax\n1:\n  inc eax\n  jmp 1b\n")
    m = Machine.from_source(src)
    with pytest.raises(RunawayKernel, match="budget of 10,000 instructions") as e:
        m.call("f", budget=10_000, trace=traced)
    assert m.symbol("f") <= e.value.pc < m.symbol("f") + 8
    assert m.call is not None  # the machine is still usable afterwards:
    src2 = write_kernel(".globl g\ng:\n  mov eax, 3\n  ret\n", "ok.S")
    assert Machine.from_source(src2).call("g", trace=traced).eax == 3


def test_budget_exactly_enough_passes(machine):
    m = machine("convert/fp16z.S")
    n = m.call("fp16z_convert", 12345, trace=True).instructions
    assert n == 6
    assert m.call("fp16z_convert", 12345, budget=n, trace=True).eax == m.call("fp16z_convert", 12345).eax
    with pytest.raises(RunawayKernel):
        m.call("fp16z_convert", 12345, budget=n - 1, trace=True)
    with pytest.raises(RunawayKernel):
        m.call("fp16z_convert", 12345, budget=n - 1)


def test_fpu_starts_in_fninit_state(write_kernel):
    """Unicorn's own start state is control word 0 (24-bit precision, exceptions unmasked)."""
    src = write_kernel("""
.globl cw, cw_after_fninit
cw:
    sub esp, 4
    fnstcw [esp]
    movzx eax, word ptr [esp]
    add esp, 4
    ret
cw_after_fninit:
    fninit
    jmp cw
""")
    m = Machine.from_source(src)
    assert m.call("cw").eax == 0x037F
    state = (m.reg("fpsw"), m.reg("fptag"))
    assert m.call("cw_after_fninit").eax == 0x037F
    assert (m.reg("fpsw"), m.reg("fptag")) == state  # status and tag words as FNINIT leaves them


def test_precision_control_changes_x87_results(write_kernel):
    """1/3 at 24-bit precision (the state Unicorn would silently start in) differs from 64-bit."""
    src = write_kernel("""
.globl third
# @entry third(cw) -> EAX = float32 bits of 1/3 computed at that control word
third:
    fldcw [esp+4]
    fld1
    fld1
    fadd st, st(1)
    fadd st, st(1)           # st0 = 3, st1 = 1
    fdivp st(1), st          # st0 = 1/3 at the precision in force
    sub esp, 8
    fstp qword ptr [esp]
    mov eax, [esp]
    mov edx, [esp+4]
    add esp, 8
    ret
""")
    m = Machine.from_source(src)
    single = m.call("third", 0x007F)
    m.reset_fpu()
    extended = m.call("third", 0x037F)
    as_double = lambda r: np.array([r.eax | (r.edx << 32)], np.uint64).view(np.float64)[0]
    assert as_double(single) == np.float32(1 / 3)
    assert as_double(extended) == 1 / 3


# -- traces ----------------------------------------------------------------------------------
def test_native_trace_equals_python_trace_across_buffer_refills(machine):
    """A small trace buffer forces many stop/drain/resume cycles; the result must not change."""
    m = machine("zbuffer/fp16z.S")
    n = 3000
    zb = m.arena.put(np.full(n, 0xFFFF, np.uint16))
    fb = m.arena.put(np.zeros(n, np.uint16))
    from sim.guest.trace import NativeTracer
    m._tracer = NativeTracer(m.uc, instruction_capacity=997, access_capacity=300)
    native = m.call("fp16z_span", zb, fb, n, 1 << 28, 77777, 5, trace=True).trace
    m.arena.reset()
    zb = m.arena.put(np.full(n, 0xFFFF, np.uint16))
    fb = m.arena.put(np.zeros(n, np.uint16))
    python = m.call("fp16z_span", zb, fb, n, 1 << 28, 77777, 5, trace="python").trace
    m._tracer = None
    for field in ("pc", "mem_addr", "mem_size", "mem_write", "mem_insn"):
        np.testing.assert_array_equal(getattr(native, field), getattr(python, field), err_msg=field)
    assert native.instructions > 10 * 997


def test_trace_contents_for_a_known_kernel(machine):
    m = machine("zbuffer/z32.S")
    n = 10
    zb = m.arena.put(np.full(n, 0xFFFFFFFF, np.uint32))
    fb = m.arena.put(np.zeros(n, np.uint16))
    t = m.call("z32_span", zb, fb, n, 100, 1, 9, trace=True).trace
    t.validate()
    # per pixel: load z (4 bytes), store z (4), store colour (2) - every pixel passes
    loads = t.mem_addr[~t.mem_write & (t.mem_addr >= zb) & (t.mem_addr < zb + 4 * n)]
    np.testing.assert_array_equal(loads, zb + 4 * np.arange(n))
    colour_stores = (t.mem_write & (t.mem_size == 2))
    np.testing.assert_array_equal(t.mem_addr[colour_stores], fb + 2 * np.arange(n))
    # 4 pushes + 6 argument loads before the loop, 4 pops and the return after it
    assert t.accesses == 4 + 6 + 3 * n + 4 + 1
    assert t.pc[0] == m.symbol("z32_span")
    # 7 instructions per passing pixel (cmp, jae, 2 stores, add, inc, jnz), the loop is entered once
    m.arena.reset()
    zb = m.arena.put(np.full(n + 1, 0xFFFFFFFF, np.uint32))
    fb = m.arena.put(np.zeros(n + 1, np.uint16))
    longer = m.call("z32_span", zb, fb, n + 1, 100, 1, 9, trace=True).trace
    assert longer.instructions - t.instructions == 7
    loop_pcs = np.unique(t.pc, return_counts=True)
    assert sorted(loop_pcs[1])[-7:] == [n] * 7


def test_trace_save_load_roundtrip_and_invariants(tmp_path, machine):
    m = machine("convert/fp16z.S")
    t = m.call("fp16z_convert", 77, trace=True).trace
    path = tmp_path / "t.npz"
    t.save(path)
    back = Trace.load(path)
    np.testing.assert_array_equal(back.pc, t.pc)
    np.testing.assert_array_equal(back.mem_insn, t.mem_insn)
    broken = Trace(t.pc, t.mem_addr, t.mem_size, t.mem_write, t.mem_insn[::-1].copy())
    with pytest.raises(ValueError, match="mem_insn"):
        broken.validate()


def test_rdtsc_answers_from_a_timing_source(write_kernel):
    src = write_kernel("""
.globl f
f:
    rdtsc
    mov ecx, eax
    nop
    nop
    rdtsc
    sub eax, ecx
    ret
""")
    seen: list[RdtscEvent] = []

    def clock(event: RdtscEvent) -> int:
        seen.append(event)
        return 1000 * (event.instructions or 0) + (1 << 32)  # EDX gets the high word

    m = Machine.from_source(src, rdtsc=clock)
    r = m.call("f", trace=True)
    assert [e.instructions for e in seen] == [0, 4]
    assert r.eax == 4000 and r.edx == 1
    assert seen[0].pc == m.symbol("f")
    # without a source, RDTSC counts instructions (traced) - deterministic, never host time
    m2 = Machine.from_source(src)
    assert m2.call("f", trace=True).eax == 4
    assert m2.call("f").eax == 0


def test_a_narrow_reference_is_named_for_what_it_is(write_kernel):
    # `.byte sym` makes GNU as emit R_386_8: refused in the user's terms, not as a type number
    src = write_kernel(".globl f\nf:\n  ret\n  .byte g\ng: .long 0\n")
    with pytest.raises(LoadError, match=r"an 8-bit reference \(R_386_8\)"):
        Machine.from_source(src)
