# 16-bit float Z-buffer span without BSR, for the AMD K6: the article's format (5-bit exponent =
# index of the highest set bit, 11-bit mantissa = the 11 bits below it, leading one dropped) and
# the rest of kernels/zbuffer/fp16z.S unchanged (interface, 32-bit wrapping interpolation, unsigned
# 16-bit compare where ties fail, stores), only the conversion differs.
#
# Why: on the K6 BSR is a vector-decoded ROM sequence of ~10 clocks and SHLD/SHRD are vector
# decoded too (sim/cpus/k6/k6.toml), so BSR/SHRD/SHRD costs the K6 about 14 decode clocks a
# pixel. The conversion below uses only short-decodable instructions (<= 7 bytes, one RISC86 op
# each, no 0x66 prefix, no byte-register writes, so no partial-register merges): two MOV, two SHR,
# one table load, AND, ADD and a JZ that is not taken for depths >= 2^24.
#
#   mov  ecx, eax             ; z
#   mov  edx, eax
#   shr  ecx, 24              ; top byte b; ZF when z < 2^24 -> the rare path below
#   jz   .Lsmall
#   mov  ecx, [fp16t_table+ecx*4]   ; ((e - 1) << 11) | (e - 11), e = 24 + msb(b)
#   shr  edx, cl              ; z >> (e - 11) = 1mmmmmmmmmmm (leading one at bit 11)
#   and  ecx, -32             ; drop the shift count: (e - 1) << 11
#   add  edx, ecx             ; the leading one carries into the exponent: DX = e << 11 | mantissa
#
# The table has 256 dwords (1 KB, 32 cache lines) indexed by the top byte: one entry holds both
# the shift count (SHR uses only CL's low 5 bits) and the exponent already shifted into place
# (bits 11..15; its low 11 bits are zero, which the AND restores). Alternatives measured on the
# models (warm span loop, depth test failing, cycles per pixel K6-233 / Pentium II-233; fp16z is
# 18 / 8): this sequence 8 / 7; a byte or dword count table plus an exponent table indexed by the
# count (ADD EDX,[exp+ECX*4]) 8-9 / 9; a word table read with MOVZX 9 / 8; adding the exponent
# with ADD DH,CH (one instruction fewer) 9 / 14, because CMP DX then reads DX after a write to DH
# (a partial-register merge on the K6, a partial-register stall on the P6).
#
# Depths below 2^24 (top byte 0) take .Lsmall: z = 0 encodes as 0 (as z = 1 does in the hazard-free
# format); otherwise z is shifted left a byte at a time until its top byte is non-zero, converted
# with the same table, and 8 << 11 taken off per byte shifted (each byte lowers the exponent by 8,
# and shifting left never loses a bit that the mantissa keeps). The result always equals
# sim.reference.fp16z_encode(z): no stale register reaches it (EDX and ECX are fully rewritten for
# every pixel), so fp16z's hazards (z < 2048 with a stale EDX, z = 0 with a stale ECX) do not exist
# here. Both buffers hold 16 bits per pixel, so one index walks them.
.intel_syntax noprefix

.include "fp16t_table.inc"

.text

# @entry fp16t_span(zbuf, fbuf, count, z, dz, colour) -> EAX = z after the span
.globl fp16t_span
.p2align 4, 0xCC                  # entry on a 16-byte fetch block (int3 fill)
fp16t_span:
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
    mov     ecx, eax
    mov     edx, eax
    shr     ecx, 24                 # top byte of z
    jz      .Lsmall                 # z < 2^24: rarely taken
    mov     ecx, [fp16t_table+ecx*4]
    shr     edx, cl                 # 0x800 | mantissa
    and     ecx, -32                # (e - 1) << 11
    add     edx, ecx                # DX = e << 11 | mantissa
.Ltest:
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

# z < 2^24 (EDX = z, ECX = 0): back to .Ltest with DX = fp16z_encode(z).
.Lsmall:
    test    edx, edx
    jz      .Ltest                  # z = 0: DX = 0
    push    eax                     # a register for the exponent correction (z is restored)
    xor     eax, eax
.Lnormalise:
    sub     eax, 8 << 11            # one byte shifted in: exponent 8 lower
    shl     edx, 8
    mov     ecx, edx
    shr     ecx, 24
    jz      .Lnormalise             # at most three times: z != 0
    mov     ecx, [fp16t_table+ecx*4]
    shr     edx, cl
    and     ecx, -32
    add     edx, ecx                # the encoding of z << 8k (exponent e + 8k, the same mantissa)
    add     edx, eax                # EDX = e << 11 | mantissa (never below 0: z >= 1)
    pop     eax
    jmp     .Ltest

# @entry fp16t_frame(spans, nspans, zbuf, zwords, zclear) -> draws a frame of spans (see draw.inc)
.include "draw.inc"
DRAW_FRAME fp16t_frame, fp16t_span
