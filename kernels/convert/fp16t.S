# 32-bit integer depth -> 16-bit float depth without BSR (the K6 variant of kernels/convert/fp16z.S):
# a 256-dword table indexed by the top byte gives both the shift that brings the 11 bits below
# the highest set bit down to the mantissa and the exponent already shifted into place,
#     mov ecx,eax / mov edx,eax / shr ecx,24 / jz small / mov ecx,[table+ecx*4]
#     shr edx,cl / and ecx,-32 / add edx,ecx
# and a rarely taken path for z < 2^24 shifts z left a byte at a time and lowers the exponent by 8
# per byte. The sequence and its reasons are in kernels/zbuffer/fp16t.S, whose span loop uses the
# same instructions and the same table. The result equals sim.reference.fp16z_encode(z) for every
# z: nothing stale enters it (no hazards to preset, unlike fp16z_convert_array).
.intel_syntax noprefix

.include "../zbuffer/fp16t_table.inc"

.text

# @entry fp16t_convert(z) -> EAX = the 16-bit float (upper half 0)
.globl fp16t_convert
.p2align 4, 0xCC                  # entry on a 16-byte fetch block (int3 fill)
fp16t_convert:
    mov     eax, [esp+4]
    call    convert
    mov     eax, edx
    ret

# @entry fp16t_convert_array(src, dst, count) -> EAX = count; dst[i] (uint16) = the 16-bit float of src[i] (uint32)
.globl fp16t_convert_array
.p2align 4, 0xCC                  # entry on a 16-byte fetch block (int3 fill)
fp16t_convert_array:
    push    esi
    push    edi
    push    ebp
    mov     esi, [esp+16]           # src (uint32[count])
    mov     edi, [esp+20]           # dst (uint16[count])
    mov     ebp, [esp+24]           # count
    test    ebp, ebp
    jz      .Ldone
.Lnext:
    mov     eax, [esi]
    call    convert
    mov     [edi], dx
    add     esi, 4
    add     edi, 2
    dec     ebp
    jnz     .Lnext
.Ldone:
    mov     eax, [esp+24]
    pop     ebp
    pop     edi
    pop     esi
    ret

# EAX = z -> EDX = the 16-bit float (upper half 0); ECX destroyed, EAX kept.
.p2align 4, 0xCC
convert:
    mov     ecx, eax
    mov     edx, eax
    shr     ecx, 24                 # top byte of z
    jz      .Lsmall                 # z < 2^24: rarely taken
    mov     ecx, [fp16t_table+ecx*4]
    shr     edx, cl                 # 0x800 | mantissa
    and     ecx, -32                # (e - 1) << 11
    add     edx, ecx                # e << 11 | mantissa
    ret
.Lsmall:
    test    edx, edx
    jz      .Lzero                  # z = 0: 0
    push    eax
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
    add     edx, ecx                # the encoding of z << 8k
    add     edx, eax                # minus 8k << 11
    pop     eax
.Lzero:
    ret
