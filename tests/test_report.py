"""Scene runs, reports, claims and baselines end to end on small scenes."""

import json

import pytest

from sim import output
from sim.guest import asm
from sim.scenes import baseline
from sim.reports import render as render_mod
from sim.scenes import registry
from sim.scenes.zbuffer import report
from sim.scenes.registry import load_scene, run_scene

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
    from sim.scenes.zbuffer import runner

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

    monkeypatch.setattr(output.os, "replace", boom)  # the one writer, sim.output
    with pytest.raises(KeyboardInterrupt):
        render_mod.atomic_write(target, b"new report")
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
        if scene.kind == "sort":  # every run (variant/distribution/keys) on every machine whose CPU has its instructions
            from sim.cpus import presets
            from sim.guest.cpu import GuestCpu
            from sim.scenes.sort.variants import VARIANTS

            has_cmov = {m.label: "cmov" in GuestCpu.from_preset(presets.load(m.preset)).extensions for m in scene.machines}
            want = {f"{v}/{d}/{n}@{m}" for v, d, n in scene.cases() for m in scene.cpus
                    if has_cmov[m] or not VARIANTS[v].needs_cmov}
            assert want == set(cases), scene.name
            continue
        # every variant on every machine; a texture scene also records its probes per machine
        want = {f"{v}@{m}" for v in scene.variants for m in scene.cpus}
        assert want <= set(cases) and all(c in want or c.startswith("probes@") for c in cases), scene.name


# -- output a person can read: the terminal summary, mixed families, partial runs ----------------
def render(parts, width):
    """Rich renderables as the terminal would show them at `width` columns (no colour codes)."""
    import io

    from rich.console import Console

    console = Console(width=width, file=io.StringIO(), color_system=None)
    for part in parts:
        console.print(part)
    return console.file.getvalue()


def assert_fits(text, width):
    assert "…" not in text and "..." not in text, text  # nothing cut or ellipsised
    for line in text.splitlines():
        assert len(line.rstrip()) <= width, (len(line), line)


CLAIM_ON_ANOTHER_CPU = """
[[claims]]
text = "fp16z costs more than z32 on the Pentium II"
cpu = "pentium2-233"
variants = ["fp16z", "z32"]
expect = "slower"
"""


def test_mixed_family_run_writes_every_report(tmp_path):
    # a K6 preset first, then a P6 one: the CSV's columns are the union of both families' counters
    scene = write_scene(tmp_path, claims=CLAIM_ON_ANOTHER_CPU)
    result = run_scene(scene, ["k6-233", "celeron-300a:edo"])
    paths = report.write_reports(result, tmp_path / "out")
    assert {p.suffix for p in paths} == {".md", ".png", ".json", ".csv", ".html"}
    import csv

    rows = list(csv.DictReader((tmp_path / "out" / "tiny-test.csv").open()))
    assert len(rows) == 2 * 2
    k6 = next(r for r in rows if r["cpu"] == "k6-233")
    p6 = next(r for r in rows if r["cpu"] == "celeron-300a")
    assert int(k6["fpu_ops"]) >= 0 and p6["fpu_ops"] == ""  # the P6 model has no such counter
    assert int(p6["cycles"]) > 0 and int(k6["cycles"]) > 0
    # the claim names a CPU this run did not include: listed as not checked, not a crash
    md = (tmp_path / "out" / "tiny-test.md").read_text()
    assert "not checked (CPU not in this run)" in md and "fp16z costs more than z32 on the Pentium II" in md
    [claim] = json.loads((tmp_path / "out" / "tiny-test.json").read_text())["claims"]
    assert claim["verdict"] == "not checked" and claim["per_cpu"] == [] and claim["not_checked"]


def test_summary_fits_80_columns_and_says_how_many_claims_held(tmp_path):
    claim = CLAIM_ON_ANOTHER_CPU.replace('"pentium2-233"', '"pentium2-233:edo"')
    claims = claim + claim.replace("slower", "faster").replace("on the", "vs the")
    scene = write_scene(tmp_path, variants='["z32", "z16", "fp16z", "fp16t", "zf32"]',
                        cpus='["pentium2-233:edo", "pentium2-233:sdram-pc100", "k6-2-300", '
                             '"k6-233{write_allocate.mode=page+sector only}"]', claims=claims)
    result = run_scene(scene)
    for width in (80, 200):
        text = render(registry.summary_tables([result]), width)
        assert_fits(text, width)
        for label in ("pentium2-233 edo", "pentium2-233 sdram-pc100", "k6-2-300 sdram-pc100"):
            assert label in text  # every CPU named in full, the two memories apart
        header = next(line for line in text.splitlines() if "fp16z" in line)
        assert header.split() == ["CPU", "(memory)", "z32", "z16", "fp16z", "fp16t", "zf32"]
        assert "claims: 1 of 2 reproduced" in text.replace("\n", " ")
        cells = {line.split()[0]: line.split()[-5:] for line in text.splitlines() if line.startswith(" k6-2-300")}
        want = [f"{result.timing(v, 'k6-2-300:sdram-pc100').per_pixel('cycles'):.2f}"
                for v in ("z32", "z16", "fp16z", "fp16t", "zf32")]
        assert cells["k6-2-300"] == want


