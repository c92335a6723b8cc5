"""Triangle setup and span generation (numpy), the exact float64 Z-buffer reference, and the
bit-exact expected frame of each Z-buffer kernel variant.

Conventions
-----------
- Screen coordinates are pixels, x to the right and y down; pixel (x, y) has its centre at
  (x + 0.5, y + 0.5). Depth is in [0, 1) and smaller is nearer.
- Depth is a plane over the screen (linear in x and y, as z/w is after projection), fixed by the
  triangle's three vertex depths.
- Fill rule (top-left): a pixel centre belongs to a triangle when it is on or right of the
  triangle's left edge and strictly left of its right edge, in a row whose centre is on or below the
  top vertex and strictly above the bottom vertex. Every edge's x at a row is computed from the
  edge's endpoints ordered top to bottom, the same way for every triangle that shares the edge, so
  two triangles sharing an edge cover each pixel along it exactly once (no cracks, no double hits).
- Spans come in draw order: triangle order, then row (top to bottom), one span per covered row.

The kernels are called with (zbuf, fbuf, count, z, dz, colour) per span (see kernels/zbuffer/);
:func:`span_parameters` gives z and dz for each variant and :func:`simulate_frame` the buffers the
kernel's frame driver (kernels/zbuffer/draw.inc) must leave behind.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit

from sim import portable_math
from sim import reference as ref

VARIANTS = ("z32", "z16", "fp16z", "fp16t", "zf32")
INTEGER_VARIANTS = ("z32", "z16", "fp16z", "fp16t")
TWO32 = float(1 << 32)
MAX_TRIANGLES = 0xFFFF  # colours are triangle index + 1 in a 16-bit frame buffer

# what each variant stores per pixel, and the value its buffer is cleared to (the far value)
ZBUF_DTYPE = {"z32": np.dtype(np.uint32), "z16": np.dtype(np.uint16), "fp16z": np.dtype(np.uint16),
              "fp16t": np.dtype(np.uint16), "zf32": np.dtype(np.float32)}
CLEAR_VALUE = {"z32": 0xFFFFFFFF, "z16": 0xFFFF, "fp16z": 0xFFFF, "fp16t": 0xFFFF, "zf32": np.inf}


def _check_variant(variant: str) -> None:
    if variant not in VARIANTS:
        raise ValueError(f"unknown Z-buffer variant {variant!r} (known: {', '.join(VARIANTS)})")


def clear_value(variant: str):
    """The far value a cleared depth buffer of this variant holds (as the buffer's dtype)."""
    _check_variant(variant)
    return ZBUF_DTYPE[variant].type(CLEAR_VALUE[variant])


def clear_dword(variant: str) -> int:
    """The 32-bit word the frame driver fills the depth buffer with (its `zclear` argument)."""
    _check_variant(variant)
    word = np.full(4 // ZBUF_DTYPE[variant].itemsize, CLEAR_VALUE[variant], ZBUF_DTYPE[variant])
    return int(word.view(np.uint32)[0])


# --------------------------------------------------------------------------------------------
# geometry

@dataclass(frozen=True, eq=False)
class Geometry:
    """Triangles in draw order.

    xy:      float64 [n, 3, 2] screen coordinates (pixels) of the vertices, either winding;
    z:       float64 [n, 3] vertex depths in [0, 1), smaller is nearer;
    colour:  uint16 [n] what the kernels write to the frame buffer (default: index + 1, so a frame
             buffer says which triangle won a pixel and 0 means "never written");
    pairs:   int32 [m, 2] (nearer, farther) triangle indices of nearly coplanar pairs, for the
             z-fighting metric (only :func:`coplanar_far_scene` sets it);
    keep_empty: the generator asks the rasterizer to keep zero-length spans (:func:`tiny_scene`).
    """

    xy: np.ndarray
    z: np.ndarray
    colour: np.ndarray = None
    pairs: np.ndarray | None = None
    keep_empty: bool = False
    name: str = field(default="", compare=False)

    def __post_init__(self):
        xy = np.ascontiguousarray(self.xy, dtype=np.float64)
        z = np.ascontiguousarray(self.z, dtype=np.float64)
        if xy.ndim != 3 or xy.shape[1:] != (3, 2):
            raise ValueError(f"xy must have shape [n, 3, 2], got {list(xy.shape)}")
        n = xy.shape[0]
        if z.shape != (n, 3):
            raise ValueError(f"z must have shape [{n}, 3], got {list(z.shape)}")
        if n > MAX_TRIANGLES:
            raise ValueError(f"{n} triangles: at most {MAX_TRIANGLES} (colours are 16-bit)")
        if not (np.all(np.isfinite(xy)) and np.all(np.isfinite(z))):
            raise ValueError("vertex coordinates and depths must be finite")
        if n and (z.min() < 0.0 or z.max() >= 1.0):
            raise ValueError(f"depths must be in [0, 1), got [{z.min()!r}, {z.max()!r}]")
        colour = np.arange(1, n + 1) if self.colour is None else np.asarray(self.colour)
        if colour.shape != (n,) or (n and (colour.min() < 0 or colour.max() > 0xFFFF)):
            raise ValueError(f"colour must be [{n}] values in 0..65535")
        colour = colour.astype(np.uint16)
        pairs = None
        if self.pairs is not None:
            pairs = np.asarray(self.pairs, dtype=np.int32).reshape(-1, 2)
            if pairs.size and (pairs.min() < 0 or pairs.max() >= n):
                raise ValueError("pairs must index triangles")
        for name, value in (("xy", xy), ("z", z), ("colour", colour), ("pairs", pairs)):
            if value is not None:
                value.setflags(write=False)
            object.__setattr__(self, name, value)

    def __len__(self) -> int:
        return self.xy.shape[0]

    def areas(self) -> np.ndarray:
        """Unsigned area of each triangle in pixels."""
        e1 = self.xy[:, 1] - self.xy[:, 0]
        e2 = self.xy[:, 2] - self.xy[:, 0]
        return 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])

    def planes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Depth plane of each triangle: (ddx, ddy, det) with depth(x, y) = z0 + ddx (x - x0) +
        ddy (y - y0) about vertex 0; det is twice the signed area (0 for a degenerate triangle,
        whose slopes are then 0)."""
        e1 = self.xy[:, 1] - self.xy[:, 0]
        e2 = self.xy[:, 2] - self.xy[:, 0]
        dz1 = self.z[:, 1] - self.z[:, 0]
        dz2 = self.z[:, 2] - self.z[:, 0]
        det = e1[:, 0] * e2[:, 1] - e2[:, 0] * e1[:, 1]
        safe = np.where(det == 0.0, 1.0, det)
        ddx = np.where(det == 0.0, 0.0, (dz1 * e2[:, 1] - dz2 * e1[:, 1]) / safe)
        ddy = np.where(det == 0.0, 0.0, (e1[:, 0] * dz2 - e2[:, 0] * dz1) / safe)
        return ddx, ddy, det

    def depth_at(self, tri, x, y) -> np.ndarray:
        """The exact (float64) plane depth of triangle(s) `tri` at screen point(s) (x, y)."""
        ddx, ddy, _ = self.planes()
        tri = np.asarray(tri)
        return (self.z[tri, 0] + ddx[tri] * (np.asarray(x, np.float64) - self.xy[tri, 0, 0])
                + ddy[tri] * (np.asarray(y, np.float64) - self.xy[tri, 0, 1]))


def _unit_triangles(rng: np.random.Generator, n: int) -> np.ndarray:
    """n random, reasonably shaped triangles of area 1 centred on their centroid: vertices at
    jittered angles around a circle, stretched by up to 3:1 in a random direction."""
    base = np.array([0.0, 2 * np.pi / 3, 4 * np.pi / 3])
    ang = base + rng.uniform(-0.45, 0.45, (n, 3)) + rng.uniform(0, 2 * np.pi, (n, 1))
    rad = rng.uniform(0.6, 1.0, (n, 3))
    sin_a, cos_a = portable_math.sin_cos(ang)
    pts = np.stack([rad * cos_a, rad * sin_a], axis=-1)
    stretch = rng.uniform(1.0, 3.0, n)
    theta = rng.uniform(0, np.pi, n)
    s, c = portable_math.sin_cos(theta)
    u = pts[..., 0] * c[:, None] + pts[..., 1] * s[:, None]
    v = -pts[..., 0] * s[:, None] + pts[..., 1] * c[:, None]
    u = u * stretch[:, None]
    pts = np.stack([u * c[:, None] - v * s[:, None], u * s[:, None] + v * c[:, None]], axis=-1)
    pts -= pts.mean(axis=1, keepdims=True)
    e1, e2 = pts[:, 1] - pts[:, 0], pts[:, 2] - pts[:, 0]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    return pts / np.sqrt(area)[:, None, None]


def _plane_depths(rng, xy, centre_depth, variation, z_range) -> np.ndarray:
    """Vertex depths of planes through `centre_depth` at each centroid, tilted in a random
    direction so that the depth changes by about `variation` across the triangle, clamped into
    z_range (clamping a vertex still leaves a plane through the three vertices)."""
    centre = xy.mean(axis=1)
    rel = xy - centre[:, None, :]
    radius = np.sqrt((rel ** 2).sum(-1)).max(axis=1)
    phi = rng.uniform(0, 2 * np.pi, len(xy))
    g = portable_math.unit_vectors(phi) * (variation / (2 * np.maximum(radius, 1e-9)))[:, None]
    z = centre_depth[:, None] + (rel * g[:, None, :]).sum(-1)
    lo, hi = z_range
    return np.clip(z, lo, np.nextafter(hi, 0.0))


def _check_range(z_range) -> tuple[float, float]:
    lo, hi = (float(v) for v in z_range)
    if not 0.0 <= lo < hi <= 1.0:
        raise ValueError(f"z_range must satisfy 0 <= lo < hi <= 1, got {z_range!r}")
    return lo, hi


def random_scene(width: int, height: int, triangles: int, depth_complexity: float, seed: int,
                 z_range=(0.05, 0.95)) -> Geometry:
    """A game-like frame: `triangles` overlapping triangles of log-normally distributed area
    (sigma 1, so a few large ones and many small ones), centred over the screen plus a 10% margin
    so that some are partly off-screen, scaled so that the rasterized (clipped) area is about
    depth_complexity x width x height (the scale is calibrated by rasterizing, so the target holds
    after clipping; it cannot be met when a few triangles would have to cover more than the whole
    screen). Each triangle has its own depth plane: a centre depth uniform in z_range and a slope
    that changes depth by up to 30% of the range across the triangle, so neighbours interpenetrate.
    Deterministic for a seed."""
    if triangles < 1 or triangles > MAX_TRIANGLES:
        raise ValueError(f"triangles must be 1..{MAX_TRIANGLES}, got {triangles}")
    if not depth_complexity > 0:
        raise ValueError(f"depth_complexity must be > 0, got {depth_complexity}")
    lo, hi = _check_range(z_range)
    rng = np.random.default_rng(seed)
    n = triangles
    shapes = _unit_triangles(rng, n)
    rel_area = portable_math.exp_array(rng.normal(0.0, 1.0, n))
    rel_area /= rel_area.sum()
    centres = np.stack([rng.uniform(-0.1 * width, 1.1 * width, n),
                        rng.uniform(-0.1 * height, 1.1 * height, n)], -1)
    centre_depth = rng.uniform(lo, hi, n)
    variation = rng.uniform(0.0, 0.3, n) * (hi - lo)
    phi_rng = np.random.default_rng([seed, 1])
    target = depth_complexity * width * height
    scale = 1.0 / 0.8  # a first guess for the clipped fraction
    for _ in range(8):
        sides = np.sqrt(rel_area * target * scale)
        xy = centres[:, None, :] + shapes * sides[:, None, None]
        covered = int(rasterize(Geometry(xy, np.full((n, 3), lo)), width, height).count.sum())
        if covered == 0 or abs(covered - target) <= 0.01 * target:
            break
        scale *= min(target / covered, 4.0)
    z = _plane_depths(phi_rng, xy, centre_depth, variation, (lo, hi))
    return Geometry(xy, z, name=f"random-{seed}")


def coplanar_far_scene(width: int, height: int, pairs: int = 40, seed: int = 0, z_range=(0.85, 0.95),
                       separation: float = 2.0 ** -20) -> Geometry:
    """Z-fighting: `pairs` pairs of nearly coplanar surfaces far from the camera. Each pair is a
    triangle on a gently sloped plane with its depth in z_range, and a second triangle (its vertices
    jittered by up to 15% of its size, so the two overlap over most of their area) on the parallel
    plane `separation` nearer. The order within each pair is random (seeded): where the farther one
    is drawn first the nearer must strictly pass a test against it, which a format that cannot tell
    the two depths apart fails (ties fail). Geometry.pairs lists (nearer, farther) per pair.
    The default separation, 2^-20 of the depth range, is 4096 steps of z32 but 1/16 step of z16."""
    lo, hi = _check_range(z_range)
    if not 0 < separation < (hi - lo):
        raise ValueError("separation must be positive and smaller than the z range")
    if pairs < 1 or 2 * pairs > MAX_TRIANGLES:
        raise ValueError(f"pairs must be 1..{MAX_TRIANGLES // 2}")
    rng = np.random.default_rng(seed)
    shapes = _unit_triangles(rng, pairs)
    side = np.sqrt(portable_math.exp_array(rng.normal(0.0, 0.5, pairs)) * 1.5 * width * height / pairs)
    centres = np.stack([rng.uniform(0.1 * width, 0.9 * width, pairs),
                        rng.uniform(0.1 * height, 0.9 * height, pairs)], -1)
    far_xy = centres[:, None, :] + shapes * side[:, None, None]
    near_xy = far_xy + rng.uniform(-0.15, 0.15, far_xy.shape) * side[:, None, None]
    centre_depth = rng.uniform(lo + separation, hi, pairs)
    # the shared plane, through the far triangle's centroid, tilted by up to 20% of the range
    variation = rng.uniform(0.0, 0.2, pairs) * (hi - lo)
    phi = rng.uniform(0, 2 * np.pi, pairs)
    radius = np.sqrt(((far_xy - centres[:, None, :]) ** 2).sum(-1)).max(axis=1)
    g = portable_math.unit_vectors(phi) * (variation / (2 * radius))[:, None]

    def plane(xy):
        return centre_depth[:, None] + ((xy - centres[:, None, :]) * g[:, None, :]).sum(-1)

    # keep both planes inside z_range: shift a pair's plane if a vertex would leave it
    zf, zn = plane(far_xy), plane(near_xy) - separation
    shift = np.maximum(lo - np.minimum(zf.min(1), zn.min(1)), 0.0)
    shift -= np.maximum(np.maximum(zf.max(1), zn.max(1)) - np.nextafter(hi, 0.0) + shift, 0.0)
    zf, zn = zf + shift[:, None], zn + shift[:, None]
    near_first = rng.random(pairs) < 0.5
    xy = np.empty((2 * pairs, 3, 2))
    z = np.empty((2 * pairs, 3))
    near_idx = np.where(near_first, 2 * np.arange(pairs), 2 * np.arange(pairs) + 1)
    far_idx = np.where(near_first, 2 * np.arange(pairs) + 1, 2 * np.arange(pairs))
    xy[near_idx], z[near_idx] = near_xy, zn
    xy[far_idx], z[far_idx] = far_xy, zf
    return Geometry(xy, z, pairs=np.stack([near_idx, far_idx], -1), name=f"coplanar_far-{seed}")


def steep_scene(width: int, height: int, triangles: int = 40, seed: int = 0, z_range=(0.02, 0.98)) -> Geometry:
    """Very steep depth slopes along long spans: long thin triangles reaching across the whole
    width (and a little beyond, so they are clipped), 8 to 60 rows tall, whose depth runs from one
    end of z_range to the other along x (alternately left to right and right to left, so bands
    cross each other near mid-screen). The integer kernels step z by dz about 600 times per span,
    so the rounding of dz accumulates to its largest here."""
    lo, hi = _check_range(z_range)
    if triangles < 1 or triangles > MAX_TRIANGLES:
        raise ValueError(f"triangles must be 1..{MAX_TRIANGLES}")
    rng = np.random.default_rng(seed)
    n = triangles
    top = rng.uniform(-10, height, n)
    tall = rng.uniform(8, 60, n)
    x_left = rng.uniform(-0.08 * width, 0.02 * width, n)
    x_right = rng.uniform(0.98 * width, 1.08 * width, n)
    apex_x = rng.uniform(x_left, x_right)
    # a long nearly horizontal edge from (x_left, top) to (x_right, top + small) and an apex below
    xy = np.stack([np.stack([x_left, top], -1),
                   np.stack([x_right, top + rng.uniform(-4, 4, n)], -1),
                   np.stack([apex_x, top + tall], -1)], axis=1)
    span = (hi - lo) * rng.uniform(0.7, 1.0, n)
    start = lo + rng.uniform(0, 1, n) * ((hi - lo) - span)
    flip = (np.arange(n) % 2).astype(bool)
    t = (xy[..., 0] - x_left[:, None]) / (x_right - x_left)[:, None]
    t = np.where(flip[:, None], 1.0 - t, t)
    z = np.clip(start[:, None] + span[:, None] * t, lo, np.nextafter(hi, 0.0))
    return Geometry(xy, z, name=f"steep-{seed}")


def near_far_scene(width: int, height: int, triangles: int = 200, seed: int = 0) -> Geometry:
    """Depths at both ends of the range. Half the triangles (alternating) lie near the camera at
    depths log-uniform in [2^-26, 2^-8] (below 2^-21, i.e. 32-bit depths under 2048, the 16-bit
    float's mantissa takes bits from a stale EDX in the article's three-instruction conversion, and
    z16 truncates everything under 2^-16 to 0); the other half lie near the far end, at 1 - d with
    d log-uniform in [2^-30, 2^-8] (with d under 2^-16 for z16, or under 2^-12 for fp16z, whose step
    there is 2^-12, the depth lands in the last code 0xFFFF, ties with the cleared buffer and is
    never written; z32 and zf32 lose resolution there too). Each triangle's vertex
    depths differ from its centre depth by up to a factor 2^±0.4 of the distance to the nearer end
    of the range, so overlapping triangles interpenetrate at every scale. About 2.5x overdraw."""
    if triangles < 1 or triangles > MAX_TRIANGLES:
        raise ValueError(f"triangles must be 1..{MAX_TRIANGLES}")
    rng = np.random.default_rng(seed)
    n = triangles
    shapes = _unit_triangles(rng, n)
    side = np.sqrt(portable_math.exp_array(rng.normal(0.0, 0.7, n)) * 3.0 * width * height / n / portable_math.exp(0.245))
    centres = np.stack([rng.uniform(-0.05 * width, 1.05 * width, n),
                        rng.uniform(-0.05 * height, 1.05 * height, n)], -1)
    xy = centres[:, None, :] + shapes * side[:, None, None]
    # portable_math, not numpy's **: its SIMD path differs in the last bit on an AVX-512 CPU
    dist = portable_math.power(2.0, rng.uniform(-26, -8, n))
    far = (np.arange(n) % 2).astype(bool)
    dist = np.where(far, portable_math.power(2.0, rng.uniform(-30, -8, n)), dist)
    vert = dist[:, None] * portable_math.power(2.0, rng.uniform(-0.4, 0.4, (n, 3)))
    z = np.where(far[:, None], 1.0 - vert, vert)
    z = np.clip(z, 0.0, np.nextafter(1.0, 0.0))
    return Geometry(xy, z, name=f"near_far-{seed}")


def tiny_scene(width: int, height: int, triangles: int = 2000, seed: int = 0) -> Geometry:
    """Single-pixel and zero-length spans: triangles 0.3 to 3 pixels across (a tenth of them
    slivers under 0.2 pixel thick, which cover rows without covering any pixel centre), scattered
    over the screen and its border, at random depths in [0.05, 0.95]. Asks the rasterizer to keep
    zero-length spans (Geometry.keep_empty), so the kernels are called with count 0."""
    if triangles < 1 or triangles > MAX_TRIANGLES:
        raise ValueError(f"triangles must be 1..{MAX_TRIANGLES}")
    rng = np.random.default_rng(seed)
    n = triangles
    shapes = _unit_triangles(rng, n)
    size = rng.uniform(0.3, 3.0, n)
    xy = rng.uniform([-2, -2], [width + 2, height + 2], (n, 2))[:, None, :] + shapes * size[:, None, None]
    sliver = rng.random(n) < 0.1
    if sliver.any():
        m = int(sliver.sum())
        length = rng.uniform(1.5, 6.0, m)
        thick = rng.uniform(0.01, 0.2, m)
        ang = rng.uniform(0, np.pi, m)
        d = portable_math.unit_vectors(ang)
        nrm = np.stack([-d[:, 1], d[:, 0]], -1)
        base = xy[sliver, 0]
        xy[sliver] = np.stack([base, base + d * length[:, None], base + nrm * thick[:, None]], 1)
    z = rng.uniform(0.05, 0.95, (n, 1)) + rng.uniform(-0.01, 0.01, (n, 3))
    return Geometry(xy, z, keep_empty=True, name=f"tiny-{seed}")


GENERATORS = {
    "random": random_scene,
    "coplanar_far": coplanar_far_scene,
    "steep": steep_scene,
    "near_far": near_far_scene,
    "tiny": tiny_scene,
}


# --------------------------------------------------------------------------------------------
# rasterization

@dataclass(frozen=True, eq=False)
class Spans:
    """One record per covered row of each triangle, in draw order.

    y, x0, count: int32, the row, first pixel and number of pixels (count 0 only with keep_empty);
    tri:          int32, the triangle index; colour: uint16, its colour (what the kernel writes);
    depth0:       float64, the plane's depth at the centre of pixel (x0, y);
    ddepth:       float64, the plane's depth step per pixel along x.
    """

    y: np.ndarray
    x0: np.ndarray
    count: np.ndarray
    tri: np.ndarray
    depth0: np.ndarray
    ddepth: np.ndarray
    colour: np.ndarray
    width: int = 0
    height: int = 0

    def __len__(self) -> int:
        return int(self.y.shape[0])

    @property
    def pixels(self) -> int:
        """Pixels drawn (with overdraw)."""
        return int(self.count.sum(dtype=np.int64))

    def depth_complexity(self) -> float:
        return self.pixels / (self.width * self.height) if self.width and self.height else float("nan")

    def select(self, mask) -> Spans:
        return Spans(self.y[mask], self.x0[mask], self.count[mask], self.tri[mask], self.depth0[mask],
                     self.ddepth[mask], self.colour[mask], self.width, self.height)


def _edge_x(ax, ay, bx, by, yc):
    """x of the edge from (ax, ay) (upper) to (bx, by) (lower) at row centre yc. The same
    expression for every triangle sharing the edge, hence the same float."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return ax + (yc - ay) * ((bx - ax) / (by - ay))


