"""The keys a sort scene sorts: 16-bit unsigned integers, synthetic (deterministic from a seed) or
the depth keys of a Z-buffer scene.

Synthetic distributions (:data:`SYNTHETIC`) are numpy draws from ``default_rng([seed, index of the
distribution, n])`` ("sorted" and "reversed" order the "uniform" draw), so each (distribution,
size) has its own keys and adding a size or a distribution changes no other. The Z-buffer keys are built only when a scene lists them
(:func:`zbuffer_keys`): only then is the Z-buffer scene's frame read (sim.scenes.geometry) and
rasterized (sim.scenes.raster, imported inside the function, never at module level).

The Z-buffer keys are the 16-bit float depth codes of the article "A 16-bit floating-point
Z-buffer" (fp16z: exponent in the top 5 bits, 11 mantissa bits below, sim.reference.fp16z_encode)
of every pixel the scene's frame draws, in draw order. The code is monotone in the depth (a larger
depth never has a smaller code), so sorting the codes as unsigned 16-bit integers sorts the pixels
by depth. A sort of n keys takes n of them evenly spaced over the frame's pixel visits (visit
floor(i * visits / n) for i < n), so every size samples the whole frame: runs of nearby, slowly
changing depths along spans, broken where one triangle's spans end and another's begin.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

# distribution name -> what it holds
SYNTHETIC = {
    "uniform": "uniform over 0..65535",
    "sorted": "the uniform keys, already in ascending order",
    "reversed": "the uniform keys in descending order",
    "few": "four distinct values (uniform over 0..65535), each key one of them at random",
    "duplicates": "n/4 distinct values (uniform over 0..65535), each key one of them at random: about four copies of each",
    "equal": "one value (uniform over 0..65535) n times",
    "max": "0xFFFF n times (the largest code: the far plane of a cleared 16-bit depth buffer)",
}
ZBUFFER = "zbuffer"
DISTRIBUTIONS = {**SYNTHETIC, ZBUFFER: "the fp16z depth codes of a Z-buffer scene's pixels, in draw order, n of them evenly "
                                       "spaced over the frame"}


def synthetic(name: str, n: int, seed: int) -> np.ndarray:
    """n uint16 keys of a synthetic distribution; the same for the same (name, n, seed)."""
    if name not in SYNTHETIC:
        raise ValueError(f"unknown key distribution '{name}' (known: {', '.join(SYNTHETIC)})")
    stream = "uniform" if name in ("sorted", "reversed") else name  # the uniform keys, put in order
    rng = np.random.default_rng([seed, list(SYNTHETIC).index(stream), n])
    if name in ("uniform", "sorted", "reversed"):
        k = rng.integers(0, 1 << 16, n)
        if name != "uniform":
            k = np.sort(k)
            if name == "reversed":
                k = k[::-1]
    elif name == "few":
        k = rng.choice(rng.integers(0, 1 << 16, 4), n)
    elif name == "duplicates":
        k = rng.choice(rng.integers(0, 1 << 16, max(1, n // 4)), n)
    elif name == "equal":
        k = np.full(n, rng.integers(0, 1 << 16))
    else:  # max
        k = np.full(n, 0xFFFF)
    return np.ascontiguousarray(k, dtype=np.uint16)


@dataclass(frozen=True)
class DepthKeys:
    """Every pixel visit's fp16z code of one Z-buffer scene's frame, in draw order."""

    scene: str
    codes: np.ndarray   # uint16, one per pixel visit
    spans: int
    triangles: int

    def take(self, n: int) -> np.ndarray:
        """n codes evenly spaced over the visits (visit floor(i * visits / n))."""
        if n > self.codes.size:
            raise ValueError(f"{self.scene} draws {self.codes.size:,} pixels, fewer than the {n:,} keys asked for")
        at = (np.arange(n, dtype=np.int64) * self.codes.size) // max(1, n)
        return np.ascontiguousarray(self.codes[at])


def zbuffer_keys(path: Path) -> DepthKeys:
    """The depth codes of the Z-buffer scene file `path`: its geometry rasterized as its runner
    does, each span's 32-bit fixed-point depth interpolated as the fp16z kernel steps it
    (z0 + k dz, modulo 2^32) and encoded without hazards (sim.reference.fp16z_encode)."""
    from sim.reference import fp16z_encode
    from sim.scenes import raster
    from sim.scenes.geometry import load_frame

    zscene = load_frame(path)
    geometry = zscene.build_geometry()
    spans = raster.rasterize(geometry, zscene.width, zscene.height)
    z0, dz = raster.span_parameters(spans, "fp16z")
    _, span_of, k = raster.expand_spans(spans, zscene.width)
    z = (z0.astype(np.uint64)[span_of] + k.astype(np.uint64) * dz.astype(np.uint64)[span_of]) & np.uint64(0xFFFFFFFF)
    return DepthKeys(zscene.name, fp16z_encode(z.astype(np.uint32)), len(spans), int(geometry.z.shape[0]))
