# Clamping 16-bit unsigned keys into [lo, hi] in place with CMOV (kernels/sort/clamp.S has the
# branchy and the SBB-mask versions): CMP/CMOVB for the lower bound, CMP/CMOVA for the upper (two
# uops each on the P6). CMOV is a P6 instruction: the P5 and the K6 family lack it, and this file
# does not assemble for them.
# @requires cmov
.intel_syntax noprefix
.text

# @entry clamp_cmov(keys, n, lo, hi) -> clamps n 16-bit keys into [lo, hi] in place, with CMOV
.globl clamp_cmov
.p2align 4, 0xCC
clamp_cmov:
    push    ebx
    push    esi
    push    edi
    mov     esi, [esp+16]           # keys
    mov     ecx, [esp+20]           # n
    mov     edx, [esp+24]           # lo
    mov     ebx, [esp+28]           # hi
    lea     edi, [esi+ecx*2]
    cmp     esi, edi
    jae     2f
    jmp     1f
.p2align 4, 0xCC
1:
    movzx   eax, word ptr [esi]
    cmp     eax, edx
    cmovb   eax, edx                # x = max(x, lo)
    cmp     eax, ebx
    cmova   eax, ebx                # x = min(x, hi)
    mov     [esi], ax
    add     esi, 2
    cmp     esi, edi
    jb      1b
2:
    pop     edi
    pop     esi
    pop     ebx
    ret

.include "load.inc"

# @entry sort_load(dst, src, n) -> copies n 16-bit keys from src to dst (the scene's set-up call)
SORT_LOAD
