"""The sort scene's kernels (kernels/sort/): what each variant runs, how one run is emulated, and
the check of its output against Python's own sort.

Every run is two calls in one machine state: ``sort_load`` copies the keys from a source buffer
into the buffer the variant works on (as the code that produced them would have written them:
the caches then hold them as far as they fit), then the variant's entry sorts (or clamps) them.
The report times the second call alone (the last call, sim.timing.kernel); branch predictors start
cold, as they would after other work. The arena layout is fixed (source, keys, tmp, histograms,
each 4 KB aligned), so addresses and cache behaviour repeat exactly.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim.errors import RetrosimError
from sim.guest.kernels import kernels_root

HIST_BYTES = 4 * ((1 << 11) + (1 << 5))  # the largest histograms (radix11_sort): 8,320 bytes
BUDGET = 400_000_000  # instructions per call: insertion sort of 64 K reversed keys is about 15 G, refused


@dataclass(frozen=True)
class Variant:
    name: str
    file: str          # under kernels/
    entry: str
    kind: str          # "comparison" | "radix" (sorts) | "clamp" (the select on its own)
    branches: str      # "branchy" | "sbb" | "cmov" | "none": how its key-dependent selects are made
    label: str

    @property
    def source(self) -> Path:
        return kernels_root() / self.file

    @property
    def sorts(self) -> bool:
        return self.kind != "clamp"

    @property
    def needs_cmov(self) -> bool:
        return self.branches == "cmov"


VARIANTS = {v.name: v for v in (
    Variant("insertion", "sort/insertion.S", "insertion_sort", "comparison", "branchy",
            "straight insertion sort, ordinary branches"),
    Variant("quicksort", "sort/quick.S", "quick_sort", "comparison", "branchy",
            "quicksort, Hoare partition around the middle key, insertion sort below 16 keys, ordinary branches"),
    Variant("merge-branchy", "sort/merge_branchy.S", "merge_sort_branchy", "comparison", "branchy",
            "bottom-up merge sort, the merge step's select an ordinary branch"),
    Variant("merge-sbb", "sort/merge_sbb.S", "merge_sort_sbb", "comparison", "sbb",
            "bottom-up merge sort, the merge step branch-free from CMP/SBB/ADC masks"),
    Variant("merge-cmov", "sort/merge_cmov.S", "merge_sort_cmov", "comparison", "cmov",
            "bottom-up merge sort, the merge step branch-free with CMOV (P6 only)"),
    Variant("radix8", "sort/radix.S", "radix8_sort", "radix", "none",
            "LSD radix sort, two 8-bit digits (histograms 2 x 1 KB)"),
    Variant("radix11", "sort/radix.S", "radix11_sort", "radix", "none",
            "LSD radix sort, digits of 11 and 5 bits (histograms 8 KB + 128 bytes)"),
    Variant("clamp-branchy", "sort/clamp.S", "clamp_branchy", "clamp", "branchy",
            "clamp each key into [lo, hi], two ordinary branches"),
    Variant("clamp-sbb", "sort/clamp.S", "clamp_sbb", "clamp", "sbb",
            "clamp each key into [lo, hi], SUB/SBB/AND masks"),
    Variant("clamp-cmov", "sort/clamp_cmov.S", "clamp_cmov", "clamp", "cmov",
            "clamp each key into [lo, hi], CMP/CMOV (P6 only)"),
)}


@dataclass(frozen=True)
class Layout:
    src: int
    keys: int
    tmp: int
    hist: int


def layout(machine, n: int) -> Layout:
    """The run's buffers in a freshly reset arena, always in this order."""
    machine.arena.reset()
    size = 2 * max(1, n)
    return Layout(*(machine.arena.alloc(b, align=4096) for b in (size, size, size, HIST_BYTES)))


def arguments(variant: Variant, lay: Layout, n: int, clamp: tuple[int, int]) -> tuple:
    if variant.kind == "clamp":
        return (lay.keys, n, clamp[0], clamp[1])
    return (lay.keys, n, lay.tmp, lay.hist)


def expected(variant: Variant, keys: np.ndarray, clamp: tuple[int, int]) -> list[int]:
    """What the kernel must leave in the keys buffer: Python's sorted(), or each key clamped."""
    values = keys.tolist()
    if variant.kind == "clamp":
        lo, hi = clamp
        return [min(max(k, lo), hi) for k in values]
    return sorted(values)


def check(variant: Variant, keys: np.ndarray, out: np.ndarray, clamp: tuple[int, int], what: str) -> None:
    """One RetrosimError if the kernel's output is not `expected` (a kernel or emulator bug)."""
    want = expected(variant, keys, clamp)
    got = out.tolist()
    if got != want:
        bad = next(i for i, (a, b) in enumerate(zip(got, want)) if a != b)
        raise RetrosimError(f"{variant.source}: {variant.entry} on {what}: key {bad} is {got[bad]:#06x}, Python's "
                            f"{'sort' if variant.sorts else 'clamp'} gives {want[bad]:#06x} (a kernel or emulator bug)")


def run_untraced(machine, variant: Variant, keys: np.ndarray, clamp: tuple[int, int]) -> np.ndarray:
    """Run a variant on `keys` in `machine` (no trace); its output."""
    n = int(keys.size)
    lay = layout(machine, n)
    machine.uc.mem_write(lay.src, np.ascontiguousarray(keys, np.uint16).tobytes())
    machine.call("sort_load", lay.keys, lay.src, n, budget=BUDGET)
    machine.call(variant.entry, *arguments(variant, lay, n, clamp), budget=BUDGET)
    return machine.arena.get(lay.keys, np.uint16, n)


def emulate(machine, variant: Variant, keys: np.ndarray, clamp: tuple[int, int]):
    """(traced emulation of sort_load then the variant, its output). The Emulation's last call is
    the variant's (sim.timing.kernel times the last call); `machine` is reused between runs (its
    arena is reset and laid out the same way each time)."""
    from sim.guest.trace import Trace
    from sim.timing.kernel import Emulation

    n = int(keys.size)
    lay = layout(machine, n)
    machine.uc.mem_write(lay.src, np.ascontiguousarray(keys, np.uint16).tobytes())
    parts = [machine.call("sort_load", lay.keys, lay.src, n, budget=BUDGET, trace=True).trace,
             machine.call(variant.entry, *arguments(variant, lay, n, clamp), budget=BUDGET, trace=True).trace]
    bounds = np.cumsum([p.instructions for p in parts]).tolist()
    emulation = Emulation(variant.source, variant.entry, None, 2, BUDGET, None, machine, Trace.concatenate(parts),
                          bounds)
    return emulation, machine.arena.get(lay.keys, np.uint16, n)
