"""Cross-check against real silicon: the same three instructions run natively on the host CPU.

x86-64 executes BSR and SHRD with 32-bit operands exactly as an i686 does, so the host is a
reference that owes nothing to Unicorn or to our numpy model. The host routine is assembled here
with GNU as (--64), mapped executable and called through ctypes.
"""

import ctypes
import mmap
import platform
import shutil
import subprocess

import numpy as np
import pytest
from elftools.elf.elffile import ELFFile

from sim import reference as ref

HOST_SOURCE = """
.intel_syntax noprefix
.text
# void convert(const uint32 *src, uint32 *dst, size_t n, uint32 edx_in, uint32 ecx_in)  (System V)
    mov     r9, rdx
    mov     r10d, ecx
    mov     r11d, r8d
    test    r9, r9
    jz      2f
1:  mov     eax, [rdi]
    mov     edx, r10d
    mov     ecx, r11d
    bsr     ecx, eax
    shrd    edx, eax, cl
    shrd    edx, ecx, 21
    mov     [rsi], edx
    add     rdi, 4
    add     rsi, 4
    dec     r9
    jnz     1b
2:  ret
"""

pytestmark = pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64") or shutil.which("as") is None,
                                reason="needs an x86-64 host and GNU as")


def host_function(tmp_path_factory, source: str, argtypes: list):
    """(function, page): `source` assembled for the host (as --64) and mapped executable; keep the
    page alive while the function is used."""
    d = tmp_path_factory.mktemp("host")
    (d / "h.S").write_text(source)
    subprocess.run(["as", "--64", "-o", str(d / "h.o"), str(d / "h.S")], check=True)
    with open(d / "h.o", "rb") as f:
        code = ELFFile(f).get_section_by_name(".text").data()
    try:
        buf = mmap.mmap(-1, mmap.PAGESIZE, prot=mmap.PROT_READ | mmap.PROT_WRITE | mmap.PROT_EXEC)
    except (OSError, ValueError) as e:  # a hardened kernel may refuse writable+executable pages
        pytest.skip(f"cannot map executable memory: {e}")
    buf.write(code)
    addr = ctypes.addressof(ctypes.c_char.from_buffer(buf))
    return ctypes.CFUNCTYPE(None, *argtypes)(addr), buf


@pytest.fixture(scope="module")
def host_convert(tmp_path_factory):
    fn, page = host_function(tmp_path_factory, HOST_SOURCE, [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t,
                                                             ctypes.c_uint32, ctypes.c_uint32])

    def convert(values, edx_in, ecx_in):
        src = np.ascontiguousarray(values, dtype=np.uint32)
        dst = np.zeros_like(src)
        fn(src.ctypes.data, dst.ctypes.data, src.size, edx_in, ecx_in)
        return dst

    yield convert  # `page` (the executable page) stays mapped until the module's tests are done


def sample() -> np.ndarray:
    rng = np.random.default_rng(233)
    k = np.arange(32, dtype=np.uint64)
    p = np.uint64(1) << k
    special = np.concatenate([p, p - np.uint64(1), p + np.uint64(1), np.array([0, 0xFFFFFFFF], np.uint64)])
    rand = rng.integers(0, 1 << 32, 50_000, dtype=np.uint64)
    return (np.concatenate([special, rand]) & np.uint64(0xFFFFFFFF)).astype(np.uint32)


@pytest.mark.parametrize("edx_in,ecx_in", [(0, 0), (0xFFFFFFFF, 5), (0x12345678, 40)])
def test_unicorn_agrees_with_host_cpu(machine, host_convert, edx_in, ecx_in):
    vals = sample()
    m = machine("convert/fp16z.S")
    src = m.arena.put(vals)
    dst = m.arena.alloc(4 * vals.size)
    m.call("fp16z_convert_array", src, dst, vals.size, edx_in, ecx_in)
    emulated = m.arena.get(dst, np.uint32, vals.size)
    native = host_convert(vals, edx_in, ecx_in)
    np.testing.assert_array_equal(emulated, native)
    np.testing.assert_array_equal(ref.fp16z_convert(vals, edx_in, ecx_in)[0], native)


def test_zero_case_on_host(host_convert):
    """Silicon leaves ECX unchanged for BSR of 0, so the result depends on the preset ECX."""
    for ecx_in in (0, 5, 40):
        got = host_convert([0], 0xCAFEBABE, ecx_in)[0]
        assert got == ref.fp16z_convert([0], 0xCAFEBABE, ecx_in)[0][0]


