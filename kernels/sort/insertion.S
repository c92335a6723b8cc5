# Straight insertion sort of 16-bit unsigned keys, ascending, in place, with ordinary branches
# (kernels/sort/insert.inc): O(n^2) moves on random keys, O(n) on sorted ones. Every sort kernel of
# kernels/sort/ takes the same arguments (keys, n, tmp, hist); this one needs neither buffer.
.intel_syntax noprefix
.text

# @entry insertion_sort(keys, n, tmp, hist) -> sorts n 16-bit keys in place (tmp, hist unused)
.globl insertion_sort
.p2align 4, 0xCC
insertion_sort:
    push    ebp
    push    ebx
    push    esi
    push    edi
    mov     esi, [esp+20]           # keys
    mov     ecx, [esp+24]           # n
    lea     edi, [esi+ecx*2-2]      # the last key (below ESI when n = 0: an empty range)
    test    ecx, ecx
    jz      1f
    call    isort_range
1:
    pop     edi
    pop     esi
    pop     ebx
    pop     ebp
    ret

.include "insert.inc"
.include "load.inc"

# @entry sort_load(dst, src, n) -> copies n 16-bit keys from src to dst (the scene's set-up call)
SORT_LOAD
