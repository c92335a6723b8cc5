"""Throughput of the compiled cache hierarchy, for the CLI and for spotting performance regressions."""

from __future__ import annotations

import time

import numpy as np

from sim.memory.hierarchy import Hierarchy, simulate


def synthetic_trace(n: int, seed: int = 1998) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` accesses shaped like a span loop: mostly sequential 2- and 4-byte reads and writes over
    two buffers, some stack traffic, and 10% random reads over 4 MB (so every level misses
    sometimes)."""
    rng = np.random.default_rng(seed)
    i = np.arange(n, dtype=np.int64)
    addr = np.where(i % 3 == 0, 0x10000000 + (i // 3) * 2 % (1 << 20),        # z-buffer reads
           np.where(i % 3 == 1, 0x10100000 + (i // 3) * 2 % (1 << 20),        # frame-buffer writes
                    0x0FFFF000 + rng.integers(0, 64, n) * 4))                 # stack
    rand = rng.random(n) < 0.10
    addr = np.where(rand, 0x20000000 + rng.integers(0, 1 << 22, n), addr)
    size = np.where(i % 3 == 2, 4, 2).astype(np.uint8)
    write = (i % 3 == 1) | ((i % 3 == 2) & (rng.random(n) < 0.5))
    return addr.astype(np.uint32), size, write & ~rand


def cache_throughput(preset, n: int = 10_000_000, repeat: int = 3) -> float:
    """Accesses per second of :func:`simulate` over an ``n``-access synthetic trace on the data
    caches of ``preset`` (a CPU preset: its ``data_caches()``, the geometry of each level; best of
    ``repeat`` runs, compilation excluded)."""
    h = Hierarchy(preset.data_caches())
    addr, size, write = synthetic_trace(n)
    simulate(*h.arrays(), addr[:1000], size[:1000], write[:1000])  # compile (or load the cache)
    best = float("inf")
    for _ in range(repeat):
        h.reset()
        t0 = time.perf_counter()
        simulate(*h.arrays(), addr, size, write)
        best = min(best, time.perf_counter() - t0)
    return n / best
