"""Claims checked on every machine their words cover, claims about machines not in the run, the
verdict's robustness to the estimated parameters, and make_model's overrides."""

import json

import pytest

from sim.scenes.zbuffer import report
from sim.cpus import presets
from sim.cpus.build import make_model
from sim.cpus.overrides import overridable
from sim.errors import RetrosimError
from sim.scenes.registry import load_scene, run_scene
from sim.scenes.schema import SceneError

SCENE = """
[scene]
name = "{name}"
width = 40
height = 24

[geometry]
generator = "random"
seed = 5
triangles = 10
depth_complexity = 2.0

[run]
variants = ["z32", "fp16z"]
cpus = {cpus}
frames = 2
{claims}
"""

FAMILY_CLAIM = """
[[claims]]
text = "BSR is exorbitant on the K6 family"
families = ["k6"]
variants = ["fp16z", "z32"]
expect = "slower"
"""


def scene(tmp_path, cpus='["pentium2-233:edo", "k6-233", "k6-2-300"]', claims=FAMILY_CLAIM, name="claims-test"):
    path = tmp_path / f"{name}.toml"
    path.write_text(SCENE.format(name=name, cpus=cpus, claims=claims))
    return load_scene(path)


def test_a_claim_is_checked_on_every_machine_its_words_cover(tmp_path):
    result = run_scene(scene(tmp_path), robustness=False)
    (c,) = report.evaluate_claims(result)
    assert [e["cpu"] for e in c["per_cpu"]] == ["k6-233:sdram-pc66", "k6-2-300:sdram-pc100"]  # not the P6
    assert c["not_checked"] == [] and c["covers"] == "every K6 preset"
    for e in c["per_cpu"]:
        a, b = e["cycles_per_pixel"]
        assert e["holds"] == (a > b) and e["verdict"] in ("reproduced", "not reproduced")
        assert e["robustness"] is None  # not measured in this run
    md = report._claim_sentence(c)
    assert "k6-233 (sdram-pc66)" in md and "k6-2-300 (sdram-pc100)" in md and "pentium2-233" not in md


def test_claims_about_cpus_not_in_the_run_are_not_checked(tmp_path):
    """Issue 13: `report --cpu k6-2-300` on a scene whose claims name other CPUs must not crash."""
    claims = FAMILY_CLAIM + """
[[claims]]
text = "about the Pentium II with EDO"
cpus = ["pentium2-233:edo"]
variants = ["fp16z", "z32"]
expect = "similar"
tolerance = 0.1
"""
    s = scene(tmp_path, claims=claims)
    result = run_scene(s, ["k6-2-300"], robustness=False)
    family, pii = report.evaluate_claims(result)
    assert [e["cpu"] for e in family["per_cpu"]] == ["k6-2-300:sdram-pc100"]
    assert family["not_checked"] == ["k6-233:sdram-pc66"]
    assert pii["per_cpu"] == [] and pii["not_checked"] == ["pentium2-233:edo"] and pii["verdict"] == "not checked"
    out = report.write_reports(result, tmp_path / "out", formats=("md", "json"))
    md = (tmp_path / "out" / "claims-test.md").read_text()
    assert "pentium2-233 (edo): not checked (CPU not in this run)" in md
    assert "k6-233 (sdram-pc66): not checked (CPU not in this run)" in md
    assert json.loads(out[1].read_text())["claims"][1]["verdict"] == "not checked"


def test_robustness_reruns_the_trace_with_each_estimate_at_its_ends(tmp_path):
    s = scene(tmp_path, cpus='["k6-2-300"]')
    result = run_scene(s)
    (c,) = report.evaluate_claims(result)
    (e,) = c["per_cpu"]
    rows = {r["parameter"]: r for r in e["robustness"]}
    # every estimate of the K6 model and the preset's estimated board-cache latency and DRAM overhead
    assert {"estimates.store_queue", "l2.latency_cycles", "memory.overhead_bus_clocks"} <= set(rows)
    over = rows["memory.overhead_bus_clocks"]
    calibrated = float(presets.load("k6-2-300").raw["memory"]["overhead_bus_clocks"])
    low, high = calibrated - 2, calibrated + 2  # calibrated on a measurement: +-2 bus clocks
    assert (over["low"], over["high"]) == (low, high)
    # a longer DRAM lead-off cannot make both formats faster: z32 and fp16z both slow down
    sens = result.sensitivity
    for v in ("z32", "fp16z"):
        table = sens[(v, "k6-2-300:sdram-pc100")]
        assert table[("memory.overhead_bus_clocks", high)]["cycles"] >= table[("memory.overhead_bus_clocks", low)]["cycles"]
    flips = [r["parameter"] for r in e["robustness"] if not r["same_verdict"]]
    assert e["verdict"] == (f"depends on {', '.join(flips)}" if flips else
                            "reproduced" if e["holds"] else "not reproduced")
    assert "Robustness:" in report._claim_sentence(c)


