"""Scene kinds share one declared schema (sim.scenes.schema.Field) and stand apart: every field a
kind declares is documented in its file format, and no kind imports another (what two kinds share
lives in sim/scenes/, e.g. the frame of sim.scenes.geometry)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from sim.scenes import geometry
from sim.scenes.registry import KINDS
from sim.scenes.schema import Field

ROOT = Path(__file__).resolve().parent.parent
SCENES = ROOT / "sim" / "scenes"


def _imports(path: Path) -> set[str]:
    """Every module a file imports, function-local imports included."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names)
    return out


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_no_kind_imports_another_kind(kind):
    others = [k for k in KINDS if k != kind]
    for path in sorted((SCENES / kind).glob("*.py")):
        bad = sorted(m for m in _imports(path) for o in others
                     if m == f"sim.scenes.{o}" or m.startswith(f"sim.scenes.{o}."))
        assert not bad, f"{path.relative_to(ROOT)} imports another kind: {bad}"


def _declared(module) -> list[Field]:
    """The Fields a module declares at its top level (in tuples, or dicts of tuples)."""
    out = []
    for value in vars(module).values():
        items = value.values() if isinstance(value, dict) else [value]
        for item in items:
            if isinstance(item, Field):
                out.append(item)
            elif isinstance(item, tuple):
                out += [f for f in item if isinstance(f, Field)]
    return out


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_every_declared_field_is_in_the_kinds_file_format(kind):
    import importlib

    module = importlib.import_module(f"sim.scenes.{kind}.scene")
    fields = _declared(module) + (_declared(geometry) if kind == geometry.KIND else [])
    assert fields, f"sim.scenes.{kind}.scene declares no fields"
    format_doc = module.__doc__.split("Format::", 1)[1]
    missing = sorted({f.name for f in fields if f"{f.name} = " not in format_doc
                      and not (f.type == "tables" and f".{f.name}]]" in format_doc)})  # [[run.machine]]
    assert not missing, f"sim.scenes.{kind}.scene declares fields its format does not document: {missing}"


def test_the_registry_names_each_kinds_own_functions():
    """No forwarding layer: each entry point of a kind is a function of the kind's own package."""
    for name, kind in KINDS.items():
        for attr in ("load", "run", "write_reports", "summary_tables", "baseline_entries", "sweep_emulation"):
            fn = getattr(kind, attr)
            assert fn.__module__.startswith(f"sim.scenes.{name}."), (name, attr, fn.__module__)
    assert not list(SCENES.glob("*/kind.py"))
