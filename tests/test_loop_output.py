"""`retrosim loop`'s output, most read first (issue 32): the summary table with each CPU's bottleneck,
then the resource pressure (also in --json), then one CPU's detail (every CPU's with --detail) with
the stall-overlap note and the timeline's legend; and `loop A.s B.s`, the two timed alike and
compared per CPU."""

import json
import math
from pathlib import Path

import pytest
from click.testing import CliRunner

from sim.cli import main
from sim.reports import compare

ROOT = Path(__file__).resolve().parents[1]
LOOP5 = ROOT / "examples" / "texture-loop.s"     # the article's reordered loop
LOOP9 = ROOT / "examples" / "texture-loop9.s"    # its 9-instruction loop, before reordering
CPUS = "pentium-mmx-233,pentium2-233,k6-2-300"   # one CPU of each family
X87 = "top:\n  fadd st(0), st(1)\n  fmul st(0), st(2)\n  dec ecx\n  jnz top\n"


def run(*args, input=None, columns="120"):
    r = CliRunner().invoke(main, ["loop", *map(str, args), "--iterations", "20"], input=input,
                           env={"COLUMNS": columns})
    assert r.exit_code == 0, r.output
    return r.output


def test_the_summary_comes_first_and_names_each_cpus_bottleneck():
    out = run(LOOP5, "--cpu", CPUS)
    lines = out.splitlines()
    assert "steady state per iteration" in lines[0], lines[0]
    summary_end = out.index("data: cold")
    assert summary_end < out.index("resource pressure") < out.index("per instruction") < out.index("timeline on")
    rows = {cpu: next(line for line in lines if line.startswith("│ " + cpu)) for cpu in CPUS.split(",")}
    # the texture loop's limits, each in its family's words: the P5 waits on its write buffer (a write
    # miss goes to the bus: no allocation), the P6 on partial-register merges, the K6 on a dependency chain
    assert "write buffer full" in rows["pentium-mmx-233"]
    assert "partial-register stalls" in rows["pentium2-233"]
    assert "dependency chain" in rows["k6-2-300"]
    assert all("│ none" not in row.split("│")[7] for row in rows.values()), rows


def test_resource_pressure_adds_up_to_the_ops_per_iteration_and_is_in_json():
    doc = json.loads(run("-", "--cpu", CPUS, "--json", input=LOOP5.read_text()))
    units = {}
    for r in doc["results"]:
        rp = r["resource_pressure"]
        units[r["cpu"]] = list(rp)
        assert math.isclose(sum(rp.values()), r["uops_per_iteration"]), (r["cpu"], rp, r["uops_per_iteration"])
        assert r["bottleneck"] and r["bottleneck"] != "none"
    assert units == {"pentium-mmx-233": ["U", "V"], "pentium2-233": ["p0", "p1", "p2", "p3", "p4"],
                     "k6-2-300": ["X", "Y", "load", "store", "branch", "FPU"]}
    k6, = json.loads(run("-", "--cpu", "k6-2-300", "--json", input=X87))["results"]
    assert k6["resource_pressure"]["FPU"] == 2  # the K6's x87 unit counts too, so the sum still holds
    assert math.isclose(sum(k6["resource_pressure"].values()), k6["uops_per_iteration"])


def test_the_text_pressure_table_gives_each_unit_and_the_total():
    out = run(LOOP5, "--cpu", "pentium2-233")
    after = out[out.index("resource pressure: uops per port, per iteration"):]
    row = next(line for line in after.splitlines() if line.strip().startswith("pentium2-233"))
    doc = json.loads(run(LOOP5, "--cpu", "pentium2-233", "--json"))["results"][0]
    figures = [float(x) for x in row.split()[1:]]
    assert figures == list(doc["resource_pressure"].values()) + [doc["uops_per_iteration"]]


def test_detail_of_the_first_cpu_unless_asked_for_every_cpu():
    out = run(LOOP5, "--cpu", CPUS)
    assert "timeline on pentium-mmx-233" in out and "timeline on pentium2-233" not in out
    assert "--detail shows every CPU's" in out
    every = run(LOOP5, "--cpu", CPUS, "--detail")
    assert all(f"timeline on {cpu}" in every for cpu in CPUS.split(","))
    assert "--detail shows" not in every
    brief = run(LOOP5, "--cpu", CPUS, "--brief")
    assert "resource pressure" not in brief and "timeline on" not in brief


