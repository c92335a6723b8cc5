"""Perspective-correct textured frames for the texture article's span renderers
(kernels/texture/persp.S): the geometry, the span records the kernels read, the exact float64
texture coordinates of every pixel, and a bit-exact model of what each variant draws.

Conventions: pixel (x, y) has its centre at (x + 0.5, y + 0.5) (sim.scenes.raster's rasterizer and fill
rule). A triangle carries per-vertex texture coordinates (s, t) in texels and a depth w; u/w, v/w
and 1/w are planes over the screen (a, b, c in the article), so the exact coordinates of a pixel
are u = a / c, v = b / c. The texture is 256x256 8-bit, rows on 256-byte boundaries, on a 64 KB
boundary; a texel is (floor(u) mod 256, floor(v) mod 256).

The kernels get a, b, c at each span's first pixel and their steps over 16 pixels as doubles
that are exact in single precision (the span set-up stores them as floats; it also makes every
x87 result in 24-bit precision one IEEE single rounding, which numpy reproduces exactly). From
there each variant's arithmetic is modelled step for step: the x87's rounding at the variant's
precision (53-bit: IEEE double; 24-bit: IEEE single), _ftol's truncation or FISTP's rounding to
nearest even, the 16.16 (or 24.8) fixed point with its arithmetic shift by 4 per 16-pixel
sub-span, and the integer parts modulo 256.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim import stats
from sim.scenes import raster
from sim.errors import RetrosimError

KERNEL = "texture/persp.S"
VARIANTS = ("a", "b", "c", "d", "e")
VARIANT_LABELS = {
    "a": "tight inner loop only: _ftol, serial divide, 53-bit",
    "b": "divide overlapped, 24-bit precision",
    "c": "FISTP, reordered loop, set-up with UPDATE_U_V",
    "d": "the 4-clock inner loop",
    "e": "24.8 fixed point instead of 16.16",
}
PRECISION_BITS = {"a": 53, "b": 24, "c": 24, "d": 24, "e": 24}
FRACTION_BITS = {"a": 16, "b": 16, "c": 16, "d": 16, "e": 8}
CONVERSION = {"a": "_ftol", "b": "_ftol", "c": "fistp", "d": "fistp", "e": "fistp"}
RECORD_BYTES = 64
SUBSPAN = 16
TEX_SIZE = 256


class TextureSceneError(RetrosimError):
    """A texture frame the kernels cannot draw as the article's code would (see the message)."""


@dataclass(frozen=True, eq=False)
class TexturedGeometry:
    """Triangles in draw order: xy [n, 3, 2] pixels, st [n, 3, 2] texels, w [n, 3] depths (> 0)."""

    xy: np.ndarray
    st: np.ndarray
    w: np.ndarray

    def __len__(self) -> int:
        return int(self.xy.shape[0])

    def planes(self) -> np.ndarray:
        """[n, 3, 3]: for a = s/w, b = t/w, c = 1/w, the plane (value at vertex 0, d/dx, d/dy)."""
        e1 = self.xy[:, 1] - self.xy[:, 0]
        e2 = self.xy[:, 2] - self.xy[:, 0]
        det = e1[:, 0] * e2[:, 1] - e2[:, 0] * e1[:, 1]
        safe = np.where(det == 0.0, 1.0, det)
        vals = np.stack([self.st[:, :, 0] / self.w, self.st[:, :, 1] / self.w, 1.0 / self.w], axis=1)  # [n, 3, 3]
        d1 = vals[:, :, 1] - vals[:, :, 0]
        d2 = vals[:, :, 2] - vals[:, :, 0]
        ddx = np.where(det[:, None] == 0.0, 0.0, (d1 * e2[:, 1, None] - d2 * e1[:, 1, None]) / safe[:, None])
        ddy = np.where(det[:, None] == 0.0, 0.0, (e1[:, 0, None] * d2 - e2[:, 0, None] * d1) / safe[:, None])
        return np.stack([vals[:, :, 0], ddx, ddy], axis=2)

    def rasterize(self, width: int, height: int) -> raster.Spans:
        return raster.rasterize(raster.Geometry(self.xy, np.zeros((len(self), 3))), width, height)


