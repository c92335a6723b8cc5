"""Hostile input, round three (issues 25 and 26), the limits part: `--set` values outside a field's
plausible range, streamed runs past the trace limit, scene files that are not what they claim,
scenes that would need more memory than the machine has, `--jobs` and `repeat` beyond reason,
report labels at 80 columns. Every bad case is one stderr line and exit 2, fast."""

from __future__ import annotations

import json
import time

import pytest
from click.testing import CliRunner

from conftest import cli_fails
from sim.cli import main
from sim.cpus.overrides import RANGES, overridable, value_range

Z32 = ["zbuffer/z32.S", "--entry", "z32_span", "--args", "buf:u32:8,buf:u16:8,8,1,1,1"]


fails = cli_fails  # exit 2, one "retrosim: error:" line, no traceback (conftest)


# -- --set: every numeric override has a finite, plausible range, checked before any work --------
HUGE = ["l2.size_kb=nan", "l2.size_kb=inf", "l2.latency_cycles=18446744073709551616", "clock.core_mhz=inf",
        "l2.latency_cycles=1e15", "clock.fsb_mhz=0.0001", "memory.overhead_bus_clocks=1e18",
        "l2.latency_cycles=9223372036854775807", "l1d.line_bytes=48", "l2.speed_ratio=0.01",
        "estimates.uop_queue=1000000", "clock.core_mhz=2000"]


@pytest.mark.parametrize("command", [["time", *Z32], ["explain", *Z32], ["report", "zbuffer-small"]])
@pytest.mark.parametrize("item", HUGE)
def test_out_of_range_overrides_are_one_line_before_any_work(command, item, tmp_path):
    start = time.monotonic()
    extra = ["--out", tmp_path / "r"] if command[0] == "report" else ["--cpu", "pentium2-233"]
    line = fails(*command, *extra, "--set", item)
    key = item.split("=")[0]
    assert time.monotonic() - start < 10
    assert (f"override {key}:" in line or "override clock:" in line), line
    assert any(w in line for w in ("finite", "between", "power of two", "outside")), line
    assert not (tmp_path / "r").exists()


def test_every_numeric_override_has_a_stated_range_holding_every_preset():
    from sim.cpus import presets

    for cpu in presets.available():
        for key, value in overridable(cpu).items():
            if isinstance(value, (bool, str)):
                continue
            low, high, what = value_range(cpu, key)
            assert low <= value <= high and what, (cpu, key, value)
    assert set(RANGES) >= {"latency_cycles", "size_kb", "ways", "line_bytes", "clock.core_mhz", "clock.fsb_mhz"}


def _at_the_top(cpu: str, geometry: bool = True) -> list[str]:
    """--set items putting every numeric field of `cpu` (but the cache geometry unless `geometry`) at
    the top of its range (the clocks at the highest ratio a PC100 bus allows)."""
    out = []
    for key in overridable(cpu):
        bounds = value_range(cpu, key)
        if bounds is None or key.startswith("clock."):
            continue
        if not geometry and key.endswith(("size_kb", "ways", "line_bytes")):
            continue
        if key == "l1d.latency_cycles" and cpu.startswith("pentium-"):
            continue  # a P5 L1 slower than its board cache is refused (below)
        out += ["--set", f"{key}={bounds[1]}"]
    return out + ["--set", "clock.core_mhz=1600", "--set", "clock.fsb_mhz=100", "--set", "memory=sdram-pc100"]


def _negative(tree, path=""):
    if isinstance(tree, dict):
        for k, v in tree.items():
            yield from _negative(v, f"{path}.{k}")
    elif isinstance(tree, list):
        for i, v in enumerate(tree):
            yield from _negative(v, f"{path}[{i}]")
    elif isinstance(tree, (int, float)) and not isinstance(tree, bool) and tree < 0:
        yield path, tree


