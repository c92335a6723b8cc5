# Texture-mapping span inner loops from "Texture Mapping Optimization for Games" (John DiCamillo):
# the 9-instruction loop, the reordered 5-clock loop, and the 4-clock loop the article proposes but
# never built (the count decrement and the pointer increment combined: EDI runs from -count to 0
# and addresses the span through EBP = dst + count).
#
# Register layout (the article's Table 1): EBX = texture base | Vi << 8 | Ui (rows on 256-byte
# boundaries, the texture on a 64 KB boundary), EDX = Uf << 16 | dVi << 8 | dUi, ESI = dUf << 16,
# EAX = Vf << 16 | colour in AL, ECX = dVf << 16 (| count in CX for tex9), EDI = screen pointer.
# u, v, du, dv are 16.16 fixed point; Ui, Vi wrap modulo 256.
#
# Hazard kept on purpose (the article's own): in tex9, ADD EAX,ECX also adds the count in CX to
# AX, so AH accumulates counts and a carry out of AX perturbs Vf by one 1/65536 step. The
# reference (sim/texture.py) reproduces it; tex5 and tex4 clear CX and draw the exact 16.16 span.
# Count: 1..65535 for tex9 (a 16-bit counter), >= 1 for tex5 and tex4.
.intel_syntax noprefix
.text

.include "span_frame.inc"
.include "span_loops.inc"

# @entry tex9(dst, tex, count, u, v, du, dv) -> EAX = count
.globl tex9
tex9:
    SETUP
    mov cx, [esp+28]
    mov edi, [esp+20]
    jmp 9f
    LOOP9 9
    RESTORE

# @entry tex5(dst, tex, count, u, v, du, dv) -> EAX = count
.globl tex5
tex5:
    SETUP
    mov ebp, [esp+28]
    mov edi, [esp+20]
    jmp 5f
    LOOP5 5
    RESTORE

# @entry tex4(dst, tex, count, u, v, du, dv) -> EAX = count
.globl tex4
tex4:
    SETUP
    mov ebp, [esp+20]
    mov edi, [esp+28]
    add ebp, edi
    neg edi
    jmp 4f
    LOOP4 4
    RESTORE
