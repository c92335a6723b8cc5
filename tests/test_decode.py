"""Tests for sim.guest.decode, driven by real instructions assembled with GNU as."""

from __future__ import annotations

import shutil
import subprocess
import textwrap
from pathlib import Path

import numpy as np
import pytest

from sim.guest import decode as D
from sim.guest.decode import DecodeError, Decoder, InsnRecord, RegRef, decode_block, decode_one

AS = shutil.which("as") or "/usr/bin/as"
OBJCOPY = shutil.which("objcopy") or "/usr/bin/objcopy"
PC = 0x0040_1000
FLAGS = frozenset(D.FLAG_NAMES)


# ---------------------------------------------------------------------------
# Assembling helpers
# ---------------------------------------------------------------------------


@pytest.fixture(scope="session")
def asm(tmp_path_factory):
    """asm(src) -> .text bytes of `src` (Intel syntax, 32-bit), cached per source."""
    if not (Path(AS).exists() and Path(OBJCOPY).exists()):
        pytest.skip("GNU binutils (as/objcopy) not available")
    cache: dict[str, bytes] = {}

    def assemble(src: str) -> bytes:
        if src not in cache:
            d = tmp_path_factory.mktemp("asm")
            s, o, b = d / "t.s", d / "t.o", d / "t.bin"
            s.write_text(".intel_syntax noprefix\n.text\n" + textwrap.dedent(src).strip() + "\n")
            for cmd in (
                [AS, "--32", "-o", str(o), str(s)],
                [OBJCOPY, "-O", "binary", "--only-section=.text", str(o), str(b)],
            ):
                res = subprocess.run(cmd, capture_output=True, text=True)
                assert res.returncode == 0, f"{cmd[0]} failed on {src!r}:\n{res.stderr}"
            cache[src] = b.read_bytes()
        return cache[src]

    return assemble


@pytest.fixture(scope="session")
def one(asm):
    """one(src) -> InsnRecord of a snippet that must be exactly one instruction."""

    def decode(src: str, pc: int = PC) -> InsnRecord:
        code = asm(src)
        rec = decode_one(code, pc)
        assert rec.length == len(code), f"{src!r} assembled to more than one instruction"
        return rec

    return decode


def reg(name: str) -> RegRef:
    return D.reg_ref(name)


def names(refs) -> set[str]:
    return {r.name for r in refs}


# ---------------------------------------------------------------------------
# Hand-checked sanity
# ---------------------------------------------------------------------------


def test_hand_checked_bytes():
    # 0F BD C8 = BSR ECX, EAX ; 66 90 = xchg ax,ax (nop with opsize prefix)
    rec = decode_one(b"\x0f\xbd\xc8\x90", 0x1000)
    assert (rec.mnemonic, rec.op_str, rec.length, rec.modrm) == ("bsr", "ecx, eax", 3, 0xC8)
    rec = decode_one(b"\x66\x90", 0x1000)
    assert rec.prefixes == (0x66,) and rec.opcode == b"\x90" and rec.modrm is None


# ---------------------------------------------------------------------------
# Required instructions
# ---------------------------------------------------------------------------


def test_bsr(one):
    rec = one("bsr ecx, eax")
    assert rec.opcode == b"\x0f\xbd"
    assert rec.escape_0f and rec.length == 3 and rec.prefixes == ()
    assert rec.regs_read == (reg("eax"),)
    assert rec.regs_written == (reg("ecx"),)
    assert "ZF" in rec.flags_written and "ZF" not in rec.flags_undefined
    assert rec.flags_undefined == {"CF", "OF", "SF", "AF", "PF"}
    assert rec.flags_undefined <= rec.flags_written
    assert rec.flags_read == frozenset()
    assert rec.signature == "r32,r32"
    assert [op.access for op in rec.operands] == ["w", "r"]


def test_shrd_cl(one):
    rec = one("shrd edx, eax, cl")
    assert rec.opcode == b"\x0f\xad"
    assert names(rec.regs_read) == {"edx", "eax", "cl"}
    cl = next(r for r in rec.regs_read if r.name == "cl")
    assert cl == RegRef("cl", "ecx", "low8")
    assert rec.regs_written == (reg("edx"),)
    assert rec.signature == "r32,r32,cl"
    # capstone reports CL with access 0; it is a read
    assert rec.operands[2].access == "r"
    assert rec.operands[0].access == "rw"


