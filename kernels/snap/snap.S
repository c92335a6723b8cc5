# Vertex snapping to 1/16 pixel (the Glide Programming Guide's "Programming Tips and Techniques"):
# Voodoo hardware takes vertex coordinates in 12.4 fixed point, so projected float coordinates are
# snapped to multiples of 1/16 first, or Glide's area calculations and the hardware's disagree.
#
# snap_trick: the guide's trick, x += 3<<18; x -= 3<<18, kept in an x87 register as optimised code
#   keeps it. With the x87 in 24-bit precision the sum x + 786432 (1.5 * 2^19) is rounded to a
#   24-bit mantissa whose last bit is worth 1/16 for |x| < 2^18, so the subtraction leaves x
#   rounded to the nearest 1/16 (ties to even). At 53 or 64 bits the sum keeps x's fraction and
#   the subtraction gives x back: no snapping at all. Beyond |x| = 2^18 the step is 1/8 or more
#   (positive) or 1/32 (negative, down to -2^18 - 2^19), so the result is off the nearest point.
# snap_portable: the guide's portable variant, tmp = (long)(x * 16); x = tmp / 16.0, as a compiler
#   of the time emitted it: FMUL, a call to a float-to-long routine that saves the control word,
#   sets rounding to chop, FISTP, restores it (what MSVC's _ftol did, here with a 32-bit FISTP:
#   `long` is 32 bits), FILD and an FDIV by the double 16.0. It truncates toward zero, so it lands
#   on the grid but not on the nearest point; |x| >= 2^27 overflows the long (FISTP stores the
#   integer indefinite 0x80000000). The guide's listing assigns tmp for y before using it for x
#   (both coordinates would get y's value); this kernel does what the listing evidently means.
#
# Both take an array of n vertices, each two floats (x, y), snapped in place, and the x87 control
# word to run with (loaded once, the caller's restored on return).
# Hazard kept on purpose: the precision and rounding bits of `cw` are used as given.
.intel_syntax noprefix
.text

# @entry snap_trick(verts, n, cw) -> EAX = 0; x = (x + 3<<18) - 3<<18 for each coordinate of n (x, y) vertices, at control word cw
.globl snap_trick
snap_trick:
    sub     esp, 4
    fnstcw  [esp]
    fldcw   [esp+16]
    mov     eax, [esp+8]
    mov     ecx, [esp+12]
    test    ecx, ecx
    jz      2f
1:  fld     dword ptr [eax]
    fadd    dword ptr [snapper]
    fsub    dword ptr [snapper]
    fstp    dword ptr [eax]
    fld     dword ptr [eax+4]
    fadd    dword ptr [snapper]
    fsub    dword ptr [snapper]
    fstp    dword ptr [eax+4]
    add     eax, 8
    dec     ecx
    jnz     1b
2:  fldcw   [esp]
    add     esp, 4
    xor     eax, eax
    ret

# @entry snap_portable(verts, n, cw) -> EAX = 0; x = (long)(x * 16) / 16.0 for each coordinate of n (x, y) vertices, at control word cw
.globl snap_portable
snap_portable:
    push    esi
    push    ebx
    sub     esp, 8
    fnstcw  [esp]
    fldcw   [esp+28]
    mov     esi, [esp+20]
    mov     ebx, [esp+24]
    test    ebx, ebx
    jz      2f
1:  fld     dword ptr [esi]
    fmul    dword ptr [sixteen_f]
    call    ftol
    mov     [esp+4], eax
    fild    dword ptr [esp+4]
    fdiv    qword ptr [sixteen_d]
    fstp    dword ptr [esi]
    fld     dword ptr [esi+4]
    fmul    dword ptr [sixteen_f]
    call    ftol
    mov     [esp+4], eax
    fild    dword ptr [esp+4]
    fdiv    qword ptr [sixteen_d]
    fstp    dword ptr [esi+4]
    add     esi, 8
    dec     ebx
    jnz     1b
2:  fldcw   [esp]
    add     esp, 8
    pop     ebx
    pop     esi
    xor     eax, eax
    ret

# ST(0) -> EAX, rounded toward zero as C's float-to-long conversion requires; pops ST(0).
ftol:
    sub     esp, 8
    fnstcw  [esp]
    movzx   eax, word ptr [esp]
    or      eax, 0x0C00
    mov     [esp+4], eax
    fldcw   [esp+4]
    fistp   dword ptr [esp+4]
    fldcw   [esp]
    mov     eax, [esp+4]
    add     esp, 8
    ret

.section .rodata
.p2align 3
sixteen_d:  .double 16.0
snapper:    .float 786432.0     # 3 << 18
sixteen_f:  .float 16.0
