# 16-bit float Z-buffer span (the article's format): depth interpolated as a 32-bit integer,
# converted with BSR/SHRD/SHRD to 5-bit exponent + 11-bit mantissa, compared as an unsigned 16-bit
# integer (the format keeps order) and stored with the 16-bit colour where nearer. Ties fail.
# As in the article EDX is not re-initialised per pixel: for depths below 2048 the low mantissa
# bits come from whatever EDX held (the previous pixel's depth or colour), and a depth of 0 keeps
# the previous exponent in ECX. Both buffers hold 16 bits per pixel, so one index walks them.
.intel_syntax noprefix
.text

# @entry fp16z_span(zbuf, fbuf, count, z, dz, colour) -> EAX = z after the span
.globl fp16z_span
.p2align 4, 0xCC                  # entry on a 16-byte fetch block (int3 fill)
fp16z_span:
    push    ebx
    push    esi
    push    edi
    push    ebp
    mov     edi, [esp+20]           # zbuf (uint16 per pixel)
    mov     esi, [esp+24]           # fbuf (uint16 per pixel)
    mov     ebp, [esp+28]           # count
    mov     eax, [esp+32]           # z
    mov     ebx, [esp+36]           # dz
    lea     edi, [edi+ebp*2]
    lea     esi, [esi+ebp*2]
    neg     ebp
    jz      .Ldone
    jmp     .Lpixel                  # skip the padding: it is never executed
.p2align 4, 0xCC                  # loop entry on a 16-byte fetch block
.Lpixel:
    bsr     ecx, eax
    shrd    edx, eax, cl
    shrd    edx, ecx, 21
    cmp     dx, [edi+ebp*2]
    jae     .Lhidden
    mov     [edi+ebp*2], dx
    mov     dx, [esp+40]            # colour
    mov     [esi+ebp*2], dx
.Lhidden:
    add     eax, ebx
    inc     ebp
    jnz     .Lpixel
.Ldone:
    pop     ebp
    pop     edi
    pop     esi
    pop     ebx
    ret

# @entry fp16z_frame(spans, nspans, zbuf, zwords, zclear) -> draws a frame of spans (see draw.inc)
.include "draw.inc"
DRAW_FRAME fp16z_frame, fp16z_span