def test_shrd_imm(one):
    rec = one("shrd edx, ecx, 21")
    assert rec.opcode == b"\x0f\xac"
    assert rec.signature == "r32,r32,i8"
    assert rec.operands[2].imm == 21 and rec.imm_size == 1
    assert names(rec.regs_read) == {"edx", "ecx"}


def test_16bit_operand_size(one):
    rec = one("mov ax, [esi+ebx*2+8]")
    assert rec.opsize_prefix and not rec.addrsize_prefix
    assert rec.prefixes == (0x66,)
    assert rec.opcode == b"\x8b"
    mem = rec.memory_operand
    assert (mem.base, mem.index, mem.scale, mem.disp, mem.size) == ("esi", "ebx", 2, 8, 2)
    assert mem.segment is None
    assert rec.regs_written == (RegRef("ax", "eax", "word"),)
    assert names(rec.regs_read) == {"esi", "ebx"}
    assert rec.reads_memory and not rec.writes_memory
    assert rec.signature == "r16,m16"
    assert rec.writes_partial == {"eax"}


def test_partial_registers(one):
    bl = one("mov bl, 1")
    assert bl.regs_written == (RegRef("bl", "ebx", "low8"),)
    assert bl.writes_partial == {"ebx"} and bl.uses_partial_register
    assert bl.signature == "r8,i8"

    bh = one("mov bh, 2")
    assert bh.regs_written == (RegRef("bh", "ebx", "high8"),)
    assert bh.writes_partial == {"ebx"}
    # the masks say BL and BH are disjoint halves of BX
    assert bl.regs_written[0].mask & bh.regs_written[0].mask == 0

    add = one("add eax, ebx")
    assert RegRef("ebx", "ebx", "dword") in add.regs_read
    assert not add.uses_partial_register
    # a full read of ebx needs bits that the byte writes did not produce
    assert add.regs_read[1].mask & ~(bl.regs_written[0].mask | bh.regs_written[0].mask)

    movzx = one("movzx eax, ah")
    assert movzx.partial_reads == (RegRef("ah", "eax", "high8"),)
    assert movzx.writes_partial == frozenset()


def test_implicit_partial_writes_are_merged(one):
    # DIV r8 writes AL and AH: reported once, as AX
    rec = one("div bl")
    assert rec.regs_written == (RegRef("ax", "eax", "word"),)
    assert names(rec.regs_read) == {"bl", "ax"}
    # MUL r8: capstone lists al and ax; we keep the widest
    assert one("mul bl").regs_written == (RegRef("ax", "eax", "word"),)


def test_addrsize_prefix(one):
    rec = one("mov eax, dword ptr [si+4]")
    assert rec.addrsize_prefix and not rec.opsize_prefix
    assert rec.prefixes == (0x67,)
    assert rec.memory_operand.base == "si" and rec.memory_operand.disp == 4
    assert rec.regs_read == (RegRef("si", "esi", "word"),)


def test_addrsize_string_op_uses_16bit_pointers(one):
    # capstone lists both edi/esi and di/si for 67 A4
    rec = one("addr16 movsb")
    assert rec.addrsize_prefix
    assert names(rec.regs_written) == {"di", "si"}
    assert {r.full: r.part for r in rec.regs_read}["esi"] == "word"


def test_adc_reads_cf(one):
    rec = one("adc eax, ebx")
    assert rec.flags_read == {"CF"}
    assert rec.flags_written == {"CF", "PF", "AF", "ZF", "SF", "OF"}
    assert not rec.is_branch


def test_jnz(asm):
    code = asm("jnz 1f\n1:\nnop")
    rec = decode_one(code, PC)
    assert rec.is_branch and rec.is_conditional_branch and rec.is_relative_branch
    assert rec.flags_read == {"ZF"}
    assert rec.flags_written == frozenset()
    assert rec.signature == "rel8"
    assert rec.branch_target == PC + 2 == rec.fallthrough


def test_jnz_rel32(asm):
    rec = decode_one(asm("jnz 1f\n.skip 300\n1:"), PC)
    assert rec.opcode == b"\x0f\x85" and rec.signature == "rel32"
    assert rec.branch_target == PC + 6 + 300


