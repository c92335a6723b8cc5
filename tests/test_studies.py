"""Studies apart from views: the conformance, validation, texture-loops and conversion reports only
render results their study hands them, and what they say of one family is that family's data."""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

import pytest

from sim.cpus.families import FAMILIES

SIM = Path(__file__).resolve().parents[1] / "sim"
STUDIES = ("conformance", "validation", "texture_loops", "conversion")
# what a renderer may not import: its study, the guest (assembler, emulator), the timing drivers
NOT_IN_A_REPORT = ("sim.studies", "sim.guest", "sim.timing", "sim.parallel", "unicorn")


def _imported(path: Path) -> set[str]:
    """Every module the file imports, but for names imported for type hints only (if TYPE_CHECKING)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    hints = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If) and getattr(node.test, "id", "") == "TYPE_CHECKING"
             for n in ast.walk(node)}
    out = set()
    for node in ast.walk(tree):
        if id(node) in hints:
            continue
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            out |= {node.module} | {f"{node.module}.{a.name}" for a in node.names}
    return out


REPORTS = sorted(p.stem for p in (SIM / "reports").glob("*.py") if p.stem != "__init__")


@pytest.mark.parametrize("name", REPORTS)
def test_a_report_imports_no_study_guest_or_timing_driver(name):
    """Views and reports only read results: none imports a study, the guest or the timing drivers."""
    bad = {m for m in _imported(SIM / "reports" / f"{name}.py")
           if any(m == p or m.startswith(p + ".") for p in NOT_IN_A_REPORT)}
    assert not bad, f"sim/reports/{name}.py imports {sorted(bad)}"
    assert name not in STUDIES or (SIM / "studies" / f"{name}.py").is_file()


@pytest.mark.parametrize("path", [f"{d}/{n}.py" for d in ("reports", "studies") for n in STUDIES])
def test_no_family_name_as_a_literal(path):
    """A study or its report asks the family's record, never compares with a family's name."""
    tree = ast.parse((SIM / path).read_text(encoding="utf-8"))
    found = sorted({n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and n.value in FAMILIES})
    assert not found, f"sim/{path} names families {found}"


def _texture_results(machines):
    from sim.studies.texture_loops import LOOPS, Machine, Results

    ms = [Machine(name, fam, 100.0) for name, fam in machines]
    per = {(m.name, loop): {"cycles": 6.0, "pairs": 1.5, "alone": 2.0, "stall_dependency": 0.25}
           for m in ms for loop in LOOPS}
    divide = {m.name: dict(subspan=80, overlap=2, serial=40, serial_single=20, overlap_single=2, timesnap=16)
              for m in ms}
    return Results(64, dict(LOOPS), ms, per, divide, {m.name: None for m in ms})


def test_texture_loops_lines_are_the_family_records_templates(monkeypatch):
    from sim.reports.texture_loops import render

    text = render(_texture_results([("a5", "p5"), ("a6", "p6"), ("a7", "k6")]))
    assert "## The article's figures against the P5 model" in text       # [family.texture_loops] article
    assert "## The same loops on the P6 and the K6" in text
    assert "- **a5**: 9-instruction loop 6.00 (article: " in text
    # p6's tex5 template: a counter the run did not record reads 0
    assert "- **a6**: tex5 6.00 clocks per pixel, partial-register waits 0.00 per pixel, summed over" in text
    assert "- **a7**: tex5 6.00 clocks per pixel; dependency stalls 0.25, store queue 0.00;" in text
    assert text.endswith("Pairing per pixel on the P5 (tex5): a5 1.50 pairs, 2.00 alone\n\n")
    # a family without a tex5 template gets its record's counters; the article moves with the key
    records = dict(FAMILIES)
    records["k6"] = dataclasses.replace(FAMILIES["k6"], texture_loops={})
    records["p6"] = dataclasses.replace(FAMILIES["p6"], texture_loops={"article": True})
    monkeypatch.setattr("sim.reports.texture_loops.FAMILIES", records)
    text = render(_texture_results([("a6", "p6"), ("a7", "k6")]))
    assert "- **a7**: tex5 6.00 clocks per pixel; dependency 0.25." in text
    assert "against the P5 and the P6 model" in text and "## The same loops on the K6" in text
    assert "- **a6**: 9-instruction loop 6.00" in text


def test_conformance_notes_are_the_family_records():
    from sim.reports.conformance import Method, render
    from sim.studies.conformance import INSTLAT_HARNESS, _family_note

    assert INSTLAT_HARNESS == {n: f.conformance["instlat_harness"] for n, f in FAMILIES.items()
                               if "instlat_harness" in f.conformance} and INSTLAT_HARNESS
    text = render({}, Method(48, 24, 0.05, 12, 48, {"zz": "code layout the ZZ front end sees"}))
    assert "Families zz: InstLatX64's harness instead (12 copies per iteration of a 32-byte-aligned loop, " \
           "48 iterations; memory forms as [reg]), whose\ncode layout the ZZ front end sees.\n" in text
    for fam, rec in FAMILIES.items():
        assert _family_note(fam, "below_nominal", "generic") == rec.conformance.get("below_nominal", "generic")
    assert _family_note("", "above_latency", "generic") == "generic"

