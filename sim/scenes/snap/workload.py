"""Vertex snapping to 1/16 pixel: the kernels' variants, the workloads, the exact reference and the
error measures (the Glide Programming Guide's "Programming Tips and Techniques"; the kernels are
kernels/snap/snap.S).

The reference is exact: a float32 coordinate is exactly a float64, times 16 is exact, and
``np.round`` rounds halves to even, so ``np.round(x * 16) / 16`` is the nearest multiple of 1/16,
ties to the even multiple, which is what the x87 does when it rounds the sum x + 3<<18 to 24 bits
(round to nearest even, the FNINIT rounding mode). Errors are distances from that grid point.

A coordinate is "wrong" when the kernel's result is not that nearest point, and "off the grid" when
it is not a multiple of 1/16 at all (the inconsistency the guide snaps to avoid; the portable
variant truncates, so it is on the grid but often not on the nearest point).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim import portable_math
from sim.guest.emu import Machine

KERNEL = Path(__file__).resolve().parents[3] / "kernels" / "snap" / "snap.S"
TRICK_BIAS = 3 << 18          # the guide's vertex_snapper, 786432 = 1.5 * 2^19
TRICK_LIMIT = 2.0 ** 18       # |x| below this: the 24-bit sum's last mantissa bit is worth 1/16
CONTROL_WORDS = {24: 0x007F, 53: 0x027F, 64: 0x037F}  # FNINIT's 0x037F with the precision field set


@dataclass(frozen=True)
class Variant:
    name: str
    entry: str        # kernels/snap/snap.S entry point
    precision: int    # x87 precision the kernel runs at (bits)
    label: str

    @property
    def control_word(self) -> int:
        return CONTROL_WORDS[self.precision]


VARIANTS = {v.name: v for v in (
    Variant("trick-24", "snap_trick", 24, "add and subtract 3<<18, x87 in 24-bit precision (the guide's setting)"),
    Variant("trick-53", "snap_trick", 53, "the same code, x87 in 53-bit precision"),
    Variant("trick-64", "snap_trick", 64, "the same code, x87 in 64-bit precision (the FNINIT state)"),
    Variant("portable-64", "snap_portable", 64, "(long)(x * 16) / 16.0, the guide's portable variant, 64-bit"),
    Variant("portable-24", "snap_portable", 24, "the portable variant with the x87 in 24-bit precision"),
)}

# workload name -> what it holds (the generators below)
WORKLOADS = {
    "screen": "ordinary screen coordinates, uniform over the screen",
    "negative": "negative coordinates, uniform over minus the screen (guard band, clipped geometry)",
    "tiny": "magnitudes 1e-45 to 1e-2, either sign (subnormal floats included)",
    "huge": "magnitudes 10^5.5 to 10^9, either sign (beyond the trick's 2^18)",
    "limit": "every 1/32 step within 4 pixels of +-2^18 and +-2^19, the trick's limits",
    "ties": "odd multiples of 1/32 over the screen: exactly halfway between two grid points",
    "grid": "exact multiples of 1/16 over the screen: snapping must leave them unchanged",
}
IN_RANGE = ("screen", "negative", "tiny", "ties", "grid")  # |x| < 2^18: where the trick is meant to work


def workload(name: str, vertices: int, width: int, height: int, seed: int) -> np.ndarray:
    """`vertices` (x, y) float32 pairs as a [vertices, 2] array; deterministic for a seed."""
    if name not in WORKLOADS:
        raise ValueError(f"unknown workload '{name}' (known: {', '.join(WORKLOADS)})")
    rng = np.random.default_rng([seed, list(WORKLOADS).index(name)])
    n = 2 * vertices
    span = np.resize(np.array([width, height], np.float64), n)  # x, y, x, y, ...
    if name == "screen":
        v = rng.uniform(0, 1, n) * span
    elif name == "negative":
        v = -rng.uniform(0, 1, n) * span
    elif name == "tiny":
        v = portable_math.power(10.0, rng.uniform(-45, -2, n)) * rng.choice([-1.0, 1.0], n)
    elif name == "huge":
        v = portable_math.power(10.0, rng.uniform(5.5, 9, n)) * rng.choice([-1.0, 1.0], n)
    elif name == "limit":
        steps = np.arange(-128, 129) / 32
        edges = np.concatenate([e + steps for e in (2.0 ** 18, -(2.0 ** 18), 2.0 ** 19, -(2.0 ** 19))])
        v = np.resize(edges, n)
    elif name == "ties":
        v = (2 * np.floor(rng.uniform(0, 1, n) * span * 16) + 1) / 32
    else:  # grid
        v = np.floor(rng.uniform(0, 1, n) * span * 16) / 16
    return v.astype(np.float32).reshape(vertices, 2)


def reference(coords: np.ndarray) -> np.ndarray:
    """The nearest multiple of 1/16 of each float32 coordinate, ties to even, exactly (float64)."""
    return np.round(np.asarray(coords, np.float32).astype(np.float64) * 16) / 16


def snap(machine: Machine, variant: Variant, coords: np.ndarray) -> np.ndarray:
    """Run one variant's kernel on a copy of `coords` ([n, 2] float32) in `machine`; the result."""
    machine.arena.reset()
    machine.reset_fpu()
    at = machine.arena.put(np.ascontiguousarray(coords, np.float32))
    machine.call(variant.entry, at, coords.shape[0], variant.control_word)
    return machine.arena.get(at, np.float32, coords.size).reshape(coords.shape)