@pytest.mark.parametrize("cpu", ["pentium-133", "pentium2-233", "k6-3-450"])
def test_the_top_of_every_range_runs_without_overflow(cpu):
    # a span that misses every level: every latency, the bus overhead and the ratio at their maximum
    base_args = ["time", "zbuffer/z32.S", "--entry", "z32_span", "--args", "buf:u32:2048,buf:u16:2048,2048,1,1,1",
                 "--cpu", cpu, "--json"]
    r = CliRunner().invoke(main, [*base_args, *_at_the_top(cpu)], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    result = json.loads(r.stdout)
    assert list(_negative(result)) == []
    assert result["cycles"] > 0
    # the latencies alone at the top (the default caches): slower, never a wrapped-around count
    slower = json.loads(CliRunner().invoke(main, [*base_args, *_at_the_top(cpu, geometry=False)],
                                           catch_exceptions=False).stdout)
    base = json.loads(CliRunner().invoke(main, base_args, catch_exceptions=False).stdout)
    assert slower["cycles"] > base["cycles"] and not list(_negative(slower))


@pytest.mark.parametrize("command", [["report", "zbuffer-small"], ["check", "zbuffer-small"]])
@pytest.mark.parametrize("jobs", ["99999999999999999999", "0", "65"])
def test_jobs_is_bounded(command, jobs, tmp_path):
    line = fails(*command, "--jobs", jobs, *(["--out", tmp_path / "r"] if command[0] == "report" else []))
    assert f"--jobs {jobs}: must be between 1 and" in line


def test_a_p5_l1_slower_than_the_board_cache_is_refused():
    # the P5 core charges a miss its time beyond the L1 hit: stall_memory went negative (-2090)
    line = fails("time", *Z32, "--cpu", "pentium-133", "--set", "l1d.latency_cycles=1000")
    assert "l1d.latency_cycles = 1000 exceeds the" in line


# -- a streamed run is bounded by RETROSIM_TRACE_MB like a held trace ------------------------------
ENDLESS = "1:  add eax, 1\n    mov [esp-8], eax\n    jmp 1b\n"


def test_an_endless_streamed_kernel_stops_at_the_trace_limit(write_kernel):
    src = write_kernel(ENDLESS, "endless.S", "f")
    start = time.monotonic()
    line = fails("time", src, "--entry", "f", "--budget", "0", "--cpu", "pentium2-233",
                 env={"RETROSIM_TRACE_MB": "8"})
    assert time.monotonic() - start < 60
    assert "the streamed trace passed 8 MB" in line and "RETROSIM_TRACE_MB=8" in line


# -- scene files -----------------------------------------------------------------------------------
SCENE = """[scene]
name = "s"
{KIND}width = 32
height = 24
[geometry]
generator = "random"
seed = 3
triangles = 4
depth_complexity = {DEPTH}
[run]
variants = ["z32"]
cpus = ["k6-233"]
"""


@pytest.mark.parametrize("kind,depth,words", [
    ('kind = ["zbuffer"]\n', "1.5", "s.toml:3: scene.kind: unknown kind"),
    ("kind = {}\n", "1.5", "s.toml:3: scene.kind: unknown kind"),
    ("", "1.7e308", "geometry.depth_complexity: must be > 0 and at most 65535"),
    ("", "65536", "geometry.depth_complexity: must be > 0 and at most 65535"),
])
def test_scene_kind_and_depth_complexity_are_one_line(tmp_path, kind, depth, words):
    path = tmp_path / "s.toml"
    path.write_text(SCENE.replace("{KIND}", kind).replace("{DEPTH}", depth))
    assert words in fails("report", path, "--out", tmp_path / "r")


SNAP = """[scene]
name = "s"
kind = "snap"
[workloads]
names = ["screen", "tiny"]
vertices = 64
seed = 1
[run]
variants = ["trick-24", "trick-64"]
cpus = ["pentium-133"]
[[claims]]
text = "only 24-bit is right"
expect = "only-exact"
variants = ["trick-24", "trick-64"]
workloads = []
"""


def test_a_snap_claim_over_no_workload_is_refused(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(SNAP)
    line = fails("report", path, "--out", tmp_path / "r")
    assert "s.toml:15: claims[0].workloads: must not be empty" in line


TEXTURE = """[scene]
kind = "texture"
name = "s"
width = {SIDE}
height = {SIDE}
[geometry]
generator = "grid"
seed = 1997
columns = 1
rows = 1
[run]
variants = ["a"]
cpus = ["pentium-133"]
timing_stride = {STRIDE}
"""


@pytest.mark.parametrize("side,stride,words", [
    (480, 9223372036854775807, "run.timing_stride: must be <= 480 (the frame's height"),
    (64, 64, "run.timing_stride = 64 times 2 of the frame's"),
])
def test_a_texture_stride_that_times_a_handful_of_spans_is_refused(tmp_path, side, stride, words):
    path = tmp_path / "s.toml"
    path.write_text(TEXTURE.replace("{SIDE}", str(side)).replace("{STRIDE}", str(stride)))
    start = time.monotonic()
    r = CliRunner().invoke(main, ["report", str(path), "--out", str(tmp_path / "r")])
    assert time.monotonic() - start < 30
    # found once the frame's spans are known (after the progress line): the error is the last line
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert words in r.stderr.strip().splitlines()[-1], r.stderr


# -- report tables at 80 columns never break a machine label mid-word --------------------------------
def test_report_labels_wrap_between_words_at_80_columns(tmp_path):
    r = CliRunner().invoke(main, ["report", "zbuffer-small", "--cpu", "k6-233", "--set",
                                  "write_allocate.mode=page+sector only", "--out", str(tmp_path / "r")],
                           env={"COLUMNS": "80"}, catch_exceptions=False)
    assert r.exit_code == 0, r.output
    words = "k6-233 {write_allocate.mode=page+sector only} sdram-pc66".split()
    table = r.stdout
    assert all(max(map(len, line.split("\n"))) <= 80 for line in table.splitlines())
    for word in words:  # every word of the label whole, on one line
        assert any(word in line.split() for line in table.splitlines()), (word, table)
