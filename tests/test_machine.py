"""The resolved Machine (sim/cpus/machine.py): built once from a label, overrides and a memory; its
cache geometry is what the memory layer builds; it pickles as its label; the package holds no code."""

from __future__ import annotations

import ast
import pickle
from pathlib import Path

import pytest

from sim.cpus import presets
from sim.cpus.build import make_model
from sim.cpus.machine import Machine, MachineKey, resolve
from sim.errors import RetrosimError

KB = 1024


def test_an_override_reaches_the_caches_as_geometry():
    """--set l2.size_kb=256 travels as data: the Machine's L2, and the model's data side, are 256 KB."""
    m = resolve("pentium2-233", {"l2.size_kb": 256}, "sdram-pc100")
    assert m.label == "pentium2-233{l2.size_kb=256}" and m.memory.name == "sdram-pc100"
    assert [(g.name, g.size_bytes, g.ways) for g in m.data_caches] == [("L1D", 16 * KB, 4), ("L2", 256 * KB, 4)]
    assert m.preset.l2.size_kb == 256 and m.instruction_cache.size_bytes == 16 * KB
    model = make_model(m)
    assert model.dside.geometries == m.data_caches and model.dram.name == "sdram-pc100"
    assert resolve("pentium2-233{l2.size_kb=none}").data_caches[-1].name == "L1D"  # no L2 at all


def test_a_label_and_its_parts_resolve_to_one_machine():
    a = resolve("k6-233{write_allocate.mode=full}", {"l2.latency_cycles": 10})
    b = resolve("k6-233", {"l2.latency_cycles": 10, "write_allocate.mode": "full"})
    assert a == b and a.label == "k6-233{l2.latency_cycles=10,write_allocate.mode=full}"
    assert a.data_caches[0].write_allocate is True and resolve("k6-233").data_caches[0].write_allocate == "page+sector"
    assert resolve(a) is a  # a Machine passes through
    assert a.key == MachineKey(a.label) and str(resolve(a, memory="edo").key) == a.label + ":edo"
    assert dict(resolve("pentium2-233", {"estimates.uop_queue": 8}).estimates) == {"uop_queue": 8}


def test_a_machine_pickles_as_its_label_and_memory():
    m = resolve("pentium2-233{l2.size_kb=256}", None, "edo")
    assert m.__reduce__()[1] == ("pentium2-233{l2.size_kb=256}", None, "edo")  # text, not the preset's dict
    again = pickle.loads(pickle.dumps(m))
    assert again == m and isinstance(again, Machine)


def test_an_impossible_machine_is_refused_when_resolved():
    """The geometry and the bus are checked at the edge, naming the machine as given."""
    with pytest.raises(RetrosimError, match=r"CPU preset 'pentium2-233\{l2.size_kb=3\}': L2: size 3072 is not"):
        resolve("pentium2-233{l2.size_kb=3}")
    with pytest.raises(RetrosimError, match="unknown override 'l2.bogus'"):
        resolve("pentium2-233", {"l2.bogus": 1})
    with pytest.raises(RetrosimError, match="unknown memory preset 'nosuch'"):
        resolve("pentium2-233", None, "nosuch")
    with pytest.raises(presets.UnknownPreset):  # a preset file is read by name only: labels are resolved
        presets.load("pentium2-233{l2.size_kb=256}")


def test_the_cpus_package_holds_no_code():
    """sim/cpus/__init__.py is a docstring: the modules below it import one way (presets < overrides <
    machine < build), with no import of the package itself."""
    root = Path(__file__).resolve().parents[1] / "sim" / "cpus"
    tree = ast.parse((root / "__init__.py").read_text(encoding="utf-8"))
    assert all(isinstance(n, ast.Expr) and isinstance(n.value, ast.Constant) for n in tree.body)
    order = ["presets", "overrides", "machine", "build"]
    for i, name in enumerate(order):
        for node in ast.walk(ast.parse((root / f"{name}.py").read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("sim.cpus"):
                targets = [node.module] if node.module != "sim.cpus" else [f"sim.cpus.{a.name}" for a in node.names]
                for t in targets:
                    mod = t.removeprefix("sim.cpus.").split(".")[0]
                    assert mod not in order[i:], f"sim/cpus/{name}.py imports {t} (against presets < overrides < machine < build)"


def test_overrides_replace_typed_fields_which_the_models_read():
    """An override replaces the preset's typed field, not its file's dict (which stays as read): so a
    model must read the typed field. The K6's board-cache latency is one the model used to take
    from the dict."""
    from sim.cpus.k6 import core as k6_core

    m = resolve("pentium2-233", {"l2.size_kb": 256, "clock.core_mhz": 300, "clock.fsb_mhz": 100}, "sdram-pc100")
    assert m.preset.l2.size_kb == 256 and m.preset.raw["l2"]["size_kb"] == 512  # the file's figure, unchanged
    assert (m.preset.core_mhz, m.preset.fsb_mhz) == (300.0, 100.0)
    for label, level in (("k6-2-300", "l2"), ("k6-3-450", "l3")):
        plain, slow = make_model(label), make_model(resolve(label, {f"{level}.latency_cycles": 60}))
        assert plain.params[k6_core.P_BOARD_LAT] != 60 and slow.params[k6_core.P_BOARD_LAT] == 60
    with pytest.raises(RetrosimError, match=r"celeron-266' \(overridden\): missing field 'size_kb'"):
        resolve("celeron-266", {"l2.present": True})  # its file has no L2 figures to turn on