def setup(variant: Variant, coords: np.ndarray):
    """A timing setup (sim.timing.kernel.Setup): the vertices in a fresh machine, the call's arguments."""
    def build(machine: Machine) -> list:
        machine.reset_fpu()
        return [machine.arena.put(np.ascontiguousarray(coords, np.float32)), coords.shape[0], variant.control_word]
    return build


@dataclass(frozen=True)
class Errors:
    """How one variant snapped one workload, against the exact reference."""

    coordinates: int
    wrong: int            # result is not the nearest 1/16 point
    off_grid: int         # result is not a multiple of 1/16
    worst: float          # largest distance from the nearest grid point, in pixels
    worst_input: float    # the input coordinate where it happened

    @property
    def wrong_share(self) -> float:
        return self.wrong / self.coordinates if self.coordinates else 0.0

    @property
    def off_grid_share(self) -> float:
        return self.off_grid / self.coordinates if self.coordinates else 0.0

    def as_dict(self) -> dict:
        return {"coordinates": self.coordinates, "wrong": self.wrong, "wrong_share": round(self.wrong_share, 6),
                "off_grid": self.off_grid, "off_grid_share": round(self.off_grid_share, 6),
                "worst_distance": self.worst, "worst_input": self.worst_input}


def errors(coords: np.ndarray, result: np.ndarray) -> Errors:
    x = np.asarray(coords, np.float32).ravel()
    got = np.asarray(result, np.float32).ravel().astype(np.float64)
    ref = reference(x)
    dist = np.abs(got - ref)  # exact: both are float32 values, their difference fits a float64
    wrong = got != ref
    off = got * 16 != np.round(got * 16)
    k = int(np.argmax(dist)) if dist.size else 0
    return Errors(int(x.size), int(np.count_nonzero(wrong)), int(np.count_nonzero(off)),
                  float(dist[k]) if dist.size else 0.0, float(x[k]) if dist.size else 0.0)


def failures(coords: np.ndarray, result: np.ndarray, limit: int = 4) -> list[dict]:
    """Up to `limit` wrong coordinates, the farthest from their grid point first (ties broken by
    input order): input, result, nearest grid point, distance in pixels, and whether the result is
    on the grid at all."""
    x = np.asarray(coords, np.float32).ravel()
    got = np.asarray(result, np.float32).ravel().astype(np.float64)
    ref = reference(x)
    dist = np.abs(got - ref)
    bad = np.flatnonzero(got != ref)
    order = bad[np.lexsort((bad, -dist[bad]))][:limit]
    return [{"input": float(x[i]), "result": float(got[i]), "nearest": float(ref[i]), "distance": float(dist[i]),
             "on_grid": bool(got[i] * 16 == np.round(got[i] * 16))} for i in order]
