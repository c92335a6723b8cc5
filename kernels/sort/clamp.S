# Clamping 16-bit unsigned keys into [lo, hi] in place, key by key: the min/max select on its own,
# without a sort around it (lo <= hi; keys[i] = min(max(keys[i], lo), hi)).
#
# clamp_branchy: two ordinary branches per key (below lo? above hi?), as a C compiler of the time
#   compiled `if (x < lo) x = lo; else if (x > hi) x = hi;`.
# clamp_sbb: no key-dependent branch: SUB sets CF when x < lo, SBB makes the mask, AND/SUB apply
#   it (x -= (x - lo) & mask); the same for hi (x += (hi - x) & mask). The P5's and the K6's
#   branch-free select (neither has CMOV).
# (clamp_cmov.S: the same with CMOV, for the P6.)
.intel_syntax noprefix
.text

# @entry clamp_branchy(keys, n, lo, hi) -> clamps n 16-bit keys into [lo, hi] in place, with branches
.globl clamp_branchy
.p2align 4, 0xCC
clamp_branchy:
    push    ebx
    push    esi
    push    edi
    mov     esi, [esp+16]           # keys
    mov     ecx, [esp+20]           # n
    mov     edx, [esp+24]           # lo
    mov     ebx, [esp+28]           # hi
    lea     edi, [esi+ecx*2]
    cmp     esi, edi
    jae     4f
    jmp     1f
.p2align 4, 0xCC
1:
    movzx   eax, word ptr [esi]
    cmp     eax, edx
    jae     2f
    mov     eax, edx                # below lo
    jmp     3f
2:
    cmp     eax, ebx
    jbe     3f
    mov     eax, ebx                # above hi
3:
    mov     [esi], ax
    add     esi, 2
    cmp     esi, edi
    jb      1b
4:
    pop     edi
    pop     esi
    pop     ebx
    ret

# @entry clamp_sbb(keys, n, lo, hi) -> clamps n 16-bit keys into [lo, hi] in place, SBB masks (no key-dependent branch)
.globl clamp_sbb
.p2align 4, 0xCC
clamp_sbb:
    push    ebp
    push    ebx
    push    esi
    push    edi
    mov     esi, [esp+20]           # keys
    mov     ecx, [esp+24]           # n
    mov     edx, [esp+28]           # lo
    mov     ebx, [esp+32]           # hi
    lea     edi, [esi+ecx*2]
    cmp     esi, edi
    jae     2f
    jmp     1f
.p2align 4, 0xCC
1:
    movzx   eax, word ptr [esi]
    mov     ecx, eax
    sub     ecx, edx                # x - lo; CF = x < lo
    sbb     ebp, ebp                # mask
    and     ecx, ebp
    sub     eax, ecx                # x = max(x, lo)
    mov     ecx, ebx
    sub     ecx, eax                # hi - x; CF = x > hi
    sbb     ebp, ebp
    and     ecx, ebp
    add     eax, ecx                # x = min(x, hi)
    mov     [esi], ax
    add     esi, 2
    cmp     esi, edi
    jb      1b
2:
    pop     edi
    pop     esi
    pop     ebx
    pop     ebp
    ret

.include "load.inc"

# @entry sort_load(dst, src, n) -> copies n 16-bit keys from src to dst (the scene's set-up call)
SORT_LOAD
