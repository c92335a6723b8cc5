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

# @entry tex9(dst, tex, count, u, v, du, dv) -> EAX = count
.globl tex9
tex9:
    SETUP
    mov cx, [esp+28]
    mov edi, [esp+20]
    jmp 9f
.p2align 4, 0xCC
9:
    mov al, [ebx]
    mov [edi], al
    add edx, esi
    adc bl, dl
    add eax, ecx
    adc bh, dh
    inc edi
    dec cx
    jnz 9b
    RESTORE

# @entry tex5(dst, tex, count, u, v, du, dv) -> EAX = count
.globl tex5
tex5:
    SETUP
    mov ebp, [esp+28]
    mov edi, [esp+20]
    jmp 5f
.p2align 4, 0xCC
5:
    mov al, [ebx]
    add edx, esi
    adc bl, dl
    add eax, ecx
    adc bh, dh
    mov [edi], al
    inc edi
    dec ebp
    jnz 5b
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
.p2align 4, 0xCC
4:
    mov al, [ebx]
    add edx, esi
    adc bl, dl
    add eax, ecx
    adc bh, dh
    mov [edi+ebp], al
    inc edi
    jnz 4b
    RESTORE
