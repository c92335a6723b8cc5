"""Test data: the user-mode instruction forms of the base IA-32 set, the x87, MMX, SSE and 3DNow! (Intel syntax,
memory operands at [esi]), one instruction per line, for tests/test_isa_forms.py.

Every operand kind is here at 8, 16 and 32 bits where the instruction has it: register,
memory and immediate (imm8 and full-size) operands; the string instructions with and without
REP/REPE/REPNE; the stack, flag, BCD, bit, segment-register and control-transfer forms; the whole
x87 set. A few forms exist only on some of the CPUs (CMOVcc, FCOMI, multi-byte NOP, FFREEP,
FXSAVE, PREFETCHh, SFENCE, ...): GNU as refuses them for the others, or sim/guest/isa.py does.
"""

R = {8: ("al", "cl"), 16: ("ax", "cx"), 32: ("eax", "ecx")}
M = {8: "byte ptr [esi]", 16: "word ptr [esi]", 32: "dword ptr [esi]", 64: "qword ptr [esi]",
     80: "tbyte ptr [esi]"}
IMM = {8: "5", 16: "300", 32: "70000"}  # imm8 / imm16 / imm32 encodings
SIZES = (8, 16, 32)


def integer_forms() -> list[str]:
    out = []
    for op in "add or adc sbb and sub xor cmp".split():
        for w in SIZES:
            dst, src = R[w][1], R[w][0]
            out += [f"{op} {dst}, {src}", f"{op} {dst}, {M[w]}", f"{op} {M[w]}, {dst}", f"{op} {dst}, {IMM[w]}",
                    f"{op} {M[w]}, {IMM[w]}", f"{op} {src}, {IMM[w]}"]  # the last: the accumulator form
            if w > 8:
                out += [f"{op} {dst}, 3", f"{op} {M[w]}, 3"]  # sign-extended imm8 (83 /r)
    for w in SIZES:
        dst, src = R[w][1], R[w][0]
        out += [f"test {dst}, {src}", f"test {M[w]}, {dst}", f"test {dst}, {IMM[w]}", f"test {M[w]}, {IMM[w]}",
                f"test {src}, {IMM[w]}",
                f"mov {dst}, {src}", f"mov {dst}, {M[w]}", f"mov {M[w]}, {dst}", f"mov {dst}, {IMM[w]}",
                f"mov {M[w]}, {IMM[w]}",
                f"xchg {dst}, {src}", f"xchg {M[w]}, {dst}", f"xadd {dst}, {src}", f"xadd {M[w]}, {dst}",
                f"cmpxchg {dst}, {src}", f"cmpxchg {M[w]}, {dst}",
                f"lock add {M[w]}, {dst}", f"lock xadd {M[w]}, {dst}", f"lock cmpxchg {M[w]}, {dst}",
                f"lock inc {M[w]}"]
        for op in "inc dec neg not mul imul div idiv".split():
            out += [f"{op} {dst}", f"{op} {M[w]}"]
        for op in "rol ror rcl rcr shl shr sar".split():
            out += [f"{op} {dst}, 1", f"{op} {dst}, cl", f"{op} {dst}, 3",
                    f"{op} {M[w]}, 1", f"{op} {M[w]}, cl", f"{op} {M[w]}, 3"]
    for w in (16, 32):
        dst, src = R[w][1], R[w][0]
        out += [f"imul {dst}, {src}", f"imul {dst}, {M[w]}", f"imul {dst}, {src}, 3", f"imul {dst}, {src}, {IMM[w]}",
                f"imul {dst}, {M[w]}, 3", f"imul {dst}, {M[w]}, {IMM[w]}"]
        for op in ("shld", "shrd"):
            out += [f"{op} {dst}, {src}, 3", f"{op} {dst}, {src}, cl", f"{op} {M[w]}, {src}, 3",
                    f"{op} {M[w]}, {src}, cl"]
        out += [f"bsf {dst}, {src}", f"bsf {dst}, {M[w]}", f"bsr {dst}, {src}", f"bsr {dst}, {M[w]}",
                f"lea {dst}, [esi+4]", f"push {dst}", f"pop {dst}", f"push {M[w]}", f"pop {M[w]}",
                f"cmove {dst}, {src}", f"cmovne {dst}, {M[w]}", f"xchg {src}, {src.replace('a', 'd')}"]
        for op in "bt bts btr btc".split():
            out += [f"{op} {dst}, {src}", f"{op} {dst}, 3", f"{op} {M[w]}, {src}", f"{op} {M[w]}, 3"]
    out += ["sete cl", "setne byte ptr [esi]", "setb byte ptr [esi]"]
    out += ["movzx ecx, al", "movzx ecx, byte ptr [esi]", "movzx ecx, ax", "movzx ecx, word ptr [esi]",
            "movzx cx, al", "movzx cx, byte ptr [esi]", "movsx ecx, al", "movsx ecx, byte ptr [esi]",
            "movsx ecx, ax", "movsx ecx, word ptr [esi]", "movsx cx, al", "movsx cx, byte ptr [esi]",
            "bswap ecx", "cmpxchg8b qword ptr [esi]", "lock cmpxchg8b qword ptr [esi]"]
    # stack and segment registers (MOV sreg,r / POP sreg load a segment register: system, refused)
    out += ["push 3", "push 70000", "pushad", "popad", "pushfd", "popfd", "pushaw", "popaw", "pushfw", "popfw",
            "push ds", "push es", "push fs", "push gs", "push ss", "push cs", "pop es", "pop ds", "pop fs", "pop gs",
            "mov cx, ds", "mov ecx, ds", "mov word ptr [esi], ds", "mov ds, cx", "mov ds, word ptr [esi]",
            "lds ecx, fword ptr [esi]", "les ecx, fword ptr [esi]", "lfs ecx, fword ptr [esi]",
            "lgs ecx, fword ptr [esi]", "lss ecx, fword ptr [esi]", "lds cx, dword ptr [esi]",
            "lfs cx, dword ptr [esi]"]
    # flags, conversions, BCD, miscellaneous
    out += ["cbw", "cwde", "cwd", "cdq", "clc", "stc", "cmc", "cld", "std", "sahf", "lahf",
            "daa", "das", "aaa", "aas", "aam", "aad", "aam 16", "aad 16", "xlatb", "nop", "cpuid", "rdtsc", "wait",
            "enter 16, 0", "enter 16, 1", "leave", "bound ecx, qword ptr [esi]", "bound cx, dword ptr [esi]",
            "mov eax, dword ptr ds:[0x1000]", "mov dword ptr ds:[0x1000], eax", "mov al, byte ptr ds:[0x1000]",
            "lea ecx, [esi+edi*4+8]", "lea cx, [esi]", "salc", "nop dword ptr [eax]", "nop word ptr [eax]",
            "pause", "prefetchnta byte ptr [esi]", "prefetch byte ptr [esi]", "sfence",
            "movnti dword ptr [esi], ecx"]
    # control transfers (a label '1:' follows every form)
    out += ["ret", "ret 4", "jmp ecx", "jmp dword ptr [esi]", "call ecx", "call dword ptr [esi]",
            "jecxz 1f", "jcxz 1f", "loop 1f", "loope 1f", "loopne 1f", "je 1f", "jmp 1f", "call 1f"]
    # strings: REP on MOVS/LODS/STOS, REPE and REPNE on SCAS/CMPS
    for s in "movs lods stos scas cmps".split():
        for suffix in "bwd":
            out.append(f"{s}{suffix}")
            if s in ("movs", "lods", "stos"):
                out.append(f"rep {s}{suffix}")
            else:
                out += [f"repe {s}{suffix}", f"repne {s}{suffix}"]
    return out


