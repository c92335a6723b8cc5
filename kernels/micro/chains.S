# Dependent chains of multi-uop instructions (latency bound): each entry runs `n` iterations of 8
# instances of one instruction, each reading the previous one's result, so cycles / (8 n) is the
# instruction's result latency (tests/test_chains.py compares it with the measured figures). The
# loop counter is EBP, off the chain (SUB, not DEC: DEC leaves CF, and ADC after it would stall on
# partial flags); ESI points at a 64-byte buffer for the memory forms.
# imul_bsr_mix interleaves IMUL and BSR on one register (latencies add: an instruction inside the
# chain can never make it faster).
.intel_syntax noprefix
.text

.include "chain_frame.inc"


# @entry bsr_chain(n, buf) -> 8 dependent instances per iteration: BSR r32,r32
.globl bsr_chain
.p2align 4, 0xCC
bsr_chain:
    PROLOGUE
    mov eax, 0x40000000
.Lbsr_chain:
    bsr eax, eax
    bsr eax, eax
    bsr eax, eax
    bsr eax, eax
    bsr eax, eax
    bsr eax, eax
    bsr eax, eax
    bsr eax, eax
    sub     ebp, 1
    jnz     .Lbsr_chain
    EPILOGUE

# @entry mul_chain(n, buf) -> 8 dependent instances per iteration: MUL r32 (EDX:EAX = EAX * ECX)
.globl mul_chain
.p2align 4, 0xCC
mul_chain:
    PROLOGUE
    mov eax, 3
    mov ecx, 5
.Lmul_chain:
    mul ecx
    mul ecx
    mul ecx
    mul ecx
    mul ecx
    mul ecx
    mul ecx
    mul ecx
    sub     ebp, 1
    jnz     .Lmul_chain
    EPILOGUE

# @entry imul1_chain(n, buf) -> 8 dependent instances per iteration: IMUL r32 (one operand)
.globl imul1_chain
.p2align 4, 0xCC
imul1_chain:
    PROLOGUE
    mov eax, 3
    mov ecx, 5
.Limul1_chain:
    imul ecx
    imul ecx
    imul ecx
    imul ecx
    imul ecx
    imul ecx
    imul ecx
    imul ecx
    sub     ebp, 1
    jnz     .Limul1_chain
    EPILOGUE

# @entry imul_chain(n, buf) -> 8 dependent instances per iteration: IMUL r32,r32
.globl imul_chain
.p2align 4, 0xCC
imul_chain:
    PROLOGUE
    mov eax, 3
.Limul_chain:
    imul eax, eax
    imul eax, eax
    imul eax, eax
    imul eax, eax
    imul eax, eax
    imul eax, eax
    imul eax, eax
    imul eax, eax
    sub     ebp, 1
    jnz     .Limul_chain
    EPILOGUE

# @entry imul_imm_chain(n, buf) -> 8 dependent instances per iteration: IMUL r32,r32,imm8
.globl imul_imm_chain
.p2align 4, 0xCC
imul_imm_chain:
    PROLOGUE
    mov eax, 3
.Limul_imm_chain:
    imul eax, eax, 3
    imul eax, eax, 3
    imul eax, eax, 3
    imul eax, eax, 3
    imul eax, eax, 3
    imul eax, eax, 3
    imul eax, eax, 3
    imul eax, eax, 3
    sub     ebp, 1
    jnz     .Limul_imm_chain
    EPILOGUE

# @entry imul_mem_chain(n, buf) -> 8 dependent instances per iteration: IMUL r32,m32 through the address ([buf] = 1, EAX = buf: the load waits for the multiply)
.globl imul_mem_chain
.p2align 4, 0xCC
imul_mem_chain:
    PROLOGUE
    mov eax, esi
    mov dword ptr [esi], 1
.Limul_mem_chain:
    imul eax, [eax]
    imul eax, [eax]
    imul eax, [eax]
    imul eax, [eax]
    imul eax, [eax]
    imul eax, [eax]
    imul eax, [eax]
    imul eax, [eax]
    sub     ebp, 1
    jnz     .Limul_mem_chain
    EPILOGUE

# @entry add_mem_chain(n, buf) -> 8 dependent instances per iteration: ADD r32,m32 through the address ([buf] = 0, EAX = buf: load 3 + add 1)
.globl add_mem_chain
.p2align 4, 0xCC
add_mem_chain:
    PROLOGUE
    mov eax, esi
    mov dword ptr [esi], 0
.Ladd_mem_chain:
    add eax, [eax]
    add eax, [eax]
    add eax, [eax]
    add eax, [eax]
    add eax, [eax]
    add eax, [eax]
    add eax, [eax]
    add eax, [eax]
    sub     ebp, 1
    jnz     .Ladd_mem_chain
    EPILOGUE

