"""Sessions share a lowered program (sim.cpus.session.lowered) only between models that lower alike:
models with equal lowering keys lower the same records to equal programs, whichever estimate is at
either end of its range or which preset field is overridden; a model that lowers otherwise (another
microcode rate, another bus ratio for a locked instruction's cost) has another key."""

import numpy as np
import pytest

from sim.cpus.build import make_model
from sim.cpus.session import lowered
from sim.scenes.claims import parameters
from sim.timing.kernel import emulate

# instructions every family decodes and lowers in its own way: microcode, a lock, a REP string,
# x87, a partial register, a call and a return
KERNEL = """.intel_syntax noprefix
.text
.globl k
k:
    push esi
    push edi
    mov esi, [esp+12]
    lea edi, [esi+256]
    mov ecx, 16
    rep movsd
    lock add dword ptr [esi], 1
    bsr eax, [esi]
    shrd eax, edx, 5
    mov dl, al
    movzx eax, dx
    imul eax, ecx
    fld dword ptr [esi]
    fdiv dword ptr [esi+4]
    fsqrt
    fstp dword ptr [esi+8]
    call 1f
    pop edi
    pop esi
    ret
1:
    xchg eax, [esi+12]
    ret
"""

CPUS = {"pentium2-233": [{"estimates.msrom_rate": 1}], "k6-2-300": [{"clock.core_mhz": 350.0}],
        "pentium-mmx-233": [{"clock.core_mhz": 166.0}]}


def _models(cpu):
    yield make_model(cpu)
    for p in parameters(cpu):
        for value in {p.low, p.high} - {p.nominal}:
            yield make_model(cpu, None, {p.key: value})
    yield make_model(cpu, None, {"l1d.latency_cycles": 2})
    for overrides in CPUS[cpu]:
        yield make_model(cpu, None, overrides)


def _same(a, b) -> bool:
    return all(np.array_equal(x, y) for x, y in zip(a.arrays(), b.arrays())) and a.matches == b.matches


@pytest.mark.parametrize("cpu", list(CPUS))
def test_models_with_one_lowering_key_lower_alike_and_the_shared_program_is_theirs(tmp_path, cpu):
    src = tmp_path / "k.S"
    src.write_text(KERNEL)
    emu = emulate(src, "k", lambda m: [m.arena.put(np.ones(1024, np.uint8), align=64)], repeat=1)
    records = emu.records()
    precisions = [None] * len(records)
    groups = {}
    for model in _models(cpu):
        groups.setdefault(model.lowering_key(), []).append(model)
    assert len(groups) >= 2  # the last overrides lower otherwise: the key must tell them apart
    firsts = []
    for key, models in groups.items():
        fresh = [m.lower(records, precisions) for m in models]
        assert all(_same(fresh[0], f) for f in fresh[1:]), key
        shared = [lowered(m, records, precisions) for m in models]
        assert all(s is shared[0] for s in shared) and _same(shared[0], fresh[0])
        firsts.append(fresh[0])
    assert any(not _same(firsts[0], f) for f in firsts[1:])  # another key: another program here
