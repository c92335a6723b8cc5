# Quicksort of 16-bit unsigned keys, ascending, in place, with ordinary branches: Hoare's partition
# around the middle key (its two scanning loops stop on keys equal to the pivot, so equal keys
# split evenly and already sorted, reversed or all-equal keys stay O(n log n)), recursion on the
# smaller part and a loop on the larger (stack depth at most log2 n), and ranges of fewer than
# CUTOFF keys finished by straight insertion sort (kernels/sort/insert.inc), as C library sorts
# of the time did. Each partition step's comparisons are branches whose direction depends on the
# keys: on random keys about half of them go each way.
.intel_syntax noprefix
.text

.set CUTOFF, 16

# @entry quick_sort(keys, n, tmp, hist) -> sorts n 16-bit keys in place (tmp, hist unused)
.globl quick_sort
.p2align 4, 0xCC
quick_sort:
    push    ebp
    push    ebx
    push    esi
    push    edi
    mov     esi, [esp+20]           # keys
    mov     ecx, [esp+24]           # n
    lea     edi, [esi+ecx*2-2]      # the last key
    cmp     ecx, 1
    jbe     1f
    call    qsort_range
1:
    pop     edi
    pop     esi
    pop     ebx
    pop     ebp
    ret

# qsort_range: sorts the keys [ESI, EDI] (inclusive, at least two). Clobbers every register but ESP.
.p2align 4, 0xCC
qsort_range:
    mov     eax, edi
    sub     eax, esi                # 2 * (keys - 1)
    cmp     eax, 2 * (CUTOFF - 1)
    jb      isort_range             # a small range: insertion sort (tail call)
    shr     eax, 2
    movzx   edx, word ptr [esi+eax*2]   # the pivot: the middle key (never the last)
    lea     ebx, [esi-2]            # i
    lea     ebp, [edi+2]            # j
2:
    add     ebx, 2                  # scan up to a key >= pivot
    movzx   eax, word ptr [ebx]
    cmp     eax, edx
    jb      2b
3:
    sub     ebp, 2                  # scan down to a key <= pivot
    movzx   ecx, word ptr [ebp]
    cmp     ecx, edx
    ja      3b
    cmp     ebx, ebp
    jae     4f                      # the scans met: [ESI, EBP] <= pivot <= [EBP+2, EDI]
    mov     [ebx], cx               # exchange the two keys and go on
    mov     [ebp], ax
    jmp     2b
4:
    mov     eax, ebp
    sub     eax, esi                # 2 * (left keys - 1)
    mov     ecx, edi
    sub     ecx, ebp                # 2 * right keys
    cmp     eax, ecx
    jae     5f
    push    edi                     # the left part is smaller: sort it, then loop on the right
    push    ebp
    mov     edi, ebp
    call    qsort_range
    pop     ebp
    pop     edi
    lea     esi, [ebp+2]
    jmp     qsort_range
5:
    push    esi                     # the right part is smaller: sort it, then loop on the left
    push    ebp
    lea     esi, [ebp+2]
    call    qsort_range
    pop     ebp
    pop     esi
    mov     edi, ebp
    jmp     qsort_range

.include "insert.inc"
.include "load.inc"

# @entry sort_load(dst, src, n) -> copies n 16-bit keys from src to dst (the scene's set-up call)
SORT_LOAD
