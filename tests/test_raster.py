"""Triangle setup, span generation, the exact reference and the kernels' expected frames."""

import numpy as np
import pytest

from sim.scenes import raster as R
from sim import reference as ref


def coverage(spans, width, height):
    """How many spans cover each pixel."""
    cover = np.zeros(width * height, np.int64)
    pix, _, _ = R.expand_spans(spans, width)
    np.add.at(cover, pix, 1)
    return cover.reshape(height, width)


def inside_convex(poly, px, py, margin):
    """Pixel centres at least `margin` inside a convex polygon (either winding)."""
    poly = np.asarray(poly, float)
    e1, e2 = poly[1] - poly[0], poly[2] - poly[1]
    sign = np.sign(e1[0] * e2[1] - e1[1] * e2[0])
    ok = np.ones(px.shape, bool)
    for a, b in zip(poly, np.roll(poly, -1, axis=0)):
        e = b - a
        d = sign * (e[0] * (py - a[1]) - e[1] * (px - a[0])) / np.hypot(*e)
        ok &= d > margin
    return ok


def barycentric_depth(geometry, tri, x, y):
    """Plane depth by barycentric interpolation of the vertex depths (independent of Geometry.planes)."""
    (x0, y0), (x1, y1), (x2, y2) = (geometry.xy[tri, i].T for i in range(3))
    det = (y1 - y2) * (x0 - x2) + (x2 - x1) * (y0 - y2)
    l0 = ((y1 - y2) * (x - x2) + (x2 - x1) * (y - y2)) / det
    l1 = ((y2 - y0) * (x - x2) + (x0 - x2) * (y - y2)) / det
    z = geometry.z[tri]
    return l0 * z[:, 0] + l1 * z[:, 1] + (1 - l0 - l1) * z[:, 2]


# --- fill rule, coverage, clipping ------------------------------------------------------------

@pytest.mark.parametrize("flip", [False, True])
def test_quad_of_two_triangles_covers_each_pixel_once(flip):
    quad = np.array([[3.3, 2.7], [41.6, 5.2], [37.05, 30.5], [6.5, 26.25]])
    a, b = [quad[0], quad[1], quad[2]], [quad[0], quad[2], quad[3]]
    if flip:  # other winding and vertex order for one of them
        b = [quad[3], quad[2], quad[0]]
    g = R.Geometry(np.array([a, b]), np.full((2, 3), 0.5))
    w, h = 48, 36
    cover = coverage(R.rasterize(g, w, h), w, h)
    py, px = np.mgrid[0:h, 0:w] + 0.5
    assert cover.max() == 1
    assert np.all(cover[inside_convex(quad, px, py, 1e-9)] == 1)
    assert not np.any(cover[~inside_convex(quad, px, py, -1e-9)])


def test_jittered_mesh_beyond_the_screen_covers_every_pixel_exactly_once():
    """A triangulated grid with jittered vertices (some on pixel centres, some on exact half
    coordinates, shared horizontal edges) reaching past every screen edge: no cracks, no double hits."""
    rng = np.random.default_rng(5)
    w, h = 97, 61
    gx, gy = np.meshgrid(np.linspace(-13, w + 11, 12), np.linspace(-9, h + 7, 9))
    pts = np.stack([gx, gy], -1) + rng.uniform(-3, 3, gx.shape + (2,))
    pts[3, :, 1] = 20.5  # a whole row of vertices on one row centre: shared horizontal edges
    pts[4, 3] = np.floor(pts[4, 3]) + 0.5  # a vertex on a pixel centre
    pts[5, 4] = np.floor(pts[5, 4])  # and one on a pixel corner
    tris = []
    for i in range(pts.shape[0] - 1):
        for j in range(pts.shape[1] - 1):
            p00, p01, p10, p11 = pts[i, j], pts[i, j + 1], pts[i + 1, j], pts[i + 1, j + 1]
            if (i + j) % 2:
                tris += [[p00, p01, p11], [p00, p11, p10]]
            else:
                tris += [[p00, p01, p10], [p01, p11, p10]]
    g = R.Geometry(np.array(tris), np.full((len(tris), 3), 0.25))
    cover = coverage(R.rasterize(g, w, h), w, h)
    assert np.all(cover == 1)


