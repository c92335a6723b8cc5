# Perspective-correct span renderers of "Texture Mapping Optimization for Games" (John DiCamillo),
# one per optimisation step of the article (the texture-article scene, sim/texture_scene.py):
#   a  the tight inner loop alone: the 9-instruction loop, every float-to-int conversion through a
#      call to _ftol (as MSVC compiled a C cast), the divide waited for right away (FSTP after FDIV),
#      the x87 in the MSVC runtime's 53-bit precision
#   b  the divide overlapped with the inner loop (FLD1 / FDIV before it, FSTP after it) and the x87
#      in 24-bit precision for the whole span (FSTCW / AND / FLDCW as the article shows; restored
#      on return); still _ftol
#   c  FISTP instead of _ftol (the article's UPDATE_U_V macro, also twice in the per-span set-up),
#      and the reordered 5-clock inner loop
#   d  c with the 4-clock loop the article proposes (count and pointer combined)
#   e  d's outer loop with 24.8 instead of 16.16 fixed point (the article's note; it shows no 24.8
#      loop, so the one below is ours: v carries the texture base, u's integer part is in CH)
#
# Span record (64 bytes, sim/texture_scene.py writes them): +0 dst, +4 count, +16 a, +24 b, +32 c
# (doubles: u/w, v/w, 1/w at the centre of the span's first pixel), +40 A, +48 B, +56 C (doubles:
# their steps over 16 pixels). The article's algorithm per span: u0, v0 from a, b, c; a += A ...;
# u1, v1; then per sub-span of run = min(count, 16) pixels: du = (u1 - u0) >> 4, dv likewise, the
# inner loop from u0, v0, then a += A ..., 1/c, u0 = u1, u1 = a / c * 65536 (256 for e).
# Each sub-span restarts the inner loop from u0, v0 (so a's 9-instruction loop, whose ADD EAX,ECX
# adds the count in CX into AX, starts each sub-span with AX = 0 and cannot carry into Vf within
# 16 pixels).
# Hazard kept on purpose (e): v must stay within 0..256 texels (the texture base rides above it);
# the scene's texture coordinates are checked for it (sim/texture_scene.py).
.intel_syntax noprefix
.text

.include "span_loops.inc"

# frame of the span functions (after 4 pushes and SUB ESP, FRAME): locals, then return, rec, tex
.equ FRAME, 80
.equ L_A, 0
.equ L_B, 8
.equ L_C, 16
.equ L_CINV, 24
.equ L_U0, 32
.equ L_V0, 36
.equ L_U1, 40
.equ L_V1, 44
.equ L_CNT, 48
.equ L_DST, 52
.equ L_REC, 56
.equ L_RUN, 60
.equ L_TEX, 64
.equ L_OLDCW, 68
.equ L_CW, 70
.equ A_REC, FRAME + 20
.equ A_TEX, FRAME + 24

.macro SPAN_ENTER
    push ebp
    push ebx
    push esi
    push edi
    sub esp, FRAME
    mov eax, [esp+A_REC]
    mov [esp+L_REC], eax
    mov ecx, [esp+A_TEX]
    mov [esp+L_TEX], ecx
    mov ecx, [eax]
    mov [esp+L_DST], ecx
    mov ecx, [eax+4]
    mov [esp+L_CNT], ecx
    fld qword ptr [eax+16]
    fstp qword ptr [esp+L_A]
    fld qword ptr [eax+24]
    fstp qword ptr [esp+L_B]
    fld qword ptr [eax+32]
    fstp qword ptr [esp+L_C]
.endm

.macro SPAN_LEAVE
    add esp, FRAME
    pop edi
    pop esi
    pop ebx
    pop ebp
    ret
.endm

# the article's "Put the FPU in 32 bit mode" and its restore
.macro LOW_PRECISION
    fstcw [esp+L_OLDCW]
    mov ax, [esp+L_OLDCW]
    and eax, ~0x0300
    mov [esp+L_CW], ax
    fldcw [esp+L_CW]
.endm

.macro RESTORE_PRECISION
    fldcw [esp+L_OLDCW]
.endm

# cinv = 1.0 / c, waited for
.macro RECIP
    fld1
    fdiv qword ptr [esp+L_C]
    fstp qword ptr [esp+L_CINV]
.endm

