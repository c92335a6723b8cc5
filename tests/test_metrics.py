"""Error measures against the exact reference: visibility, depth error, z-fighting, format precision."""

import json

import numpy as np
import pytest

from sim.scenes.zbuffer import metrics as M
from sim.scenes import raster as R
from sim import reference as ref


def test_visibility_errors_hand_built():
    owner = np.array([[0, 0, 1, -1],
                      [0, 1, 1, -1],
                      [2, 2, 2, -1]], np.int32)
    fbuf = np.array([[1, 1, 2, 0],
                     [2, 2, 2, 0],     # (1, 0): triangle 1 won where 0 should have
                     [3, 0, 1, 5]], np.uint16)  # (2, 1): nothing written; (2, 2): 0 won; (2, 3): spurious
    v = M.visibility_errors(fbuf, owner)
    assert (v.covered, v.errors, v.spurious) == (9, 3, 1)
    assert v.fraction == pytest.approx(3 / 9)
    zbuf = np.full(owner.shape, 0x1000, np.uint16)
    zbuf[2, 1] = 0xFFFF  # the unwritten pixel still holds the clear value
    assert M.visibility_errors(fbuf, owner, zbuf=zbuf, variant="z16").unwritten == 1
    # explicit colours: triangle 2 drawn in colour 3 and triangle 0 in colour 9
    colours = np.array([9, 2, 3], np.uint16)
    fb2 = np.where(owner == 0, 9, np.where(owner >= 0, owner + 1, 0)).astype(np.uint16)
    assert M.visibility_errors(fb2, owner, colours).errors == 0
    assert M.visibility_errors(fb2, owner).errors == 3  # the default colours (index + 1) disagree
    json.dumps(v.as_dict())


def test_depth_error_hand_built():
    depth = np.array([[0.25, 0.5], [0.75, np.inf]])
    owner = np.array([[0, 0], [1, -1]])
    zbuf = np.array([[0x4000, 0x8001], [0xC000, 0xFFFF]], np.uint16)  # one pixel off by one z16 step
    d = M.depth_error(zbuf, "z16", depth, owner)
    assert d.pixels == 3 and d.depth_range == 0.5
    assert d.worst_abs == 2.0 ** -16 and d.worst == 2.0 ** -15
    assert d.mean_abs == pytest.approx(2.0 ** -16 / 3)
    json.dumps(d.as_dict())


def test_random_scene_measured_errors():
    """The article's scene at 640x480, depth complexity 3: exact winners per variant (measured).
    z32 and zf32 match the exact reference everywhere; both 16-bit formats lose a few pixels along
    intersection lines, the 16-bit float more (it is coarser than z16 beyond depth 2^-5)."""
    g = R.random_scene(640, 480, 300, 3.0, 1998)
    s = R.rasterize(g, 640, 480)
    depth, owner = R.reference(s, 640, 480)
    res = {}
    for v in R.VARIANTS:
        if v == "zf32" and not ref.x87_extended_available():
            continue
        zb, fb = R.simulate_frame(s, v, 640, 480)
        res[v] = M.frame_errors(v, zb, fb, depth, owner, g.colour)
        json.dumps(res[v].as_dict())
    assert res["z32"].visibility.errors == 0
    assert 0 < res["z16"].visibility.errors < res["fp16z"].visibility.errors < 1e-3 * res["fp16z"].visibility.covered
    assert res["z32"].depth.worst < 1e-7 < res["z16"].depth.worst < res["fp16z"].depth.worst
    # z16 truncates: never more than one step (plus interpolation error) from the exact depth
    assert res["z16"].depth.worst_abs < 2.0 ** -16 + 1e-7
    if "zf32" in res:
        assert res["zf32"].visibility.errors == 0 and res["zf32"].depth.worst < 1e-6


def test_z16_z_fights_on_coplanar_far_surfaces_that_z32_resolves():
    g = R.coplanar_far_scene(640, 480, pairs=40, seed=1998)
    s = R.rasterize(g, 640, 480)
    depth, owner = R.reference(s, 640, 480)
    zf = {}
    for v in ("z32", "z16", "fp16z"):
        zb, fb = R.simulate_frame(s, v, 640, 480)
        zf[v] = M.z_fighting(fb, s, g.pairs, owner, g.colour)
    assert zf["z32"].contested > 50_000
    assert zf["z32"].lost == 0
    # 2^-20 apart is 1/16 of a z16 step: drawn far-first, the nearer surface ties and loses ~15/16
    assert 0.85 < zf["z16"].far_first_fraction < 0.99
    assert zf["z16"].fraction > 0.3
    assert zf["fp16z"].far_first_fraction > 0.98  # 2^-12 steps at depth ~0.9
    assert zf["z16"].far_first_contested < zf["z16"].contested  # both draw orders occur
    json.dumps(zf["z16"].as_dict())