def test_pixel_counts_match_areas():
    rng = np.random.default_rng(11)
    n = 400
    xy = rng.uniform(200, 800, (n, 1, 2)) + rng.normal(0, 25, (n, 3, 2))
    assert xy.min() > 0 and xy.max() < 1000  # all on screen: no clipping here
    g = R.Geometry(xy, np.full((n, 3), 0.5))
    spans = R.rasterize(g, 1000, 1000)
    counts = np.bincount(spans.tri, weights=spans.count, minlength=n)
    area = g.areas()
    perimeter = sum(np.hypot(*(xy[:, (i + 1) % 3] - xy[:, i]).T) for i in range(3))
    # a pixel centre can only be misjudged within half a pixel of an edge
    assert np.all(np.abs(counts - area) <= 0.5 * perimeter + 1)
    assert abs(counts.sum() - area.sum()) < 0.005 * area.sum()  # no bias: edges neither grow nor shrink


def test_clipping_keeps_exactly_the_on_screen_part():
    rng = np.random.default_rng(3)
    n = 60
    xy = rng.uniform(-150, 250, (n, 3, 2))
    z = rng.uniform(0.1, 0.9, (n, 3))
    w, h, off = 120, 90, 200
    clipped = R.rasterize(R.Geometry(xy, z), w, h)
    assert clipped.y.min() >= 0 and clipped.y.max() < h and clipped.x0.min() >= 0
    assert np.all(clipped.x0 + clipped.count <= w) and np.all(clipped.count > 0)
    # the same triangles on a screen big enough to hold them whole, then cut to the window
    whole = R.rasterize(R.Geometry(xy + off, z), 600, 600)
    big = coverage(whole, 600, 600)[off:off + h, off:off + w]
    np.testing.assert_array_equal(coverage(clipped, w, h), big)
    # and the reference agrees on who is visible (the plane depths are the same surfaces)
    _, own_clip = R.reference(clipped, w, h)
    _, own_big = R.reference(whole, 600, 600)
    np.testing.assert_array_equal(own_clip, own_big[off:off + h, off:off + w])


def test_degenerate_and_off_screen_triangles_give_no_spans():
    xy = np.array([[[1, 1], [5, 5], [9, 9]],            # collinear
                   [[-50, -50], [-10, -40], [-30, -5]],  # off screen
                   [[2, 2], [2, 2], [2, 2]]], float)     # a point
    assert len(R.rasterize(R.Geometry(xy, np.full((3, 3), 0.5)), 32, 32, keep_empty=True)) == 0


def test_spans_come_in_draw_order():
    g = R.random_scene(320, 240, 80, 2.0, 4)
    s = R.rasterize(g, 320, 240)
    key = s.tri.astype(np.int64) * 1000 + s.y
    assert np.all(np.diff(key) > 0)
    np.testing.assert_array_equal(s.colour, s.tri + 1)


# --- generators -------------------------------------------------------------------------------

def test_random_scene_is_deterministic_for_a_seed():
    a = R.random_scene(640, 480, 300, 3.0, 1998)
    b = R.random_scene(640, 480, 300, 3.0, 1998)
    c = R.random_scene(640, 480, 300, 3.0, 1999)
    np.testing.assert_array_equal(a.xy, b.xy)
    np.testing.assert_array_equal(a.z, b.z)
    assert not np.array_equal(a.xy, c.xy)
    for gen in (R.coplanar_far_scene, R.steep_scene, R.near_far_scene, R.tiny_scene):
        np.testing.assert_array_equal(gen(200, 100, seed=7).z, gen(200, 100, seed=7).z)


