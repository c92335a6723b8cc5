import functools
from pathlib import Path

import pytest

from sim.emu import Machine

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