def test_z_fighting_counts_only_contested_pixels():
    """A nearer and a farther triangle overlapping in a known region; a third triangle in front
    of part of it removes those pixels from the contest."""
    w, h = 32, 16
    sq = lambda x0, x1, y0, y1: [[[x0, y0], [x1, y0], [x0, y1]], [[x1, y0], [x1, y1], [x0, y1]]]
    xy = np.array(sq(0, 20, 0, 16) + sq(10, 32, 0, 16) + sq(0, 12, 0, 8), float)
    far = 0.5 + 2 ** -17  # mid-way through a z16 step, so the nearer one, 2^-20 nearer, ties
    z = np.array([[far] * 3] * 2 + [[far - 2 ** -20] * 3] * 2 + [[0.1] * 3] * 2)
    tris = R.Geometry(xy, z)
    pairs = np.array([[2, 0], [3, 1], [2, 1], [3, 0]])  # square 1 (nearer) against square 0
    s = R.rasterize(tris, w, h)
    depth, owner = R.reference(s, w, h)
    zb, fb = R.simulate_frame(s, "z16", w, h)
    zf = M.z_fighting(fb, s, pairs, owner)
    overlap = 10 * 16 - 2 * 8  # x 10..19, all rows, minus x 10..11 of rows 0..7 (occluded)
    assert zf.contested == overlap
    assert zf.lost == overlap and zf.far_first_lost == overlap  # a tie at z16: the nearer never wins
    zb, fb = R.simulate_frame(s, "z32", w, h)
    assert M.z_fighting(fb, s, pairs, owner).lost == 0


def test_fp16_precision_table():
    t = M.fp16_precision(2.0 ** -30, 1.0, 60)
    mid = np.array(t.depth_mid)
    rel = np.array(t.relative["fp16z"])
    above = mid > 2.0 ** -21
    # a float: relative step between 2^-12 and 2^-11 wherever the exponent is in use
    assert np.all((rel[above] >= 2.0 ** -12) & (rel[above] <= 2.0 ** -11))
    assert np.all(np.array(t.worst_relative["fp16z"])[np.array(t.depth_lo) >= 2.0 ** -21] <= 2.0 ** -11)
    # below 2^-21 every 32-bit depth is representable: the step is z32's
    np.testing.assert_array_equal(np.array(t.step["fp16z"])[mid < 2.0 ** -22], 2.0 ** -32)
    # fixed point: uniform absolute step, so the relative step grows toward the camera
    assert set(t.step["z16"]) == {2.0 ** -16} and set(t.step["z32"]) == {2.0 ** -32}
    np.testing.assert_allclose(np.array(t.relative["z16"]) * mid, 2.0 ** -16)
    # the crossover: fp16z is finer than z16 nearer than 2^-5, equal up to 2^-4, coarser beyond
    f, z = np.array(t.step["fp16z"]), np.array(t.step["z16"])
    assert np.all(f[mid < 2.0 ** -5] < z[mid < 2.0 ** -5]) and np.all(f[mid >= 2.0 ** -4] > z[mid >= 2.0 ** -4])
    band = (mid >= 2.0 ** -5) & (mid < 2.0 ** -4)
    assert band.any() and np.all(f[band] == z[band])
    rows = t.rows()
    assert len(rows) == 60 and rows[0]["depth_lo"] == pytest.approx(2.0 ** -30)
    json.dumps(t.as_dict())
    lin = M.fp16_precision(0.0, 1.0, 4, spacing="linear")
    assert lin.depth_mid == (0.125, 0.375, 0.625, 0.875)
    with pytest.raises(ValueError):
        M.fp16_precision(0.0, 1.0, 4)  # log bins need depth_lo > 0


def test_quantization_step_matches_the_encoding():
    rng = np.random.default_rng(0)
    z = np.concatenate([rng.integers(2, 1 << 32, 20000, dtype=np.uint64),
                        np.arange(2, 5000, dtype=np.uint64), 2 ** np.arange(1, 32, dtype=np.uint64)])
    z = z[z < (1 << 32) - (1 << 21)].astype(np.uint32)
    step = (M.quantization_step(z / 2.0 ** 32, "fp16z") * 2.0 ** 32).astype(np.uint64)
    h = ref.fp16z_encode(z)
    lower = ref.fp16z_decode(h).astype(np.uint64)
    np.testing.assert_array_equal(ref.fp16z_encode((lower + step - 1).astype(np.uint32)), h)  # same code...
    assert np.all(ref.fp16z_encode((lower + step).astype(np.uint32)) > h)                     # ...until lower + step