@pytest.mark.parametrize("seed,dc", [(1998, 3.0), (1, 1.5), (42, 5.0)])
def test_random_scene_depth_complexity_near_target(seed, dc):
    g = R.random_scene(640, 480, 300, dc, seed)
    s = R.rasterize(g, 640, 480)
    assert abs(s.depth_complexity() - dc) <= 0.15 * dc
    lo, hi = 0.05, 0.95
    assert g.z.min() >= lo and g.z.max() < hi
    # game-like: varied sizes, some triangles partly off-screen, planes that are not all flat
    area = g.areas()
    assert area.max() > 8 * np.median(area)
    off = (g.xy[..., 0] < 0) | (g.xy[..., 0] > 640) | (g.xy[..., 1] < 0) | (g.xy[..., 1] > 480)
    assert 0.05 < off.any(axis=1).mean() < 0.6
    assert np.mean(np.ptp(g.z, axis=1) > 0.01) > 0.5


def test_generators_do_what_they_say():
    w, h = 640, 480
    cop = R.coplanar_far_scene(w, h, pairs=30, seed=2)
    near, far = cop.pairs[:, 0], cop.pairs[:, 1]
    # the nearer surface is nearer by the separation everywhere on its plane
    pts = cop.xy[far].mean(axis=1)
    gap = cop.depth_at(far, pts[:, 0], pts[:, 1]) - cop.depth_at(near, pts[:, 0], pts[:, 1])
    np.testing.assert_allclose(gap, 2.0 ** -20, rtol=1e-6)
    assert cop.z.min() >= 0.85 and cop.z.max() < 0.95
    assert 0 < np.mean(far < near) < 1  # both draw orders occur

    steep = R.rasterize(R.steep_scene(w, h, seed=2), w, h)
    assert steep.count.mean() > 0.4 * w and np.mean(steep.count > 0.9 * w) > 0.1
    assert np.all(np.abs(steep.ddepth) > 0.7 * 0.96 / (1.16 * w))  # most of the range across the screen
    assert 0.2 < np.mean(steep.ddepth > 0) < 0.8  # both directions, so bands cross

    nf = R.near_far_scene(w, h, seed=2)
    assert nf.z.min() < 2.0 ** -21 and nf.z.max() > 1 - 2.0 ** -16
    assert np.all((nf.z < 2.0 ** -7) | (nf.z > 1 - 2.0 ** -7))

    tiny = R.tiny_scene(w, h, seed=2)
    s = R.rasterize(tiny, w, h)
    assert tiny.keep_empty and np.any(s.count == 0) and np.any(s.count == 1)
    assert np.all(s.x0 < w) and np.all(s.x0 >= 0)
    assert not np.any(R.rasterize(tiny, w, h, keep_empty=False).count == 0)


def test_geometry_rejects_bad_input():
    with pytest.raises(ValueError, match="shape"):
        R.Geometry(np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"\[0, 1\)"):
        R.Geometry(np.zeros((1, 3, 2)), np.array([[0.1, 0.2, 1.0]]))
    with pytest.raises(ValueError, match="65535"):
        R.Geometry(np.zeros((70000, 3, 2)), np.zeros((70000, 3)))


# --- depths and the exact reference -----------------------------------------------------------

def test_span_depths_reproduce_the_plane_at_pixel_centres():
    g = R.random_scene(320, 240, 100, 3.0, 9)
    s = R.rasterize(g, 320, 240)
    pix, span_of, k = R.expand_spans(s, 320)
    x = s.x0[span_of] + k + 0.5
    y = s.y[span_of] + 0.5
    want = barycentric_depth(g, s.tri[span_of], x, y)
    got = s.depth0[span_of] + k * s.ddepth[span_of]
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-13)
    # the pixel centres really are inside (or on the edge of) their triangle: depth within its vertex range
    z = g.z[s.tri[span_of]]
    assert np.all(want >= z.min(1) - 1e-12) and np.all(want <= z.max(1) + 1e-12)


