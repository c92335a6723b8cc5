// The 9-instruction texture-mapping inner loop of John DiCamillo's "Texture Mapping Optimization for
// Games", as kernels/texture/loops.S runs it (the count in CX), before the article reordered it into
// examples/texture-loop.s. Compare them: retrosim loop examples/texture-loop9.s examples/texture-loop.s
ml9:
      mov   al, BYTE PTR [ebx]   // read from texture
      mov   BYTE PTR [edi], al   // write to screen
      add   edx, esi             // update fractional part of u
      adc   bl,  dl              // update integral part of u
      add   eax, ecx             // update fractional part of v
      adc   bh,  dh              // update integral part of v
      inc   edi                  // next pixel in screen
      dec   cx                   // decrement count
      jnz   ml9                  // and do it again
