"""The pipeline view's data and page without a browser (sim/reports/pipeline_html.py) and the
request checks of `retrosim serve` (sim/cli/serve.py); the browser tests are in
test_pipeline_browser.py."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from sim.cli import main, serve
from sim.errors import ArgumentError
from sim.reports import pipeline_html, views
from sim.timing import loop

ROOT = Path(__file__).resolve().parents[1]
TEXTURE = (ROOT / "examples" / "texture-loop.s").read_text()


def script_json(page: str, name: str):
    m = re.search(rf'<script type="application/json" id="{name}">(.*?)</script>', page, re.S)
    return json.loads(m.group(1))


def test_page_carries_the_data_and_no_markup_from_it():
    nasty = 'x.s</script><script>alert(1)</script><!-- & "\u2028'
    data = {"kind": "loop", "doc": {"source": nasty, "results": []}, "views": [], "body": nasty}
    page = pipeline_html.page(data)
    assert "<script>alert(1)" not in page and "<!--" not in page.split("<body>")[1]
    assert script_json(page, "retrosim-data") == data  # the page reads back exactly what it was given
    assert "http://" not in page and "https://" not in page  # nothing loaded from the network
    assert "<title>x.s&lt;/script&gt;" in page


@pytest.fixture(scope="module")
def timings():
    return loop.time_body(TEXTURE, ["pentium-mmx-233", "pentium2-233", "k6-2-300"], name="texture-loop.s",
                          iterations=20)


def test_stage_words_name_every_mark_of_each_familys_timeline(timings):
    """Every mark the family's timeline draws (views.timeline_text: D, R, =, E, -, C, as its rows
    need them) has a word in the view, and the word is not the mark itself."""
    seen = set()
    for t in timings:
        stages = dict(pipeline_html.view(t.result)["stages"])
        width = 72
        chart = [line[:width] for line in views.timeline_text(t.result, width=width).splitlines()[1:]]
        drawn = set("".join(chart)) - {" "}
        assert drawn, t.cpu
        for mark in drawn:
            assert stages.get(mark, "").strip() not in ("", mark), (t.cpu, mark, stages)
        seen |= drawn
    assert {"=", "-"} & seen  # the loops make some instruction wait or finish before it retires


def test_every_stall_cause_a_row_shows_is_explained(timings):
    """A cause's help is an explanation in words, not the cause's own name (the view once fell back
    to the name, so every cause seemed explained)."""
    shown = 0
    for t in timings:
        v = pipeline_html.view(t.result)
        helps = dict(v["causes"])
        for row in views.timeline_rows(t.result):
            cause = row["cause"]
            assert cause in helps
            if cause == "none" and v["family"] != "p5":  # the P5's "none" means paired: explained too
                continue
            text = helps[cause].strip()
            assert text and text not in (cause, cause.replace("_", " ")), (t.cpu, cause, text)
            assert len(text.split()) >= 3, (t.cpu, cause, text)  # a phrase, not a label
            shown += 1
    assert shown  # the loops stall for some reason on some CPU


def test_every_stall_field_the_page_names_is_an_explain_field_in_words(timings):
    """The page marks each instruction with the biggest of view["stalls"]: every one is a stall
    field of that family's explain rows (a name the rows lack would never be marked) and has words,
    not the field's name; together they cover every stall field the rows carry."""
    for t in timings:
        v = pipeline_html.view(t.result)
        rows = views.explain_rows(t.result)
        fields = dict(v["stalls"])
        carried = {k for k in rows[0] if k.startswith("stall_")}
        assert set(fields) == carried, (t.cpu, set(fields) ^ carried)
        for field, words in fields.items():
            assert words and words not in (field, field[6:], field[6:].replace("_", " ")), (t.cpu, field, words)


def test_p5_lanes_agree_with_the_models_pipe_counters(timings):
    # the page's U/V per timeline row against the P5 core's own per-instruction U and V counts: an
    # instruction that always ran in V must be drawn in V, one that always ran in U in U
    p5 = next(t for t in timings if t.cpu == "pentium-mmx-233")
    rows = views.timeline_rows(p5.result)
    lanes = pipeline_html.view(p5.result)["lanes"]
    per = {r["pc"]: r for r in views.explain_rows(p5.result)}
    checked = 0
    for row, lane in zip(rows[1:], lanes[1:]):  # the first row's partner may be outside the window
        r = per[row["pc"]]
        if r["v_pipe"] == r["executions"]:
            assert lane == "V", row
            checked += 1
        elif r["u_pipe"] == r["executions"]:
            assert lane == "U", row
            checked += 1
    assert checked >= len(rows) // 2