@pytest.mark.parametrize("order", [(0, 1), (1, 0)])
def test_reference_owner_changes_exactly_where_planes_cross(order):
    w, h = 64, 16
    big = [[-10, -10], [3 * w, -10], [-10, 3 * h]]
    xy = np.array([big, big], float)
    # plane A rises along x and crosses the flat plane B at x = 40.25
    za = [0.5 + 0.001 * (p[0] - 40.25) for p in big]
    zb = [0.5, 0.5, 0.5]
    z = np.array([za, zb])[list(order)]
    s = R.rasterize(R.Geometry(xy[list(order)], z), w, h)
    depth, owner = R.reference(s, w, h)
    a = order.index(0)
    cols = np.arange(w)
    want = np.where(cols + 0.5 < 40.25, a, 1 - a)
    assert np.all(owner == want[None, :])
    assert np.all(depth <= 0.5)


def test_reference_empty_pixels_and_ties():
    w, h = 16, 8
    tri = [[0, 0], [8, 0], [0, 8]]
    g = R.Geometry(np.array([tri, tri]), np.full((2, 3), 0.25))
    depth, owner = R.reference(R.rasterize(g, w, h), w, h)
    assert np.all(owner[owner >= 0] == 0)  # an exact tie keeps the first drawn
    assert np.all(np.isinf(depth[owner < 0])) and np.all(owner[:, 9:] == -1)


# --- span parameters --------------------------------------------------------------------------

def test_integer_span_parameters_decode_within_the_rounding_error():
    g = R.random_scene(640, 480, 200, 3.0, 21)
    s = R.rasterize(g, 640, 480)
    z0, dz = R.span_parameters(s, "z32")
    assert z0.dtype == np.uint32 and dz.dtype == np.uint32
    pix, span_of, k = R.expand_spans(s, 640)
    exact = s.depth0[span_of] + k * s.ddepth[span_of]
    z = ((z0.astype(np.uint64)[span_of] + k.astype(np.uint64) * dz.astype(np.uint64)[span_of]) & 0xFFFFFFFF)
    bound = (0.5 + 0.5 * k + 1e-6) / 2.0 ** 32  # round(z0) and k times round(dz)
    err32 = R.stored_depth(z.astype(np.uint32), "z32") - exact
    assert np.all(np.abs(err32) <= bound)
    assert np.abs(err32).max() > 50 / 2.0 ** 32  # long spans really accumulate
    err16 = R.stored_depth((z >> 16).astype(np.uint16), "z16") - exact
    assert np.all((err16 <= bound) & (err16 > -2.0 ** -16 - bound))
    h = ref.fp16z_encode(z.astype(np.uint32))
    err_f = R.stored_depth(h, "fp16z") - exact
    step = exact * 2.0 ** -11  # one 16-bit float step is at most 2^-11 of the depth (depths >= 0.05 here)
    assert np.all((err_f <= bound) & (err_f > -step - bound))
    assert np.abs(err_f).max() > 10 * np.abs(err16).max()  # far away the float is coarser than z16


