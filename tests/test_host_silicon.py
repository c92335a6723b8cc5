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


@pytest.fixture(scope="module")
def host_convert(tmp_path_factory):
    d = tmp_path_factory.mktemp("host")
    (d / "h.S").write_text(HOST_SOURCE)
    subprocess.run(["as", "--64", "-o", str(d / "h.o"), str(d / "h.S")], check=True)
    with open(d / "h.o", "rb") as f:
        code = ELFFile(f).get_section_by_name(".text").data()
    try:
        buf = mmap.mmap(-1, mmap.PAGESIZE, prot=mmap.PROT_READ | mmap.PROT_WRITE | mmap.PROT_EXEC)
    except (OSError, ValueError) as e:  # a hardened kernel may refuse writable+executable pages
        pytest.skip(f"cannot map executable memory: {e}")
    buf.write(code)
    addr = ctypes.addressof(ctypes.c_char.from_buffer(buf))
    proto = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t, ctypes.c_uint32, ctypes.c_uint32)
    fn = proto(addr)

    def convert(values, edx_in, ecx_in):
        src = np.ascontiguousarray(values, dtype=np.uint32)
        dst = np.zeros_like(src)
        fn(src.ctypes.data, dst.ctypes.data, src.size, edx_in, ecx_in)
        return dst

    yield convert  # `buf` (the executable page) stays mapped until the module's tests are done


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
