# CMOV dependent chain (latency bound), apart from chains.S because CMOV is not on every CPU:
# the P5 and the K6 family lack it, and this file does not assemble for them.
# @requires cmov
.intel_syntax noprefix
.text

.include "chain_frame.inc"


# @entry cmov_chain(n, buf) -> 8 dependent instances per iteration: CMOVNZ r32,r32 (flags from the loop counter, never zero inside the body)
.globl cmov_chain
.p2align 4, 0xCC
cmov_chain:
    PROLOGUE
    mov eax, 1
    mov edx, 2
.Lcmov_chain:
    cmovnz eax, edx
    cmovnz eax, edx
    cmovnz eax, edx
    cmovnz eax, edx
    cmovnz eax, edx
    cmovnz eax, edx
    cmovnz eax, edx
    cmovnz eax, edx
    sub     ebp, 1
    jnz     .Lcmov_chain
    EPILOGUE