def test_jmp_unconditional(asm):
    rec = decode_one(asm("1:\njmp 1b"), PC)
    assert rec.is_branch and not rec.is_conditional_branch
    assert "jump" in rec.groups and rec.branch_target == PC
    indirect = decode_one(asm("jmp dword ptr [eax+ebx*4]"), PC)
    assert indirect.is_branch and not indirect.is_relative_branch
    assert indirect.reads_memory and indirect.branch_target is None


def test_call_and_ret(asm, one):
    call = decode_one(asm("call 1f\n1:"), PC)
    assert "call" in call.groups and call.is_branch
    assert call.writes_memory and not call.reads_memory  # pushes the return address
    assert reg("esp") in call.regs_read and reg("esp") in call.regs_written
    assert call.signature == "rel32"

    ret = one("ret")
    assert "ret" in ret.groups and ret.is_branch and not ret.is_conditional_branch
    assert ret.reads_memory and not ret.writes_memory
    assert ret.signature == ""
    assert one("ret 8").signature == "i16"


def test_push_pop(one):
    push = one("push eax")
    assert names(push.regs_read) == {"eax", "esp"}
    assert push.regs_written == (reg("esp"),)
    assert push.writes_memory and not push.reads_memory
    assert push.memory_operand is None and push.implicit_mem == "w"

    pop = one("pop ebx")
    assert names(pop.regs_written) == {"ebx", "esp"}
    assert pop.reads_memory and not pop.writes_memory

    # push mem: explicit load + implicit store
    pm = one("push dword ptr [eax]")
    assert pm.reads_memory and pm.writes_memory

    # capstone has no esp access for segment pushes/pops
    for src in ("push es", "pop ds"):
        rec = one(src)
        assert reg("esp") in rec.regs_read and reg("esp") in rec.regs_written, src
    assert reg("es") in one("push es").regs_read


def test_div_reads_edx_eax(one):
    rec = one("div ecx")
    assert names(rec.regs_read) == {"ecx", "eax", "edx"}
    assert names(rec.regs_written) == {"eax", "edx"}
    assert rec.flags_undefined == {"CF", "PF", "AF", "ZF", "SF", "OF"}


# ---------------------------------------------------------------------------
# x87
# ---------------------------------------------------------------------------


def test_fld_m32(one):
    rec = one("fld dword ptr [esp+4]")
    assert "fpu" in rec.groups and rec.is_x87
    assert rec.memory_operand.size == 4 and rec.memory_operand.base == "esp"
    assert rec.reads_memory and not rec.writes_memory
    assert rec.signature == "m32fp"
    assert reg("st0") in rec.regs_written and reg("esp") in rec.regs_read
    assert rec.fpu_stack_delta == 1
    # capstone's eflags word is really fpu_flags here: no EFLAGS effect
    assert rec.flags_written == rec.flags_read == frozenset()


def test_fadd_st0_st1(one):
    rec = one("fadd st(0), st(1)")
    assert rec.opcode == b"\xd8" and rec.modrm == 0xC1
    assert names(rec.regs_read) == {"st0", "st1"}  # capstone omits st0
    assert RegRef("st0", "st0", "full") in rec.regs_written
    assert rec.signature == "st,sti"
    assert rec.flags_written == frozenset()
    # the other direction: DC C1 = fadd st(1), st(0)
    rev = one("fadd st(1), st(0)")
    assert rev.signature == "sti,st"
    assert reg("st1") in rev.regs_written and reg("st0") not in rev.regs_written
    assert one("faddp st(1), st(0)").fpu_stack_delta == -1
    assert one("fadd dword ptr [eax]").signature == "st,m32fp"


def test_fistp_writes_memory(one):
    rec = one("fistp dword ptr [eax]")
    assert rec.writes_memory and not rec.reads_memory  # capstone says "read"
    assert rec.signature == "m32int"
    assert reg("st0") in rec.regs_read and rec.fpu_stack_delta == -1


@pytest.mark.parametrize(
    "src, sig",
    [
        ("fstp qword ptr [eax]", "m64fp"),
        ("fst dword ptr [eax]", "m32fp"),
        ("fnstcw word ptr [eax]", "m16"),
        ("fnsave [eax]", "m108byte"),
        ("fbstp tbyte ptr [eax]", "m80bcd"),
    ],
)
def test_x87_stores_write_memory(one, src, sig):
    rec = one(src)
    assert rec.writes_memory and not rec.reads_memory
    assert rec.signature == sig


