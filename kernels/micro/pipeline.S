# Micro-benchmarks with known answers on the P6 (and K6) pipelines: a dependency chain (latency),
# independent streams (throughput), 4-1-1 decode patterns, a partial-register stall and store
# forwarding that works or fails. Each entry runs `n` iterations of an unrolled body; the body
# is what the tests divide by.
.intel_syntax noprefix
.text

# @entry imul_chain(n) -> 8 dependent IMUL r32,r32 per iteration (latency bound)
.globl imul_chain
.p2align 4, 0xCC
imul_chain:
    mov     ecx, [esp+4]
    mov     eax, 3
.Limul:
    imul    eax, eax
    imul    eax, eax
    imul    eax, eax
    imul    eax, eax
    imul    eax, eax
    imul    eax, eax
    imul    eax, eax
    imul    eax, eax
    dec     ecx
    jnz     .Limul
    ret

# @entry add_streams(n) -> 12 independent ADD r32,i8 on 6 registers per iteration (port bound)
.globl add_streams
.p2align 4, 0xCC
add_streams:
    push    ebx
    push    esi
    push    edi
    push    ebp
    mov     ebp, [esp+20]
.Ladd:
    add     eax, 1
    add     ebx, 1
    add     ecx, 1
    add     edx, 1
    add     esi, 1
    add     edi, 1
    add     eax, 1
    add     ebx, 1
    add     ecx, 1
    add     edx, 1
    add     esi, 1
    add     edi, 1
    dec     ebp
    jnz     .Ladd
    pop     ebp
    pop     edi
    pop     esi
    pop     ebx
    ret

# @entry two_uop_run(n, buf) -> 12 ADD r32,m32 (2 uops: decoder 0 only) per iteration
.globl two_uop_run
.p2align 4, 0xCC
two_uop_run:
    push    ebx
    push    esi
    push    edi
    push    ebp
    mov     ebp, [esp+20]
    mov     esi, [esp+24]
.Lrun:
    add     eax, [esi]
    add     ebx, [esi+4]
    add     ecx, [esi+8]
    add     edx, [esi+12]
    add     edi, [esi+16]
    add     eax, [esi+20]
    add     ebx, [esi+24]
    add     ecx, [esi+28]
    add     edx, [esi]
    add     edi, [esi+4]
    add     eax, [esi+8]
    add     ebx, [esi+12]
    dec     ebp
    jnz     .Lrun
    pop     ebp
    pop     edi
    pop     esi
    pop     ebx
    ret

# @entry two_uop_interleaved(n, buf) -> 4 x (ADD r32,m32 + 2 one-uop INC) per iteration: 4-1-1 order
.globl two_uop_interleaved
.p2align 4, 0xCC
two_uop_interleaved:
    push    ebx
    push    esi
    push    edi
    push    ebp
    mov     ebp, [esp+20]
    mov     esi, [esp+24]
.Linter:
    add     eax, [esi]
    inc     ebx
    inc     ecx
    add     edx, [esi+4]
    inc     edi
    inc     ebx
    add     eax, [esi+8]
    inc     ecx
    inc     edi
    add     edx, [esi+12]
    inc     ebx
    inc     ecx
    dec     ebp
    jnz     .Linter
    pop     ebp
    pop     edi
    pop     esi
    pop     ebx
    ret

# @entry partial_stall(n, buf) -> per iteration: MOV AL,[m8] then ADD EBX,EAX (reads EAX after an AL write)
.globl partial_stall
.p2align 4, 0xCC
partial_stall:
    push    ebx
    push    esi
    mov     ecx, [esp+12]
    mov     esi, [esp+16]
    xor     ebx, ebx
    mov     eax, 1                  # not a zeroing idiom: the stall is not excused
.Lpartial:
    mov     al, [esi]
    add     ebx, eax
    dec     ecx
    jnz     .Lpartial
    pop     esi
    pop     ebx
    ret

# @entry partial_avoided(n, buf) -> the same with MOVZX EAX,[m8]: no partial write, no stall
.globl partial_avoided
.p2align 4, 0xCC
partial_avoided:
    push    ebx
    push    esi
    mov     ecx, [esp+12]
    mov     esi, [esp+16]
    xor     ebx, ebx
    mov     eax, 1
.Lavoided:
    movzx   eax, byte ptr [esi]
    add     ebx, eax
    dec     ecx
    jnz     .Lavoided
    pop     esi
    pop     ebx
    ret

# @entry forward_ok(n, buf) -> per iteration: MOV [m32],EAX then MOV EAX,[m32] (same address and size)
.globl forward_ok
.p2align 4, 0xCC
forward_ok:
    push    esi
    mov     ecx, [esp+8]
    mov     esi, [esp+12]
    xor     eax, eax
.Lfwd_ok:
    mov     [esi], eax
    mov     eax, [esi]
    dec     ecx
    jnz     .Lfwd_ok
    pop     esi
    ret

# @entry forward_fail(n, buf) -> per iteration: MOV [m16],AX then MOV EAX,[m32]: a larger load after a smaller store
.globl forward_fail
.p2align 4, 0xCC
forward_fail:
    push    esi
    mov     ecx, [esp+8]
    mov     esi, [esp+12]
    xor     eax, eax
.Lfwd_fail:
    mov     [esi], ax
    mov     eax, [esi]
    dec     ecx
    jnz     .Lfwd_fail
    pop     esi
    ret
