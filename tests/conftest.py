import functools
from pathlib import Path

import pytest

from sim.guest.emu import Machine

ROOT = Path(__file__).resolve().parent.parent
KERNELS = ROOT / "kernels"


@functools.cache
def _machine(relpath: str) -> Machine:
    return Machine.from_source(KERNELS / relpath)


@pytest.fixture
def machine():
    """machine('zbuffer/z32.S') -> a Machine with that kernel loaded and a fresh arena.
    Machines are shared across tests (assembling and mapping is the slow part); the arena is reset."""

    def get(relpath: str) -> Machine:
        m = _machine(relpath)
        m.arena.reset()
        m.reset_fpu()
        return m

    return get


RDTSC_KERNEL = """.intel_syntax noprefix
.text
# @entry timed(n) -> EAX = cycles measured by RDTSC around n dependent IMULs
.globl timed
timed:
    push ebx
    mov ecx, [esp+8]
    rdtsc
    mov ebx, eax
    mov eax, 3
1:  imul eax, eax
    dec ecx
    jnz 1b
    rdtsc
    sub eax, ebx
    pop ebx
    ret
"""


def rdtsc_kernel(tmp_path):
    """A kernel that times n dependent IMULs with RDTSC itself (for the timing models' RDTSC tests)."""
    src = tmp_path / "tsc.S"
    src.write_text(RDTSC_KERNEL)
    return src
