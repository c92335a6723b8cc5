"""retrosim: cycle-level timing of late-1990s x86 kernels (Pentium, P6, K6) from Unicorn traces."""

import os

__version__ = "0.1.0"

# numba's loop vectorizer stays off for everything the package compiles (NUMBA_LOOP_VECTORIZE set
# in the environment still decides). The cores' cycle loops are scalar; vectorized copies of their
# short inner loops (a cache set's ways, an instruction's registers) only made the loops longer:
# the speed check's trace ran 1.3-1.5x as fast on the P5 core without them, its four placements
# all at 42.6-43.6 M instructions/s (against 24.8-39.4); the K6 and P6 cores stayed within their
# spread. Results are the same either way (no floating-point
# reassociation without fastmath). Set here, before any compilation: numba reads the environment
# again before each compilation when it has changed.
os.environ.setdefault("NUMBA_LOOP_VECTORIZE", "0")