def test_a_cpu_restricted_run_does_not_replace_the_committed_reports(tmp_path, monkeypatch):
    from click.testing import CliRunner

    from sim import cli

    committed, partial = tmp_path / "reports", tmp_path / "build" / "reports"
    committed.mkdir()
    (committed / "tiny-test.md").write_text("committed report")
    monkeypatch.setattr(cli.scene_cmds, "REPORTS_DIR", committed)
    monkeypatch.setattr(cli.scene_cmds, "PARTIAL_DIR", partial)
    scene = write_scene(tmp_path, metrics="[]")
    r = CliRunner().invoke(cli.main, ["report", str(scene.path), "--cpu", "k6-233"], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    assert (committed / "tiny-test.md").read_text() == "committed report"
    assert sorted(p.name for p in committed.iterdir()) == ["tiny-test.md"]
    assert "k6-233" in (partial / "tiny-test.md").read_text()
    assert str(partial) in r.output.replace("\n", "")  # says where the reports went
    # --out still chooses the directory
    r = CliRunner().invoke(cli.main, ["report", str(scene.path), "--cpu", "k6-233", "--out", str(tmp_path / "x")])
    assert r.exit_code == 0 and (tmp_path / "x" / "tiny-test.md").is_file()


def test_work_precision_plot_names_every_point_and_nothing_collides(tmp_path):
    import matplotlib.pyplot as plt

    scene = write_scene(tmp_path, variants='["z32", "z16", "fp16z", "fp16t", "zf32"]',
                        cpus='["pentium2-233:edo", "pentium2-233:sdram-pc100", "celeron-266", "k6-233", "k6-2-300"]')
    result = run_scene(scene)
    fig = report.work_precision_figure(result)
    ax = fig.axes[0]
    ticks = {t.get_text().split(":")[0]: t.get_text() for t in ax.get_yticklabels()}
    assert set(ticks) == set(scene.variants)  # every row names its variant and its error
    for v in scene.variants:
        vis = result.accuracy[v].visibility
        assert ("exact" in ticks[v]) == (vis["errors"] == 0)
    assert ax.get_yscale() == "linear"  # no log axis with a made-up floor for zero
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    for key in result.cpu_keys:
        assert report._cpu_label(key) in legend  # every marker names its CPU and memory
    # one marker per (variant, CPU), at that pair's cycles per pixel
    points = [tuple(p) for c in ax.collections for p in c.get_offsets()]
    assert len(points) == len(scene.variants) * len(result.cpu_keys)
    want = sorted(round(result.timing(v, k).per_pixel("cycles"), 6) for v in scene.variants for k in result.cpu_keys)
    assert sorted(round(float(x), 6) for x, _ in points) == want
    # no two markers share a spot, and no two texts overlap
    assert len(set(points)) == len(points)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    texts = [t for t in fig.findobj(plt.Text) if t.get_text().strip() and t.get_visible()]
    boxes = [t.get_window_extent(renderer) for t in texts]
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            assert not boxes[i].overlaps(boxes[j]), (texts[i].get_text(), texts[j].get_text())
    assert min(t.get_fontsize() for t in texts) >= 9  # legible at the committed size
    plt.close(fig)


def test_html_report_renders_the_markdowns_code_and_bold_spans():
    # the reports write `kernels/sort/` and **reproduced**: the HTML page shows them as code and
    # bold, not as backticks and asterisks, and still escapes what is not markup
    from sim.reports.render import render_html

    page = render_html("Variants (`kernels/sort/`), a < b:\n\n- a claim — **reproduced**\n  - on `k6-2-300`: x\n"
                       "| variant | note |\n|---|---|\n| `radix8` | **1** |\n", None)
    assert "`" not in page and "**" not in page
    assert "<code>kernels/sort/</code>" in page and "a &lt; b" in page
    assert "<strong>reproduced</strong>" in page and "<td><code>radix8</code></td>" in page
    assert '<li style="margin-left:2em">on <code>k6-2-300</code>: x</li>' in page
