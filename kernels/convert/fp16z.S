# 32-bit integer depth -> 16-bit float depth: 5-bit exponent (the index of the highest set bit)
# over an 11-bit mantissa (the 11 bits below it). The order of the integers is kept, so the result
# compares as an unsigned 16-bit integer. The conversion is the article's three instructions:
#     BSR ECX,EAX / SHRD EDX,EAX,CL / SHRD EDX,ECX,21
# EDX is deliberately not initialised: for inputs below 2048 its old bits fill the low mantissa,
# and for input 0 BSR leaves ECX unchanged. Callers choose EDX and ECX to study those hazards.
.intel_syntax noprefix
.text

# @entry fp16z_convert(z) -> EAX = EDX after the conversion (DX holds the 16-bit float); ECX, EDX as the caller preset them
.globl fp16z_convert
.p2align 4, 0xCC                  # entry on a 16-byte fetch block (int3 fill)
fp16z_convert:
    mov     eax, [esp+4]
    bsr     ecx, eax
    shrd    edx, eax, cl
    shrd    edx, ecx, 21
    mov     eax, edx
    ret

# @entry fp16z_convert_array(src, dst, count, edx_in, ecx_in) -> EAX = count; dst[i] = full EDX after converting src[i]
# EDX and ECX are set to edx_in and ecx_in before every conversion, so each result is independent.
.globl fp16z_convert_array
.p2align 4, 0xCC                  # entry on a 16-byte fetch block (int3 fill)
fp16z_convert_array:
    push    esi
    push    edi
    push    ebp
    mov     esi, [esp+16]           # src (uint32[count])
    mov     edi, [esp+20]           # dst (uint32[count])
    mov     ebp, [esp+24]           # count
    test    ebp, ebp
    jz      .Ldone
.Lnext:
    mov     eax, [esi]
    mov     edx, [esp+28]
    mov     ecx, [esp+32]
    bsr     ecx, eax
    shrd    edx, eax, cl
    shrd    edx, ecx, 21
    mov     [edi], edx
    add     esi, 4
    add     edi, 4
    dec     ebp
    jnz     .Lnext
.Ldone:
    mov     eax, [esp+24]
    pop     ebp
    pop     edi
    pop     esi
    ret