def test_an_integer_board_overhead_is_varied_over_whole_clocks_the_preset_accepts():
    """The P5 presets' board overhead is a whole number of bus clocks carried over from another
    system: its range (9 to 19.5) is widened to whole clocks, which make_model accepts."""
    from sim.cpus.build import make_model
    from sim.scenes.claims import parameters

    (over,) = [p for p in parameters("pentium-mmx-166") if p.key == "memory.overhead_bus_clocks"]
    assert (over.low, over.high) == (9, 20)
    for value in (over.low, over.high):
        make_model("pentium-mmx-166", None, {over.key: value})


P6_CLAIM = FAMILY_CLAIM.replace('families = ["k6"]', 'families = ["p6"]').replace("on the K6", "on the P6")


def test_a_claim_on_an_edo_machine_is_checked_against_the_estimated_page_figures(tmp_path):
    """The EDO preset's page figures are estimates (edo.toml [pages.ranges]): each joins the
    robustness pass at the range the preset states; PC100's sourced savings do not."""
    from sim.scenes.claims import parameters

    result = run_scene(scene(tmp_path, cpus='["pentium2-233:edo"]', claims=P6_CLAIM))
    (c,) = report.evaluate_claims(result)
    (e,) = c["per_cpu"]
    rows = {r["parameter"]: r for r in e["robustness"]}
    stated = {"pages.open_pages": (1, 2), "pages.page_bytes": (4096, 16384),
              "pages.hit_saving_bus_clocks": (2, 4), "pages.write_saving_bus_clocks": (0, 1)}
    for key, ends in stated.items():
        assert (rows[key]["low"], rows[key]["high"]) == ends, key
        assert "estimated page figure" in rows[key]["why"]
    assert "pages.hit_saving_bus_clocks 2..4" in report._claim_sentence(c)
    mechanisms = {p.key: p.mechanism for p in parameters("pentium2-233", "edo")}
    assert mechanisms["pages.hit_saving_bus_clocks"] == "dram_page_hits"
    sdram = {p.key for p in parameters("pentium2-233", "sdram-pc100")}
    assert {"pages.open_pages", "pages.page_bytes"} <= sdram  # the geometry is estimated there too
    assert "pages.hit_saving_bus_clocks" not in sdram  # tRP + tRCD from the datasheet


def test_claim_coverage_is_validated(tmp_path):
    bad = FAMILY_CLAIM.replace('families = ["k6"]', 'families = ["z80"]')
    with pytest.raises(SceneError, match=r"claims\[0\]\.families: unknown family 'z80'"):
        scene(tmp_path, claims=bad)
    bad = FAMILY_CLAIM.replace('families = ["k6"]', 'cpus = ["pentium5"]')
    with pytest.raises(SceneError, match=r"claims\[0\]\.cpus: unknown CPU preset 'pentium5'"):
        scene(tmp_path, claims=bad)
    bad = FAMILY_CLAIM.replace('families = ["k6"]\n', '')
    with pytest.raises(SceneError, match=r"claims\[0\]: names no CPU"):
        scene(tmp_path, claims=bad)
    with pytest.raises(SceneError, match=r"claims\[0\]: covers none of run.cpus"):
        scene(tmp_path, cpus='["pentium2-233"]')


def test_make_model_overrides():
    base = make_model("pentium2-233")
    m = make_model("pentium2-233", "edo", {"l2.latency_cycles": 10, "memory.overhead_bus_clocks": 4,
                                           "estimates.uop_queue": 8})
    assert m.params is not base.params and m.estimates["uop_queue"] == 8
    assert m.preset.l2.latency_cycles == 10
    assert m.dram.lead_off == 32 and base.dram.lead_off == 83  # ceil((4 + 5) x 3.5), ceil((18.5 + 5) x 3.5)
    assert make_model("pentium2-233").preset.l2.latency_cycles == 23  # the preset file is untouched
    assert "estimates.store_queue" in overridable("k6-233") and "l1d.latency_cycles" in overridable("k6-233")


