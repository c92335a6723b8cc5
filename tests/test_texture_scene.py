"""Texture scenes (kind = "texture", sim/scenes/texture/scene.py): loading with clear errors, the
dispatch from sim.scenes.zbuffer.scene / sim.scenes.zbuffer.runner / sim.scenes.zbuffer.report / sim.scenes.baseline, a small run, its claims."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from sim.scenes import baseline
from sim.scenes import registry
from sim.scenes.texture import scene as T
from sim.scenes.registry import load_scene, run_scene
from sim.scenes.schema import SceneError

ROOT = Path(__file__).resolve().parent.parent

SMALL = """[scene]
kind = "texture"
name = "{name}"
width = 160
height = 120

[geometry]
generator = "grid"
seed = 3
columns = 2
rows = 2

[run]
variants = ["a", "c", "e"]
cpus = ["pentium-133", "k6-2-300"]
timing_stride = 2

[[claims]]
text = "c is faster than a"
quantity = "cycles_ratio"
variants = ["a", "c"]
expect = "at_least"
value = 1.0
families = ["p5", "k6"]

[[claims]]
text = "TIMESNAP on the P5 only"
quantity = "timesnap_overhead"
expect = "about"
value = 16
tolerance = 0.25
cpus = ["pentium-133"]
"""


def _write(tmp_path, text, name="tex-small"):
    p = tmp_path / f"{name}.toml"
    p.write_text(text.replace("{name}", name))
    return p


def test_shipped_scene_loads():
    s = load_scene(ROOT / "scenes" / "texture-article.toml")
    assert s.kind == "texture" and s.variants == ("a", "b", "c", "d", "e")
    assert (s.width, s.height) == (640, 480)
    assert {"pentium-133", "pentium2-233", "k6-2-300"} <= {m.preset for m in s.machines}
    assert all(c.quantity in T.QUANTITIES for c in s.claims)


def test_zbuffer_scenes_still_load_with_or_without_kind(tmp_path):
    text = (ROOT / "scenes" / "zbuffer-small.toml").read_text()
    assert load_scene(ROOT / "scenes" / "zbuffer-small.toml").kind == "zbuffer"
    p = tmp_path / "zbuffer-small.toml"
    p.write_text(text.replace("[scene]\n", '[scene]\nkind = "zbuffer"\n', 1))
    assert load_scene(p).kind == "zbuffer"


@pytest.mark.parametrize("change, field", [
    (('kind = "texture"', 'kind = "textures"'), "scene.kind"),
    (('variants = ["a", "c", "e"]', 'variants = ["a", "z"]'), "run.variants[1]"),
    (('columns = 2', 'columns = 0'), "geometry.columns"),
    (('rows = 2', 'rows = 2\nst_range = [0, 300]'), "geometry.st_range"),
    (('timing_stride = 2', 'timing_stride = 2\nframes = 2'), "run.frames"),
    (('quantity = "cycles_ratio"', 'quantity = "speed"'), "claims[0].quantity"),
    (('variants = ["a", "c"]\nexpect', 'variants = ["a"]\nexpect'), "claims[0].variants"),
    (('expect = "at_least"', 'expect = "roughly"'), "claims[0].expect"),
    (('cpus = ["pentium-133"]\n', 'cpus = ["pentium-2000"]\n'), "claims[1].cpus"),
    (('cpus = ["pentium-133", "k6-2-300"]', 'cpus = ["pentium-133", "k6-2-300:ddr"]'), "run.cpus[1]"),
])
def test_bad_scene_is_one_error_naming_file_line_and_field(tmp_path, change, field):
    text = SMALL.replace(*change)
    assert text != SMALL
    p = _write(tmp_path, text)
    with pytest.raises(SceneError) as e:
        load_scene(p)
    msg = str(e.value)
    assert msg.startswith(f"{p}:") and f" {field}" in msg and "\n" not in msg


def test_coordinates_that_break_the_24_8_loop_are_refused_at_load(tmp_path):
    p = _write(tmp_path, SMALL.replace("rows = 2", "rows = 2\nst_range = [256.0, 256.0]"))
    with pytest.raises(SceneError, match=r"geometry: .*24\.8"):
        load_scene(p)


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    p = _write(tmp_path_factory.mktemp("tex"), SMALL)
    return run_scene(load_scene(p))


def test_small_run_times_every_variant_on_every_machine(small):
    assert small.pixels == 160 * 120 and 0 < small.timed_pixels < small.pixels
    assert set(small.timings) == {(v, k) for v in ("a", "c", "e") for k in small.keys}
    for t in small.timings.values():
        assert t["cycles"] > 0 and t["instructions"] > small.timed_pixels  # more than one per pixel
    # the 24.8 loop reads coarser coordinates than 16.16 (the article's distortion)
    assert small.accuracy["e"]["mean_coordinate_error"] > small.accuracy["c"]["mean_coordinate_error"]


def test_probes_follow_the_sources_on_the_pentium(small):
    p = small.probes["pentium-133:" + small.keys[0].split(":")[1]]
    # AF28.2: FDIV 39 clocks at 64-bit, 19 at 24-bit precision (the probe sets each by FLDCW)
    assert p["fdiv_precision_saving"] == 39 - 19
    # _ftol: two FLDCW (8 each, AF28.2) alone make it dearer than a bare FISTP
    assert p["ftol_call"] > p["fistp"] + 16
    assert p["timesnap_overhead"] > 0 and p["timesnap_ftol"] > p["timesnap_overhead"]


def test_claims_cover_only_their_machines_and_follow_the_measurement(small):
    claims = T.evaluate(small)
    ratio, snap = claims
    assert [e["cpu"].split(":")[0] for e in snap["per_cpu"]] == ["pentium-133"]
    assert len(ratio["per_cpu"]) == 2
    for e in ratio["per_cpu"]:
        a = small.cycles_per_pixel("a", e["cpu"])
        c = small.cycles_per_pixel("c", e["cpu"])
        assert e["measured"] == pytest.approx(a / c, abs=1e-4)
        assert e["holds"] == (a / c >= 1.0)
    e = snap["per_cpu"][0]
    assert e["holds"] == (abs(e["measured"] - 16) <= 4) and "RDTSC uops" in e["explanation"]


def test_reports_and_baselines_through_the_generic_entry_points(small, tmp_path):
    written = registry.write_reports(small, tmp_path)
    assert {p.suffix for p in written} == {".md", ".png", ".json", ".csv", ".html"}
    doc = json.loads((tmp_path / "tex-small.json").read_text())
    assert doc["kind"] == "texture" and len(doc["claims"]) == 2
    md = (tmp_path / "tex-small.md").read_text()
    assert "## Error against the exact mapping" in md and "TIMESNAP" in md
    cases = baseline.entries(small)
    assert {f"{v}@{k}" for v in ("a", "c", "e") for k in small.keys} | {f"probes@{k}" for k in small.keys} == set(cases)
    assert all(isinstance(x, int) for case in cases.values() for x in case.values())
    assert baseline.compare({"tex-small": cases}, [small]) == []
    assert registry.summary_tables([small])  # the terminal summary renders


def test_same_report_for_any_number_of_worker_processes(small, tmp_path):
    again = run_scene(small.scene, jobs=2)
    assert T.to_json(again) == T.to_json(small) and T.to_csv(again) == T.to_csv(small)
