# Bottom-up merge sort of 16-bit unsigned keys (kernels/sort/merge.inc) whose merge step has no
# key-dependent branch: CMP sets CF when the right head is smaller, SBB turns CF into a mask
# (-1 or 0, CF kept), ADC adds CF to the right index, LEA adds 1 + mask to the left one, and the
# mask selects the key (left ^ ((left ^ right) & mask)). The P5 and the K6 have no CMOV: this is
# their branch-free select. The loop's only branches test the runs' ends.
.intel_syntax noprefix
.text

.include "merge.inc"

# @entry merge_sort_sbb(keys, n, tmp, hist) -> sorts n 16-bit keys (tmp: n keys of scratch; hist unused)
MERGE_SORT merge_sort_sbb

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
    cmp     edx, eax                # CF = right < left (ties take the left key: stable)
    sbb     ecx, ecx                # mask = -CF; SBB r,r leaves CF as it was
    adc     edi, 0                  # right += CF
    lea     esi, [esi+ecx+1]        # left += 1 - CF
    xor     edx, eax
    and     edx, ecx
    xor     eax, edx                # the smaller head
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
