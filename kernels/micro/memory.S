# Memory-latency micro-benchmark: a pointer chase. Each load's address is the previous load's
# value, so loads cannot overlap and each costs the full latency of wherever the line lives.
.intel_syntax noprefix
.text

# @entry chase(n, start) -> EAX = the pointer after n dependent loads (8 per iteration)
.globl chase
.p2align 4, 0xCC
chase:
    mov     ecx, [esp+4]
    mov     eax, [esp+8]
.Lchase:
    mov     eax, [eax]
    mov     eax, [eax]
    mov     eax, [eax]
    mov     eax, [eax]
    mov     eax, [eax]
    mov     eax, [eax]
    mov     eax, [eax]
    mov     eax, [eax]
    dec     ecx
    jnz     .Lchase
    ret
