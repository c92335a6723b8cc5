"""Error of a Z-buffer variant's frame against the exact float64 reference (sim.scenes.raster.reference).

Every measure takes the variant's final buffers (zbuf, fbuf) as the kernel (or
sim.scenes.raster.simulate_frame) left them, and the exact (depth, owner) of the same spans. The frame
buffer tells which triangle won a pixel through its colour (by default triangle index + 1; pass
`colours`, the Geometry's colour array, otherwise: triangles sharing a colour cannot be told apart).
Results are frozen dataclasses with `.as_dict()` for JSON.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from sim import reference as ref
from sim import portable_math, stats
from sim.scenes.raster import CLEAR_VALUE, VARIANTS, Spans, expand_spans, stored_depth

FORMATS = ("fp16z", "z16", "z32")  # the fixed-point formats fp16_precision tabulates


def _expected_colour(owner: np.ndarray, colours) -> np.ndarray:
    """The colour each pixel should hold: colours[owner], 0 where nothing covers it."""
    owner = np.asarray(owner)
    if colours is None:
        return np.where(owner >= 0, owner + 1, 0).astype(np.int64)
    colours = np.asarray(colours, dtype=np.int64)
    return np.where(owner >= 0, colours[np.maximum(owner, 0)], 0)


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


@dataclass(frozen=True)
class VisibilityErrors:
    """Pixels whose winning triangle differs from the exact result.

    covered:   pixels some span covers (the denominator);
    errors:    covered pixels showing another triangle's colour, or none;
    fraction:  errors / covered;
    unwritten: of the errors, pixels no span won (the depth buffer still holds the far value: a depth
               that rounds to the clear value ties with it and ties fail). Only counted when zbuf is
               given;
    spurious:  uncovered pixels that nevertheless show a colour (0 unless the buffers are wrong).
    """

    covered: int
    errors: int
    fraction: float
    unwritten: int
    spurious: int

    def as_dict(self) -> dict:
        return asdict(self)


def visibility_errors(fbuf, owner, colours=None, zbuf=None, variant: str | None = None) -> VisibilityErrors:
    """Compare the frame buffer with the exact winners. With zbuf and variant, also count the
    erroneous pixels whose depth was never written (see VisibilityErrors.unwritten)."""
    fbuf = np.asarray(fbuf).astype(np.int64)
    owner = np.asarray(owner)
    if fbuf.shape != owner.shape:
        raise ValueError(f"fbuf shape {fbuf.shape} differs from owner shape {owner.shape}")
    covered = owner >= 0
    want = _expected_colour(owner, colours)
    wrong = covered & (fbuf != want)
    unwritten = 0
    if zbuf is not None:
        if variant not in VARIANTS:
            raise ValueError(f"give the variant of zbuf (one of {', '.join(VARIANTS)})")
        clear = np.asarray(zbuf) == np.asarray(CLEAR_VALUE[variant]).astype(np.asarray(zbuf).dtype)
        unwritten = int(np.count_nonzero(wrong & clear))
    n = int(np.count_nonzero(covered))
    e = int(np.count_nonzero(wrong))
    return VisibilityErrors(n, e, e / n if n else 0.0, unwritten, int(np.count_nonzero(~covered & (fbuf != 0))))


@dataclass(frozen=True)
class DepthError:
    """Stored depth (decoded with sim.scenes.raster.stored_depth) against the exact depth of the pixel's
    exact winner, over covered pixels, in units of the scene's exact depth range (max - min of the
    covered exact depths; `depth_range`, or 1.0 when all depths are equal). `worst_abs`/`mean_abs`
    are in depth units. The stored depth belongs to whichever triangle the variant let win, so a
    visibility error shows up here as the depth difference of the two surfaces."""

    variant: str
    pixels: int
    depth_range: float
    worst: float
    mean: float
    worst_abs: float
    mean_abs: float

    def as_dict(self) -> dict:
        d = asdict(self)
        for k in ("worst", "mean", "worst_abs", "mean_abs"):
            d[k] = _finite(d[k])  # JSON has no inf: an unwritten zf32 pixel gives null
        return d


def depth_error(zbuf, variant: str, depth, owner) -> DepthError:
    stored = stored_depth(zbuf, variant)
    depth = np.asarray(depth, dtype=np.float64)
    covered = np.asarray(owner) >= 0
    n = int(np.count_nonzero(covered))
    if n == 0:
        return DepthError(variant, 0, 1.0, 0.0, 0.0, 0.0, 0.0)
    exact = depth[covered]
    err = np.abs(stored[covered] - exact)
    rng = float(exact.max() - exact.min())
    unit = rng if rng > 0 else 1.0
    worst, mean = float(err.max()), stats.mean(err)  # exact: the same digits on every machine
    return DepthError(variant, n, unit, worst / unit, mean / unit, worst, mean)


@dataclass(frozen=True)
class ZFighting:
    """Nearly coplanar pairs (Geometry.pairs: nearer, farther). A pixel is contested when the
    farther surface covers it and the nearer surface is its exact winner (so nothing else is in
    front); the nearer surface loses it when the frame buffer shows anything else there.
    `far_first_*` restrict to pairs drawn farther-first, the only order in which a tie loses
    (nearer-first, a tie keeps the nearer surface)."""

    pairs: int
    contested: int
    lost: int
    fraction: float
    far_first_contested: int
    far_first_lost: int
    far_first_fraction: float

    def as_dict(self) -> dict:
        return asdict(self)


def z_fighting(fbuf, spans: Spans, pairs, owner, colours=None) -> ZFighting:
    """Measure z-fighting over the (nearer, farther) `pairs` (a triangle may be in several pairs;
    a pixel counts once, as drawn far-first if any farther partner covering it precedes the
    nearer one)."""
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    owner = np.asarray(owner)
    h, w = owner.shape
    ntri = int(max(spans.tri.max(initial=-1), pairs.max(initial=-1), owner.max(initial=-1))) + 1
    keys = np.unique(pairs[:, 1] * ntri + pairs[:, 0])  # farther * ntri + nearer
    is_far = np.zeros(ntri, bool)
    is_far[pairs[:, 1]] = True
    far_spans = spans.select(is_far[spans.tri])
    pix, span_of, _ = expand_spans(far_spans, w)
    far_tri = far_spans.tri[span_of].astype(np.int64)
    win = owner.reshape(-1)[pix].astype(np.int64)
    contested = (win >= 0) & np.isin(far_tri * ntri + win, keys)
    pix, near, far_first = pix[contested], win[contested], far_tri[contested] < win[contested]
    pix, first, inverse = np.unique(pix, return_index=True, return_inverse=True)
    near = near[first]
    ff = np.zeros(pix.size, bool)
    np.logical_or.at(ff, inverse, far_first)
    want = near + 1 if colours is None else np.asarray(colours, np.int64)[near]
    lost = np.asarray(fbuf).reshape(-1)[pix].astype(np.int64) != want
    c, l_ = int(pix.size), int(np.count_nonzero(lost))
    fc, fl = int(np.count_nonzero(ff)), int(np.count_nonzero(lost & ff))
    return ZFighting(int(len(pairs)), c, l_, l_ / c if c else 0.0, fc, fl, fl / fc if fc else 0.0)


@dataclass(frozen=True)
class FrameErrors:
    """The per-frame measures of one variant together."""

    variant: str
    visibility: VisibilityErrors
    depth: DepthError
    z_fighting: ZFighting | None = None

    def as_dict(self) -> dict:
        return {"variant": self.variant, "visibility": self.visibility.as_dict(), "depth": self.depth.as_dict(),
                "z_fighting": None if self.z_fighting is None else self.z_fighting.as_dict()}


def frame_errors(variant: str, zbuf, fbuf, depth, owner, colours=None, spans: Spans | None = None,
                 pairs=None) -> FrameErrors:
    """Visibility and depth errors of one variant's frame; z-fighting too when spans and pairs are
    given."""
    zf = None if pairs is None or spans is None else z_fighting(fbuf, spans, pairs, owner, colours)
    return FrameErrors(variant, visibility_errors(fbuf, owner, colours, zbuf, variant),
                       depth_error(zbuf, variant, depth, owner), zf)


# ---------------------------------------------------------------------------------------------
# the precision each format delivers across the depth range

def quantization_step(depth, fmt: str) -> np.ndarray:
    """Distance between the representable depth at or below `depth` and the next one up, for the
    fixed-point formats: z32 2^-32 and z16 2^-16 everywhere; fp16z (z = floor(depth x 2^32), 5-bit
    exponent e = msb(z), 11-bit mantissa) 2^(e - 11 - 32) for z >= 2^11 and 2^-32 below (small
    depths are stored exactly, except that 0 and 1 share a code; depth 0 in a running kernel also
    hits the stale-ECX hazard)."""
    d = np.asarray(depth, dtype=np.float64)
    if fmt == "z32":
        return np.full(d.shape, 2.0 ** -32)
    if fmt == "z16":
        return np.full(d.shape, 2.0 ** -16)
    if fmt != "fp16z":
        raise ValueError(f"unknown format {fmt!r} (known: {', '.join(FORMATS)})")
    z = np.clip(np.floor(d * 2.0 ** 32), 0, 2.0 ** 32 - 1).astype(np.uint32)
    e = ref.msb_index(z)
    # each code covers 2^(e - 11) consecutive 32-bit depths from e = 11 up, a single depth below;
    # 0 and 1 share code 0 (SHRD by a count of 0 leaves EDX as it was)
    units = np.where(z < 2, 2.0, 2.0 ** np.maximum(e - 11, 0))
    return units / 2.0 ** 32


@dataclass(frozen=True)
class PrecisionTable:
    """Per depth bin: the bin's edges and centre (geometric centre for log bins), and for each
    format the quantization step at the centre (`step`), that step relative to the centre depth
    (`relative`), and the largest step/depth anywhere in the bin (`worst_relative`, attained at the
    bin's lower edge or where the 16-bit float's exponent steps up). Columns are tuples by format."""

    spacing: str
    depth_lo: tuple[float, ...]
    depth_hi: tuple[float, ...]
    depth_mid: tuple[float, ...]
    step: dict
    relative: dict
    worst_relative: dict

    def rows(self) -> list[dict]:
        out = []
        for i in range(len(self.depth_mid)):
            row = {"depth_lo": self.depth_lo[i], "depth_hi": self.depth_hi[i], "depth_mid": self.depth_mid[i]}
            for f in self.step:
                row[f"{f}_step"] = self.step[f][i]
                row[f"{f}_relative"] = self.relative[f][i]
                row[f"{f}_worst_relative"] = self.worst_relative[f][i]
            out.append(row)
        return out

    def as_dict(self) -> dict:
        return {"spacing": self.spacing, "depth_lo": list(self.depth_lo), "depth_hi": list(self.depth_hi),
                "depth_mid": list(self.depth_mid), "step": {k: list(v) for k, v in self.step.items()},
                "relative": {k: list(v) for k, v in self.relative.items()},
                "worst_relative": {k: list(v) for k, v in self.worst_relative.items()}}


def fp16_precision(depth_lo: float, depth_hi: float, bins: int, spacing: str = "log") -> PrecisionTable:
    """The relative precision the 16-bit float Z-buffer (and, for comparison, z16 and z32) delivers
    across [depth_lo, depth_hi): quantization step / depth per bin. Log spacing (default, needs
    depth_lo > 0) shows the float format's constant ~2^-11..2^-12 relative step above depth 2^-21
    against z16's relative step growing as 1/depth toward the camera."""
    if spacing not in ("log", "linear"):
        raise ValueError("spacing must be 'log' or 'linear'")
    if not (0 <= depth_lo < depth_hi <= 1) or (spacing == "log" and depth_lo <= 0):
        raise ValueError(f"need 0 {'<' if spacing == 'log' else '<='} depth_lo < depth_hi <= 1")
    if bins < 1:
        raise ValueError("bins must be >= 1")
    if spacing == "log":
        edges = portable_math.geomspace(depth_lo, depth_hi, bins + 1)
        mid = np.sqrt(edges[:-1] * edges[1:])
    else:
        edges = np.linspace(depth_lo, depth_hi, bins + 1)
        mid = 0.5 * (edges[:-1] + edges[1:])
    lo, hi = edges[:-1], edges[1:]
    step, rel, worst = {}, {}, {}
    for f in FORMATS:
        s = quantization_step(mid, f)
        step[f] = tuple(s.tolist())
        with np.errstate(divide="ignore"):
            rel[f] = tuple((s / mid).tolist())
            w = quantization_step(lo, f) / lo
        if f == "fp16z":
            # the step doubles at each power of two from 2^11 units (2^-21) up: step/depth = 2^-11 there
            e_lo = (np.frexp(np.maximum(lo, 2.0 ** -21))[1] - 1).astype(np.float64)  # floor(log2), exactly
            has_boundary = (2.0 ** (e_lo + 1) < hi) | ((2.0 ** e_lo == lo) & (lo >= 2.0 ** -21))
            w = np.where(has_boundary, np.maximum(w, 2.0 ** -11), w)
        worst[f] = tuple(w.tolist())
    return PrecisionTable(spacing, tuple(lo.tolist()), tuple(hi.tolist()), tuple(mid.tolist()), step, rel, worst)
