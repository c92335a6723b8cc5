"""`retrosim serve`'s second body (issue 32): a request with `body_b` answers both runs and the
comparison `retrosim loop A.s B.s --json` gives for the same two bodies; B is held to A's bounds and
checks. The bodies run through serve.compute, what a forked child runs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from sim.cli import main, serve
from sim.guest import loop_body

ROOT = Path(__file__).resolve().parents[1]
LOOP5 = ROOT / "examples" / "texture-loop.s"     # the article's reordered loop
LOOP9 = ROOT / "examples" / "texture-loop9.s"    # its 9-instruction loop, before reordering
CPUS = ["pentium-mmx-233", "pentium2-233", "k6-2-300"]  # one CPU of each family
LOOP_TAIL = "  dec edx\n  jnz top\n"


def test_the_answers_comparison_is_the_command_lines():
    r = CliRunner().invoke(main, ["loop", str(LOOP9), str(LOOP5), "--cpu", ",".join(CPUS), "--json"])
    assert r.exit_code == 0, r.output
    cli = json.loads(r.output)
    answer = serve.compute({"body": LOOP9.read_text(), "body_b": LOOP5.read_text(), "cpus": CPUS})
    assert "error" not in answer, answer
    (pair,), (cli_pair,) = answer["comparison"], cli["comparison"]
    assert pair["per_cpu"] == cli_pair["per_cpu"] and len(pair["per_cpu"]) == len(CPUS)
    assert {e["faster"] for e in pair["per_cpu"]} != {"same"}  # the two bodies do differ somewhere
    assert (pair["a"], pair["b"]) == ("<body>", "<body B>")  # the CLI names its files; the server its boxes
    # both runs are drawn: each side's cycles are the CLI's for that body
    for key, side in (("data", "a"), ("data_b", "b")):
        assert [x["cycles_per_iteration"] for x in answer[key]["doc"]["results"]] == \
            [x["cycles_per_iteration"] for x in cli[side]["results"]]
    alone = serve.compute({"body": LOOP9.read_text(), "cpus": CPUS})
    assert "comparison" not in alone and "data_b" not in alone  # without B: A alone, as before


@pytest.mark.parametrize("body_b, words", [
    ("  \n", "<body B>: no instructions in the body"),
    ("top:\n  movv eax, 1\n" + LOOP_TAIL, "<body B>:2: no such instruction"),
    ("top:\n  add eax, 1 \ud800\n" + LOOP_TAIL, "<body B>:2: a lone UTF-16 surrogate"),
    ('top:\n  .incbin "/etc/passwd"\n' + LOOP_TAIL, "<body B>:2: '.incbin' reads a file"),
    ("top:\n  .file \"x.c\"\n" + LOOP_TAIL, "<body B>:2: '.file'"),
    (17, "body_b: expected text"),
    ("top:\n" + "  nop\n" * (loop_body.MAX_BODY_BYTES // 6) + LOOP_TAIL, "<body B>"),
])
def test_body_b_is_held_to_the_bounds_and_checks_of_body(body_b, words):
    answer = serve.compute({"body": "top:\n  add eax, 1\n" + LOOP_TAIL, "body_b": body_b, "cpus": ["pentium2-233"]})
    assert answer.get("status") == 400 and words in answer["error"], answer


def test_regions_that_do_not_pair_up_are_the_command_lines_one_error():
    marked = ROOT / "tests" / "fixtures" / "compiler" / "marked-pentium-intel.s"  # two marked regions
    answer = serve.compute({"body": marked.read_text(), "body_b": LOOP5.read_text(), "cpus": ["pentium2-233"],
                            "iterations": 20})
    assert answer["status"] == 400, answer
    assert "<body> holds 2 regions and <body B> one body: they do not pair up" in answer["error"]