@pytest.mark.parametrize("overrides,message", [
    ({"l2.latency": 10}, r"unknown override 'l2.latency'"),
    ({"estimates.store_queue": 4}, r"unknown override 'estimates.store_queue'"),  # a K6 estimate on a P6
    ({"l2.latency_cycles": -1}, r"override l2.latency_cycles: must be >= 0"),
    ({"l2.latency_cycles": 0}, r"override l2.latency_cycles: must be > 0"),
    ({"l2.latency_cycles": 2.5}, r"must be a whole number"),
    ({"l2.latency_cycles": "fast"}, r"expected a finite number"),
    ({"l2.size_kb": 300}, r"CPU preset 'pentium2-233\{l2.size_kb=300\}': .*L2"),  # not a cache geometry: the machine named
    ({"pages.open_pages": 3}, r"override pages.open_pages: must be a power of two"),
    ({"pages.page_bytes": 1 << 20}, r"override pages.page_bytes: must be between 512 and 65536"),
    ({"pages.hit_saving_bus_clocks": 17}, r"override pages.hit_saving_bus_clocks: must be between 0 and 16"),
    ({"pages.hit_saving": 3}, r"unknown override 'pages.hit_saving'"),
])
def test_make_model_refuses_bad_overrides(overrides, message):
    with pytest.raises(RetrosimError, match=message):
        make_model("pentium2-233", None, overrides)


def test_a_claim_naming_machines_the_scene_does_not_run_is_refused(tmp_path):
    """Issue 33: "every P5 preset, every K6 preset" on a scene without a P5 checked only the K6 half,
    silently. Each such claim is refused on loading, with one line naming the file and the claim."""
    both = FAMILY_CLAIM.replace('families = ["k6"]', 'families = ["p5", "k6"]')
    with pytest.raises(SceneError) as e:
        scene(tmp_path, claims=both)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(str(tmp_path / "claims-test.toml") + ":")
    assert "claims[0]: names every P5 preset, which the scene does not run" in msg
    assert scene(tmp_path, cpus='["pentium-166", "k6-233"]', claims=both).claims[0].families == ("p5", "k6")
    named = FAMILY_CLAIM.replace('families = ["k6"]', 'cpus = ["k6-2-300", "pentium3-500"]')
    with pytest.raises(SceneError, match=r"claims\[0\]: names pentium3-500, which the scene does not run"):
        scene(tmp_path, claims=named)
    narrowed = FAMILY_CLAIM + 'memories = ["sdram-pc100"]\n'  # k6-233 runs on PC66 only, k6-2-300 on PC100
    assert scene(tmp_path, claims=narrowed).claims[0].memories == ("sdram-pc100",)
    with pytest.raises(SceneError, match=r"names k6-233 with memory sdram-pc100, which the scene does not run"):
        scene(tmp_path, claims=narrowed.replace('families = ["k6"]', 'cpus = ["k6-233", "k6-2-300"]'))


def test_the_article_scene_runs_every_machine_its_claims_name():
    """The Z-buffer article's BSR claim covers P5 machines it runs; the SDRAM claim its three P6s."""
    from sim.cpus.machine import family_of

    s = load_scene("scenes/zbuffer-article.toml")
    bsr = next(c for c in s.claims if c.families == ("p5", "k6"))
    covered = {m.preset.split("{")[0] for m in s.run.cpus if bsr.covers(m.preset, m.memory, family_of(m.preset))}
    assert {"pentium-166", "pentium-mmx-233", "k6-2-300", "k6-3-450", "k6-233"} <= covered
    sdram = next(c for c in s.claims if c.memories == ("sdram-pc100",))
    assert {m.preset for m in s.run.cpus if sdram.covers(m.preset, m.memory, family_of(m.preset))} == \
        set(sdram.cpus)


def test_a_report_opens_with_its_verdicts(tmp_path):
    """Issue 33: one line per claim first (verdict, machines, ratio range), then a reading, then the
    detail; the HTML page the same."""
    result = run_scene(scene(tmp_path), robustness=False)
    (c,) = report.evaluate_claims(result)
    report.write_reports(result, tmp_path / "out", formats=("md", "html"))
    md = (tmp_path / "out" / "claims-test.md").read_text().splitlines()
    assert md[:4] == ["# claims-test", "", "## Verdicts", ""]
    ratios = [e["ratio"] for e in c["per_cpu"]]
    line = md[4]
    assert line.startswith(f"- **{c['verdict'].split(' (')[0]}** — BSR is exorbitant on the K6 family — ")
    assert all(report._cpu_label(e["cpu"]) in line for e in c["per_cpu"]) and "pentium2-233" not in line
    assert f"cycles fp16z/z32 {min(ratios):.3f}..{max(ratios):.3f}" in line
    assert md.index("## The article's claims, checked") > md.index("## Verdicts")
    assert md[6] == f"1 claim(s): 1 {c['verdict']}."
    page = (tmp_path / "out" / "claims-test.html").read_text()
    assert page.index("<h2>Verdicts</h2>") < page.index("<h2>Cycles per pixel</h2>")