def test_loop_html_and_json_come_from_one_run(tmp_path):
    out = tmp_path / "sub" / "view.html"  # its folder is created
    r = CliRunner().invoke(main, ["loop", "-", "--cpu", "pentium2-233,k6-233", "--iterations", "20", "--json",
                                  "--html", str(out)], input=TEXTURE)
    assert r.exit_code == 0, r.output
    data = script_json(out.read_text(), "retrosim-data")
    assert data["doc"] == json.loads(r.output)
    assert [v["family"] for v in data["views"]] == ["p6", "k6"]


def test_the_text_output_says_where_the_page_went(tmp_path):
    out = tmp_path / "view.html"
    r = CliRunner().invoke(main, ["loop", "-", "--cpu", "pentium2-233", "--iterations", "20", "--brief",
                                  "--html", str(out)], input=TEXTURE)
    assert r.exit_code == 0, r.output
    assert f"wrote {out}" in r.stderr and out.is_file()


def test_bad_html_path_fails_before_the_work(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    r = CliRunner().invoke(main, ["loop", "-", "--html", str(blocker / "x.html")], input="movv eax, 1\n")
    assert r.exit_code == 2
    assert "--html" in r.output and "movv" not in r.output  # the path was refused before assembling


@pytest.mark.parametrize("cmd", [["loop", "-"], ["explain", "convert/fp16z.S"]])
def test_html_path_naming_a_folder_is_refused(tmp_path, cmd):
    # "out/" means a folder: writing a file called "out" instead would surprise; "" is no name at all
    for given in (str(tmp_path / "out") + "/", ""):
        r = CliRunner().invoke(main, [*cmd, "--html", given], input="movv eax, 1\n")
        assert r.exit_code == 2 and "--html" in r.output and "movv" not in r.output, r.output
        assert len(r.output.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_explain_html(tmp_path):
    out = tmp_path / "e.html"
    r = CliRunner().invoke(main, ["explain", "convert/fp16z.S", "--entry", "fp16z_convert_array", "--args",
                                  "buf:u32:64:7,buf:u32:64,64,0,0", "--cpu", "k6-233", "--json", "--html", str(out)])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    data = script_json(out.read_text(), "retrosim-data")
    assert data["kind"] == "explain"
    assert data["doc"]["results"][0]["cycles"] == doc["summary"]["cycles"]
    assert data["doc"]["results"][0]["timeline"] == doc["timeline"]


@pytest.mark.parametrize("req, message", [
    ([], "not a JSON object"),
    ({"body": "nop", "colour": 1}, "unknown request field(s): colour"),
    ({"body": 3}, "body: expected text"),
    ({"body": " \n"}, "no instructions"),
    ({"body": "nop", "cpus": "k6-233"}, "cpus: expected a list"),
    ({"body": "nop", "iterations": True}, "iterations: expected an integer"),
    ({"body": "nop", "syntax": "masm"}, "--syntax masm"),
    ({"body": "nop", "timeline": 5000}, "--timeline 5000"),
])
def test_bad_requests_get_one_line(req, message):
    with pytest.raises(ArgumentError, match=re.escape(message)):
        serve.parse_request(req)


def test_request_errors_are_the_clis_line():
    answer = serve.compute({"body": "top:\n  add eax, 1\n  jnz top\n", "cpus": ["pentium9"]})
    r = CliRunner().invoke(main, ["loop", "-", "--cpu", "pentium9"], input="top:\n  add eax, 1\n  jnz top\n")
    assert answer["error"] == r.output.strip().splitlines()[-1]


def test_a_request_over_its_memory_bound_is_refused_and_the_next_answers():
    # 64 MB more than the server process is far less than timing a body needs: the forked child fails
    # inside its bound and says so in one line. In a fresh process, as the server is: one that ran
    # other tests holds freed heap a child may reuse without growing (the bound is on growth).
    code = (
        "import json\n"
        "from sim.cli import serve\n"
        "serve.warm_up()  # as the server does before it forks\n"
        "small = {'body': 'top:\\n  add eax, 1\\n  dec edx\\n  jnz top\\n', 'cpus': ['pentium2-233']}\n"
        "print(json.dumps([serve.Worker(timeout=30, memory_mb=m, jobs=1).run(small) for m in (64, 2048)]))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    refused, answered = json.loads(out.stdout.strip().splitlines()[-1])
    assert refused["error"].startswith("retrosim: error: ") and "--memory-mb" in refused["error"]
    assert "error" not in answered and answered["data"]["doc"]["results"][0]["cycles_per_iteration"] > 0


def test_a_port_in_use_fails_before_the_warm_up(monkeypatch):
    # the warm-up may take a minute (numba compiling each family's model): a port that cannot be
    # had must be said first, not after it
    import socket

    warmed = []
    monkeypatch.setattr(serve, "warm_up", lambda say=None: warmed.append(True))
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        r = CliRunner().invoke(main, ["serve", "--port", str(port)])
    assert r.exit_code == 2 and f"cannot listen on 127.0.0.1:{port}" in r.output
    assert not warmed
