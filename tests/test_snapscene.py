"""Vertex-snapping scenes ([scene] kind = "snap"): loading, running, reports, claims, baselines."""

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from sim.scenes import baseline
from sim.scenes.snap import scene as snapscene
from sim.cli import main
from sim.scenes.registry import load_scene, run_scene
from sim.scenes.schema import SceneError

ROOT = Path(__file__).resolve().parent.parent
SMALL = """
[scene]
name = "{name}"
kind = "snap"

[workloads]
names = ["screen", "ties", "huge"]
vertices = 64
seed = 5

[run]
variants = ["trick-24", "trick-64", "portable-64"]
cpus = ["pentium-133", "k6-2-300"]

[[claims]]
text = "only 24-bit is right"
expect = "only-exact"
variants = ["trick-24", "trick-64"]
workloads = ["screen", "ties"]

[[claims]]
text = "portable is slower"
expect = "slower"
variants = ["portable-64", "trick-24"]
families = ["p5", "k6"]

[[claims]]
text = "a claim that does not hold: the trick is exact on huge coordinates"
expect = "exact"
variants = ["trick-24"]
workloads = ["huge"]
"""


def write(tmp_path, text, name="snap-small"):
    p = tmp_path / f"{name}.toml"
    p.write_text(text.replace("{name}", name))
    return p


def test_shipped_scene_builds_only_what_it_names():
    s = load_scene(ROOT / "scenes" / "vertex-snap.toml")
    assert s.kind == "snap"
    assert s.needs["kernels"] == ["kernels/snap/snap.S"]
    assert s.needs["entries"] == ["snap_trick", "snap_portable"]
    assert len(s.cpus) == 14  # every P5, P6 and K6 preset
    small = load_scene(write(Path(__import__("tempfile").mkdtemp()), SMALL.replace(
        '"trick-24", "trick-64", "portable-64"', '"trick-24", "trick-64"').split("[[claims]]")[0]))
    assert small.needs["entries"] == ["snap_trick"] and small.needs["workloads"] == ["screen", "ties", "huge"]


@pytest.mark.parametrize("edit,message", [
    (('kind = "snap"', 'kind = "snapping"'), r":4: scene.kind: unknown kind 'snapping' \(known: zbuffer, texture, snap, sort\)"),
    (('"ties", "huge"', '"ties", "giant"'), r"workloads.names\[2\]: unknown workload 'giant'"),
    (('"trick-64", "portable-64"]', '"trick-65", "portable-64"]'), r"run.variants\[1\]: unknown variant 'trick-65'"),
    (('expect = "slower"', 'expect = "slowest"'), r"claims\[1\].expect: unknown expectation 'slowest'"),
    (('families = ["p5", "k6"]', 'families = ["p6"]'), r"claims\[1\]: covers none of run.cpus"),
    (('vertices = 64', 'vertices = 0'), r"workloads.vertices: must be >= 1"),
    (('seed = 5', 'seed = 5\ncolour = 3'), r"workloads.colour: unknown key"),
    (('workloads = ["screen", "ties"]', 'workloads = ["grid"]'), r"claims\[0\].workloads: 'grid' is not one of"),
])
def test_bad_scene_files_give_one_clear_error(tmp_path, edit, message):
    with pytest.raises(SceneError, match=message):
        load_scene(write(tmp_path, SMALL.replace(*edit)))


def test_zbuffer_is_the_default_kind_and_may_be_named():
    text = (ROOT / "scenes" / "zbuffer-small.toml").read_text()
    assert load_scene(ROOT / "scenes" / "zbuffer-small.toml").kind == "zbuffer"
    import tempfile

    d = Path(tempfile.mkdtemp())
    p = d / "zbuffer-small.toml"
    p.write_text(text.replace('[scene]\n', '[scene]\nkind = "zbuffer"\n', 1))
    assert load_scene(p).variants == load_scene(ROOT / "scenes" / "zbuffer-small.toml").variants


@pytest.fixture(scope="module")
def small_result(tmp_path_factory):
    return run_scene(load_scene(write(tmp_path_factory.mktemp("s"), SMALL)))


