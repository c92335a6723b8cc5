# LSD radix sort of 16-bit unsigned keys, ascending, stable, in two passes: the low digit of BITS
# bits, then the high digit of the other 16 - BITS bits (Steven Tovey's radix sort essay describes
# the method: one counting pass builds every digit's histogram, running totals turn each into
# offsets, and each pass scatters the keys to their digit's next offset).
#
#   radix8_sort:  8 + 8 bits: two histograms of 256 dwords (1 KB each, 2 KB in all)
#   radix11_sort: 11 + 5 bits: a histogram of 2048 dwords (8 KB: as large as the whole P5 data
#                 cache) and one of 32; still two passes, as 16 bits need two digits of 8 bits too
#
# Arguments (keys, n, tmp, hist): tmp holds n keys (the first pass's output), hist the histograms
# (4 << BITS bytes, then 4 << (16 - BITS)). The passes have no key-dependent branch: the cost per
# key is the same for any order of the keys, plus the histograms' clearing and running totals
# (2^BITS + 2^(16-BITS) entries) once per call.
.intel_syntax noprefix
.text

.macro RADIX_SORT name, bits
.globl \name
.p2align 4, 0xCC
\name:
    push    ebp
    push    ebx
    push    esi
    push    edi
    mov     ebx, [esp+32]           # hist: low digit's counts, then the high digit's
    mov     edi, ebx                # clear both (REP STOSD, as memset did)
    mov     ecx, (1 << \bits) + (1 << (16 - \bits))
    xor     eax, eax
    rep stosd
    mov     esi, [esp+20]           # keys
    mov     ecx, [esp+24]           # n
    lea     ebp, [esi+ecx*2]        # their end
    cmp     esi, ebp
    jae     2f
1:                                  # count both digits of every key
    movzx   eax, word ptr [esi]
    mov     edx, eax
    and     eax, (1 << \bits) - 1
    shr     edx, \bits
    inc     dword ptr [ebx+eax*4]
    inc     dword ptr [ebx+edx*4+(4 << \bits)]
    add     esi, 2
    cmp     esi, ebp
    jb      1b
2:
    xor     eax, eax                # running totals: each count becomes its digit's first offset
    xor     ecx, ecx
3:
    mov     edx, [ebx+ecx*4]
    mov     [ebx+ecx*4], eax
    add     eax, edx
    inc     ecx
    cmp     ecx, (1 << \bits)
    jb      3b
    xor     eax, eax
    xor     ecx, ecx
4:
    mov     edx, [ebx+ecx*4+(4 << \bits)]
    mov     [ebx+ecx*4+(4 << \bits)], eax
    add     eax, edx
    inc     ecx
    cmp     ecx, (1 << (16 - \bits))
    jb      4b
    mov     esi, [esp+20]           # pass 1: keys -> tmp by the low digit
    mov     edi, [esp+28]
    cmp     esi, ebp
    jae     6f
5:
    movzx   eax, word ptr [esi]
    mov     edx, eax
    and     edx, (1 << \bits) - 1
    mov     ecx, [ebx+edx*4]        # the digit's next offset
    mov     [edi+ecx*2], ax
    inc     ecx
    mov     [ebx+edx*4], ecx
    add     esi, 2
    cmp     esi, ebp
    jb      5b
6:
    mov     esi, [esp+28]           # pass 2: tmp -> keys by the high digit
    mov     edi, [esp+20]
    mov     ecx, [esp+24]
    lea     ebp, [esi+ecx*2]
    cmp     esi, ebp
    jae     8f
7:
    movzx   eax, word ptr [esi]
    mov     edx, eax
    shr     edx, \bits
    mov     ecx, [ebx+edx*4+(4 << \bits)]
    mov     [edi+ecx*2], ax
    inc     ecx
    mov     [ebx+edx*4+(4 << \bits)], ecx
    add     esi, 2
    cmp     esi, ebp
    jb      7b
8:
    pop     edi
    pop     esi
    pop     ebx
    pop     ebp
    ret
.endm

# @entry radix8_sort(keys, n, tmp, hist) -> sorts n 16-bit keys, two 8-bit digits (tmp: n keys; hist: 2 KB)
RADIX_SORT radix8_sort, 8

# @entry radix11_sort(keys, n, tmp, hist) -> sorts n 16-bit keys, digits of 11 and 5 bits (tmp: n keys; hist: 8320 bytes)
RADIX_SORT radix11_sort, 11

.include "load.inc"

# @entry sort_load(dst, src, n) -> copies n 16-bit keys from src to dst (the scene's set-up call)
SORT_LOAD