def grid_scene(width: int, height: int, columns: int, rows: int, seed: int, w_range=(1.0, 4.0),
               st_range=(40.0, 216.0), jitter: float = 0.35) -> TexturedGeometry:
    """The screen tiled by a jittered grid of columns x rows cells, two triangles per cell, no
    overdraw (what the article's span sorter hands the renderer): each triangle textured with its
    own vertex coordinates in st_range and depths in w_range."""
    rng = np.random.default_rng(seed)
    gx = np.linspace(0.0, width, columns + 1)
    gy = np.linspace(0.0, height, rows + 1)
    px, py = np.meshgrid(gx, gy)
    inner = (slice(1, -1), slice(1, -1))
    px[inner] += rng.uniform(-jitter, jitter, px[inner].shape) * (width / columns)
    py[inner] += rng.uniform(-jitter, jitter, py[inner].shape) * (height / rows)
    tris = []
    for r in range(rows):
        for c in range(columns):
            p00, p10 = (px[r, c], py[r, c]), (px[r, c + 1], py[r, c + 1])
            p01, p11 = (px[r + 1, c], py[r + 1, c]), (px[r + 1, c + 1], py[r + 1, c + 1])
            if (r + c) % 2:
                tris += [(p00, p10, p11), (p00, p11, p01)]
            else:
                tris += [(p00, p10, p01), (p10, p11, p01)]
    xy = np.array(tris, np.float64)
    n = xy.shape[0]
    st = rng.uniform(st_range[0], st_range[1], (n, 3, 2))
    w = rng.uniform(w_range[0], w_range[1], (n, 3))
    return TexturedGeometry(xy, st, w)


def texture(seed: int = 1997) -> np.ndarray:
    """A 256x256 8-bit texture (the same as sim.studies.texture_loops's, so both reports read one bitmap)."""
    return np.random.default_rng(seed).integers(0, 256, TEX_SIZE * TEX_SIZE, dtype=np.uint8)


@dataclass(frozen=True, eq=False)
class SpanParams:
    """Per span: the screen position and the kernel's inputs (doubles exact in single precision)."""

    y: np.ndarray
    x0: np.ndarray
    count: np.ndarray
    tri: np.ndarray
    start: np.ndarray   # [n, 3] a, b, c at the first pixel's centre
    step: np.ndarray    # [n, 3] A, B, C: steps over 16 pixels

    def __len__(self) -> int:
        return int(self.y.shape[0])

    @property
    def pixels(self) -> int:
        return int(self.count.sum(dtype=np.int64))

    def select(self, mask) -> SpanParams:
        return SpanParams(self.y[mask], self.x0[mask], self.count[mask], self.tri[mask], self.start[mask],
                          self.step[mask])


def span_params(geometry: TexturedGeometry, width: int, height: int) -> SpanParams:
    spans = geometry.rasterize(width, height)
    planes = geometry.planes()[spans.tri]  # [n, 3, 3]
    x = spans.x0 + 0.5 - geometry.xy[spans.tri, 0, 0]
    y = spans.y + 0.5 - geometry.xy[spans.tri, 0, 1]
    start = planes[:, :, 0] + planes[:, :, 1] * x[:, None] + planes[:, :, 2] * y[:, None]
    step = SUBSPAN * planes[:, :, 1]
    # the set-up stores its values as floats
    start, step = (x.astype(np.float32).astype(np.float64) for x in (start, step))
    return SpanParams(spans.y.astype(np.int64), spans.x0.astype(np.int64), spans.count.astype(np.int64),
                      spans.tri.astype(np.int64), start, step)


