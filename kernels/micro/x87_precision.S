# x87 precision control: the control word's precision field (24, 53 or 64 bits) sets both the
# rounding of every x87 result and, on the P5, P6 and K6, the time FDIV and FSQRT take.
# Each entry loads the control word it is given and restores the caller's before returning.
# Hazard kept on purpose: fdiv_chain divides by 3.0 and then divides 3.0 by the result, so the
# values stay bounded (a, a/3, 9/a, 3/a, a); the timing models do not depend on values.
.intel_syntax noprefix
.text

# @entry fdiv_chain(cw, n) -> EAX = 0; 4 * n dependent FDIV/FDIVR at control word cw
.globl fdiv_chain
fdiv_chain:
    sub     esp, 4
    fnstcw  [esp]
    fldcw   [esp+8]
    mov     ecx, [esp+12]
    fld     dword ptr [three]
    fld1
    test    ecx, ecx
    jz      2f
1:  fdiv    st(0), st(1)
    fdivr   st(0), st(1)
    fdiv    st(0), st(1)
    fdivr   st(0), st(1)
    dec     ecx
    jnz     1b
2:  fstp    st(0)
    fstp    st(0)
    fldcw   [esp]
    add     esp, 4
    xor     eax, eax
    ret

# @entry cw_cycle(cws, n) -> EAX = 0; iteration i loads control word cws[i % 3] (u16) and runs two dependent divides
.globl cw_cycle
cw_cycle:
    push    esi
    push    ebx
    sub     esp, 4
    fnstcw  [esp]
    mov     esi, [esp+16]
    mov     ecx, [esp+20]
    xor     ebx, ebx
    fld     dword ptr [three]
    fld1
    test    ecx, ecx
    jz      2f
1:  fldcw   [esi+2*ebx]
    fdiv    st(0), st(1)
    fdivr   st(0), st(1)
    inc     ebx
    cmp     ebx, 3
    jb      3f
    xor     ebx, ebx
3:  dec     ecx
    jnz     1b
2:  fstp    st(0)
    fstp    st(0)
    fldcw   [esp]
    add     esp, 4
    pop     ebx
    pop     esi
    xor     eax, eax
    ret

# @entry x87_ops(a, b, snap, quotient, root, n, cw) -> EAX = 0; per element at control word cw: snap[i] = (a[i] + 3<<18) - 3<<18, quotient[i] = a[i] / b[i], root[i] = sqrt(|a[i]|), each stored as the full 80-bit register
.globl x87_ops
x87_ops:
    push    esi
    push    edi
    push    ebx
    push    ebp
    sub     esp, 4
    fnstcw  [esp]
    fldcw   [esp+48]
    mov     esi, [esp+24]
    mov     edi, [esp+28]
    mov     ebx, [esp+32]
    mov     edx, [esp+36]
    mov     ebp, [esp+40]
    mov     ecx, [esp+44]
    test    ecx, ecx
    jz      2f
1:  fld     dword ptr [esi]
    fadd    dword ptr [snap_bias]
    fsub    dword ptr [snap_bias]
    fstp    tbyte ptr [ebx]
    fld     dword ptr [esi]
    fdiv    dword ptr [edi]
    fstp    tbyte ptr [edx]
    fld     dword ptr [esi]
    fabs
    fsqrt
    fstp    tbyte ptr [ebp]
    add     esi, 4
    add     edi, 4
    add     ebx, 10
    add     edx, 10
    add     ebp, 10
    dec     ecx
    jnz     1b
2:  fldcw   [esp]
    add     esp, 4
    pop     ebp
    pop     ebx
    pop     edi
    pop     esi
    xor     eax, eax
    ret

.section .rodata
.p2align 2
three:      .float 3.0
snap_bias:  .float 786432.0     # 3 << 18