def test_frstor_reads_memory(one):
    rec = one("frstor [eax]")  # capstone: write, size 4
    assert rec.reads_memory and not rec.writes_memory
    assert rec.memory_operand.size == 108


def test_fnstsw_ax(one):
    rec = one("fnstsw ax")
    assert rec.regs_written == (RegRef("ax", "eax", "word"),)
    assert reg("fpsw") in rec.regs_read
    assert rec.signature == "ax" and "fpu" in rec.groups  # capstone drops the group
    assert rec.flags_written == frozenset()


def test_fldcw_writes_control_word(one):
    rec = one("fldcw word ptr [eax]")
    assert reg("fpcw") in rec.regs_written and rec.reads_memory


def test_fcomip(one):
    rec = one("fcomip st, st(1)")
    assert rec.mnemonic in ("fcomip", "fcompi")
    assert {"ZF", "PF", "CF"} <= rec.flags_written
    assert rec.flags_undefined == frozenset()
    assert names(rec.regs_read) == {"st0", "st1"}
    assert rec.fpu_stack_delta == -1 and rec.signature == "st,sti"


def test_fcmov_reads_flags_and_st0(one):
    rec = one("fcmovbe st, st(3)")
    assert rec.flags_read == {"CF", "ZF"} and rec.flags_written == frozenset()
    assert names(rec.regs_read) == {"st0", "st3"}
    assert reg("st0") in rec.regs_written and reg("st3") not in rec.regs_written


def test_fxch(one):
    rec = one("fxch st(3)")
    assert names(rec.regs_read) == {"st0", "st3"}
    assert {"st0", "st3"} <= names(rec.regs_written)
    assert rec.signature == "sti"


X87_STORES = {"fst", "fstp", "fstpnce", "fist", "fistp", "fisttp", "fbstp",
              "fnstcw", "fnstsw", "fnstenv", "fnsave"}


def test_every_x87_encoding_is_in_the_table():
    """All decodable D8-DF encodings ([eax] memory forms and all register forms)."""
    seen = set()
    for op in range(0xD8, 0xE0):
        modrms = [reg_field << 3 for reg_field in range(8)] + list(range(0xC0, 0x100))
        for modrm in modrms:
            try:
                rec = decode_one(bytes([op, modrm]), PC)
            except DecodeError:
                continue
            seen.add(rec.mnemonic)
            assert rec.mnemonic in D._X87_TABLE, rec
            assert "fpu" in rec.groups
            assert rec.opcode == bytes([op]) and rec.modrm == modrm
            assert -2 <= rec.fpu_stack_delta <= 1
            if rec.mnemonic not in ("fcomi", "fcompi", "fucomi", "fucompi"):
                assert rec.flags_written == frozenset(), rec
            if modrm < 0xC0:
                assert rec.writes_memory == (rec.mnemonic in X87_STORES), rec
                assert rec.reads_memory != rec.writes_memory, rec
                assert rec.regs_read and reg("eax") in rec.regs_read
            else:
                assert not rec.reads_memory and not rec.writes_memory
            assert len(rec.operands) == (len(rec.signature.split(",")) if rec.signature else 0)
    assert len(seen) > 80


# ---------------------------------------------------------------------------
# Prefixes
# ---------------------------------------------------------------------------


def test_rep_movsd(one):
    rec = one("rep movsd")
    assert rec.mnemonic == "movsd" and rec.rep == "rep"
    assert rec.prefixes == (0xF3,)
    assert rec.reads_memory and rec.writes_memory
    assert {"ecx", "esi", "edi"} <= names(rec.regs_read)
    assert {"ecx", "esi", "edi"} <= names(rec.regs_written)
    assert rec.flags_read == {"DF"}
    assert rec.signature == "m32,m32"


def test_repne_scasb_and_plain(one):
    rec = one("repne scasb")
    assert rec.mnemonic == "scasb" and rec.rep == "repne"
    assert one("movsb").rep is None
    # F3 as a mandatory SSE prefix or the 'rep ret' idiom is not a repeat
    movss = one("movss xmm0, xmm1")
    assert movss.rep is None and movss.prefixes == (0xF3,)
    assert movss.flags_read == frozenset()  # capstone claims it tests DF
    rep_ret = one("rep ret")
    assert rep_ret.mnemonic == "ret" and rep_ret.rep is None


