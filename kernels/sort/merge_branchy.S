# Bottom-up merge sort of 16-bit unsigned keys (kernels/sort/merge.inc) whose merge step takes the
# smaller head key with an ordinary branch: which run it comes from is a branch whose direction
# depends on the keys (about half each way on random keys, never changing on sorted ones).
.intel_syntax noprefix
.text

.include "merge.inc"

# @entry merge_sort_branchy(keys, n, tmp, hist) -> sorts n 16-bit keys (tmp: n keys of scratch; hist unused)
MERGE_SORT merge_sort_branchy

# merge_runs (merge.inc): ESI left, EBP its end = right start, ECX right end, EBX destination (halved)
.p2align 4, 0xCC
merge_runs:
    push    ecx
    mov     edi, ebp                # right
    cmp     edi, ecx
    jae     .Lright_done            # no right run: copy the left one
    jmp     .Lmerge
.p2align 4, 0xCC
.Lmerge:
    movzx   eax, word ptr [esi*2]   # left head
    movzx   edx, word ptr [edi*2]   # right head
    cmp     edx, eax
    jb      .Ltake_right            # right < left (ties take the left key: stable)
    mov     [ebx*2], ax
    inc     esi
    inc     ebx
    cmp     esi, ebp
    jb      .Lmerge
    jmp     .Lleft_done
.Ltake_right:
    mov     [ebx*2], dx
    inc     edi
    inc     ebx
    cmp     edi, [esp]
    jb      .Lmerge
    jmp     .Lright_done
MERGE_TAILS

.include "load.inc"

# @entry sort_load(dst, src, n) -> copies n 16-bit keys from src to dst (the scene's set-up call)
SORT_LOAD