def x87_forms() -> list[str]:
    out = []
    for op in "fadd fsub fsubr fmul fdiv fdivr".split():
        out += [f"{op} dword ptr [esi]", f"{op} qword ptr [esi]", f"{op} st, st(1)", f"{op} st(1), st",
                f"{op}p st(1), st", f"fi{op[1:]} word ptr [esi]", f"fi{op[1:]} dword ptr [esi]"]
    out += ["fld dword ptr [esi]", "fld qword ptr [esi]", "fld tbyte ptr [esi]", "fld st(1)",
            "fst dword ptr [esi]", "fst qword ptr [esi]", "fst st(1)", "fstp dword ptr [esi]", "fstp qword ptr [esi]",
            "fstp tbyte ptr [esi]", "fstp st(1)", "fild word ptr [esi]", "fild dword ptr [esi]",
            "fild qword ptr [esi]", "fist word ptr [esi]", "fist dword ptr [esi]", "fistp word ptr [esi]",
            "fistp dword ptr [esi]", "fistp qword ptr [esi]", "fbld tbyte ptr [esi]", "fbstp tbyte ptr [esi]",
            "fcom dword ptr [esi]", "fcom qword ptr [esi]", "fcom st(1)", "fcomp dword ptr [esi]",
            "fcomp qword ptr [esi]", "fcomp st(1)", "fcompp", "fucom st(1)", "fucomp st(1)", "fucompp",
            "ficom word ptr [esi]", "ficom dword ptr [esi]", "ficomp word ptr [esi]", "ficomp dword ptr [esi]",
            "fcomi st, st(1)", "fcomip st, st(1)", "fucomi st, st(1)", "fucomip st, st(1)", "fcmove st, st(1)",
            "fcmovnbe st, st(1)", "ftst", "fxam", "fchs", "fabs", "fld1", "fldz", "fldpi", "fldl2e", "fldl2t",
            "fldlg2", "fldln2", "f2xm1", "fyl2x", "fyl2xp1", "fptan", "fpatan", "fxtract", "fprem", "fprem1",
            "fdecstp", "fincstp", "fsqrt", "fscale", "frndint", "fsin", "fcos", "fsincos", "fxch st(1)", "fxch",
            "ffree st(1)", "ffreep st(1)", "fnop", "fninit", "finit", "fnclex", "fclex", "fldcw word ptr [esi]",
            "fnstcw word ptr [esi]", "fstcw word ptr [esi]", "fnstsw ax", "fnstsw word ptr [esi]", "fstsw ax",
            "fnstenv [esi]", "fldenv [esi]", "fnsave [esi]", "frstor [esi]", "fwait", "fisttp dword ptr [esi]",
            "fxsave [esi]", "fxrstor [esi]", "ldmxcsr dword ptr [esi]", "stmxcsr dword ptr [esi]"]
    return out


