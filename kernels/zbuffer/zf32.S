# 32-bit float Z-buffer span on the x87: depth interpolated on the FPU stack (at the precision the
# control word sets; 64-bit mantissa after FNINIT), compared with FCOM against the stored float,
# stored rounded to single precision with the 16-bit colour where strictly nearer. An unordered
# compare (a NaN) fails the test. The FPU stack is empty again on return.
.intel_syntax noprefix
.text

# @entry zf32_span(zbuf, fbuf, count, z, dz, colour) -> EAX = pixels written; z and dz are float32
.globl zf32_span
.p2align 4, 0xCC                  # entry on a 16-byte fetch block (int3 fill)
zf32_span:
    push    ebx
    push    esi
    push    edi
    push    ebp
    mov     edi, [esp+20]           # zbuf (float32 per pixel)
    mov     esi, [esp+24]           # fbuf (uint16 per pixel)
    mov     ecx, [esp+28]           # count
    mov     ebp, [esp+40]           # colour (low 16 bits)
    xor     ebx, ebx                # pixels written
    fld     dword ptr [esp+36]      # st0 = dz
    fld     dword ptr [esp+32]      # st0 = z, st1 = dz
    lea     edi, [edi+ecx*4]
    lea     esi, [esi+ecx*2]
    neg     ecx
    jz      .Ldone
    jmp     .Lpixel                  # skip the padding: it is never executed
.p2align 4, 0xCC                  # loop entry on a 16-byte fetch block
.Lpixel:
    fcom    dword ptr [edi+ecx*4]
    fnstsw  ax
    and     ah, 0x45                # C3, C2, C0
    cmp     ah, 0x01                # only "z below stored" passes
    jne     .Lhidden
    fst     dword ptr [edi+ecx*4]
    mov     [esi+ecx*2], bp
    inc     ebx
.Lhidden:
    fadd    st(0), st(1)
    inc     ecx
    jnz     .Lpixel
.Ldone:
    fstp    st(0)
    fstp    st(0)
    mov     eax, ebx
    pop     ebp
    pop     edi
    pop     esi
    pop     ebx
    ret

# @entry zf32_frame(spans, nspans, zbuf, zwords, zclear) -> draws a frame of spans (see draw.inc)
.include "draw.inc"
DRAW_FRAME zf32_frame, zf32_span