# a += A; b += B; c += C
.macro STEP
    mov eax, [esp+L_REC]
    fld qword ptr [esp+L_A]
    fadd qword ptr [eax+40]
    fstp qword ptr [esp+L_A]
    fld qword ptr [esp+L_B]
    fadd qword ptr [eax+48]
    fstp qword ptr [esp+L_B]
    fld qword ptr [esp+L_C]
    fadd qword ptr [eax+56]
    fstp qword ptr [esp+L_C]
.endm

# u = (long)(a * cinv * 65536.0); v = (long)(b * cinv * 65536.0), as compiled C: two _ftol calls
.macro FTOL_UV u, v
    fld qword ptr [esp+L_A]
    fmul qword ptr [esp+L_CINV]
    fmul qword ptr [k65536]
    call _ftol
    mov [esp+\u], eax
    fld qword ptr [esp+L_B]
    fmul qword ptr [esp+L_CINV]
    fmul qword ptr [k65536]
    call _ftol
    mov [esp+\v], eax
.endm

# the article's UPDATE_U_V: one multiply shared, FISTP (round to nearest) instead of _ftol
.macro UPDATE_UV u, v, scale
    fld qword ptr [\scale]
    fmul qword ptr [esp+L_CINV]
    fld st(0)
    fmul qword ptr [esp+L_A]
    fistp dword ptr [esp+\u]
    fmul qword ptr [esp+L_B]
    fistp dword ptr [esp+\v]
.endm

# run = min(count, 16); EDX = u0, EAX = v0, ESI = du = (u1 - u0) >> 4, ECX = dv
.macro DELTAS
    mov eax, [esp+L_CNT]
    cmp eax, 16
    jbe 1f
    mov eax, 16
1:
    mov [esp+L_RUN], eax
    mov edx, [esp+L_U0]
    mov eax, [esp+L_V0]
    mov esi, [esp+L_U1]
    sub esi, edx
    sar esi, 4
    mov ecx, [esp+L_V1]
    sub ecx, eax
    sar ecx, 4
.endm

# the article's Table 1 from EDX = u0, EAX = v0, ESI = du, ECX = dv (16.16): EBX = tex | Vi | Ui,
# EDX = Uf | dVi | dUi, ESI = dUf << 16, EAX = Vf << 16, ECX = dVf << 16; EDI = dst
.macro REGS16
    mov ebx, edx
    shr ebx, 16
    and ebx, 0xFF
    mov edi, eax
    shr edi, 8
    and edi, 0xFF00
    or ebx, edi
    or ebx, [esp+L_TEX]
    shl edx, 16
    shl eax, 16
    mov edi, esi
    shr edi, 16
    and edi, 0xFF
    or edx, edi
    mov edi, ecx
    shr edi, 8
    and edi, 0xFF00
    or edx, edi
    shl esi, 16
    shl ecx, 16
    mov edi, [esp+L_DST]
.endm

# u0 = u1; v0 = v1; dst += run; count -= run (flags: ZF when the span is done)
.macro ADVANCE
    mov eax, [esp+L_U1]
    mov [esp+L_U0], eax
    mov eax, [esp+L_V1]
    mov [esp+L_V0], eax
    mov eax, [esp+L_RUN]
    add [esp+L_DST], eax
    sub [esp+L_CNT], eax
.endm

# The MSVC run-time's float-to-long conversion as the article describes it (and as MSVC 4-6
# shipped it): a call, a frame, the control word saved, set to truncation and restored around a
# 64-bit FISTP. ST(0) in, EAX (EDX: high half) out, ST(0) popped.
.globl _ftol
_ftol:
    push ebp
    mov ebp, esp
    add esp, -12
    wait
    fnstcw [ebp-2]
    wait
    mov ax, [ebp-2]
    or ah, 0x0C
    mov [ebp-4], ax
    fldcw [ebp-4]
    fistp qword ptr [ebp-12]
    fldcw [ebp-2]
    mov eax, [ebp-12]
    mov edx, [ebp-8]
    leave
    ret

# @entry ftol_of(x) -> EAX = _ftol of the double at x, EDX = the control word after the call
.globl ftol_of
ftol_of:
    mov eax, [esp+4]
    fld qword ptr [eax]
    call _ftol
    sub esp, 4
    fnstcw [esp]
    movzx edx, word ptr [esp]
    add esp, 4
    ret