def test_run_reports_errors_timings_and_claims(small_result, tmp_path):
    r = small_result
    assert {(t.variant, t.key) for t in r.timings} == {(v, k) for v in r.scene.variants
                                                      for k in ("pentium-133:edo-430fx", "k6-2-300:sdram-pc100")}
    assert r.errors[("trick-24", "screen")].wrong == 0 and r.errors[("trick-64", "screen")].wrong > 0
    claims = snapscene.evaluate_claims(r)
    assert [c["verdict"] for c in claims] == ["reproduced", "reproduced", "not reproduced"]
    paths = snapscene.write_reports(r, tmp_path)
    assert sorted(p.suffix for p in paths) == [".csv", ".html", ".json", ".md", ".png"]
    data = json.loads((tmp_path / "snap-small.json").read_text())
    assert data["errors"]["trick-24"]["ties"]["wrong"] == 0
    assert data["failures"]["trick-64"]["ties"][0]["distance"] == 1 / 32
    md = (tmp_path / "snap-small.md").read_text()
    assert "## Failure cases" in md and "| trick-24 | huge |" in md
    assert (tmp_path / "snap-small.csv").read_text().count("\n") == 1 + len(r.timings)
    # generic entry points dispatch on the kind
    from sim.scenes import registry

    assert registry.write_reports(r, tmp_path / "again", formats=("md",))[0].read_text() == md
    assert baseline.entries(r)["trick-24@k6-2-300:sdram-pc100"]["cycles"] == r.timings[1].counters["cycles"]


def test_results_do_not_depend_on_jobs(small_result, tmp_path):
    again = run_scene(small_result.scene, jobs=2)
    assert [t.counters for t in again.timings] == [t.counters for t in small_result.timings]
    assert snapscene.to_json(again) == snapscene.to_json(small_result)


def test_check_against_a_recorded_baseline(tmp_path, monkeypatch):
    """`retrosim check vertex-snap` against a baseline recorded in a temporary copy: it passes, and a
    changed count fails with the case named."""
    path = tmp_path / "baselines.json"
    path.write_text((ROOT / "reports" / "baselines.json").read_text())
    monkeypatch.setattr(baseline, "BASELINE_FILE", path)
    runner = CliRunner()
    r = runner.invoke(main, ["check", "vertex-snap", "--update", "--jobs", "1"])
    assert r.exit_code == 0, r.output
    recorded = json.loads(path.read_text())
    assert len(recorded["vertex-snap"]) == 5 * 14
    r = runner.invoke(main, ["check", "vertex-snap", "--jobs", "1"])
    assert r.exit_code == 0, r.output
    assert "70 case(s) in 1 scene(s) match the baselines" in r.output
    recorded["vertex-snap"]["portable-64@k6-2-300:sdram-pc100"]["cycles"] += 1
    path.write_text(json.dumps(recorded))
    r = runner.invoke(main, ["check", "vertex-snap", "--jobs", "1"])
    assert r.exit_code == 1 and "1 counter(s) differ" in r.output and "-1" in r.output


def test_check_of_a_scene_with_no_baselines_says_so_in_one_line(tmp_path, monkeypatch):
    """A scene the baselines file does not know (a new scene) is one line saying how to record it,
    not a table row for every counter of every case; a changed count of a recorded case is still
    named in full (its case name folded, not cut, at 80 columns)."""
    path = tmp_path / "baselines.json"
    recorded = json.loads((ROOT / "reports" / "baselines.json").read_text())
    recorded.pop("vertex-snap", None)
    path.write_text(json.dumps(recorded))
    monkeypatch.setattr(baseline, "BASELINE_FILE", path)
    runner = CliRunner()
    r = runner.invoke(main, ["check", "vertex-snap", "--jobs", "1"], env={"COLUMNS": "80"})
    assert r.exit_code == 1
    assert "vertex-snap: no baselines recorded" in r.output and "check vertex-snap --update" in r.output
    assert "differ" not in r.output and len(r.output.strip().splitlines()) <= 3, r.output
    assert runner.invoke(main, ["check", "vertex-snap", "--update", "--jobs", "1"]).exit_code == 0
    recorded = json.loads(path.read_text())
    recorded["vertex-snap"]["portable-64@k6-2-300:sdram-pc100"]["cycles"] += 1
    path.write_text(json.dumps(recorded))
    r = runner.invoke(main, ["check", "vertex-snap", "--jobs", "1"], env={"COLUMNS": "80"})
    assert r.exit_code == 1 and "…" not in r.output
    case = "".join(line.split("│")[2].strip() for line in r.output.splitlines() if line.startswith("│"))
    assert case == "portable-64@k6-2-300:sdram-pc100", r.output