def test_stall_columns_say_they_overlap_and_the_timeline_has_a_legend():
    every = run(LOOP5, "--cpu", CPUS, "--detail")
    assert every.count("note: stall cycles are charged to each instruction") == 3
    text = " ".join(every.split())  # the legend wraps at the terminal's width
    assert "legend: D decode, R rename, = wait in the reservation station, E execute, - done, C retire" in text
    assert "legend: D decode, R enter the scheduler" in text  # the K6's words
    assert "legend: D the previous group left the pipe, R issue" in text  # the P5's
    assert text.count("legend: ") == 3


def test_a_b_gives_each_ones_cycles_the_ratio_and_the_winner_of_the_single_runs():
    single = {p: {r["cpu"]: r for r in json.loads(run(p, "--cpu", CPUS, "--json"))["results"]} for p in (LOOP9, LOOP5)}
    doc = json.loads(run(LOOP9, LOOP5, "--cpu", CPUS, "--json"))
    assert doc["a"]["source"].endswith("texture-loop9.s") and doc["b"]["source"].endswith("texture-loop.s")
    pair, = doc["comparison"]
    assert [e["cpu"] for e in pair["per_cpu"]] == CPUS.split(",")
    winners = set()
    for e in pair["per_cpu"]:
        a, b = single[LOOP9][e["cpu"]], single[LOOP5][e["cpu"]]
        ca, cb = a["cycles_per_iteration"], b["cycles_per_iteration"]
        assert e["cycles_per_iteration"] == [ca, cb]
        assert e["ratio"] == round(ca / cb, 4)
        assert e["faster"] == ("same" if ca == cb else "A" if ca < cb else "B")
        winners.add(e["faster"])
        for d in e["differences"]:  # what differs is the single runs' per-iteration difference
            assert d["a_minus_b"] == round(a["per_iteration"][d["counter"]] - b["per_iteration"][d["counter"]], 3)
        sizes = [abs(d["a_minus_b"]) for d in e["differences"]]
        assert sizes == sorted(sizes, reverse=True) and len(sizes) <= 4
    assert "B" in winners  # the reordered loop wins somewhere (the P6 and K6: fewer dependency waits)
    text = run(LOOP9, LOOP5, "--cpu", CPUS)
    assert text.index("A/B, cycles per iteration") < text.index("A: ") < text.index("B: ")
    p6 = next(e for e in pair["per_cpu"] if e["cpu"] == "pentium2-233")
    row = next(line for line in text.splitlines() if line.startswith("│ pentium2-233"))
    assert f"{p6['ratio']:.3f}" in row and f"│ {p6['faster']} " in row.replace("neither", "same")


def test_a_b_of_outputs_that_do_not_pair_up_is_one_error(tmp_path):
    marked = ROOT / "tests" / "fixtures" / "compiler" / "marked-pentium-intel.s"  # two marked regions
    r = CliRunner().invoke(main, ["loop", str(marked), str(LOOP5), "--iterations", "20"])
    assert r.exit_code == 2 and "do not pair up" in r.output and "2 regions" in r.output, r.output
    r = CliRunner().invoke(main, ["loop", str(LOOP5), str(LOOP5), str(LOOP5)])
    assert r.exit_code == 2 and "3 files given" in r.output


def test_differences_are_the_counters_that_differ_biggest_first():
    a = {"x": 3.0, "y": 1.0, "z": 5.0, "only_a": 9.0}
    b = {"x": 1.0, "y": 1.001, "z": 0.0}
    diffs = compare.differences(a, b, ["x", "y", "z", "only_a"])
    assert diffs == {"x": 2.0, "z": 5.0}  # y below the threshold, only_a not in both
    assert compare.largest(diffs, 1) == [("z", 5.0)]
    assert compare.faster(2, 3) == "A" and compare.faster(3, 2) == "B" and compare.faster(2, 2) == "same"


def test_ops_on_no_unit_are_shown_so_the_total_is_the_ops_per_iteration():
    # the P6's FXCH row (sim/cpus/p6/p6.toml) is one uop on no port, latency 0: renamed, not executed;
    # the pressure table gives such uops a column, so its total is still the uops per iteration
    body = "top:\n  fxch st(1)\n  fadd st(0), st(2)\n  dec ecx\n  jnz top\n"
    r, = json.loads(run("-", "--cpu", "pentium2-233", "--json", input=body))["results"]
    rest = r["uops_per_iteration"] - sum(r["resource_pressure"].values())
    assert rest > 0
    out = run("-", "--cpu", "pentium2-233", input=body)
    head = next(line for line in out.splitlines() if line.strip().startswith("cpu") and "p0" in line)
    row = next(line for line in out.splitlines() if line.strip().startswith("pentium2-233") and "│" not in line)
    assert head.split()[-2:] == ["unit", "total"]
    assert [float(x) for x in row.split()[-2:]] == [rest, r["uops_per_iteration"]]
