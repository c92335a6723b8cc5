# The article's conversion in a loop over an array, two ways. Both convert src[i] (uint32 depth)
# to the 16-bit float dst[i] with BSR/SHRD/SHRD and EDX cleared once at entry (so depths below 2048
# carry stale bits from the previous element, as in the article's span loop).
#   convert_plain:       the three long-decoded instructions back to back, bookkeeping after them
#   convert_interleaved: the same work ordered so each long-decoded (2-uop) instruction is followed
#                        by simple 1-uop ones that decoders 1 and 2 take in the same cycle (4-1-1);
#                        the next element is loaded one iteration ahead
.intel_syntax noprefix
.text

# @entry convert_plain(src, dst, n) -> dst[i] = 16-bit float of src[i]; n >= 1
.globl convert_plain
.p2align 4, 0xCC
convert_plain:
    push    ebx
    push    esi
    push    edi
    mov     esi, [esp+16]
    mov     edi, [esp+20]
    mov     ebx, [esp+24]
    xor     edx, edx
    jmp     .Lplain
.p2align 4, 0xCC
.Lplain:
    mov     eax, [esi]
    bsr     ecx, eax
    shrd    edx, eax, cl
    shrd    edx, ecx, 21
    mov     [edi], dx
    add     esi, 4
    add     edi, 2
    dec     ebx
    jnz     .Lplain
    pop     edi
    pop     esi
    pop     ebx
    ret

# @entry convert_interleaved(src, dst, n) -> the same results as convert_plain; n >= 1
.globl convert_interleaved
.p2align 4, 0xCC
convert_interleaved:
    push    ebx
    push    esi
    push    edi
    mov     esi, [esp+16]
    mov     edi, [esp+20]
    mov     ebx, [esp+24]
    xor     edx, edx
    mov     eax, [esi]              # element 0, loaded ahead
    jmp     .Linter
.p2align 4, 0xCC
.Linter:
    bsr     ecx, eax                # decoder 0 (2 uops)
    lea     esi, [esi+4]            # decoder 1
    lea     edi, [edi+2]            # decoder 2
    shrd    edx, eax, cl            # decoder 0
    mov     eax, [esi]              # decoder 1: the next element (one past the end on the last pass)
    shrd    edx, ecx, 21            # decoder 0
    dec     ebx                     # decoder 1
    mov     [edi-2], dx             # decoder 0 (a store is 2 uops)
    jnz     .Linter                 # decoder 1
    pop     edi
    pop     esi
    pop     ebx
    ret