def test_negative_steps_wrap_like_twos_complement():
    xy = np.array([[[0, 0], [200, 0], [0, 4]]], float)
    z = np.array([[0.6, 0.2, 0.6]])  # depth falls along x
    s = R.rasterize(R.Geometry(xy, z), 256, 4)
    z0, dz = R.span_parameters(s, "z32")
    assert np.all(s.ddepth < 0)
    step = int(np.rint(s.ddepth[0] * 2.0 ** 32))
    assert step < 0 and int(dz[0]) == step + (1 << 32)
    for i in range(len(s)):
        signed = ref.interpolate_u32(int(z0[i]), step, int(s.count[i]))
        unsigned = ref.interpolate_u32(int(z0[i]), int(dz[i]), int(s.count[i]))
        np.testing.assert_array_equal(signed, unsigned)
        exact = (s.depth0[i] + np.arange(s.count[i]) * s.ddepth[i]) * 2.0 ** 32
        assert np.all(np.abs(signed - exact) <= 0.5 + 0.5 * np.arange(s.count[i]) + 1e-3)
    # a span that steps below depth 0 wraps to the far end, as the 32-bit register does
    nz0 = np.uint32(1000)
    vals = ref.interpolate_u32(int(nz0), step, 3)
    assert vals[0] == 1000 and vals[1] == (1000 + step) % (1 << 32) and vals[1] > 0xF0000000


def test_span_parameters_clip_and_float():
    s = R.Spans(np.zeros(3, np.int32), np.zeros(3, np.int32), np.ones(3, np.int32), np.arange(3, dtype=np.int32),
                np.array([0.0, 0.999999999999, 1 - 2.0 ** -40]), np.array([0.0, -1e-9, 1e-9]),
                np.ones(3, np.uint16), 4, 1)
    z0, dz = R.span_parameters(s, "z32")
    assert z0.tolist()[0] == 0 and z0[2] == 0xFFFFFFFF  # rounds to 2^32: clipped into range
    assert dz[1] == (1 << 32) - round(1e-9 * 2 ** 32)
    f0, fd = R.span_parameters(s, "zf32")
    assert f0.dtype == np.float32 and fd[2] == np.float32(1e-9)
    with pytest.raises(ValueError, match="unknown"):
        R.span_parameters(s, "z24")


def test_stored_depth_decodes_each_format():
    assert R.stored_depth(np.uint32(1 << 31), "z32") == 0.5
    assert R.stored_depth(np.uint16(0x4000), "z16") == 0.25
    h = ref.fp16z_encode(np.uint32(0x15553270))  # the article's example
    assert h == 0b11100_01010101010  # exponent 28; SHRD drops the leading 1 the article's text shows
    assert R.stored_depth(h, "fp16z") * 2 ** 32 == 0x15553270 & ~0x1FFFF  # the lower end of its interval
    assert R.stored_depth(np.float32(0.3), "zf32") == float(np.float32(0.3))


# --- the kernels' expected frames -------------------------------------------------------------

SMALL = {
    "random": lambda: R.random_scene(96, 64, 40, 3.0, 8),
    "tiny": lambda: R.tiny_scene(96, 64, 400, seed=8),
    "near_far": lambda: R.near_far_scene(96, 64, 40, seed=8),
    "steep": lambda: R.steep_scene(96, 64, 12, seed=8),
}


@pytest.mark.parametrize("scene", SMALL)
@pytest.mark.parametrize("variant", R.VARIANTS)
def test_simulate_frame_equals_span_by_span_reference(scene, variant):
    if variant == "zf32" and not ref.x87_extended_available():
        pytest.skip("needs x87 80-bit numpy.longdouble")
    g = SMALL[scene]()
    s = R.rasterize(g, 96, 64)
    rng = np.random.default_rng(1)
    fb0 = rng.integers(0, 1 << 16, (64, 96)).astype(np.uint16)  # the driver never clears fbuf
    got = R.simulate_frame(s, variant, 96, 64, edx=0xDEADBEEF, fbuf=fb0)
    want = R.simulate_frame_per_span(s, variant, 96, 64, edx=0xDEADBEEF, fbuf=fb0)
    assert got[0].dtype == R.ZBUF_DTYPE[variant] and got[0].shape == (64, 96)
    np.testing.assert_array_equal(got[0].view(np.uint8), want[0].view(np.uint8))
    np.testing.assert_array_equal(got[1], want[1])
    covered = coverage(s, 96, 64) > 0
    assert np.all(got[1][~covered] == fb0[~covered])


