"""The texture article's perspective span renderers (kernels/texture/persp.S): each variant draws
exactly what the model of its arithmetic says (sim/scenes/texture/frame.py), and that model stays within
the error its approximations allow of the exact perspective mapping."""

from __future__ import annotations

import numpy as np
import pytest

from sim.scenes.texture import frame as F
from sim.guest.emu import Machine
from sim.guest.kernels import kernels_root

W, H = 200, 150


def _frame():
    g = F.grid_scene(W, H, 3, 2, seed=7, w_range=(1.0, 3.0))
    return g, F.span_params(g, W, H)


def _draw(m, variant, params, tex):
    m.arena.reset()
    recs = m.arena.alloc(F.RECORD_BYTES * max(1, len(params)), align=4096)
    t = m.arena.put(tex, align=1 << 16)
    fb = m.arena.alloc(W * H, align=4096)
    m.uc.mem_write(recs, F.span_records(params, fb, W))
    m.call(f"frame_{variant}", recs, len(params), t)
    return m.arena.get(fb, np.uint8, W * H)


@pytest.fixture(scope="module")
def machine():
    return Machine.from_source(kernels_root() / F.KERNEL)


@pytest.mark.parametrize("variant", F.VARIANTS)
def test_each_variant_draws_its_model_bit_for_bit(machine, variant):
    _, p = _frame()
    tex = F.texture()
    got = _draw(machine, variant, p, tex)
    px = F.variant_pixels(variant, p)
    span, off = F.pixel_index(p)
    want = np.zeros(W * H, np.uint8)
    want[p.y[span] * W + p.x0[span] + off] = px.texels(tex)
    assert p.pixels == W * H  # the grid covers the screen once (no overdraw, no holes)
    assert np.array_equal(got, want)
    # the x87 is left as FNINIT left it (the frame driver restores it; span_b..e restore theirs)
    assert machine.uc.reg_read(__import__("unicorn").x86_const.UC_X86_REG_FPCW) & 0x0F00 == 0x0300


@pytest.mark.parametrize("variant", F.VARIANTS)
def test_error_within_what_the_approximations_allow(variant):
    """Against the affine interpolation of exact end points (what 16-pixel sub-spans draw with
    perfect arithmetic), each variant's coordinates may only differ by its fixed point's
    truncation of du (less than one unit per pixel step, 15 steps) and its float precision
    (endpoint rounding after up to 40 steps of a += A at 2^-24 relative)."""
    g, p = _frame()
    span, off = F.pixel_index(p)
    planes = g.planes()[p.tri[span]]
    k, i = off // 16, off % 16
    xs = p.x0[span] + 16 * k + 0.5 - g.xy[p.tri[span], 0, 0]
    ys = p.y[span] + 0.5 - g.xy[p.tri[span], 0, 1]
    at = lambda dx, j: (planes[:, j, 0] + planes[:, j, 1] * (xs + dx) + planes[:, j, 2] * ys)
    u0, u1 = at(0, 0) / at(0, 2), at(16, 0) / at(16, 2)
    affine_u = u0 + (u1 - u0) * i / 16
    px = F.variant_pixels(variant, p)
    scale = float(1 << F.FRACTION_BITS[variant])
    unit = 1.0 / scale
    float_err = 2e-3 if F.PRECISION_BITS[variant] == 24 else 1e-6
    bound = 16 * unit + unit + float_err
    assert np.abs(px.u / scale - affine_u).max() <= bound
    u_exact, v_exact = F.exact_coordinates(g, p)
    m = F.error_metrics(px, variant, u_exact, v_exact)
    assert 0 < m["wrong_texel_share"] < 0.5 and m["max_coordinate_error"] >= m["mean_coordinate_error"] > 0


def test_24_8_is_coarser_than_16_16():
    g, p = _frame()
    ue, ve = F.exact_coordinates(g, p)
    d = F.error_metrics(F.variant_pixels("d", p), "d", ue, ve)
    e = F.error_metrics(F.variant_pixels("e", p), "e", ue, ve)
    assert e["mean_coordinate_error"] > d["mean_coordinate_error"]


@pytest.mark.parametrize("x, want", [(2.75, 2), (-2.75, -2), (1e6 + 0.5, 1_000_000), (-0.25, 0)])
def test_ftol_truncates_and_restores_the_control_word(machine, x, want):
    machine.arena.reset()
    at = machine.arena.put(np.array([x], np.float64))
    r = machine.call("ftol_of", at)
    assert np.int32(np.uint32(r.eax)) == want
    assert r.edx == 0x037F  # the FNINIT word it found, not its truncating one


def test_24_8_refuses_coordinates_that_leave_the_texture():
    g = F.grid_scene(W, H, 3, 2, seed=7, st_range=(0.0, 255.0))
    g = F.TexturedGeometry(g.xy, g.st * 1.5 - 60.0, g.w)  # some v below 0 and above 256
    with pytest.raises(F.TextureSceneError, match="24.8"):
        F.variant_pixels("e", F.span_params(g, W, H))
