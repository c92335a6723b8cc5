"""The P6 core's two compiled versions (sim.cpus.p6.core simulate's `rare`): the version without
the REP string, RDTSC and timeline paths times a trace that needs none of them exactly as the full
one does, and the full one is chosen wherever one of those paths can run
(sim.cpus.p6.model P6Session.rare_paths). The K6 core has the same paths, but leaving them out
did not make it faster (the same speed, or 8 % slower), so it has one version."""

import numpy as np
import pytest

import sim.cpus.p6.core as core
from sim.cpus.build import make_model
from sim.cpus.p6.model import P6Session
from sim.timing.bench import span_emulation
from sim.timing.kernel import time_kernel

CPU = "pentium2-233"

REP_KERNEL = """.intel_syntax noprefix
.text
.globl k
k:
    push edi
    mov edi, [esp+8]
    mov ecx, [esp+12]
    xor eax, eax
    rep stosd
    pop edi
    ret
"""

RDTSC_KERNEL = """.intel_syntax noprefix
.text
.globl k
k:
    rdtsc
    mov ecx, eax
    rdtsc
    sub eax, ecx
    ret
"""


@pytest.fixture
def versions(monkeypatch):
    """The `rare` argument of every call of the core, in order."""
    seen = []
    real = core.simulate

    def spy(*args):
        seen.append(args[-1])
        return real(*args)

    monkeypatch.setattr(core, "simulate", spy)
    return seen


def test_the_lean_version_times_a_plain_trace_as_the_full_one(monkeypatch, versions):
    emu = span_emulation(4096, isa_cpu=CPU)
    runs = []
    for force in (False, True):
        if force:
            monkeypatch.setattr(P6Session, "rare_paths", lambda self, rdtsc_out: True)
        runs.append(make_model(CPU).run(emu.trace, emu.decoder(), [emu.trace.instructions]))
    assert versions == [None, True]
    lean, full = runs
    assert lean.total_cycles == full.total_cycles > 0
    assert np.array_equal(lean.counters, full.counters)
    assert np.array_equal(lean.per_static, full.per_static)


def _timed(tmp_path, source, setup, **kw):
    path = tmp_path / "k.S"
    path.write_text(source)
    return time_kernel(path, "k", setup, cpu=CPU, repeat=2, **kw)


def test_a_rep_string_gets_the_full_version(tmp_path, monkeypatch, versions):
    setup = lambda m: [m.arena.put(np.zeros(4096, np.uint8), align=4096), 256]
    full = _timed(tmp_path, REP_KERNEL, setup).last
    assert versions and all(v is True for v in versions)
    # the check can fail: the lean version does not run the microcode loop, so it times the
    # string differently (its later elements are taken for instructions of their own)
    monkeypatch.setattr(P6Session, "rare_paths", lambda self, rdtsc_out: None)
    assert _timed(tmp_path, REP_KERNEL, setup).last != full


def test_an_rdtsc_or_a_timeline_gets_the_full_version(tmp_path, versions):
    _timed(tmp_path, RDTSC_KERNEL, lambda m: [])
    assert versions and versions[-1] is True
    versions.clear()
    setup = lambda m: [m.arena.put(np.zeros(4096, np.uint8), align=4096), 0]
    plain = REP_KERNEL.replace("    rep stosd\n", "")
    _timed(tmp_path, plain, setup)
    assert versions and all(v is None for v in versions)
    versions.clear()
    _timed(tmp_path, plain, setup, timeline_iterations=1)
    assert versions and all(v is True for v in versions)
