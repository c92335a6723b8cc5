"""Vertex snapping kernels (kernels/snap/snap.S) against the exact reference and the arithmetic the
Glide guide's trick relies on."""

import numpy as np
import pytest

from sim.scenes.snap import workload as S
from sim.timing.kernel import emulate, time_emulation

V = S.VARIANTS


@pytest.fixture(scope="module")
def machine():
    from sim.guest.emu import Machine

    return Machine.from_source(S.KERNEL)


def run(machine, name, coords):
    return S.snap(machine, V[name], coords)


def test_reference_is_nearest_sixteenth_ties_to_even():
    x = np.array([0.03, 1 / 32, 3 / 32, -1 / 32, -3 / 32, 5.5 / 16, 639.97, -0.0], np.float32)
    assert S.reference(x).tolist() == [0.0, 0.0, 0.125, 0.0, -0.125, 0.375, 640.0, 0.0]


@pytest.mark.parametrize("workload", S.IN_RANGE)
def test_trick_at_24_bits_is_exact_below_its_limit(machine, workload):
    coords = S.workload(workload, 1024, 640, 480, 7)
    got = run(machine, "trick-24", coords)
    assert np.array_equal(got.astype(np.float64), S.reference(coords))


@pytest.mark.parametrize("name", ["trick-53", "trick-64"])
def test_trick_at_53_and_64_bits_does_not_snap(machine, name):
    """x + 786432 is exact at 53 and 64 bits for screen coordinates of at least 2^-10 (x's lowest
    bit is then at least 2^-33, within 53 bits of 2^19), so subtracting gives x back unchanged."""
    coords = S.workload("screen", 1024, 640, 480, 7)
    got = run(machine, name, coords)
    big = np.abs(coords) >= 2.0 ** -10
    assert np.array_equal(got[big], coords[big])
    e = S.errors(coords, got)
    assert e.wrong_share > 0.9 and e.off_grid_share > 0.9


def test_ties_go_to_even_with_the_trick_and_toward_zero_with_the_portable_variant(machine):
    coords = S.workload("ties", 512, 640, 480, 3)
    x = coords.astype(np.float64)
    trick = run(machine, "trick-24", coords).astype(np.float64)
    assert np.all((trick * 16) % 2 == 0)  # the even neighbour
    assert np.all(np.abs(trick - x) == 1 / 32)
    portable = run(machine, "portable-64", coords).astype(np.float64)
    assert np.array_equal(portable, np.trunc(x * 16) / 16)  # C's float-to-long conversion chops


@pytest.mark.parametrize("name", ["portable-64", "portable-24"])
def test_portable_variant_truncates_and_overflows_its_long(machine, name):
    coords = np.concatenate([S.workload("screen", 256, 640, 480, 5), S.workload("negative", 256, 640, 480, 5),
                             np.array([[2.0 ** 27, -(2.0 ** 27) - 64]], np.float32)])
    got = run(machine, name, coords).astype(np.float64).ravel()
    x = coords.astype(np.float64).ravel()
    fits = np.abs(x * 16) < 2.0 ** 31
    assert np.array_equal(got[fits], np.trunc(x[fits] * 16) / 16)
    # FISTP of a value outside 32 bits stores the integer indefinite, -2^31, when invalid is masked
    assert np.all(got[~fits] == -(2.0 ** 31) / 16) and (~fits).sum() == 2


def test_trick_beyond_its_limit(machine):
    """At 24 bits, 2^18 <= x < 2^19 puts the sum in [2^20, 2^21): steps of 1/8; -2^19 <= x < -2^18
    puts it in [2^18, 2^19): steps of 1/32, off the 1/16 grid for odd multiples of 1/32."""
    coords = S.workload("limit", 514, 640, 480, 0)
    x = coords.astype(np.float64).ravel()
    got = run(machine, "trick-24", coords).astype(np.float64).ravel()
    up = (x >= 2.0 ** 18) & (x < 2.0 ** 19)
    assert np.array_equal(got[up], np.round(x[up] * 8) / 8)
    down = (x >= -(2.0 ** 19)) & (x < -(2.0 ** 18))
    assert np.array_equal(got[down], x[down])  # multiples of 1/32 already: kept as they are
    assert np.any(got[down] * 16 != np.round(got[down] * 16))
    inside = np.abs(x) < 2.0 ** 18
    assert np.array_equal(got[inside], S.reference(x[inside].astype(np.float32)))


def test_errors_and_failures():
    coords = np.array([[0.03, 1 / 32], [2.0, 5.0]], np.float32)
    result = np.array([[0.03, 0.0625], [2.0, 5.0]], np.float32)
    e = S.errors(coords, result)
    assert (e.wrong, e.off_grid, e.coordinates) == (2, 1, 4)
    assert e.worst == 0.0625 and e.worst_input == np.float32(1 / 32)
    f = S.failures(coords, result)
    assert [r["input"] for r in f] == [np.float32(1 / 32), np.float32(0.03)]
    assert f[0]["on_grid"] and not f[1]["on_grid"]


@pytest.mark.parametrize("cpu", ["pentium-133", "pentium2-233", "k6-2-300"])
def test_cycles_per_vertex(cpu):
    """FADD and FSUB do not depend on precision in any family's sources, so the trick costs the
    same at 24 and 64 bits; the portable variant's FMUL, call, two FLDCW, FISTP, FILD and FDIV
    cost more (the guide: 'very inefficient')."""
    coords = S.workload("screen", 256, 640, 480, 1)
    cyc = {}
    for name in ("trick-24", "trick-64", "portable-64", "portable-24"):
        emu = emulate(S.KERNEL, V[name].entry, S.setup(V[name], coords), repeat=2)
        cyc[name] = time_emulation(emu, cpu).last["cycles"]
    assert cyc["trick-24"] == cyc["trick-64"]
    assert cyc["portable-64"] > cyc["trick-24"]
    assert cyc["portable-24"] < cyc["portable-64"]  # its FDIV at 24 bits
