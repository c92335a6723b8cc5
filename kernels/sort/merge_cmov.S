# Bottom-up merge sort of 16-bit unsigned keys (kernels/sort/merge.inc) whose merge step selects
# with CMOV: the smaller head and both run indices are conditional moves on one CMP (each CMOV is
# two uops on the P6). CMOV is a P6 instruction: the P5 and the K6 family lack it, and this file
# does not assemble for them.
# @requires cmov
.intel_syntax noprefix
.text

.include "merge.inc"

# @entry merge_sort_cmov(keys, n, tmp, hist) -> sorts n 16-bit keys (tmp: n keys of scratch; hist unused)
MERGE_SORT merge_sort_cmov

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
    lea     ecx, [esi+1]
    cmp     edx, eax                # below: right < left (ties take the left key: stable)
    cmovb   eax, edx                # the smaller head
    lea     edx, [edi+1]
    cmovb   edi, edx                # right += 1 if taken
    cmovae  esi, ecx                # left += 1 otherwise
    mov     [ebx*2], ax
    inc     ebx
    cmp     esi, ebp
    jae     .Lleft_done
    cmp     edi, [esp]
    jb      .Lmerge
    jmp     .Lright_done
MERGE_TAILS

.include "load.inc"

# @entry sort_load(dst, src, n) -> copies n 16-bit keys from src to dst (the scene's set-up call)
SORT_LOAD
