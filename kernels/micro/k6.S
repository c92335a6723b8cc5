# K6 micro-benchmarks with known answers (sim/cpus/k6/k6.toml, k6_machine.toml): vector-decoded
# BSR and SHRD (dependent and independent), a run of long-decoded instructions, long and short
# decodes interleaved, operand-size prefixes, and repeated stores to a line that is never read
# (write allocation). Each entry runs `n` iterations of an unrolled body; the body is what the
# tests divide by. BSR of 0 leaves its destination as it was (as the hardware does); the chains
# reach 0 after a few steps and stay there, which changes no timing.
.intel_syntax noprefix
.text

# @entry bsr_chain(n) -> 8 dependent BSR r32,r32 per iteration (latency bound)
.globl bsr_chain
.p2align 4, 0xCC
bsr_chain:
    mov     ecx, [esp+4]
    mov     eax, 0x40000000
.Lbsr_chain:
    bsr     eax, eax
    bsr     eax, eax
    bsr     eax, eax
    bsr     eax, eax
    bsr     eax, eax
    bsr     eax, eax
    bsr     eax, eax
    bsr     eax, eax
    dec     ecx
    jnz     .Lbsr_chain
    ret

# @entry bsr_streams(n) -> 8 independent BSR r32,r32 per iteration (throughput bound)
.globl bsr_streams
.p2align 4, 0xCC
bsr_streams:
    push    esi
    push    edi
    mov     ecx, [esp+12]
    mov     edx, 0x00012345
.Lbsr_streams:
    bsr     eax, edx
    bsr     esi, edx
    bsr     edi, edx
    bsr     eax, edx
    bsr     esi, edx
    bsr     edi, edx
    bsr     eax, edx
    bsr     esi, edx
    dec     ecx
    jnz     .Lbsr_streams
    pop     edi
    pop     esi
    ret

# @entry shrd_chain(n) -> 8 dependent SHRD r32,r32,imm8 per iteration (latency bound)
.globl shrd_chain
.p2align 4, 0xCC
shrd_chain:
    mov     ecx, [esp+4]
    mov     eax, 0x12345678
    mov     edx, 0x9ABCDEF0
.Lshrd_chain:
    shrd    eax, edx, 3
    shrd    eax, edx, 3
    shrd    eax, edx, 3
    shrd    eax, edx, 3
    shrd    eax, edx, 3
    shrd    eax, edx, 3
    shrd    eax, edx, 3
    shrd    eax, edx, 3
    dec     ecx
    jnz     .Lshrd_chain
    ret

# @entry bswap_run(n) -> 12 BSWAP r32 (long decoder: one per clock) on 6 registers per iteration
.globl bswap_run
.p2align 4, 0xCC
bswap_run:
    push    ebx
    push    esi
    push    edi
    push    ebp
    mov     ebp, [esp+20]
.Lbswap:
    bswap   eax
    bswap   ebx
    bswap   ecx
    bswap   edx
    bswap   esi
    bswap   edi
    bswap   eax
    bswap   ebx
    bswap   ecx
    bswap   edx
    bswap   esi
    bswap   edi
    dec     ebp
    jnz     .Lbswap
    pop     ebp
    pop     edi
    pop     esi
    pop     ebx
    ret

# @entry long_short_mix(n) -> 4 x (BSWAP + two ADD r32,i8) per iteration: long alone, shorts paired
.globl long_short_mix
.p2align 4, 0xCC
long_short_mix:
    push    ebx
    push    esi
    push    edi
    push    ebp
    mov     ebp, [esp+20]
.Lmix:
    bswap   eax
    add     ebx, 1
    add     ecx, 1
    bswap   edx
    add     esi, 1
    add     edi, 1
    bswap   eax
    add     ebx, 1
    add     ecx, 1
    bswap   edx
    add     esi, 1
    add     edi, 1
    dec     ebp
    jnz     .Lmix
    pop     ebp
    pop     edi
    pop     esi
    pop     ebx
    ret

# @entry prefix_imm8(n) -> 12 ADD r16,imm8 (one 0x66 prefix) on 6 registers per iteration
.globl prefix_imm8
.p2align 4, 0xCC
prefix_imm8:
    push    ebx
    push    esi
    push    edi
    push    ebp
    mov     ebp, [esp+20]
.Lpfx8:
    add     ax, 1
    add     bx, 1
    add     cx, 1
    add     dx, 1
    add     si, 1
    add     di, 1
    add     ax, 1
    add     bx, 1
    add     cx, 1
    add     dx, 1
    add     si, 1
    add     di, 1
    dec     ebp
    jnz     .Lpfx8
    pop     ebp
    pop     edi
    pop     esi
    pop     ebx
    ret

# @entry prefix_imm16(n) -> 12 ADD r16,imm16 (0x66 prefix and a 16-bit immediate) per iteration
.globl prefix_imm16
.p2align 4, 0xCC
prefix_imm16:
    push    ebx
    push    esi
    push    edi
    push    ebp
    mov     ebp, [esp+20]
.Lpfx16:
    add     ax, 0x1234
    add     bx, 0x1234
    add     cx, 0x1234
    add     dx, 0x1234
    add     si, 0x1234
    add     di, 0x1234
    add     ax, 0x1234
    add     bx, 0x1234
    add     cx, 0x1234
    add     dx, 0x1234
    add     si, 0x1234
    add     di, 0x1234
    dec     ebp
    jnz     .Lpfx16
    pop     ebp
    pop     edi
    pop     esi
    pop     ebx
    ret

# @entry store_same(n, buf) -> 8 MOV [m32],r32 to one address per iteration; the line is never read
.globl store_same
.p2align 4, 0xCC
store_same:
    mov     ecx, [esp+4]
    mov     edx, [esp+8]
    xor     eax, eax
.Lstore_same:
    mov     [edx], eax
    mov     [edx], eax
    mov     [edx], eax
    mov     [edx], eax
    mov     [edx], eax
    mov     [edx], eax
    mov     [edx], eax
    mov     [edx], eax
    dec     ecx
    jnz     .Lstore_same
    ret

# @entry div_window(n) -> per iteration: DIV r32 (20 clocks on X, the next DIV depends on it), then
# 16 independent ADD r32,i8 (8 opquads) and DEC/JNZ: the 6-opquad scheduler fills behind the DIV
.globl div_window
.p2align 4, 0xCC
div_window:
    push    ebx
    push    esi
    push    edi
    push    ebp
    mov     ecx, [esp+20]
    mov     esi, 1
    mov     eax, 1000
    xor     edx, edx
.Ldiv_window:
    div     esi
    add     ebx, 1
    add     edi, 1
    add     ebp, 1
    add     ebx, 1
    add     edi, 1
    add     ebp, 1
    add     ebx, 1
    add     edi, 1
    add     ebp, 1
    add     ebx, 1
    add     edi, 1
    add     ebp, 1
    add     ebx, 1
    add     edi, 1
    add     ebp, 1
    add     ebx, 1
    dec     ecx
    jnz     .Ldiv_window
    pop     ebp
    pop     edi
    pop     esi
    pop     ebx
    ret
