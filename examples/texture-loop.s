// The reordered texture-mapping inner loop of John DiCamillo's "Texture Mapping Optimization for
// Games" (its 5-cycle Pentium version, EBP as the counter), pasted as printed there.
ml5:
      mov   al, BYTE PTR [ebx]   // read from texture
      add   edx, esi             // update fractional part of u
      adc   bl,  dl              // update integral part of u
      add   eax, ecx             // update fractional part of v
      adc   bh,  dh              // update integral part of v
      mov   BYTE PTR [edi], al   // write to screen
      inc   edi                  // next pixel in screen
      dec   ebp                  // decrement count
      jnz   ml5                  // and do it again
