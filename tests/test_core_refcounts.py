"""The family cores' loops hold no reference counting.

numba counts an array up and down around every call of a helper it inlines (inline="always") and
prunes the pairs it can prove redundant; in the cores' loops it could not prune all of them, and
each left pair is two atomic instructions per access or branch (12 % of the main job's CPU
samples, under perf). Those helpers are compiled without counts (sim.cpus.shared_core.uncounted).
This test compiles the cores afresh (numba shows the LLVM IR only
of code it compiled, not of code it loaded from its cache) and checks the IR: the top function
counts its arguments up in its entry block and nowhere else, and nothing it calls counts at all
(but the per-call set-up that builds the P6's operand lists)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from sim.guest.kernels import kernels_root

# run in a child with its own empty numba cache: the IR exists only for code compiled in-process
CHILD = r"""
import json, re, sys
from dataclasses import replace
import numpy as np
from sim.timing.bench import span_workload, SPAN_KERNEL
from sim.timing.kernel import emulate, time_emulation
from sim.cpus.build import make_model
from sim.cpus.p5 import core as p5
from sim.cpus.p6 import core as p6
from sim.cpus.k6 import core as k6

kernels, pixels = sys.argv[1], 2048
zinit, (z, dz, colour) = span_workload(pixels)

def setup(m):
    return [m.arena.put(zinit), m.arena.put(np.zeros(pixels, np.uint16)), pixels, z, dz, colour]

emu = emulate(kernels + "/" + SPAN_KERNEL, "fp16z_span", setup, repeat=2, budget=0)
for cpu in ("pentium2-233", "k6-233", "pentium-mmx-233"):
    time_emulation(replace(emu), make_model(cpu), warm_start=True)  # simulate's lean version, warm
time_emulation(replace(emu), make_model("pentium2-233"), resumable=True, rooms=True)  # the full one

found = {}
for family, module in (("p6", p6), ("k6", k6), ("p5", p5)):
    for fname in ("simulate", "warm"):
        dispatcher = getattr(module, fname, None)
        for sig, cres in (dispatcher.overloads.items() if dispatcher is not None else ()):
            top = cres.fndesc.llvm_func_name
            for body in cres.library.get_llvm_str().split("\ndefine ")[1:]:
                head, _, rest = body.partition("{")
                name = re.search(r"@(\S+?)\(", head).group(1).strip('"')
                if name.startswith(("cpython.", "cfunc.", "NRT_")) or "_operand_lists" in name:
                    continue
                blocks = re.split(r"\n(?=[^\s;}][^\n]*:)", rest.split("\n}\n")[0].lstrip("\n"))
                counts = [b.count("@NRT_incref(") for b in blocks]
                stray = sum(counts[1:]) if name == top else sum(counts)
                found[f"{family}.{fname}[{sig[-1]}] {name[:60]}"] = stray
print(json.dumps(found))
"""


@pytest.mark.slow
def test_cores_count_no_references_in_their_loops(tmp_path):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    out = subprocess.run([sys.executable, "-c", CHILD, str(kernels_root())], env=env, capture_output=True,
                         text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-3000:]
    found = json.loads(out.stdout.strip().splitlines()[-1])
    # each family's simulate, the P6 and K6 warm-up walks, and both versions of the P6 core
    assert {key.split("[")[0] for key in found} == {"p6.simulate", "p6.warm", "k6.simulate", "k6.warm", "p5.simulate"}
    assert len({key.split(" ")[0] for key in found if key.startswith("p6.simulate")}) == 2
    assert not {key: n for key, n in found.items() if n}, found