def rasterize(geometry: Geometry, width: int, height: int, keep_empty: bool | None = None) -> Spans:
    """Scan-convert the triangles with the top-left fill rule (see the module docstring), clipped to
    the screen. Vectorised over all rows of all triangles at once. `keep_empty` (default: what the
    geometry asks for) keeps rows inside the screen that the triangle crosses without covering a
    pixel centre, as count-0 spans with x0 clamped into the row. Degenerate (zero-area) triangles
    produce no spans."""
    if keep_empty is None:
        keep_empty = geometry.keep_empty
    xy = geometry.xy
    n = len(geometry)
    ddx, ddy, det = geometry.planes()
    order = np.argsort(xy[:, :, 1], axis=1, kind="stable")
    v = np.take_along_axis(xy, order[:, :, None], axis=1)  # vertices top to bottom
    (x0v, y0v), (x1v, y1v), (x2v, y2v) = ((v[:, i, 0], v[:, i, 1]) for i in range(3))
    row0 = np.clip(np.ceil(y0v - 0.5), 0, height).astype(np.int64)
    row1 = np.clip(np.ceil(y2v - 0.5), 0, height).astype(np.int64)
    rows = np.where(det == 0.0, 0, np.maximum(row1 - row0, 0))
    total = int(rows.sum())
    tri = np.repeat(np.arange(n, dtype=np.int64), rows)
    first = np.cumsum(rows) - rows
    y = row0[tri] + (np.arange(total, dtype=np.int64) - first[tri])
    yc = y + 0.5
    x_long = _edge_x(x0v[tri], y0v[tri], x2v[tri], y2v[tri], yc)
    upper = yc < y1v[tri]
    x_short = np.where(upper, _edge_x(x0v[tri], y0v[tri], x1v[tri], y1v[tri], yc),
                       _edge_x(x1v[tri], y1v[tri], x2v[tri], y2v[tri], yc))
    xl, xr = np.minimum(x_long, x_short), np.maximum(x_long, x_short)
    start = np.clip(np.ceil(xl - 0.5), 0, width).astype(np.int64)
    stop = np.clip(np.ceil(xr - 0.5), 0, width).astype(np.int64)
    count = np.maximum(stop - start, 0)
    if keep_empty:
        start = np.minimum(start, width - 1)
    else:
        keep = count > 0
        tri, y, start, count = tri[keep], y[keep], start[keep], count[keep]
    depth0 = (geometry.z[tri, 0] + ddx[tri] * (start + 0.5 - xy[tri, 0, 0])
              + ddy[tri] * (y + 0.5 - xy[tri, 0, 1]))
    return Spans(y.astype(np.int32), start.astype(np.int32), count.astype(np.int32), tri.astype(np.int32),
                 depth0, ddx[tri].copy(), geometry.colour[tri], int(width), int(height))


