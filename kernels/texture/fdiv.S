# The texture article's other Pentium claims, as kernels:
# - the perspective divide of each 16-pixel sub-span run beside the integer inner loop ("That
#   expensive (39 cycle) floating point divide ... can actually be done in parallel with the inner
#   loop. This converts a 40 cycle operation to 2 cycles"): tex5 spans of 16 pixels with no divide
#   (sub16), with FLD1/FDIV before the inner loop and FSTP after it (sub16_overlap), and with the
#   FSTP right after the FDIV (sub16_serial);
# - the TIMESNAP macro (PUSH EAX / PUSH EDX / RDTSC / MOV clock,EAX / POP EDX / POP EAX), which the
#   article says adds "about 16 clock cycles of overhead": timesnap returns stop - start of two
#   back-to-back TIMESNAPs.
# Register layout and arguments of the span entries as in loops.S; count is a multiple of 16; c
# points to two floats: c[0] the divisor, c[1] receives 1/c. The divisor never changes, so every
# sub-span draws with the same du, dv (the divide is timed, not used).
.intel_syntax noprefix
.text

.include "span_frame.inc"
.include "span_loops.inc"

# SETUP, then EDI = dst
.macro SETUP_DST
    SETUP
    mov edi, [esp+20]
.endm

# the 16-pixel inner loop of tex5 (the sub-span counter is a local at [esp], pushed after SETUP)
.macro INNER16
    mov ebp, 16
    jmp 1f
    LOOP5 1
.endm

# @entry sub16(dst, tex, count, u, v, du, dv, c) -> EAX = count
.globl sub16
sub16:
    SETUP_DST
    mov ebp, [esp+28]
    shr ebp, 4
    push ebp
0:
    INNER16
    dec dword ptr [esp]
    jnz 0b
    add esp, 4
    RESTORE

# @entry sub16_overlap(dst, tex, count, u, v, du, dv, c) -> EAX = count
.globl sub16_overlap
sub16_overlap:
    SETUP_DST
    mov ebp, [esp+28]
    shr ebp, 4
    push ebp
0:
    mov ebp, [esp+52]
    fld1
    fdiv dword ptr [ebp]
    INNER16
    mov ebp, [esp+52]
    fstp dword ptr [ebp+4]
    dec dword ptr [esp]
    jnz 0b
    add esp, 4
    RESTORE

# @entry sub16_serial(dst, tex, count, u, v, du, dv, c) -> EAX = count
.globl sub16_serial
sub16_serial:
    SETUP_DST
    mov ebp, [esp+28]
    shr ebp, 4
    push ebp
0:
    mov ebp, [esp+52]
    fld1
    fdiv dword ptr [ebp]
    fstp dword ptr [ebp+4]
    INNER16
    dec dword ptr [esp]
    jnz 0b
    add esp, 4
    RESTORE

# The same two loops with the x87 in single (24-bit) precision, as the article advises ("this
# reduces the execution time for the divide from 39 clocks to 19 clocks"): FLDCW of a constant
# control word before the span, and back to the FNINIT word (64-bit) after it.
# @entry sub16_overlap_single(dst, tex, count, u, v, du, dv, c) -> EAX = count
.globl sub16_overlap_single
sub16_overlap_single:
    fldcw [cw_single]
    push dword ptr [esp+32]
    push dword ptr [esp+32]
    push dword ptr [esp+32]
    push dword ptr [esp+32]
    push dword ptr [esp+32]
    push dword ptr [esp+32]
    push dword ptr [esp+32]
    push dword ptr [esp+32]
    call sub16_overlap
    add esp, 32
    fldcw [cw_default]
    ret

# @entry sub16_serial_single(dst, tex, count, u, v, du, dv, c) -> EAX = count
.globl sub16_serial_single
sub16_serial_single:
    fldcw [cw_single]
    push dword ptr [esp+32]
    push dword ptr [esp+32]
    push dword ptr [esp+32]
    push dword ptr [esp+32]
    push dword ptr [esp+32]
    push dword ptr [esp+32]
    push dword ptr [esp+32]
    push dword ptr [esp+32]
    call sub16_serial
    add esp, 32
    fldcw [cw_default]
    ret

# @entry timesnap() -> EAX = stop - start of two back-to-back TIMESNAP macros
.globl timesnap
timesnap:
    push ebx
    push eax
    push edx
    rdtsc
    mov ebx, eax
    pop edx
    pop eax
    push eax
    push edx
    rdtsc
    mov ecx, eax
    pop edx
    pop eax
    mov eax, ecx
    sub eax, ebx
    pop ebx
    ret

.section .rodata
.p2align 1
cw_single:  .short 0x007F    # FNINIT control word with precision control 00 (24-bit)
cw_default: .short 0x037F    # the FNINIT control word (64-bit)