MMX = ("packssdw packsswb packuswb paddb paddd paddsb paddsw paddusb paddusw paddw pand pandn pcmpeqb pcmpeqd "
       "pcmpeqw pcmpgtb pcmpgtd pcmpgtw pmaddwd pmulhw pmullw por psllw pslld psllq psraw psrad psrlw psrld psrlq "
       "psubb psubd psubsb psubsw psubusb psubusw psubw punpckhbw punpckhdq punpckhwd punpcklbw punpckldq "
       "punpcklwd pxor").split()
SSE_MMX = "pavgb pavgw pmaxsw pmaxub pminsw pminub pmulhuw psadbw".split()  # MMX-register forms added by SSE
SSE = ("addps addss andnps andps divps divss maxps maxss minps minss mulps mulss orps rcpps rcpss rsqrtps rsqrtss "
       "sqrtps sqrtss subps subss unpckhps unpcklps xorps comiss ucomiss").split()
NOW3 = ("pavgusb pf2id pfacc pfadd pfcmpeq pfcmpge pfcmpgt pfmax pfmin pfmul pfrcp pfrcpit1 pfrcpit2 pfrsqit1 "
        "pfrsqrt pfsub pfsubr pi2fd pmulhrw").split()


def simd_forms() -> list[str]:
    """MMX (with its memory and shift-by-immediate forms), the SSE set of the Pentium III (with its
    MMX-register additions and cacheability instructions) and 3DNow! of the K6-2."""
    out = []
    for m in MMX:
        out += [f"{m} mm0, mm1", f"{m} mm0, qword ptr [esi]"] + ([f"{m} mm0, 3"] if m[:3] in ("psl", "psr") else [])
    out += ["movd mm0, eax", "movd eax, mm0", "movd mm0, dword ptr [esi]", "movd dword ptr [esi], mm0",
            "movq mm0, mm1", "movq mm0, qword ptr [esi]", "movq qword ptr [esi], mm0", "emms"]
    for m in SSE_MMX:
        out += [f"{m} mm0, mm1", f"{m} mm0, qword ptr [esi]"]
    out += ["pshufw mm0, mm1, 3", "pshufw mm0, qword ptr [esi], 3", "pextrw eax, mm0, 1", "pinsrw mm0, eax, 1",
            "pinsrw mm0, word ptr [esi], 1", "pmovmskb eax, mm0", "maskmovq mm0, mm1", "movntq qword ptr [esi], mm0",
            "prefetcht0 byte ptr [esi]", "prefetcht1 byte ptr [esi]", "prefetcht2 byte ptr [esi]"]
    for m in SSE:
        out += [f"{m} xmm0, xmm1", f"{m} xmm0, {'dword' if m.endswith('ss') else 'xmmword'} ptr [esi]"]
    out += ["cmpps xmm0, xmm1, 1", "cmpps xmm0, xmmword ptr [esi], 1", "cmpss xmm0, xmm1, 1",
            "cmpss xmm0, dword ptr [esi], 1", "cmpeqps xmm0, xmm1", "cmpltss xmm0, xmm1",
            "shufps xmm0, xmm1, 3", "shufps xmm0, xmmword ptr [esi], 3", "movaps xmm0, xmm1",
            "movaps xmm0, xmmword ptr [esi]", "movaps xmmword ptr [esi], xmm0", "movups xmm0, xmm1",
            "movups xmm0, xmmword ptr [esi]", "movups xmmword ptr [esi], xmm0", "movss xmm0, xmm1",
            "movss xmm0, dword ptr [esi]", "movss dword ptr [esi], xmm0", "movhps xmm0, qword ptr [esi]",
            "movhps qword ptr [esi], xmm0", "movlps xmm0, qword ptr [esi]", "movlps qword ptr [esi], xmm0",
            "movhlps xmm0, xmm1", "movlhps xmm0, xmm1", "movmskps eax, xmm0", "movntps xmmword ptr [esi], xmm0",
            "cvtpi2ps xmm0, mm0", "cvtpi2ps xmm0, qword ptr [esi]", "cvtps2pi mm0, xmm0",
            "cvtps2pi mm0, qword ptr [esi]", "cvttps2pi mm0, xmm0", "cvttps2pi mm0, qword ptr [esi]",
            "cvtsi2ss xmm0, eax", "cvtsi2ss xmm0, dword ptr [esi]", "cvtss2si eax, xmm0",
            "cvtss2si eax, dword ptr [esi]", "cvttss2si eax, xmm0", "cvttss2si eax, dword ptr [esi]"]
    for m in NOW3:
        out += [f"{m} mm0, mm1", f"{m} mm0, qword ptr [esi]"]
    out += ["femms", "prefetchw byte ptr [esi]"]
    return out


def forms() -> list[str]:
    return integer_forms() + x87_forms() + simd_forms()