# @entry shld_chain(n, buf) -> 8 dependent instances per iteration: SHLD r32,r32,imm8
.globl shld_chain
.p2align 4, 0xCC
shld_chain:
    PROLOGUE
    mov eax, 0x12345678
    mov edx, 0x9ABCDEF0
.Lshld_chain:
    shld eax, edx, 3
    shld eax, edx, 3
    shld eax, edx, 3
    shld eax, edx, 3
    shld eax, edx, 3
    shld eax, edx, 3
    shld eax, edx, 3
    shld eax, edx, 3
    sub     ebp, 1
    jnz     .Lshld_chain
    EPILOGUE

# @entry shrd_chain(n, buf) -> 8 dependent instances per iteration: SHRD r32,r32,imm8
.globl shrd_chain
.p2align 4, 0xCC
shrd_chain:
    PROLOGUE
    mov eax, 0x12345678
    mov edx, 0x9ABCDEF0
.Lshrd_chain:
    shrd eax, edx, 3
    shrd eax, edx, 3
    shrd eax, edx, 3
    shrd eax, edx, 3
    shrd eax, edx, 3
    shrd eax, edx, 3
    shrd eax, edx, 3
    shrd eax, edx, 3
    sub     ebp, 1
    jnz     .Lshrd_chain
    EPILOGUE

# @entry shrd_cl_chain(n, buf) -> 8 dependent instances per iteration: SHRD r32,r32,CL
.globl shrd_cl_chain
.p2align 4, 0xCC
shrd_cl_chain:
    PROLOGUE
    mov eax, 0x12345678
    mov edx, 0x9ABCDEF0
    mov ecx, 5
.Lshrd_cl_chain:
    shrd eax, edx, cl
    shrd eax, edx, cl
    shrd eax, edx, cl
    shrd eax, edx, cl
    shrd eax, edx, cl
    shrd eax, edx, cl
    shrd eax, edx, cl
    shrd eax, edx, cl
    sub     ebp, 1
    jnz     .Lshrd_cl_chain
    EPILOGUE

# @entry xchg_chain(n, buf) -> 8 dependent instances per iteration: XCHG r32,r32
.globl xchg_chain
.p2align 4, 0xCC
xchg_chain:
    PROLOGUE
    mov eax, 1
    mov ecx, 2
.Lxchg_chain:
    xchg eax, ecx
    xchg eax, ecx
    xchg eax, ecx
    xchg eax, ecx
    xchg eax, ecx
    xchg eax, ecx
    xchg eax, ecx
    xchg eax, ecx
    sub     ebp, 1
    jnz     .Lxchg_chain
    EPILOGUE

# @entry adc_chain(n, buf) -> 8 dependent instances per iteration: ADC r32,r32 (through EAX and CF)
.globl adc_chain
.p2align 4, 0xCC
adc_chain:
    PROLOGUE
    mov eax, 1
    mov ecx, 2
.Ladc_chain:
    adc eax, ecx
    adc eax, ecx
    adc eax, ecx
    adc eax, ecx
    adc eax, ecx
    adc eax, ecx
    adc eax, ecx
    adc eax, ecx
    sub     ebp, 1
    jnz     .Ladc_chain
    EPILOGUE

# @entry sbb_chain(n, buf) -> 8 dependent instances per iteration: SBB r32,r32 (through EAX and CF)
.globl sbb_chain
.p2align 4, 0xCC
sbb_chain:
    PROLOGUE
    mov eax, 1
    mov ecx, 2
.Lsbb_chain:
    sbb eax, ecx
    sbb eax, ecx
    sbb eax, ecx
    sbb eax, ecx
    sbb eax, ecx
    sbb eax, ecx
    sbb eax, ecx
    sbb eax, ecx
    sub     ebp, 1
    jnz     .Lsbb_chain
    EPILOGUE

# @entry imul_bsr_mix(n, buf) -> 4 dependent pairs per iteration: IMUL r32,r32 then BSR r32,r32, 4 pairs (IMUL 4 + BSR 2 per pair on the P6)
.globl imul_bsr_mix
.p2align 4, 0xCC
imul_bsr_mix:
    PROLOGUE
    mov eax, 0x40000000
.Limul_bsr_mix:
    imul eax, eax
    bsr eax, eax
    imul eax, eax
    bsr eax, eax
    imul eax, eax
    bsr eax, eax
    imul eax, eax
    bsr eax, eax
    sub     ebp, 1
    jnz     .Limul_bsr_mix
    EPILOGUE