# -- x87 precision control ------------------------------------------------------------------
# The x87 of an x86-64 host rounds to the precision field of its control word exactly as an i686's
# does, so the same operations at 24, 53 and 64 bits check Unicorn's x87 (which the models' traces
# and the snapping scene rely on) against silicon. Results are compared as the full 80-bit register.
HOST_X87 = """
.intel_syntax noprefix
.text
# void x87_ops(const float *a, const float *b, void *snap, void *quot, void *root, size_t n, uint32 cw)
    sub     rsp, 8
    fnstcw  [rsp]
    fldcw   [rsp+16]
    test    r9, r9
    jz      2f
1:  fld     dword ptr [rdi]
    fadd    dword ptr [rip+bias]
    fsub    dword ptr [rip+bias]
    fstp    tbyte ptr [rdx]
    fld     dword ptr [rdi]
    fdiv    dword ptr [rsi]
    fstp    tbyte ptr [rcx]
    fld     dword ptr [rdi]
    fabs
    fsqrt
    fstp    tbyte ptr [r8]
    add     rdi, 4
    add     rsi, 4
    add     rdx, 10
    add     rcx, 10
    add     r8, 10
    dec     r9
    jnz     1b
2:  fldcw   [rsp]
    add     rsp, 8
    ret
bias: .float 786432.0
"""
CONTROL_WORDS = {24: 0x007F, 53: 0x027F, 64: 0x037F}


@pytest.fixture(scope="module")
def host_x87(tmp_path_factory):
    fn, page = host_function(tmp_path_factory, HOST_X87, [*[ctypes.c_void_p] * 5, ctypes.c_size_t, ctypes.c_uint32])

    def run(a, b, cw):
        a = np.ascontiguousarray(a, np.float32)
        b = np.ascontiguousarray(b, np.float32)
        outs = [np.zeros(10 * a.size, np.uint8) for _ in range(3)]
        fn(a.ctypes.data, b.ctypes.data, *(o.ctypes.data for o in outs), a.size, cw)
        return outs

    yield run  # `page` stays mapped until the module's tests are done


def x87_sample() -> tuple[np.ndarray, np.ndarray]:
    """Ordinary, tiny, huge and negative operands, values on and between 1/16 steps (the snap's
    ties), and values around the 2^19 where the 3<<18 snap stops working."""
    rng = np.random.default_rng(87)
    sixteenths = np.arange(-4096, 4096, dtype=np.float64) / 16
    ties = sixteenths + 1 / 32
    limit = np.concatenate([2.0 ** 19 + np.arange(-40, 40) / 16, -(2.0 ** 19) + np.arange(-40, 40) / 16,
                            2.0 ** 18 + np.arange(-8, 8) / 32])
    rand = np.concatenate([rng.uniform(-2048, 2048, 4000), rng.uniform(-1, 1, 1000) * 1e-6,
                           rng.uniform(-1, 1, 1000) * 3e7, 10.0 ** rng.uniform(-30, 30, 1000)])
    a = np.concatenate([sixteenths, ties, limit, rand]).astype(np.float32)
    b = np.resize(np.concatenate([rng.uniform(0.1, 100, 997), [3.0, 7.0, -9.0]]), a.size).astype(np.float32)
    return a, b


@pytest.mark.parametrize("bits", [24, 53, 64])
def test_unicorn_x87_agrees_with_host_cpu_at_each_precision(machine, host_x87, bits):
    a, b = x87_sample()
    m = machine("micro/x87_precision.S")
    pa, pb = m.arena.put(a), m.arena.put(b)
    outs = [m.arena.alloc(10 * a.size) for _ in range(3)]
    m.call("x87_ops", pa, pb, *outs, a.size, CONTROL_WORDS[bits])
    native = host_x87(a, b, CONTROL_WORDS[bits])
    for name, at, want in zip(("snap", "quotient", "root"), outs, native):
        got = m.arena.get(at, np.uint8, 10 * a.size)
        bad = np.flatnonzero((got.reshape(-1, 10) != want.reshape(-1, 10)).any(axis=1))
        assert bad.size == 0, f"{name} at {bits}-bit precision differs from the host for a = {a[bad[:5]]}"


def test_snap_trick_on_host_is_exact_only_at_24_bit(host_x87):
    """Silicon itself: (x + 3<<18) - 3<<18 lands on a multiple of 1/16 for every |x| < 2^18 only
    when the x87 rounds to 24 bits; at 53 and 64 bits the sum keeps x's fraction."""
    a, b = x87_sample()
    small = np.abs(a.astype(np.float64)) < 2.0 ** 18
    for bits in (24, 53, 64):
        snap = host_x87(a, b, CONTROL_WORDS[bits])[0].reshape(-1, 10)
        mant = snap[:, :8].copy().view(np.uint64)[:, 0]
        expo = (snap[:, 8].astype(np.int64) | (snap[:, 9].astype(np.int64) << 8)) & 0x7FFF
        sign = np.where(snap[:, 9] & 0x80, -1.0, 1.0)
        value = sign * np.ldexp(mant.astype(np.float64), (expo - 16383 - 63).astype(np.int64))
        value[(expo == 0) & (mant == 0)] = 0.0
        on_grid = value[small] * 16 == np.round(value[small] * 16)
        if bits == 24:
            assert on_grid.all()
        else:
            assert not on_grid.all()
