# 32-bit integer Z-buffer span: depth interpolated in 32-bit fixed point (wrapping modulo 2^32,
# as the hardware does), tested unsigned "nearer if smaller", 32-bit depth and 16-bit colour stored
# where the test passes. Ties fail. One index register walks both buffers from -count up to 0.
.intel_syntax noprefix
.text

# @entry z32_span(zbuf, fbuf, count, z, dz, colour) -> EAX = z after the span
.globl z32_span
.p2align 4, 0xCC                  # entry on a 16-byte fetch block (int3 fill)
z32_span:
    push    ebx
    push    esi
    push    edi
    push    ebp
    mov     edi, [esp+20]           # zbuf (uint32 per pixel)
    mov     esi, [esp+24]           # fbuf (uint16 per pixel)
    mov     ecx, [esp+28]           # count
    mov     eax, [esp+32]           # z
    mov     ebx, [esp+36]           # dz
    mov     ebp, [esp+40]           # colour (low 16 bits)
    lea     edi, [edi+ecx*4]
    lea     esi, [esi+ecx*2]
    neg     ecx
    jz      .Ldone
    jmp     .Lpixel                  # skip the padding: it is never executed
.p2align 4, 0xCC                  # loop entry on a 16-byte fetch block
.Lpixel:
    cmp     eax, [edi+ecx*4]
    jae     .Lhidden
    mov     [edi+ecx*4], eax
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

# @entry z32_frame(spans, nspans, zbuf, zwords, zclear) -> draws a frame of spans (see draw.inc)
.include "draw.inc"
DRAW_FRAME z32_frame, z32_span
