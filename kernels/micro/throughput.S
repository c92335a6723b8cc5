# Independent instances of instructions whose measured reciprocal throughput is more than their
# ports and decoders allow (tests/test_p6.py compares cycles per instance with the table's
# figure). Each entry runs `n` iterations of an unrolled body of 8 instances (loop_run: n LOOPs).
.intel_syntax noprefix
.text

# @entry loop_run(n) -> n LOOP instructions, each jumping to itself until ECX reaches 0
.globl loop_run
.p2align 4, 0xCC
loop_run:
    mov     ecx, [esp+4]
.Lloop_run:
    loop    .Lloop_run
    ret

# @entry emms_stream(n) -> 8 EMMS per iteration
.globl emms_stream
.p2align 4, 0xCC
emms_stream:
    mov     ecx, [esp+4]
.Lemms:
    .rept 8
    .byte   0x0f, 0x77              # EMMS (the kernels assemble with -march=i686, which has no MMX)
    .endr
    sub     ecx, 1
    jnz     .Lemms
    ret

# @entry cmp_stream(n) -> 8 CMP r32,r32 on independent registers per iteration
.globl cmp_stream
.p2align 4, 0xCC
cmp_stream:
    push    ebx
    push    esi
    mov     ecx, [esp+12]
.Lcmp:
    cmp     eax, ebx
    cmp     edx, esi
    cmp     eax, esi
    cmp     edx, ebx
    cmp     eax, ebx
    cmp     edx, esi
    cmp     eax, esi
    cmp     edx, ebx
    sub     ecx, 1
    jnz     .Lcmp
    pop     esi
    pop     ebx
    ret

# @entry fmul_stream(n) -> 8 FMUL ST(i),ST on four independent registers per iteration (ST = 1.0)
.globl fmul_stream
.p2align 4, 0xCC
fmul_stream:
    mov     ecx, [esp+4]
    fld1
    fld1
    fld1
    fld1
    fld1
.Lfmul:
    .rept 2
    fmul    st(1), st
    fmul    st(2), st
    fmul    st(3), st
    fmul    st(4), st
    .endr
    sub     ecx, 1
    jnz     .Lfmul
    .rept 5
    fstp    st(0)
    .endr
    ret

# @entry div_stream(n) -> 4 DIV r32 per iteration (EDX:EAX = 0:1000 / 7 each time: independent)
.globl div_stream
.p2align 4, 0xCC
div_stream:
    push    ebx
    mov     ecx, [esp+8]
    mov     ebx, 7
.Ldiv:
    .rept 4
    mov     edx, 0                  # not XOR: the P6 does not break the dependency of a zero idiom
    mov     eax, 1000
    div     ebx
    .endr
    sub     ecx, 1
    jnz     .Ldiv
    pop     ebx
    ret

# @entry movq_store_same(n, buf) -> 8 MOVQ [m64],MM0 to one address per iteration; the line is never read
.globl movq_store_same
.p2align 4, 0xCC
movq_store_same:
    mov     ecx, [esp+4]
    mov     edx, [esp+8]
.Lmovq_store:
    .rept 8
    .byte   0x0f, 0x7f, 0x02        # MOVQ [EDX], MM0 (the kernels assemble with -march=i686, which has no MMX)
    .endr
    sub     ecx, 1
    jnz     .Lmovq_store
    .byte   0x0f, 0x77              # EMMS
    ret

# @entry xchg_stream(n) -> 8 XCHG r32,r32 per iteration on three register pairs (throughput bound)
# (two pairs spelled in bytes: GNU as and clang pick different, equivalent ModRM encodings)
.globl xchg_stream
.p2align 4, 0xCC
xchg_stream:
    push    ebx
    push    esi
    push    edi
    push    ebp
    mov     ebp, [esp+20]
.Lxchg:
    xchg    eax, ecx
    .byte   0x87, 0xda              # XCHG EDX, EBX
    .byte   0x87, 0xfe              # XCHG ESI, EDI
    xchg    eax, ecx
    .byte   0x87, 0xda              # XCHG EDX, EBX
    .byte   0x87, 0xfe              # XCHG ESI, EDI
    xchg    eax, ecx
    .byte   0x87, 0xda              # XCHG EDX, EBX
    sub     ebp, 1
    jnz     .Lxchg
    pop     ebp
    pop     edi
    pop     esi
    pop     ebx
    ret
