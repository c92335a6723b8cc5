"""The texture article's span loops: bit-exact pixels against the references, and the report."""

from __future__ import annotations

import numpy as np
import pytest

from sim.studies import texture_loops as T
from sim.guest.emu import Machine
from sim.guest.kernels import kernels_root


@pytest.mark.parametrize("loop", list(T.LOOPS))
@pytest.mark.parametrize("span", [T.SPAN, dict(u=0x00FF_F000, v=0x00FE_0100, du=-0x0001_2345 & 0xFFFFFFFF,
                                                  dv=0x0002_8001)])
def test_loops_draw_the_reference_pixels(loop, span):
    m = Machine.from_source(kernels_root() / T.KERNEL)
    tex = T.texture()
    count = 777
    args = T.setup(count, tex=tex, **span)(m)
    m.call(loop, *args)
    got = m.arena.get(args[0], np.uint8, count)
    want = T.REFERENCES[loop](tex, count, span["u"], span["v"], span["du"], span["dv"])
    assert np.array_equal(got, want)


def test_four_clock_loop_draws_what_the_five_clock_loop_draws():
    m = Machine.from_source(kernels_root() / T.KERNEL)
    out = {}
    for loop in ("tex5", "tex4"):
        m.arena.reset()
        args = T.setup(1000, **T.SPAN)(m)
        m.call(loop, *args)
        out[loop] = m.arena.get(args[0], np.uint8, 1000).copy()
    assert np.array_equal(out["tex5"], out["tex4"])


def test_report_on_a_pentium(tmp_path):
    out = T.write_report(tmp_path / "t.md", ["pentium-133", "pentium2-233"])
    text = out.read_text()
    assert "pentium-133" in text and "pentium2-233" in text and "4-clock loop" in text
    per = {loop: T.cycles_per_pixel("pentium-133", loop, 64) for loop in T.LOOPS}
    # sourced pairing facts: tex5 has 9 instructions in 4 pairs + the lone JNZ; tex4 has 8 in 4 pairs
    assert per["tex5"]["pairs"] == 4 and per["tex5"]["alone"] == 1
    assert per["tex4"]["pairs"] == 4 and per["tex4"]["alone"] == 0


def test_subspan_kernels_draw_the_span_and_divide():
    m = Machine.from_source(kernels_root() / T.FDIV_KERNEL)
    for entry in ("sub16", "sub16_overlap", "sub16_serial", "sub16_overlap_single", "sub16_serial_single"):
        m.arena.reset()
        args = T.fdiv_setup(64)(m)
        m.call(entry, *args)
        assert np.array_equal(m.arena.get(args[0], np.uint8, 64), T.span_reference(T.texture(), 64, **T.SPAN))
        if entry != "sub16":
            assert m.arena.get(args[-1], np.float32, 2)[1] == np.float32(1 / T.DIVISOR)


def test_fdiv_runs_beside_the_integer_loop_on_a_pentium():
    # AF28.2: FDIV takes 39 clocks of which 38 overlap later integer instructions; only the FSTP
    # that needs its result waits. A 16-pixel sub-span (80 clocks of integer work) hides it.
    d = T.divide_costs("pentium-133", 64)
    assert d["overlap"] < 10  # FLD1 2 + FDIV 1 + FSTP 2 + two pointer reloads, no wait
    assert d["serial"] >= 39  # FSTP right after FDIV waits for all of it
    # AF28.2 note p: FDIV 19 clocks at 24-bit precision, 39 at 64-bit (the *_single entries FLDCW a
    # constant 24-bit control word)
    assert d["serial"] - d["serial_single"] == 39 - 19
    assert d["overlap_single"] == d["overlap"]
