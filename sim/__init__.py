"""retrosim: cycle-level timing of late-1990s x86 kernels (Pentium, P6, K6) from Unicorn traces."""

__version__ = "0.1.0"