# ---------------------------------------------------------------------------------------------
# (a) naive
.globl span_a
span_a:
    SPAN_ENTER
    RECIP
    FTOL_UV L_U0, L_V0
    STEP
    RECIP
    FTOL_UV L_U1, L_V1
    cmp dword ptr [esp+L_CNT], 0
    je 9f
0:
    DELTAS
    REGS16
    mov cx, [esp+L_RUN]
    jmp 2f
    LOOP9 2
    STEP
    RECIP
    ADVANCE
    FTOL_UV L_U1, L_V1
    cmp dword ptr [esp+L_CNT], 0
    jne 0b
9:
    SPAN_LEAVE

# (b) divide overlapped, 24-bit precision
.globl span_b
span_b:
    SPAN_ENTER
    LOW_PRECISION
    RECIP
    FTOL_UV L_U0, L_V0
    STEP
    RECIP
    FTOL_UV L_U1, L_V1
    cmp dword ptr [esp+L_CNT], 0
    je 9f
0:
    STEP
    fld1
    fdiv qword ptr [esp+L_C]
    DELTAS
    REGS16
    mov cx, [esp+L_RUN]
    jmp 2f
    LOOP9 2
    fstp qword ptr [esp+L_CINV]
    ADVANCE
    FTOL_UV L_U1, L_V1
    cmp dword ptr [esp+L_CNT], 0
    jne 0b
9:
    RESTORE_PRECISION
    SPAN_LEAVE

# (c) FISTP, reordered loop, UPDATE_U_V in the set-up
.globl span_c
span_c:
    SPAN_ENTER
    LOW_PRECISION
    RECIP
    UPDATE_UV L_U0, L_V0, k65536
    STEP
    RECIP
    UPDATE_UV L_U1, L_V1, k65536
    cmp dword ptr [esp+L_CNT], 0
    je 9f
0:
    STEP
    fld1
    fdiv qword ptr [esp+L_C]
    DELTAS
    REGS16
    mov ebp, [esp+L_RUN]
    jmp 2f
    LOOP5 2
    fstp qword ptr [esp+L_CINV]
    ADVANCE
    UPDATE_UV L_U1, L_V1, k65536
    cmp dword ptr [esp+L_CNT], 0
    jne 0b
9:
    RESTORE_PRECISION
    SPAN_LEAVE

# (d) the 4-clock loop: EDI runs from -run to 0, EBP = dst + run
.globl span_d
span_d:
    SPAN_ENTER
    LOW_PRECISION
    RECIP
    UPDATE_UV L_U0, L_V0, k65536
    STEP
    RECIP
    UPDATE_UV L_U1, L_V1, k65536
    cmp dword ptr [esp+L_CNT], 0
    je 9f
0:
    STEP
    fld1
    fdiv qword ptr [esp+L_C]
    DELTAS
    REGS16
    mov ebp, [esp+L_RUN]
    add ebp, edi
    mov edi, [esp+L_RUN]
    neg edi
    jmp 2f
    LOOP4 2
    fstp qword ptr [esp+L_CINV]
    ADVANCE
    UPDATE_UV L_U1, L_V1, k65536
    cmp dword ptr [esp+L_CNT], 0
    jne 0b
9:
    RESTORE_PRECISION
    SPAN_LEAVE

# (e) 24.8: EDX = tex | v (Vi in DH, Vf in DL), ECX = u (Ui in CH), ESI = du, EBP = dv,
# EAX = (run - 1) << 8 counts down above AL; EBX is formed one pixel ahead (no AGI)
.globl span_e
span_e:
    SPAN_ENTER
    LOW_PRECISION
    RECIP
    UPDATE_UV L_U0, L_V0, k256
    STEP
    RECIP
    UPDATE_UV L_U1, L_V1, k256
    cmp dword ptr [esp+L_CNT], 0
    je 9f
0:
    STEP
    fld1
    fdiv qword ptr [esp+L_C]
    DELTAS
    mov ebp, ecx
    mov ecx, edx
    mov edx, eax
    and edx, 0xFFFF
    or edx, [esp+L_TEX]
    mov ebx, edx
    mov bl, ch
    add edx, ebp
    add ecx, esi
    mov eax, [esp+L_RUN]
    dec eax
    shl eax, 8
    mov edi, [esp+L_DST]
    jmp 2f
.p2align 4, 0xCC
2:
    mov al, [ebx]
    mov ebx, edx
    mov bl, ch
    add edx, ebp
    add ecx, esi
    mov [edi], al
    inc edi
    sub eax, 256
    jnc 2b
    fstp qword ptr [esp+L_CINV]
    ADVANCE
    UPDATE_UV L_U1, L_V1, k256
    cmp dword ptr [esp+L_CNT], 0
    jne 0b
