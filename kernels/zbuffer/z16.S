# 16-bit integer Z-buffer span: depth interpolated in 32-bit fixed point, its top 16 bits tested
# unsigned "nearer if smaller" and stored with the 16-bit colour where the test passes. Ties fail.
.intel_syntax noprefix
.text

# @entry z16_span(zbuf, fbuf, count, z, dz, colour) -> EAX = z after the span
.globl z16_span
.p2align 4, 0xCC                  # entry on a 16-byte fetch block (int3 fill)
z16_span:
    push    ebx
    push    esi
    push    edi
    push    ebp
    mov     edi, [esp+20]           # zbuf (uint16 per pixel)
    mov     esi, [esp+24]           # fbuf (uint16 per pixel)
    mov     ecx, [esp+28]           # count
    mov     eax, [esp+32]           # z (16.16: the depth is the top half)
    mov     ebx, [esp+36]           # dz
    mov     ebp, [esp+40]           # colour (low 16 bits)
    lea     edi, [edi+ecx*2]
    lea     esi, [esi+ecx*2]
    neg     ecx
    jz      .Ldone
    jmp     .Lpixel                  # skip the padding: it is never executed
.p2align 4, 0xCC                  # loop entry on a 16-byte fetch block
.Lpixel:
    mov     edx, eax
    shr     edx, 16
    cmp     dx, [edi+ecx*2]
    jae     .Lhidden
    mov     [edi+ecx*2], dx
    mov     [esi+ecx*2], bp
.Lhidden:
    add     eax, ebx
    inc     ecx
    jnz     .Lpixel
.Ldone:
    pop     ebp
    pop     edi
    pop     esi
    pop     ebx
    ret

# @entry z16_frame(spans, nspans, zbuf, zwords, zclear) -> draws a frame of spans (see draw.inc)
.include "draw.inc"
DRAW_FRAME z16_frame, z16_span
