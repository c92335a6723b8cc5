"""Report statistics are exact (sim.stats) and scene data is built without numpy's SIMD-dependent
elementary functions (sim.portable_math), so regenerated reports are the same bytes on any machine."""

from __future__ import annotations

import os
import subprocess
import sys
from fractions import Fraction

import numpy as np
import pytest

from sim import portable_math, stats


def _reference_mean(xs: list[float]) -> float:
    """Plain Python: the exact rational mean, rounded once."""
    return float(sum(map(Fraction, xs)) / len(xs))


def _hard_data(seed: int) -> np.ndarray:
    """Values of both signs over 40 binades: adding them in blocks loses low bits."""
    rng = np.random.default_rng(seed)
    return rng.uniform(-1, 1, 1001) * 2.0 ** rng.integers(-40, 0, 1001)


@pytest.mark.parametrize("seed", [0, 1, 2, 5])
def test_mean_is_the_exact_mean_where_numpys_mean_is_not(seed):
    x = _hard_data(seed)
    want = _reference_mean(x.tolist())
    assert float(np.mean(x)) != want  # the data this test needs: numpy's blocked sum misses it
    assert stats.mean(x) == want
    assert stats.mean(x[::-1]) == want  # and the order of the values does not matter
    assert stats.exact_sum(x) == sum(map(Fraction, x.tolist()))


def test_mean_of_edge_cases():
    assert stats.mean([]) == 0.0 and np.isnan(stats.mean([], float("nan")))
    assert stats.mean([0.0, -0.0]) == 0.0
    assert stats.mean([1.0, float("inf")]) == float("inf")  # an unwritten pixel's infinite error shows
    assert stats.mean([2.0 ** -1074, 2.0 ** -1074]) == 2.0 ** -1074  # subnormals, exactly
    big = [1.7e308, 1.7e308, -1.7e308]  # the exact sum is representable though a running sum overflows
    assert stats.mean(big) == _reference_mean(big)


def test_depth_error_mean_is_exact():
    """The Z-buffer reports' mean depth error: the exact mean of |stored - exact| over covered pixels."""
    from sim.scenes.zbuffer.metrics import depth_error

    rng = np.random.default_rng(3)
    depth = rng.uniform(0, 1, (40, 50)) * 2.0 ** rng.integers(-30, 0, (40, 50))
    zbuf = np.floor(depth * 2.0 ** 32).astype(np.uint32)  # a z32 buffer: each depth truncated
    owner = np.where(rng.uniform(size=depth.shape) < 0.9, 0, -1)
    got = depth_error(zbuf, "z32", depth, owner)
    from sim.scenes.raster import stored_depth

    err = np.abs(stored_depth(zbuf, "z32")[owner >= 0] - depth[owner >= 0])
    assert float(np.mean(err)) != _reference_mean(err.tolist())  # data numpy's mean gets wrong
    assert got.mean_abs == _reference_mean(err.tolist())


def test_texture_mean_coordinate_error_is_exact():
    from sim.scenes.texture.frame import VariantPixels, error_metrics

    rng = np.random.default_rng(9)  # a seed where numpy's mean misses the exact one
    u_exact, v_exact = rng.uniform(0, 255, 5000), rng.uniform(0, 255, 5000)
    u = np.floor(u_exact * 65536 + rng.integers(-3, 4, 5000) * 2 ** rng.integers(0, 20, 5000)).astype(np.int64)
    v = np.floor(v_exact * 65536).astype(np.int64)
    px = VariantPixels(u, v, np.zeros(5000, np.int64))
    got = error_metrics(px, "d", u_exact, v_exact)["mean_coordinate_error"]
    err = np.maximum(np.abs(u / 65536.0 - u_exact), np.abs(v / 65536.0 - v_exact))
    assert float(np.mean(err)) != _reference_mean(err.tolist())
    assert got == _reference_mean(err.tolist())


_GEOMETRY = ("import hashlib, numpy as np; from sim.scenes import raster; "
             "g = raster.random_scene(320, 240, 300, 3.0, 0) if '{gen}' == 'random' "
             "else raster.GENERATORS['{gen}'](320, 240, seed=0); "
             "print(hashlib.sha1(g.xy.tobytes() + g.z.tobytes()).hexdigest())")
_NO_AVX512 = "AVX512_ICL AVX512_SPR X86_V4"  # numpy's dispatch targets of a CPU without AVX-512


def _has_x86_v4() -> bool:
    try:
        from numpy._core._multiarray_umath import __cpu_features__
    except ImportError:
        return False
    return bool(__cpu_features__.get("X86_V4"))


@pytest.mark.skipif(not _has_x86_v4(), reason="needs an AVX-512 CPU to compare numpy's two code paths")
@pytest.mark.parametrize("gen", ["random", "near_far", "coplanar_far", "steep", "tiny"])
def test_scene_geometry_is_the_same_without_avx512(gen):
    """Scene geometry comes from sin, cos, exp and powers of 2: with numpy's (and libm's) functions
    they differed in the last bit between this CPU's AVX-512 path and the AVX2 path (issue 33: the
    stiff-near-far error means did not reproduce), so sim.portable_math computes them."""
    def run(extra):
        env = {**os.environ, **extra}
        return subprocess.run([sys.executable, "-c", _GEOMETRY.format(gen=gen)], env=env, capture_output=True,
                              text=True, check=True).stdout
    assert run({}) == run({"NPY_DISABLE_CPU_FEATURES": _NO_AVX512})


def test_portable_sin_cos_is_within_one_ulp_of_libm():
    """The portable sin/cos are the same functions (to a double's last bit), quadrants included."""
    import math

    x = np.concatenate([np.random.default_rng(3).uniform(-20, 20, 20000),
                        np.arange(-8, 9) * (np.pi / 4), [0.0, -0.0, 1e-300]])
    s, c = portable_math.sin_cos(x)
    for got, fn in ((s, math.sin), (c, math.cos)):
        want = np.array([fn(t) for t in x.tolist()])
        assert np.all(np.abs(got - want) <= np.spacing(np.abs(want)) + 1e-300)


def test_portable_exp_draws_what_lognormal_draws():
    """exp_array(normal) is the same draw as Generator.lognormal, to within a double's last bit."""
    a = np.random.default_rng(5).lognormal(0.0, 0.7, 4000)
    b = portable_math.exp_array(np.random.default_rng(5).normal(0.0, 0.7, 4000))
    assert np.all(np.abs(a - b) <= np.spacing(a))


def test_portable_geomspace_is_the_exact_log_spacing_to_a_last_bit():
    """Ends exact, every point within one ulp of start * (stop/start) ** (i/(n-1)) worked out in 50
    digits (numpy's own geomspace, through log10 and a power, is up to 16 ulps off here)."""
    import decimal

    lo, hi, n = 2.0 ** -24, 1.0, 65
    got = portable_math.geomspace(lo, hi, n)
    ctx = decimal.Context(prec=50)
    want = np.array([float(ctx.multiply(decimal.Decimal(lo), ctx.power(ctx.divide(decimal.Decimal(hi), decimal.Decimal(lo)),
                                                                         ctx.divide(decimal.Decimal(i), decimal.Decimal(n - 1)))))
                     for i in range(n)])
    assert got[0] == lo and got[-1] == hi
    assert np.all(np.abs(got - want) <= np.spacing(want))
