"""Preset overrides: `--set KEY=VALUE`, machine labels and scene [[run.machine]] tables, each
validated through sim.cpus.build.make_model with one clear error."""

import json

import pytest
from click.testing import CliRunner

from sim.cli import main
from sim.cpus.build import make_model
from sim.cpus.overrides import machine_label, split_label
from sim.errors import RetrosimError
from sim.scenes.registry import load_scene
from sim.scenes.schema import SceneError

STORE = ["micro/k6.S", "--entry", "store_same", "--args", "200,buf:u32:16", "--cpu", "k6-233", "--json"]


def run(*args):
    return CliRunner().invoke(main, list(args), catch_exceptions=False)


def errors(r) -> str:
    return r.output + (getattr(r, "stderr", "") or "")


@pytest.mark.parametrize("sets,words", [
    (["l2.size_kb=384"], "power-of-two sets"),   # 384 KB / (4 ways x 32 B) = 3072 sets
    (["l2.ways=0"], "must be > 0"),
    (["l2.wayz=4"], "unknown override 'l2.wayz'"),
    (["l2.present=1"], "expected one of true, false"),
    (["l2.size_kb"], "expected KEY=VALUE"),
    (["memory=ddr"], "unknown memory preset 'ddr'"),
])
def test_bad_set_is_one_error_line_with_status_2(sets, words):
    args = ["time", "zbuffer/z32.S", "--entry", "z32_span", "--args", "buf:u32:8,buf:u16:8,8,1,1,1"]
    r = run(*args, *[x for s in sets for x in ("--set", s)])
    assert r.exit_code == 2
    text = errors(r)
    assert words in text and "Traceback" not in text


def test_k6_233_write_allocation_is_a_choice():
    # Stores to a line that is never read: 36 clocks each on the measured K6-233, whose BIOS left the
    # write-allocate limit off (InstLatX64 AuthenticAMD0000562: MOV [m32],r32 T 36); with write
    # allocation the line is filled once and stores hit L1 at one per clock (IL-K62/IL-K63 T 1.00).
    stores = 200 * 8
    measured = json.loads(run("time", *STORE).output)
    full = json.loads(run("time", *STORE, "--set", "write_allocate.mode=full").output)
    assert measured["cpu"] == "k6-233" and full["cpu"] == "k6-233{write_allocate.mode=full}"
    assert measured["cycles"] / stores > 30
    assert full["cycles"] / stores < 2


def test_an_absent_l2_sends_misses_to_memory():
    p = make_model("pentium2-233{l2.size_kb=none}")
    assert p.preset.l2 is None and len(p.dside.geometries) == 1
    assert make_model("pentium2-233", overrides={"l2.size_kb": 256}).preset.l2.size_kb == 256


def test_labels_round_trip_and_sort_keys():
    label = machine_label("pentium2-233", {"l2.size_kb": 256, "l2.latency_cycles": 10})
    assert label == "pentium2-233{l2.latency_cycles=10,l2.size_kb=256}"
    assert split_label(label) == ("pentium2-233", {"l2.latency_cycles": 10, "l2.size_kb": 256})
    with pytest.raises(RetrosimError, match="malformed"):
        split_label("pentium2-233{l2.size_kb=256")
    with pytest.raises(RetrosimError, match="may not contain"):
        machine_label("pentium2-233", {"l2.size_kb": "a:b"})


SCENE = """[scene]
name = "ov"
width = 32
height = 24
[geometry]
generator = "random"
seed = 3
triangles = 4
depth_complexity = 1.5
[run]
variants = ["z32"]
cpus = ["k6-233"]
[[run.machine]]
cpu = "k6-233"
set = {SET}
"""


def test_scene_machine_table(tmp_path):
    p = tmp_path / "ov.toml"
    p.write_text(SCENE.replace("{SET}", '{ "write_allocate.mode" = "full" }'))
    assert load_scene(p).cpus == ["k6-233:sdram-pc66", "k6-233{write_allocate.mode=full}:sdram-pc66"]
    p.write_text(SCENE.replace("{SET}", '{ l2.ways = 0 }'))
    with pytest.raises(SceneError, match=r"ov\.toml:15: run\.machine\[0\].*l2\.ways: must be > 0"):
        load_scene(p)
    p.write_text(SCENE.replace("{SET}", '{ "write_allocate.mode" = "sometimes" }'))
    with pytest.raises(SceneError, match=r"run\.machine\[0\].*expected one of full"):
        load_scene(p)


def test_article_scene_reports_k6_233_both_ways():
    from pathlib import Path

    cpus = load_scene(Path(__file__).resolve().parent.parent / "scenes/zbuffer-article.toml").cpus
    k6 = [c for c in cpus if c.startswith("k6-233")]
    assert k6 == ["k6-233{write_allocate.mode=page+sector only}:sdram-pc66",
                  "k6-233{write_allocate.mode=full}:sdram-pc66"]