@pytest.mark.parametrize("src, rep, mnemonic", [
    ("repe cmpsb", "repe", "cmpsb"), ("repe scasd", "repe", "scasd"),     # F3 on CMPS/SCAS repeats while equal
    ("repne cmpsw", "repne", "cmpsw"), ("repne scasb", "repne", "scasb"),
    ("rep stosd", "rep", "stosd"), ("rep lodsb", "rep", "lodsb"),         # F3 on the others just repeats
])
def test_rep_prefix_names_the_repeat_condition(one, src, rep, mnemonic):
    rec = one(src)
    assert (rec.rep, rec.mnemonic) == (rep, mnemonic)


def test_cl_as_shift_destination_is_read_and_written(one):
    rec = one("shl cl, cl")
    assert [op.access for op in rec.operands] == ["rw", "r"]
    assert rec.regs_read == (reg("cl"),) and rec.regs_written == (reg("cl"),)


def test_lock_and_segment_prefix_order(one):
    # a stand-alone `lock` line makes gas emit F0 before the FS override
    rec = one("lock\nadd dword ptr fs:[eax], 1")
    assert rec.mnemonic == "add" and rec.lock
    assert rec.prefixes == (0xF0, 0x64)  # encoding order, not capstone's slots
    assert rec.opcode == b"\x83" and rec.raw[:2] == b"\xf0\x64"
    assert rec.segment_override == "fs" and rec.memory_operand.segment == "fs"
    assert rec.reads_memory and rec.writes_memory
    assert rec.signature == "m32,i8"


# ---------------------------------------------------------------------------
# Signatures and capstone quirks
# ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "src, sig",
    [
        ("add ebx, 500", "r32,i32"),
        ("add ebx, 5", "r32,i8"),
        ("mov word ptr [eax], bx", "m16,r16"),
        ("mov word ptr [eax], 5", "m16,i16"),
        ("shl eax, 1", "r32,1"),
        ("shl eax, 3", "r32,i8"),
        ("rcr eax, cl", "r32,cl"),
        ("imul eax, ebx, 10", "r32,r32,i8"),
        ("lea eax, [ebx+8]", "r32,m"),
        ("movq mm0, qword ptr [eax]", "mm,m64"),
        ("movaps xmm0, xmm1", "xmm,xmm"),
        ("in al, dx", "r8,dx"),
        ("enter 8, 0", "i16,i8"),
        ("fild word ptr [eax]", "m16int"),
        ("fld tbyte ptr [eax]", "m80fp"),
        ("fld st(2)", "sti"),
        ("fchs", ""),
        ("cdq", ""),
        ("les eax, [ebx]", "r32,m48"),
        # CL is 'cl' only as the COUNT of a shift or rotate; as the destination it is a byte register
        ("rol cl, 1", "r8,1"),
        ("shl cl, cl", "r8,cl"),
        ("sar cl, 3", "r8,i8"),
        ("rcr byte ptr [eax], cl", "m8,cl"),
        ("shld cx, ax, cl", "r16,r16,cl"),
        ("fldenv [esi]", "m28byte"),
        ("fnstenv [esi]", "m28byte"),
        ("fnstsw word ptr [esi]", "m16"),
        ("fnstsw ax", "ax"),
        ("ldmxcsr dword ptr [esi]", "m32"),
    ],
)
def test_signatures(one, src, sig):
    assert one(src).signature == sig


def test_store_reported_as_load_is_fixed(one):
    for src in ("movq qword ptr [eax], mm0", "movd dword ptr [eax], mm1",
                "movups xmmword ptr [eax], xmm0", "stmxcsr dword ptr [eax]"):
        rec = one(src)
        assert rec.writes_memory and not rec.reads_memory, src


def test_cdq_does_not_write_eax(one):
    rec = one("cdq")
    assert rec.regs_written == (reg("edx"),) and rec.regs_read == (reg("eax"),)


def test_cmpxchg(one):
    rec = one("cmpxchg dword ptr [ebx], ecx")
    assert rec.reads_memory and rec.writes_memory
    assert {"eax", "ebx", "ecx"} <= names(rec.regs_read)
    assert reg("eax") in rec.regs_written
    assert one("cmpxchg8b qword ptr [esi]").writes_memory


