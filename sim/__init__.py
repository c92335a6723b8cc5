"""retrosim: cycle-level timing of late-1990s x86 kernels (Pentium, P6, K6) from Unicorn traces."""

import os

__version__ = "0.1.0"

# numba's loop vectorizer stays off for everything the package compiles (NUMBA_LOOP_VECTORIZE set
# in the environment still decides). The cores' cycle loops are scalar; vectorized copies of their
# short inner loops (a cache set's ways, an instruction's registers) only made the loops longer,
# and slower wherever their code landed: the speed check's trace ran 1.3-1.5x as fast on the P5
# core without them and 1.05-1.2x on the K6's (4 placements each, alternated). Results are the
# same either way (no floating-point reassociation without fastmath). Set here, before any
# compilation: numba reads it again before each compilation when the environment has changed.
os.environ.setdefault("NUMBA_LOOP_VECTORIZE", "0")
