# The inner loop gcc -O2 -m32 -S makes of `for (p = a; p != end; p++) s += *p;` (AT&T syntax)
.L3:
	addl	(%eax), %edx
	addl	$4, %eax
	cmpl	%ecx, %eax
	jne	.L3