def test_simulate_frame_fp16z_carries_registers_across_spans():
    """Span 0 ends on a depth with exponent e; span 1 starts at depth 0 and so encodes with that e
    (ECX is never reloaded), exactly as sim.reference.fp16z_span does with carried registers."""
    s = R.Spans(np.array([0, 1], np.int32), np.zeros(2, np.int32), np.array([3, 2], np.int32),
                np.arange(2, dtype=np.int32), np.array([0.3, 0.0]), np.array([0.001, 0.0]),
                np.array([1, 2], np.uint16), 4, 2)
    zb, fb = R.simulate_frame(s, "fp16z", 4, 2)
    last = ref.interpolate_u32(*[int(v[0]) for v in R.span_parameters(s, "fp16z")], 3)[-1]
    e = int(ref.msb_index(np.array([last]))[0])
    assert zb[1, 0] == e << 11 and zb[1, 1] == e << 11
    np.testing.assert_array_equal(fb, [[1, 1, 1, 0], [2, 2, 0, 0]])


def test_simulate_frame_is_fast_at_full_size():
    import time
    g = R.random_scene(640, 480, 300, 3.0, 1998)
    s = R.rasterize(g, 640, 480)
    t = time.perf_counter()
    for v in R.VARIANTS:
        if v != "zf32" or ref.x87_extended_available():
            R.simulate_frame(s, v, 640, 480)
    R.reference(s, 640, 480)
    assert time.perf_counter() - t < 10.0


def test_clear_words():
    assert R.clear_dword("z16") == 0xFFFFFFFF and R.clear_dword("z32") == 0xFFFFFFFF
    assert R.clear_dword("zf32") == 0x7F800000


def span_records(spans, variant, zaddr, faddr, width):
    """The frame driver's 8-dword span records (kernels/zbuffer/draw.inc)."""
    z0, dz = R.span_parameters(spans, variant)
    if variant == "zf32":
        z0, dz = z0.view(np.uint32), dz.view(np.uint32)
    at = spans.y.astype(np.int64) * width + spans.x0
    rec = np.zeros((len(spans), 8), np.uint32)
    rec[:, 0] = zaddr + at * R.ZBUF_DTYPE[variant].itemsize
    rec[:, 1] = faddr + at * 2
    rec[:, 2], rec[:, 3], rec[:, 4], rec[:, 5] = spans.count, z0, dz, spans.colour
    return rec


@pytest.mark.parametrize("scene", ["random", "near_far", "tiny"])
@pytest.mark.parametrize("variant", R.VARIANTS)
def test_simulate_frame_equals_the_kernel_frame_under_unicorn(machine, scene, variant):
    """What the other stages rely on: the guest's frame driver + span kernel leave exactly these buffers."""
    if variant == "zf32" and not ref.x87_extended_available():
        pytest.skip("needs x87 80-bit numpy.longdouble")
    w, h = 96, 64
    s = R.rasterize(SMALL[scene](), w, h)
    m = machine(f"zbuffer/{variant}.S")
    dt = R.ZBUF_DTYPE[variant]
    zaddr = m.arena.put(np.zeros(w * h, dt))
    faddr = m.arena.put(np.zeros(w * h, np.uint16))
    recs = m.arena.put(span_records(s, variant, zaddr, faddr, w))
    m.call(f"{variant}_frame", recs, len(s), zaddr, w * h * dt.itemsize // 4, R.clear_dword(variant),
           regs={"edx": 0x12345678, "ecx": 77})
    got_z = m.arena.get(zaddr, dt, w * h).reshape(h, w)
    got_f = m.arena.get(faddr, np.uint16, w * h).reshape(h, w)
    want_z, want_f = R.simulate_frame(s, variant, w, h, edx=0x12345678)
    np.testing.assert_array_equal(got_z.view(np.uint8), want_z.view(np.uint8))
    np.testing.assert_array_equal(got_f, want_f)