def span_records(params: SpanParams, fbuf: int, width: int) -> np.ndarray:
    """The 64-byte records of kernels/texture/persp.S, as bytes."""
    n = len(params)
    rec = np.zeros((n, RECORD_BYTES // 8), np.float64)
    ints = rec.view(np.uint32)  # [n, 16]
    ints[:, 0] = fbuf + params.y * width + params.x0
    ints[:, 1] = params.count
    rec[:, 2:5] = params.start
    rec[:, 5:8] = params.step
    return rec.tobytes()


def pixel_index(params: SpanParams) -> tuple[np.ndarray, np.ndarray]:
    """(span of each pixel, offset within its span), pixels in draw order."""
    counts = params.count
    span = np.repeat(np.arange(len(params)), counts)
    offset = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
    return span, offset


def exact_coordinates(geometry: TexturedGeometry, params: SpanParams) -> tuple[np.ndarray, np.ndarray]:
    """u, v (texels, float64) at every pixel's centre, from the exact planes."""
    span, offset = pixel_index(params)
    planes = geometry.planes()[params.tri[span]]
    x = params.x0[span] + offset + 0.5 - geometry.xy[params.tri[span], 0, 0]
    y = params.y[span] + 0.5 - geometry.xy[params.tri[span], 0, 1]
    a, b, c = (planes[:, i, 0] + planes[:, i, 1] * x + planes[:, i, 2] * y for i in range(3))
    return a / c, b / c


def _wrap32(x: np.ndarray) -> np.ndarray:
    return ((x + (1 << 31)) & 0xFFFFFFFF) - (1 << 31)


def endpoint_coordinates(variant: str, params: SpanParams) -> tuple[np.ndarray, np.ndarray]:
    """[n, K + 1] fixed-point u, v the variant computes at the start of each sub-span k (and one
    past the last: the end point of the last sub-span), K = the most sub-spans of any span."""
    f = np.float64 if PRECISION_BITS[variant] == 53 else np.float32
    scale = float(1 << FRACTION_BITS[variant])
    conv = np.trunc if CONVERSION[variant] == "_ftol" else np.rint  # _ftol truncates; FISTP rounds to even
    k_max = int(-(-params.count.max() // SUBSPAN)) if len(params) else 0
    a, b, c = (params.start[:, i].astype(f) for i in range(3))
    A, B, C = (params.step[:, i].astype(f) for i in range(3))
    us, vs = [], []
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        for _ in range(k_max + 1):
            cinv = f(1.0) / c
            us.append(conv(((a * cinv).astype(np.float64)) * scale))
            vs.append(conv(((b * cinv).astype(np.float64)) * scale))
            a, b, c = a + A, b + B, c + C
    U, V = np.stack(us, axis=1), np.stack(vs, axis=1)
    # a span of n sub-spans uses end points 0..n; the kernel computes one more that it never uses
    used = np.arange(k_max + 1)[None, :] <= -(-params.count[:, None] // SUBSPAN)
    U, V = np.where(used, U, 0.0), np.where(used, V, 0.0)
    if not (np.all(np.isfinite(U)) and np.all(np.isfinite(V)) and np.abs(U).max(initial=0) < 2**31
            and np.abs(V).max(initial=0) < 2**31):
        raise TextureSceneError(f"variant {variant}: a texture coordinate does not fit FISTP's 32-bit integer "
                                "(a span reaches w <= 0 or very far texels)")
    return U.astype(np.int64), V.astype(np.int64)


@dataclass(frozen=True)
class VariantPixels:
    """What a variant draws: per pixel its fixed-point u, v (texels x 2^fraction bits) and the
    texel index Vi * 256 + Ui it reads."""

    u: np.ndarray
    v: np.ndarray
    index: np.ndarray

    def texels(self, tex: np.ndarray) -> np.ndarray:
        return tex[self.index]


def variant_pixels(variant: str, params: SpanParams) -> VariantPixels:
    U, V = endpoint_coordinates(variant, params)
    span, offset = pixel_index(params)
    k, i = offset // SUBSPAN, offset % SUBSPAN
    du = _wrap32(U[:, 1:] - U[:, :-1]) >> 4
    dv = _wrap32(V[:, 1:] - V[:, :-1]) >> 4
    u = U[span, k] + i * du[span, k]
    v = V[span, k] + i * dv[span, k]
    fb = FRACTION_BITS[variant]
    if variant == "e":
        # v carries the texture base (EDX = tex | v): it must start each sub-span inside 0..256 and
        # stay there, or the loop reads beside the texture
        v0 = V[span, k]
        if np.any((v0 < 0) | (v0 >= 1 << 16) | (v < 0) | (v >= 1 << 16)):
            bad = int(np.flatnonzero((v0 < 0) | (v0 >= 1 << 16) | (v < 0) | (v >= 1 << 16))[0])
            raise TextureSceneError(f"variant e (24.8): pixel {bad} has v = {v[bad] / 256:.3f} texels, outside 0..256, "
                                    "where the 24.8 loop's v carries the texture base; keep texture coordinates "
                                    "further inside the texture")
    index = (((v >> fb) & 255) << 8) | ((u >> fb) & 255)
    return VariantPixels(u, v, index)


def error_metrics(pixels: VariantPixels, variant: str, u_exact: np.ndarray, v_exact: np.ndarray) -> dict:
    """Share of pixels reading another texel than the exact mapping, and the coordinate errors
    (texels: the larger of |u - u_exact|, |v - v_exact| per pixel)."""
    scale = float(1 << FRACTION_BITS[variant])
    exact_index = ((np.floor(v_exact).astype(np.int64) & 255) << 8) | (np.floor(u_exact).astype(np.int64) & 255)
    err = np.maximum(np.abs(pixels.u / scale - u_exact), np.abs(pixels.v / scale - v_exact))
    n = int(err.size)
    wrong = int(np.count_nonzero(pixels.index != exact_index))
    return {"pixels": n, "wrong_texel": wrong, "wrong_texel_share": wrong / n if n else 0.0,
            "max_coordinate_error": float(err.max()) if n else 0.0,
            "mean_coordinate_error": stats.mean(err)}  # exact: the same digits on every machine