def test_cmov_reads_destination(one):
    rec = one("cmovz eax, ebx")
    assert names(rec.regs_read) == {"eax", "ebx"} and rec.flags_read == {"ZF"}


def test_flag_reads_capstone_misses(one):
    assert one("rcl eax, cl").flags_read == {"CF"}
    assert one("cmc").flags_read == {"CF"}
    assert one("lahf").flags_read == {"SF", "ZF", "AF", "PF", "CF"}
    assert one("pushfd").flags_read == FLAGS
    assert one("daa").flags_read == {"AF", "CF"}
    assert one("prefetchw [eax]").flags_written == frozenset()


def test_shift_overflow_flag(one):
    assert "OF" not in one("shl eax, 1").flags_undefined
    assert "OF" in one("shl eax, 3").flags_undefined
    assert "OF" in one("shl eax, cl").flags_undefined
    # capstone marks OF undefined for every rotate; a count of 1 defines it
    for src in ("rol eax, 1", "rcr eax, 1", "ror al, 1"):
        rec = one(src)
        assert "OF" in rec.flags_written and "OF" not in rec.flags_undefined, src
    assert "OF" in one("rol eax, 4").flags_undefined


def test_partial_flag_writers(one):
    assert one("inc eax").writes_partial_flags  # leaves CF alone
    assert not one("add eax, 1").writes_partial_flags
    assert not one("mov eax, 1").writes_partial_flags


def test_address_only_operands(one):
    lea = one("lea eax, [ebx+ecx*4+8]")
    assert not lea.reads_memory and not lea.writes_memory
    assert names(lea.regs_read) == {"ebx", "ecx"}
    nop = one("nop dword ptr [eax+eax*1+0]")
    assert not nop.reads_memory and nop.regs_read == ()


def test_xlatb_and_stack_frames(one):
    x = one("xlatb")
    assert names(x.regs_read) == {"al", "ebx"} and x.regs_written == (reg("al"),)
    assert x.reads_memory
    enter = one("enter 16, 0")
    assert {"ebp", "esp"} <= names(enter.regs_read) and enter.writes_memory
    leave = one("leave")
    assert names(leave.regs_written) == {"ebp", "esp"} and leave.reads_memory


def test_loop_is_conditional_branch(asm):
    rec = decode_one(asm("1:\nloop 1b"), PC)
    assert rec.is_branch and rec.is_conditional_branch and "jump" in rec.groups
    assert rec.regs_read == (reg("ecx"),) and rec.regs_written == (reg("ecx"),)


def test_zero_idiom(one):
    assert one("xor eax, eax").is_zero_idiom
    assert one("sub ecx, ecx").is_zero_idiom
    assert not one("xor eax, ebx").is_zero_idiom


def test_3dnow_opcode_includes_suffix(one):
    rec = one("pfadd mm0, mm1")
    assert rec.opcode == b"\x0f\x0f\x9e" and rec.modrm == 0xC1
    assert rec.is_mmx and rec.signature == "mm,mm"


# ---------------------------------------------------------------------------
# Structural invariants over a broad corpus
# ---------------------------------------------------------------------------

CORPUS = """
    bsr ecx, eax
    shrd edx, eax, cl
    mov ax, [esi+ebx*2+8]
    mov eax, dword ptr [si+4]
    lock xadd dword ptr [eax], ebx
    xchg dword ptr [eax], ebx
    cmpxchg ebx, ecx
    rep stosb
    repe cmpsb
    lodsd
    outsd
    insb
    movzx eax, word ptr [ebx]
    movsx ax, bl
    sete bl
    setb ah
    cmovb ax, bx
    bt eax, ebx
    bts dword ptr [eax], 3
    aam
    aad
    cbw
    cwd
    imul ebx
    idiv ebx
    mul bl
    push 500
    pop dword ptr [eax]
    call eax
    call dword ptr [eax]
    pushad
    popad
    pushfd
    popfd
    sahf
    iretd
    int 0x80
    int3
    cpuid
    rdtsc
    rdpmc
    mov ds, ax
    mov eax, cr0
    lgdt [eax]
    invlpg [eax]
    lds eax, [ebx]
    bound eax, [ebx]
    mov eax, dword ptr fs:[0x1234]
    paddd mm0, qword ptr [eax]
    pshufw mm0, mm1, 3
    maskmovq mm0, mm1
    femms
    pi2fd mm0, mm1
    prefetch [eax]
    comiss xmm0, xmm1
    ldmxcsr dword ptr [eax]
    fxsave [eax]
    fsincos
    fpatan
    fcompp
    ffree st(2)
    fnstenv [eax]
    wait
    pause
    ud2
    hlt
    ljmp 0x10:0x1234
    """


