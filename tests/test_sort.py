"""Sort scenes ([scene] kind = "sort"): every kernel variant sorts correctly (Python's sorted() on the
guest's output), CMOV is refused where the CPU lacks it, the keys, the loader's errors, building
only what a scene needs, and the reports end to end on a tiny scene."""

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from sim.cli import main
from sim.guest.emu import Machine
from sim.reference import fp16z_encode
from sim.scenes.registry import KINDS, baseline_entries, load_scene, run_scene
from sim.scenes.schema import SceneError
from sim.scenes.sort import keys as K
from sim.scenes.sort import variants as V

ROOT = Path(__file__).resolve().parent.parent
SIZES = [0, 1, 2, 3, 15, 16, 17, 31, 100, 257]  # 0 and 1, both sides of quicksort's 16-key cutoff, odd
EXTREMES = {  # keys the synthetic distributions do not draw on their own
    "zeros": lambda n: np.zeros(n, np.uint16),
    "ends": lambda n: np.resize(np.array([0xFFFF, 0, 0xFFFF, 1, 0xFFFE], np.uint16), n),  # the extremes, mixed
    "two-runs": lambda n: np.concatenate([np.arange(n // 2, dtype=np.uint16), np.arange(n - n // 2, dtype=np.uint16)]),
}


@pytest.fixture(scope="module")
def depth_keys():
    return K.zbuffer_keys(ROOT / "scenes" / "zbuffer-small.toml")


@pytest.mark.parametrize("name", list(V.VARIANTS))
def test_every_variant_sorts_every_distribution_on_the_guest(name, depth_keys):
    """Each variant on every distribution (all equal, all 0xFFFF, sorted, reversed, ... and the
    Z-buffer depth codes) at sizes 0 to 257, run by Unicorn: the output is Python's sorted() of the
    input (the clamp variants': each key clamped). `run_untraced` raises on any difference too; the
    comparison here does not rely on it."""
    variant = V.VARIANTS[name]
    machine = Machine.from_source(variant.source)
    bounds = [(16384, 49152), (0, 0xFFFF), (300, 300)] if variant.kind == "clamp" else [(16384, 49152)]
    for n in SIZES:
        cases = {d: K.synthetic(d, n, seed=3) for d in K.SYNTHETIC}
        cases.update({d: f(n) for d, f in EXTREMES.items()})
        cases[K.ZBUFFER] = depth_keys.take(n)
        for dist, keys in cases.items():
            for lo, hi in bounds:
                out = V.run_untraced(machine, variant, keys, (lo, hi))
                want = ([min(max(k, lo), hi) for k in keys.tolist()] if variant.kind == "clamp"
                        else sorted(keys.tolist()))
                assert out.tolist() == want, f"{name} on {n} {dist} keys"


def test_a_wrong_output_is_one_error_naming_the_kernel():
    variant = V.VARIANTS["radix8"]
    keys = np.array([3, 1, 2], np.uint16)
    with pytest.raises(Exception, match=r"kernels/sort/radix\.S: radix8_sort on 3 test keys: key 0 is 0x0003, "
                                        r"Python's sort gives 0x0001"):
        V.check(variant, keys, keys, (0, 0), "3 test keys")


def test_synthetic_keys_are_what_their_names_say_and_deterministic():
    n = 4096
    u = K.synthetic("uniform", n, 1)
    assert np.array_equal(u, K.synthetic("uniform", n, 1)) and not np.array_equal(u, K.synthetic("uniform", n, 2))
    s, r = K.synthetic("sorted", n, 1), K.synthetic("reversed", n, 1)
    assert np.all(np.diff(s.astype(int)) >= 0) and np.array_equal(r, s[::-1])
    assert len(set(K.synthetic("few", n, 1).tolist())) <= 4
    dup = K.synthetic("duplicates", n, 1)
    assert n // 8 < len(set(dup.tolist())) <= n // 4
    assert len(set(K.synthetic("equal", n, 1).tolist())) == 1
    assert set(K.synthetic("max", n, 1).tolist()) == {0xFFFF}
    assert all(K.synthetic(d, n, 1).dtype == np.uint16 and K.synthetic(d, n, 1).size == n for d in K.SYNTHETIC)


def test_depth_codes_sort_as_integers_because_the_format_is_monotone():
    """The fp16z code of a larger 32-bit depth is never smaller: sorting codes sorts depths."""
    z = np.sort(np.random.default_rng(4).integers(1, 1 << 32, 200_000, dtype=np.uint64)).astype(np.uint32)
    assert np.all(np.diff(fp16z_encode(z).astype(np.int64)) >= 0)


def test_depth_keys_sample_the_whole_frame(depth_keys):
    assert depth_keys.scene == "zbuffer-small" and depth_keys.codes.dtype == np.uint16
    taken = depth_keys.take(100)
    assert taken[0] == depth_keys.codes[0] and taken[-1] == depth_keys.codes[(99 * depth_keys.codes.size) // 100]
    with pytest.raises(ValueError, match="fewer than"):
        depth_keys.take(depth_keys.codes.size + 1)


# -- scenes -----------------------------------------------------------------------------------------
TINY = """
[scene]
name = "{name}"
kind = "sort"

[keys]
distributions = ["uniform", "sorted"{zdist}]
seed = 9
table_size = 16
sizes = [16, 64]
{zscene}
[run]
variants = ["quicksort", "merge-cmov", "radix8", "clamp-cmov"]
cpus = ["pentium-mmx-166", "pentium2-233", "k6-2-300"]
max_size = {{ quicksort = 64 }}

[[claims]]
text = "radix beats quicksort"
expect = "faster"
variants = ["radix8", "quicksort"]
families = ["p5", "p6", "k6"]
distribution = "uniform"
size = 64

[[claims]]
text = "CMOV clamp on every family"
expect = "distribution-independent"
variants = ["clamp-cmov"]
families = ["p5", "p6", "k6"]
tolerance = 0.5
"""


def write(tmp_path, name="sort-tiny", zbuffer=False, text=TINY):
    p = tmp_path / f"{name}.toml"
    z = ('zbuffer_scene = "zbuffer-small"\n', ', "zbuffer"') if zbuffer else ("", "")
    p.write_text(text.format(name=name, zscene=z[0], zdist=z[1]))
    if zbuffer:
        (tmp_path / "zbuffer-small.toml").write_text((ROOT / "scenes" / "zbuffer-small.toml").read_text())
    return p


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    path = write(tmp_path_factory.mktemp("sort"))
    return run_scene(load_scene(path), robustness=False)


def test_the_kind_is_registered_and_the_shipped_scene_loads():
    assert "sort" in KINDS
    s = load_scene(ROOT / "scenes" / "sort.toml")
    assert s.kind == "sort" and s.needs["zbuffer_scene"] == "zbuffer-article"
    assert set(s.needs["kernels"]) == {V.VARIANTS[v].file for v in s.variants}


def test_cmov_is_refused_on_the_p5_and_the_k6_and_timed_on_the_p6(tiny):
    refused = {(v, k.split(":")[0]): m for (v, k), m in tiny.refused.items()}
    assert set(refused) == {(v, c) for v in ("merge-cmov", "clamp-cmov") for c in ("pentium-mmx-166", "k6-2-300")}
    for (v, cpu), message in refused.items():
        fam = "P5" if cpu.startswith("pentium") else "K6"
        assert re.match(rf"^kernels/sort/\w+\.S:\d+: cmov\w+ is not available on {cpu} \(the {fam} family has no "
                        r"CMOV\)", message), message
        assert "\n" not in message
    timed = {(t.variant, t.cpu) for t in tiny.timings}
    assert ("merge-cmov", "pentium2-233") in timed and ("clamp-cmov", "pentium2-233") in timed
    assert not any(v.endswith("cmov") and c != "pentium2-233" for v, c in timed)
    claim = next(c for c in __import__("sim.scenes.sort.report", fromlist=["x"]).evaluate_claims(tiny)
                 if c["variants"] == ["clamp-cmov"])
    assert [e["cpu"].split(":")[0] for e in claim["per_cpu"]] == ["pentium2-233"]
    assert sorted(r["cpu"].split(":")[0] for r in claim["refused"]) == ["k6-2-300", "pentium-mmx-166"]


def test_every_run_is_checked_and_timed_once_per_machine(tiny):
    s = tiny.scene
    assert sorted(tiny.checked) == sorted(s.cases())
    assert ("quicksort", "uniform", 64) in tiny.checked and ("radix8", "uniform", 64) in tiny.checked
    cases = baseline_entries(tiny)
    assert len(cases) == len(tiny.timings) == len({(t.variant, t.distribution, t.size, t.key) for t in tiny.timings})
    assert all(c["cycles"] > 0 for c in cases.values())


def test_synthetic_keys_never_rasterize(tmp_path, monkeypatch):
    """'Builds only what it needs': a scene without "zbuffer" keys neither loads nor rasterizes a
    Z-buffer scene, and the sort modules do not even import the rasterizer."""
    from sim.scenes import raster

    def refuse(*a, **k):
        raise AssertionError("rasterized for synthetic keys")

    monkeypatch.setattr(raster, "rasterize", refuse)
    monkeypatch.setattr(K, "zbuffer_keys", refuse)
    result = run_scene(load_scene(write(tmp_path)), cpus=["pentium2-233"], robustness=False)
    assert result.zbuffer is None and result.timings
    code = ("import sys, sim.scenes.sort.scene, sim.scenes.sort.runner, sim.scenes.sort.report; "
            "print(sorted(m for m in sys.modules if m in ('sim.scenes.raster', 'sim.scenes.zbuffer.scene')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT).stdout
    assert out.strip() == "[]"


def test_zbuffer_keys_are_built_when_asked_for(tmp_path, monkeypatch):
    calls = []
    real = K.zbuffer_keys
    monkeypatch.setattr(K, "zbuffer_keys", lambda path: calls.append(path.name) or real(path))
    result = run_scene(load_scene(write(tmp_path, zbuffer=True)), cpus=["pentium2-233"], robustness=False)
    assert calls == ["zbuffer-small.toml"]  # once for every run that uses them
    assert result.zbuffer["scene"] == "zbuffer-small" and result.zbuffer["pixels"] > 64


@pytest.mark.parametrize("edit, message", [
    (lambda t: t.replace('"radix8", "clamp-cmov"]', '"radix9"]'), r"run\.variants\[2\]: unknown variant 'radix9'"),
    (lambda t: t.replace('"sorted"]', '"shuffled"]'), r"keys\.distributions\[1\]: unknown distribution 'shuffled'"),
    (lambda t: t.replace('"sorted"]', '"zbuffer"]'), r"keys\.zbuffer_scene: required with the 'zbuffer' distribution"),
    (lambda t: t.replace("quicksort = 64", "quicksort = 8"), r"run\.max_size\.quicksort: 8 is below keys\.table_size"),
    (lambda t: t.replace("sizes = [16, 64]", "sizes = [16, 70000]"), r"keys\.sizes\[1\]: must be between 1 and 65,536"),
    (lambda t: t.replace("table_size = 16", "table_size = 0"), r"keys\.table_size: must be between 1 and 65,536"),
    (lambda t: t.replace("quicksort = 64", "quicksort = 16"), r"claims\[0\]: the scene does not run quicksort on uniform"),
    (lambda t: t.replace('expect = "faster"', 'expect = "quicker"'), r"claims\[0\]\.expect: unknown expectation 'quicker'"),
    (lambda t: t.replace('distribution = "uniform"\nsize = 64', 'distribution = "unifrom"\nsize = 64'),
     r"claims\[0\]\.distribution: unknown distribution 'unifrom'"),
    # an empty sweep list left the linear claims' default distribution to an IndexError
    (lambda t: t.replace("sizes = [16, 64]", "sizes = [16, 64]\nsweep_distributions = []"),
     r"keys\.sweep_distributions: must not be empty"),
])
def test_bad_scenes_are_one_error_naming_file_line_and_field(tmp_path, edit, message):
    p = write(tmp_path)
    p.write_text(edit(p.read_text()))
    with pytest.raises(SceneError, match=rf"^{re.escape(str(p))}:\d+: {message}"):
        load_scene(p)


def test_sweep_emulation_is_the_table_run(tiny):
    """A sweep point of a sort variant times what the scene's table times: the same emulation (first
    distribution, table size, the copy then the sort) gives the table's counters on every machine."""
    from sim.cpus.build import make_model
    from sim.cpus.machine import MachineKey
    from sim.timing.kernel import time_emulation

    s = tiny.scene
    for variant in ("quicksort", "radix8"):  # quicksort's work depends on the keys, radix8's on the size
        emulation, units = KINDS["sort"].sweep_emulation(s, variant)
        assert units == s.table_size and len(emulation.bounds) == 2
        for key in tiny.cpu_keys:
            m = MachineKey.parse(key)
            swept = time_emulation(emulation, make_model(m.label, m.memory)).last
            assert swept == tiny.timing(variant, s.distributions[0], s.table_size, key).counters, (variant, key)


def test_report_writes_every_format(tmp_path):
    scene = write(tmp_path)
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["report", str(scene), "--out", str(out), "--jobs", "1"])
    assert r.exit_code == 0, r.output
    names = sorted(p.name for p in out.iterdir())
    assert names == [f"sort-tiny.{x}" for x in ("csv", "html", "json", "md", "png")]
    md = (out / "sort-tiny.md").read_text()
    assert "## Not timed" in md and "## Where radix sort starts to win" in md and "## The essays' claims, checked" in md
    data = json.loads((out / "sort-tiny.json").read_text())
    assert data["checked_runs"] == len(load_scene(scene).cases())
    assert {c["text"] for c in data["claims"]} == {"radix beats quicksort", "CMOV clamp on every family"}


def test_the_markdown_is_the_same_whichever_formats_are_written(tiny, tmp_path):
    # `check --reports` writes md/json/csv only and compares them with what `report` committed
    from sim.scenes.registry import write_reports

    every = write_reports(tiny, tmp_path / "all")
    three = write_reports(tiny, tmp_path / "three", formats=("md", "json", "csv"))
    md = {p.parent.name: p.read_bytes() for p in every + three if p.suffix == ".md"}
    assert md["all"] == md["three"] and b"## Plot" in md["three"]


def test_the_terminal_summary_fits_80_columns(tiny):
    import io

    from rich.console import Console

    from sim.scenes.registry import summary_tables

    console = Console(width=80, file=io.StringIO(), color_system=None)
    for part in summary_tables([tiny]):
        console.print(part)
    text = console.file.getvalue()
    assert "…" not in text and all(len(line.rstrip()) <= 80 for line in text.splitlines())
    assert "refused" in text and "pentium-mmx-" in text


def test_the_terminal_summary_reads_a_claims_sentence_then_its_verdict(tiny, monkeypatch):
    # a claim is a sentence ending in a period: "... branch.: mixed" misreads; the terminal says it
    # as the Markdown report does, "claim. — verdict"
    import io

    from rich.console import Console

    from sim.scenes.registry import summary_tables
    from sim.scenes.sort import report

    monkeypatch.setattr(report, "evaluate_claims", lambda result: [
        {"text": "Branch-free code wins.", "verdict": "mixed: not reproduced on k6-2-300"}])
    console = Console(width=80, file=io.StringIO(), color_system=None)
    for part in summary_tables([tiny]):
        console.print(part)
    text = console.file.getvalue()
    assert "Branch-free code wins. — mixed: not reproduced on k6-2-300" in text and ".:" not in text