def count_rows(geometry: Geometry, width: int, height: int) -> int:
    """An upper bound on len(rasterize(...)) without rasterizing: rows crossed inside the screen."""
    ys = geometry.xy[:, :, 1]
    row0 = np.clip(np.ceil(ys.min(1) - 0.5), 0, height)
    row1 = np.clip(np.ceil(ys.max(1) - 0.5), 0, height)
    return int(np.maximum(row1 - row0, 0).sum())


# --------------------------------------------------------------------------------------------
# the exact reference and the kernels' expected frames

def expand_spans(spans: Spans, width: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every pixel visit in draw order: (flat pixel index, span index, k = position in the span)."""
    counts = spans.count.astype(np.int64)
    total = int(counts.sum())
    span_of = np.repeat(np.arange(len(spans), dtype=np.int64), counts)
    first = np.cumsum(counts) - counts
    k = np.arange(total, dtype=np.int64) - first[span_of]
    pix = spans.y.astype(np.int64)[span_of] * width + spans.x0.astype(np.int64)[span_of] + k
    return pix, span_of, k


@njit(cache=True)
def _scan_float(pix, hi, lo, store, span_of, zbuf, winner):
    """Depth test in draw order for values hi + lo (lo: the sign of an exact residual below hi's
    precision): a visit passes when hi + lo < zbuf[p] exactly, and then stores `store`. NaN fails."""
    for i in range(pix.size):
        p = pix[i]
        zb = zbuf[p]
        if hi[i] < zb or (hi[i] == zb and lo[i] < 0.0):
            zbuf[p] = store[i]
            winner[p] = span_of[i]


@njit(cache=True)
def _scan_int(pix, values, span_of, zbuf, winner):
    for i in range(pix.size):
        p = pix[i]
        if values[i] < zbuf[p]:
            zbuf[p] = values[i]
            winner[p] = span_of[i]


def reference(spans: Spans, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """The exact float64 Z-buffer: spans drawn in order into a buffer cleared to +inf, a pixel
    taking a span's depth when strictly nearer than what it holds. Depth at pixel k of a span is
    evaluated as depth0 + k * ddepth in float64 (within a few ulps, ~1e-16, of the plane itself:
    far below any format's resolution, so "exact" for every comparison made here; exact ties between
    different triangles' planes are resolved in draw order, as in the kernels).
    Returns depth float64 [h, w] (+inf where nothing was drawn) and owner int32 [h, w] (the winning
    triangle index, -1 where nothing was drawn)."""
    pix, span_of, k = expand_spans(spans, width)
    values = spans.depth0[span_of] + k * spans.ddepth[span_of]
    depth = np.full(width * height, np.inf)
    winner = np.full(width * height, -1, np.int64)
    _scan_float(pix, values, np.zeros_like(values), values, span_of, depth, winner)
    if len(spans) == 0:  # a scene that draws nothing: no pixel has an owner
        owner = np.full(width * height, -1, np.int32)
    else:
        owner = np.where(winner >= 0, spans.tri[np.maximum(winner, 0)], -1).astype(np.int32)
    return depth.reshape(height, width), owner.reshape(height, width)


def span_parameters(spans: Spans, variant: str) -> tuple[np.ndarray, np.ndarray]:
    """(z0, dz) per span, as the kernel variant is called.

    Integer variants (z32, z16, fp16z, fp16t) interpolate the 32-bit fixed-point depth z = depth x 2^32:
      z0 = round(depth0 x 2^32) clipped into [0, 2^32 - 1] (uint32),
      dz = round(ddepth x 2^32) as a signed integer taken modulo 2^32 (uint32; a negative step is
           its two's complement, and the kernel's 32-bit ADD wraps exactly as a signed add would).
    Rounding is to nearest (ties to even). The kernel's depth at pixel k is z0 + k dz (mod 2^32),
    so its error against the plane is at most 0.5 + 0.5 k units of 2^-32: up to ~320 units (7.4e-8)
    at the end of a 640-pixel span. That is below z16's step (2^-16 = 65536 units) and the 16-bit
    float's step above depth 2^-13, but 320 times z32's own step: on long spans the interpolation,
    not the format, limits z32. Depths within that error of 0 or of 1 can wrap around (a near
    depth becomes the farthest, or the reverse); :func:`near_far_scene` provokes it.
    zf32: float32 z0 and dz (each rounded to nearest single); the x87 then adds dz in 64-bit
    precision, so the error is ~2^-25 relative for z0 plus k times dz's rounding (2^-25 relative).
    """
    _check_variant(variant)
    if variant == "zf32":
        return spans.depth0.astype(np.float32), spans.ddepth.astype(np.float32)
    z0 = np.clip(np.rint(spans.depth0 * TWO32), 0, TWO32 - 1).astype(np.uint32)
    step = np.clip(np.rint(spans.ddepth * TWO32), -2.0 ** 62, 2.0 ** 62).astype(np.int64)
    dz = (step & 0xFFFFFFFF).astype(np.uint32)
    return z0, dz


def stored_depth(values, variant: str) -> np.ndarray:
    """Decode a z-buffer's stored values back to depth in [0, 1) (float64).

    z32: v / 2^32; z16: v / 2^16; zf32: the float itself. fp16z, and fp16t (the same format converted
    without BSR): fp16z_decode(v) / 2^32, the lower end of the interval of 32-bit depths that
    encode to v. The lower end is chosen for consistency with z16 (whose v / 2^16 is equally the
    lower end of a truncation interval): both 16-bit formats
    then report a one-sided error of up to one step, comparable like for like, and the decoded value
    is what the format's integer comparison actually orders. (The midpoint would halve the worst
    error of both.) A cleared pixel decodes to the far value's own depth (zf32: +inf)."""
    _check_variant(variant)
    v = np.asarray(values)
    if variant == "z32":
        return v.astype(np.uint32).astype(np.float64) / TWO32
    if variant == "z16":
        return v.astype(np.uint16).astype(np.float64) / 65536.0
    if variant in ("fp16z", "fp16t"):
        return ref.fp16z_decode(v.astype(np.uint16)).astype(np.float64) / TWO32
    return v.astype(np.float32).astype(np.float64)


def _zf32_values(spans: Spans, total: int) -> np.ndarray:
    """The x87's running depth at every visit (flat, draw order), in extended precision: per span
    z = float32 z0, then z += float32 dz once per pixel with one rounding to 64 bits per add (what
    FADD does at the FNINIT precision). Stepped across all spans at once, one add per pixel column,
    so each span's chain of additions is the same sequence of roundings as in the kernel."""
    if not ref.x87_extended_available():
        raise RuntimeError("the zf32 frame needs numpy.longdouble to be the x87 80-bit format")
    z0, dz = span_parameters(spans, "zf32")
    counts = spans.count.astype(np.int64)
    first = np.cumsum(counts) - counts
    out = np.empty(total, np.longdouble)
    order = np.argsort(-counts, kind="stable")  # longest first: live spans are a prefix
    live_counts = counts[order]
    cur = z0[order].astype(np.longdouble)
    step = dz[order].astype(np.longdouble)
    pos = first[order]
    live = int(np.count_nonzero(live_counts > 0))
    k = 0
    while live:
        out[pos[:live] + k] = cur[:live]
        k += 1
        live = int(np.count_nonzero(live_counts[:live] > k))
        cur[:live] += step[:live]
    return out


def simulate_frame(spans: Spans, variant: str, width: int, height: int, *, edx: int = 0,
                   fbuf: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The bit-exact buffers kernels/zbuffer/<variant>.S's frame driver leaves: depth buffer cleared
    to the far value, then every span drawn in order with :func:`span_parameters`' z and dz and
    colour = spans.colour. Returns (zbuf [h, w] of the variant's dtype, fbuf uint16 [h, w]).

    fbuf: the colour buffer's contents before the frame (default zeros; the driver never clears it,
    so a pixel no span wins keeps it). edx (fp16z only): EDX at the frame's entry. The driver leaves
    ECX = 0 after its clear loop and touches neither register between spans, so the kernel's stale
    EDX/ECX carry from span to span; they are modelled exactly (sim.reference.fp16z_span, carried
    across spans). The entry EDX matters only if the frame's first pixel has z < 2048.

    z32, z16, fp16t and zf32 are computed for all pixels at once and tested in draw order by a
    compiled loop; the result equals calling sim.reference's span functions span by span (tested).
    fp16t converts every pixel's depth afresh (sim.reference.fp16t_convert = fp16z_encode), so
    nothing carries between pixels or spans and edx has no effect on it."""
    _check_variant(variant)
    zdtype = ZBUF_DTYPE[variant]
    fb = np.zeros(width * height, np.uint16) if fbuf is None else np.array(fbuf, np.uint16).reshape(-1).copy()
    if fb.size != width * height:
        raise ValueError(f"fbuf has {fb.size} pixels, the screen {width * height}")
    if variant == "fp16z":
        zb = np.full(width * height, CLEAR_VALUE[variant], zdtype)
        z0, dz = span_parameters(spans, variant)
        reg_edx, reg_ecx = int(edx) & ref.U32, 0
        starts = spans.y.astype(np.int64) * width + spans.x0
        for s, c, z, d, col in zip(starts.tolist(), spans.count.tolist(), z0.tolist(), dz.tolist(),
                                   spans.colour.tolist()):
            if c:
                _, reg_edx, reg_ecx = ref.fp16z_span(zb[s:s + c], fb[s:s + c], z, d, col, reg_edx, reg_ecx)
        return zb.reshape(height, width), fb.reshape(height, width)
    pix, span_of, k = expand_spans(spans, width)
    winner = np.full(width * height, -1, np.int64)
    if variant == "zf32":
        ext = _zf32_values(spans, pix.size)
        hi = ext.astype(np.float64)
        with np.errstate(invalid="ignore", over="ignore"):
            lo = (ext - hi.astype(np.longdouble)).astype(np.float64)
            store = ext.astype(np.float32).astype(np.float64)
        zb64 = np.full(width * height, np.inf)
        _scan_float(pix, hi, lo, store, span_of, zb64, winner)
        zb = zb64.astype(np.float32)
    else:
        z0, dz = span_parameters(spans, variant)
        z = (z0.astype(np.uint64)[span_of] + k.astype(np.uint64) * dz.astype(np.uint64)[span_of]) & np.uint64(ref.U32)
        values = z.astype(np.int64)
        if variant == "z16":
            values >>= 16
        elif variant == "fp16t":
            values = ref.fp16t_convert(z.astype(np.uint32)).astype(np.int64)
        zb64 = np.full(width * height, CLEAR_VALUE[variant], np.int64)
        _scan_int(pix, values, span_of, zb64, winner)
        zb = zb64.astype(zdtype)
    won = winner >= 0
    fb[won] = spans.colour[winner[won]]
    return zb.reshape(height, width), fb.reshape(height, width)


def simulate_frame_per_span(spans: Spans, variant: str, width: int, height: int, *, edx: int = 0,
                            fbuf: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The same frame by brute force: sim.reference's span function called once per span on the
    buffer rows, exactly as the frame driver calls the kernel. Slow; for tests and spot checks."""
    _check_variant(variant)
    zb = np.full(width * height, CLEAR_VALUE[variant], ZBUF_DTYPE[variant])
    fb = np.zeros(width * height, np.uint16) if fbuf is None else np.array(fbuf, np.uint16).reshape(-1).copy()
    z0, dz = span_parameters(spans, variant)
    reg_edx, reg_ecx = int(edx) & ref.U32, 0
    for i in range(len(spans)):
        s = int(spans.y[i]) * width + int(spans.x0[i])
        c = int(spans.count[i])
        col = int(spans.colour[i])
        zs, fs = zb[s:s + c], fb[s:s + c]
        if variant == "fp16z":
            _, reg_edx, reg_ecx = ref.fp16z_span(zs, fs, int(z0[i]), int(dz[i]), col, reg_edx, reg_ecx)
        elif variant == "zf32":
            ref.zf32_span(zs, fs, float(z0[i]), float(dz[i]), col)
        else:
            getattr(ref, f"{variant}_span")(zs, fs, int(z0[i]), int(dz[i]), col)
    return zb.reshape(height, width), fb.reshape(height, width)