def test_corpus_invariants(asm):
    code = asm(CORPUS)
    recs = decode_block(code, PC)
    assert len(recs) == len([ln for ln in CORPUS.splitlines() if ln.strip()])
    offset = 0
    for rec in recs:
        hash(rec)  # frozen and hashable
        assert rec.pc == PC + offset and rec.raw == code[offset: offset + rec.length]
        offset += rec.length
        n = len(rec.prefixes)
        assert all(p in D._LEGACY_PREFIXES for p in rec.prefixes)
        assert rec.opsize_prefix == (0x66 in rec.prefixes)
        assert rec.addrsize_prefix == (0x67 in rec.prefixes)
        assert rec.lock == (0xF0 in rec.prefixes)
        assert rec.escape_0f == (rec.opcode[:1] == b"\x0f")
        body = rec.opcode[:2] if rec.opcode[:2] == b"\x0f\x0f" else rec.opcode
        assert rec.raw[n: n + len(body)] == body, rec
        if rec.modrm is not None:
            assert rec.raw[n + len(body)] == rec.modrm, rec
        assert " " not in rec.mnemonic and rec.mnemonic == rec.mnemonic.lower()
        assert rec.rep is None or rec.mnemonic in D._STRING_OPS
        # flags
        assert rec.flags_read <= FLAGS and rec.flags_written <= FLAGS
        assert rec.flags_undefined <= rec.flags_written
        # registers: each full register once, no EFLAGS/EIP, consistent with operands
        for regs in (rec.regs_read, rec.regs_written):
            fulls = [r.full for r in regs]
            assert len(fulls) == len(set(fulls)), rec
            assert not {"eflags", "eip", "rax", "rdx"} & set(fulls), rec
        for op in rec.operands:
            assert op.kind in ("reg", "imm", "mem") and op.access in ("r", "w", "rw", "")
            if op.kind == "reg":
                if "r" in op.access:
                    assert op.reg.full in rec.full_regs_read, rec
                if "w" in op.access:
                    assert op.reg.full in rec.full_regs_written, rec
            if op.kind == "mem" and rec.mnemonic != "nop":
                for r in (op.mem.base, op.mem.index):
                    assert r is None or reg(r).full in rec.full_regs_read, rec
        tokens = rec.signature.split(",") if rec.signature else []
        assert len(tokens) == len(rec.operands), rec


def test_regs_access_matches_capstone_where_capstone_is_right(one):
    """Spot check that we did not lose anything capstone gets right."""
    rec = one("pushad")
    assert names(rec.regs_read) == {"eax", "ecx", "edx", "ebx", "esp", "ebp", "esi", "edi"}
    rec = one("cpuid")
    assert names(rec.regs_read) == {"eax", "ecx"}
    assert names(rec.regs_written) == {"eax", "ebx", "ecx", "edx"}
    assert one("rdpmc").regs_written == (reg("eax"), reg("edx"))  # capstone: rax, rdx


# ---------------------------------------------------------------------------
# Decoder cache and trace decoding
# ---------------------------------------------------------------------------

LOOP_SRC = """
    top:
        mov eax, dword ptr [esi]
        add ebx, eax
        add esi, 4
        dec ecx
        jnz top
        ret
"""


@pytest.fixture
def loop_region(asm):
    code = asm(LOOP_SRC)
    base = 0x0804_8000
    calls: list[tuple[int, int]] = []

    def fetch(addr: int, n: int) -> bytes:
        calls.append((addr, n))
        off = addr - base
        return code[off: off + n]  # short near the end of the region

    return code, base, fetch, calls