9:
    RESTORE_PRECISION
    SPAN_LEAVE

# ---------------------------------------------------------------------------------------------
# Frame drivers: the x87 as the MSVC run-time leaves it (53-bit precision, round to nearest), then
# DrawSpan for every record, then back to the FNINIT word.
.macro FRAME_DRIVER name, span
.globl \name
\name:
    push ebx
    push esi
    push edi
    fldcw [cw_msvc]
    mov esi, [esp+16]
    mov edi, [esp+20]
    mov ebx, [esp+24]
    test edi, edi
    jz 9f
1:
    push ebx
    push esi
    call \span
    add esp, 8
    add esi, 64
    dec edi
    jnz 1b
9:
    fldcw [cw_fninit]
    mov eax, [esp+20]
    pop edi
    pop esi
    pop ebx
    ret
.endm

# @entry frame_a(records, nspans, tex) -> EAX = nspans
FRAME_DRIVER frame_a, span_a
# @entry frame_b(records, nspans, tex) -> EAX = nspans
FRAME_DRIVER frame_b, span_b
# @entry frame_c(records, nspans, tex) -> EAX = nspans
FRAME_DRIVER frame_c, span_c
# @entry frame_d(records, nspans, tex) -> EAX = nspans
FRAME_DRIVER frame_d, span_d
# @entry frame_e(records, nspans, tex) -> EAX = nspans
FRAME_DRIVER frame_e, span_e

# ---------------------------------------------------------------------------------------------
# Probes for the article's component figures (sim/texture_scene.py times each at n and 2n and
# takes the difference per iteration): n conversions of the double at x, through a call to
# _ftol, through FISTP, or neither (FLD / FSTP ST(0): the baseline both are compared with).
# The x87 is in the MSVC run-time's 53-bit precision, as in variant a.
.macro PROBE name, body
.globl \name
\name:
    fldcw [cw_msvc]
    mov ecx, [esp+4]
    sub esp, 8
    jmp 1f
.p2align 4, 0xCC
1:
    mov eax, [esp+16]
    fld qword ptr [eax]
    \body
    dec ecx
    jnz 1b
    add esp, 8
    fldcw [cw_fninit]
    mov eax, [esp+4]
    ret
.endm

.macro BODY_FTOL
    call _ftol
    mov [esp], eax
.endm

.macro BODY_FISTP
    fistp dword ptr [esp]
.endm

.macro BODY_NONE
    fstp st(0)
.endm

# @entry probe_ftol(n, x) -> EAX = n
PROBE probe_ftol, BODY_FTOL
# @entry probe_fistp(n, x) -> EAX = n
PROBE probe_fistp, BODY_FISTP
# @entry probe_none(n, x) -> EAX = n
PROBE probe_none, BODY_NONE

# The article's self-timing macro, TIMESNAP(clock): PUSH EAX / PUSH EDX / RDTSC / MOV clock,EAX /
# POP EDX / POP EAX, with clock a local at [esp+off] (as seen before the pushes).
.macro TIMESNAP off
    push eax
    push edx
    rdtsc
    mov [esp+8+\off], eax
    pop edx
    pop eax
.endm

# @entry snap_ftol(x) -> EAX = stop - start around one _ftol conversion of the double at x
.globl snap_ftol
snap_ftol:
    fldcw [cw_msvc]
    mov ecx, [esp+4]
    sub esp, 8
    TIMESNAP 0
    fld qword ptr [ecx]
    call _ftol
    TIMESNAP 4
    mov eax, [esp+4]
    sub eax, [esp]
    add esp, 8
    fldcw [cw_fninit]
    ret

# @entry snap_none() -> EAX = stop - start of two back-to-back TIMESNAPs (the article's overhead)
.globl snap_none
snap_none:
    sub esp, 8
    TIMESNAP 0
    TIMESNAP 4
    mov eax, [esp+4]
    sub eax, [esp]
    add esp, 8
    ret

.section .rodata
.p2align 3
k65536:    .double 65536.0
k256:      .double 256.0
cw_msvc:   .short 0x027F    # MSVC run-time default: exceptions masked, 53-bit, round to nearest
cw_fninit: .short 0x037F    # FNINIT: 64-bit
