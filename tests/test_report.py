"""Scene runs, reports, claims and baselines end to end on small scenes."""

import json

import pytest

from sim import asm, baseline, report
from sim.runner import run_scene
from sim.scene import load_scene

SCENE = """
[scene]
name = "{name}"
description = "A test scene."
width = 48
height = 32

[geometry]
generator = "random"
seed = 3
triangles = 12
depth_complexity = 2.0

[run]
variants = {variants}
cpus = {cpus}
metrics = {metrics}
frames = 2
{claims}
"""


def write_scene(tmp_path, name="tiny-test", variants='["z32", "fp16z"]', cpus='["pentium2-233:edo"]',
                metrics='["visibility", "depth_error"]', claims=""):
    path = tmp_path / f"{name}.toml"
    path.write_text(SCENE.format(name=name, variants=variants, cpus=cpus, metrics=metrics, claims=claims))
    return load_scene(path)


def test_scene_builds_only_what_it_asks_for(tmp_path, monkeypatch):
    assembled = []
    real = asm.assemble
    monkeypatch.setattr(asm, "assemble", lambda src, *a, **k: assembled.append(str(src)) or real(src, *a, **k))
    made = []
    import sim.runner as runner

    real_model = runner.make_model
    monkeypatch.setattr(runner, "make_model", lambda cpu, mem=None: made.append((cpu, mem)) or real_model(cpu, mem))
    scene = write_scene(tmp_path, variants='["z16"]', metrics="[]")
    result = run_scene(scene)
    assert [a.rsplit("/", 1)[-1] for a in assembled] == ["z16.S"]
    assert made == [("pentium2-233", "edo")]
    assert [t.variant for t in result.timings] == ["z16"]
    acc = result.accuracy["z16"]
    assert acc.visibility is None and acc.depth_error is None  # no metric asked, none computed
    assert result.precision is None


def test_report_files_claims_and_findings(tmp_path):
    claims = """
[[claims]]
text = "fp16z costs more than z32 when everything fits in L1"
cpu = "pentium2-233"
variants = ["fp16z", "z32"]
expect = "slower"
tolerance = 0.0

[[claims]]
text = "a claim the model does not reproduce"
cpu = "pentium2-233:edo"
variants = ["fp16z", "z32"]
expect = "faster"
"""
    scene = write_scene(tmp_path, claims=claims)
    result = run_scene(scene)
    paths = report.write_reports(result, tmp_path / "out")
    assert {p.suffix for p in paths} == {".md", ".png", ".json", ".csv", ".html"}
    md = (tmp_path / "out" / "tiny-test.md").read_text()
    assert "## Cycles per pixel" in md and "## Findings" in md and "tiny-test.png" in md
    data = json.loads((tmp_path / "out" / "tiny-test.json").read_text())
    verdicts = [c["holds"] for c in data["claims"]]
    assert verdicts == [True, False]  # the same two numbers: one claim holds, its opposite does not
    assert "not reproduced" in md and "uops" in data["claims"][0]["per_cpu"][0]["explanation"]
    assert (tmp_path / "out" / "tiny-test.png").read_bytes()[:4] == b"\x89PNG"
    csv_lines = (tmp_path / "out" / "tiny-test.csv").read_text().splitlines()
    assert len(csv_lines) == 1 + 2  # header + one row per (variant, cpu)
    html = (tmp_path / "out" / "tiny-test.html").read_text()
    assert "<table>" in html and "data:image/png;base64," in html


def test_reports_are_deterministic_and_written_atomically(tmp_path, monkeypatch):
    scene = write_scene(tmp_path)
    a = report.to_markdown(run_scene(scene), "x.png", [])
    b = report.to_markdown(run_scene(scene), "x.png", [])
    assert a == b
    target = tmp_path / "keep.md"
    target.write_text("old report")

    def boom(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(report.os, "replace", boom)
    with pytest.raises(KeyboardInterrupt):
        report.atomic_write(target, b"new report")
    assert target.read_text() == "old report"
    assert list(tmp_path.glob(".keep.md.*")) == []  # no temp file left behind


def test_baseline_detects_and_explains_drift(tmp_path):
    result = run_scene(write_scene(tmp_path))
    recorded = baseline.update({}, [result])
    assert baseline.compare(recorded, [result]) == []
    case = next(iter(recorded["tiny-test"]))
    recorded["tiny-test"][case]["cycles"] += 7
    drift = baseline.compare(recorded, [result])
    assert len(drift) == 1 and drift[0].counter == "cycles" and drift[0].delta == -7
    assert drift[0].percent == pytest.approx(-700 / drift[0].old)
    del recorded["tiny-test"][case]
    assert any(d.old is None for d in baseline.compare(recorded, [result]))


def test_committed_baselines_cover_every_shipped_scene():
    from sim.cli import SCENES_DIR

    data = baseline.load()
    for path in SCENES_DIR.glob("*.toml"):
        scene = load_scene(path)
        cases = data.get(scene.name, {})
        assert len(cases) == len(scene.variants) * len(scene.cpus), scene.name