def test_decode_trace_caches_per_static_pc(loop_region):
    code, base, fetch, calls = loop_region
    static = decode_block(code, base)
    loop_pcs = np.array([r.pc for r in static[:5]], dtype=np.uint32)
    ret_pc = static[5].pc
    # enter mid-body, iterate 1000 times, return
    stream = np.concatenate([loop_pcs[2:], np.tile(loop_pcs, 1000), [ret_pc]]).astype(np.uint32)

    dec = Decoder(fetch)
    records, index = dec.decode_trace(stream)

    assert len(records) == 6 and all(type(r.pc) is int for r in records)
    expected_order = [*loop_pcs[2:], *loop_pcs[:2], ret_pc]  # first appearance
    assert [r.pc for r in records] == [int(p) for p in expected_order]
    assert index.dtype == np.int32 and index.shape == stream.shape
    np.testing.assert_array_equal(np.array([r.pc for r in records])[index], stream)
    assert all(records[index[i]].pc == stream[i] for i in (0, 1, 2, 3, 500, len(stream) - 1))
    # one fetch per distinct PC
    assert len(calls) == 6 and len({a for a, _ in calls}) == 6
    assert records == static[2:5] + static[:2] + [static[5]]

    # a second trace (other dtype) hits the cache only
    again, index2 = dec.decode_trace(stream.astype(np.uint64))
    assert len(calls) == 6
    assert all(a is b for a, b in zip(again, records))
    np.testing.assert_array_equal(index2, index)
    assert dec.at(int(loop_pcs[0])) is records[3] and len(calls) == 6


def test_decode_trace_long_stream(loop_region):
    code, base, fetch, calls = loop_region
    pcs = np.array([r.pc for r in decode_block(code, base)[:5]], dtype=np.uint64)
    stream = np.tile(pcs, 400_000)  # 2M dynamic instructions
    records, index = Decoder(fetch).decode_trace(stream)
    assert len(records) == 5 and len(calls) == 5
    assert np.array_equal(np.array([r.pc for r in records], dtype=np.uint64)[index], stream)


def test_decode_trace_edge_cases(loop_region):
    *_, fetch, calls = loop_region
    dec = Decoder(fetch)
    records, index = dec.decode_trace(np.array([], dtype=np.uint32))
    assert records == [] and index.dtype == np.int32 and index.size == 0
    with pytest.raises(ValueError):
        dec.decode_trace(np.zeros((2, 2), dtype=np.uint32))
    with pytest.raises(TypeError):
        dec.decode_trace(np.array([1.5, 2.5]))
    assert calls == []


def test_invalidate(loop_region):
    code, base, fetch, calls = loop_region
    dec = Decoder(fetch)
    dec.at(base)
    dec.invalidate(base + 1)  # overlaps the first instruction
    assert base not in dec
    dec.at(base)
    assert len(calls) == 2


# ---------------------------------------------------------------------------
# Errors
# ---------------------------------------------------------------------------


def test_undecodable_bytes_raise():
    with pytest.raises(DecodeError, match=r"0x00401234") as info:
        decode_one(b"\xff\xff", 0x401234)  # FF /7 is undefined
    assert "ff ff" in str(info.value)
    assert isinstance(info.value, ValueError)
    with pytest.raises(DecodeError):
        decode_one(b"", 0x1000)


def test_truncated_fetch_raises(asm):
    code = asm("mov eax, 0x12345678")
    dec = Decoder(lambda addr, n: code[:3])  # region ends mid-instruction
    with pytest.raises(DecodeError, match=r"0x00002000"):
        dec.at(0x2000)
    assert 0x2000 not in dec


def test_decoders_share_records_by_bytes_and_pc():
    """Decoders of one kernel share its records (the sort scene decodes each instruction once), but
    other bytes at the same PC are decoded as what they are."""
    add = b"\x01\xd8" + b"\x90" * 13   # add eax, ebx
    sub = b"\x29\xd8" + b"\x90" * 13   # sub eax, ebx
    a, b = Decoder(lambda pc, n: add[:n]), Decoder(lambda pc, n: add[:n])
    assert a.at(0x400000) is b.at(0x400000)
    other = Decoder(lambda pc, n: sub[:n]).at(0x400000)
    assert (a.at(0x400000).mnemonic, other.mnemonic) == ("add", "sub")
    assert Decoder(lambda pc, n: add[:n]).at(0x400010).pc == 0x400010
