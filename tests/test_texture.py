"""The texture article's span loops: bit-exact pixels against the references, and the report."""

from __future__ import annotations

import numpy as np
import pytest

from sim import texture as T
from sim.emu import Machine
from sim.kernels import kernels_root


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
