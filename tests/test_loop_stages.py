"""A loop body's way through the layers (issue 35): its text becomes a traced program on the guest
side (sim/guest/loop_body.py, sim/guest/loop_program.py), and the timing side only times it."""

from __future__ import annotations

import ast
from pathlib import Path

SIM = Path(__file__).resolve().parents[1] / "sim"


def _imported(path: Path) -> set[str]:
    """Every module a file imports (module-level or inside a function), as written."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            out.add(node.module)
            out |= {f"{node.module}.{a.name}" for a in node.names}
    return out


def test_only_the_guest_imports_the_emulator():
    outside = {str(p.relative_to(SIM.parent)): sorted(m for m in _imported(p) if m.split(".")[0] == "unicorn")
               for p in sorted(SIM.rglob("*.py")) if SIM / "guest" not in p.parents}
    assert {k: v for k, v in outside.items() if v} == {}


def test_loop_timing_imports_no_emulator_module():
    # the emulator and its tracer are the guest's; loop timing takes the traced program it is handed
    names = _imported(SIM / "timing" / "loop.py")
    assert not {m for m in names if m.split(".")[0] == "unicorn" or m.startswith(("sim.guest.emu", "sim.guest.trace"))}
