"""The pipeline view in a real browser (headless Chromium, tests/browser.py): the page `loop --html`
writes and the app `retrosim serve` answers with show the numbers `retrosim loop --json` gives,
errors as the CLI's one line, and the server stays up through concurrent and runaway requests.

Marked `browser`; in the default run. Without /usr/bin/chromium they skip, except under CI=true,
where they fail (CI must run them: .ci/run installs chromium)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest
from click.testing import CliRunner

from sim.cli import main
from sim.reports import pipeline_html

sys.path.insert(0, str(Path(__file__).resolve().parent))
import browser as chromium  # noqa: E402  (tests/browser.py)

pytestmark = pytest.mark.browser
ROOT = Path(__file__).resolve().parents[1]
CPUS = ["pentium-mmx-233", "pentium2-233", "k6-2-300"]  # one CPU of each family
BODY = "top:\n  add eax, [esi]\n  imul ebx, ecx\n  add esi, 4\n  dec edx\n  jnz top\n"


@pytest.fixture(scope="module")
def context():
    chromium.require()
    with chromium.browser_context() as ctx:
        yield ctx


def cli_json(body: str, cpus: list[str], *extra) -> dict:
    r = CliRunner().invoke(main, ["loop", "-", "--cpu", ",".join(cpus), "--json", *extra], input=body)
    assert r.exit_code == 0, r.output
    return json.loads(r.output)


def shown_cycles(page) -> dict[str, str]:
    """cpu -> the cycles-per-iteration text of the summary table, as on screen."""
    rows = page.locator("#summary-table tr[data-cpu]")
    return {rows.nth(i).get_attribute("data-cpu"): rows.nth(i).locator("td.cycles").inner_text()
            for i in range(rows.count())}


def test_saved_page_shows_the_clis_cycles(context, tmp_path):
    # a comment that would be markup if the page pasted the body as HTML
    body = BODY.replace("top:\n", "top:  // </script><img id=injected src=x onerror=alert(1)> & <b>\n")
    out = tmp_path / "view.html"
    r = CliRunner().invoke(main, ["loop", "-", "--cpu", ",".join(CPUS), "--json", "--html", str(out)], input=body)
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    page = context.new_page()
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(out.as_uri())
    page.wait_for_selector("body[data-state=ready]")
    assert not errors
    assert shown_cycles(page) == {x["cpu"]: f"{x['cycles_per_iteration']:.2f}" for x in doc["results"]}
    assert page.locator("#injected").count() == 0  # the body is text, never markup
    assert "<img id=injected" in page.locator("#body-text").text_content()
    for x in doc["results"]:  # every CPU's chart: its timeline rows (capped), side by side
        panel = page.locator(f".cpu[data-cpu='{x['cpu']}']")
        assert panel.locator(".row").count() == min(len(x["timeline"]), pipeline_html.MAX_ROWS) > 0
    boxes = [page.locator(f".cpu[data-cpu='{c}']").bounding_box() for c in CPUS]
    assert boxes[0]["y"] == boxes[1]["y"] == boxes[2]["y"] and boxes[0]["x"] < boxes[1]["x"] < boxes[2]["x"]
    # hovering an instruction shows its table row and the row's source
    p6 = next(x for x in doc["results"] if x["cpu"] == "pentium2-233")
    page.hover(".cpu[data-cpu='pentium2-233'] .row >> nth=0")
    tip = page.locator("#tip").inner_text()
    first = next(i for i in p6["instructions"] if i["pc"] == p6["timeline"][0]["pc"])
    assert first["row"] in tip and first["source"] in tip
    page.close()


@pytest.fixture(scope="module")
def server():
    proc = subprocess.Popen([sys.executable, "-m", "sim.cli", "serve", "--port", "0", "--timeout", "4", "--quiet"],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        line = proc.stdout.readline()  # printed once every family's model is warm
        m = re.search(r"http://\S+/", line)
        assert m, f"retrosim serve did not start: {line!r}"
        yield m.group(0)
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def post(url: str, headers: dict | None = None, status: int = 200, **request) -> dict:
    """The answer to a POST of `request`, which must come with HTTP status `status`."""
    data = json.dumps(request).encode()
    try:
        with urllib.request.urlopen(urllib.request.Request(url + "api/loop", data, {
                "Content-Type": "application/json", **(headers or {})}), timeout=60) as r:
            got, answer = r.status, json.loads(r.read())
    except urllib.error.HTTPError as e:
        got, answer = e.code, json.loads(e.read())
    assert got == status, (got, answer)
    return answer


def run_in_page(page, body: str, cpus: list[str]) -> None:
    page.fill("#body", body)
    for box in page.locator("input[name=cpu]").all():
        box.set_checked(box.get_attribute("value") in cpus)
    page.evaluate("document.body.removeAttribute('data-state')")
    page.click("#run")
    page.wait_for_selector("body[data-state=done]")


def test_served_app_shows_the_clis_cycles_and_errors(context, server):
    page = context.new_page()
    page.goto(server)
    page.wait_for_selector("body[data-state=ready]")
    run_in_page(page, BODY, CPUS)
    assert page.locator("#error").is_hidden()
    doc = cli_json(BODY, CPUS)
    assert shown_cycles(page) == {x["cpu"]: f"{x['cycles_per_iteration']:.2f}" for x in doc["results"]}
    # a bad body: the CLI's one line (the server names the body <body>, the CLI its stdin)
    bad = "top:\n  movv eax, 1\n  jnz top\n"
    r = CliRunner().invoke(main, ["loop", "-", "--cpu", "pentium2-233"], input=bad)
    assert r.exit_code == 2
    expected = r.output.strip().splitlines()[-1].replace("<stdin>", "<body>")
    run_in_page(page, bad, ["pentium2-233"])
    assert page.locator("#error").is_visible()
    assert page.locator("#error").inner_text() == expected
    page.close()


def test_concurrent_requests_both_answer(server):
    cycles = {x["cpu"]: x["cycles_per_iteration"] for x in cli_json(BODY, CPUS)["results"]}
    answers = [None, None]

    def ask(k):
        answers[k] = post(server, body=BODY, cpus=CPUS)
    threads = [threading.Thread(target=ask, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    for a in answers:
        assert a and "error" not in a, a
        assert {x["cpu"]: x["cycles_per_iteration"] for x in a["data"]["doc"]["results"]} == cycles


def test_runaway_request_is_stopped_and_the_server_answers_after(server):
    # a block is repeated, not looped: 40,000 copies take GNU as far longer than the server's 4 s
    t = time.monotonic()
    a = post(server, body="add eax, 1\n", cpus=["pentium2-233"], iterations=39_999, status=422)
    assert "took more than 4 s" in a["error"] and a["error"].startswith("retrosim: error: ")
    assert time.monotonic() - t < 15
    b = post(server, body=BODY, cpus=["pentium2-233"])
    assert "error" not in b and b["data"]["doc"]["results"][0]["cycles_per_iteration"] > 0


def test_only_json_from_this_machine(server):
    # a form on another site cannot post JSON without asking first; a rebound name is refused
    data = json.dumps({"body": BODY}).encode()
    with pytest.raises(urllib.error.HTTPError) as e:
        urllib.request.urlopen(urllib.request.Request(server + "api/loop", data, {"Content-Type": "text/plain"}))
    assert e.value.code == 415
    with pytest.raises(urllib.error.HTTPError) as e:
        urllib.request.urlopen(urllib.request.Request(server, headers={"Host": "evil.example:8022"}))
    assert e.value.code == 403
    port = server.rsplit(":", 1)[1].strip("/")
    # DNS rebinding: a name that starts like the address and resolves to it is still another site's
    with pytest.raises(urllib.error.HTTPError) as e:
        urllib.request.urlopen(urllib.request.Request(server, headers={"Host": f"127.0.0.1.rebind.example:{port}"}))
    assert e.value.code == 403
    # a page of another site that posts here (a cross-site POST: its Origin is its own)
    a = post(server, {"Origin": "http://attacker.example"}, status=403, body=BODY, cpus=["pentium2-233"])
    assert "Origin" in a["error"]
    post(server, {"Origin": server.rstrip("/")}, body=BODY, cpus=["pentium2-233"])


def test_a_served_body_reads_no_file_and_bad_input_is_a_4xx(server):
    # the attacks of issue 31: .include quotes a file's first line in its error; .incbin feeds its
    # bytes to a loop whose instruction count then tells them
    a = post(server, body='top:\n  .include "/etc/passwd"\n  dec edx\n  jnz top\n', status=400)
    assert a["error"] == ("retrosim: error: <body>:2: '.include' reads a file: a body sent to the server may read "
                          "or name no file (it is for your own files, with `retrosim loop FILE`)")
    a = post(server, body='top:\n  movzx ecx, byte ptr [d]\n1:\n  dec ecx\n  jns 1b\n  dec edx\n  jnz top\n'
                          'd:\n  .incbin "/etc/passwd", 0, 1\n', status=400)
    assert "'.incbin' reads a file" in a["error"] and "data" not in a
    # a bad body: the CLI's whole line, with 400
    bad = "top:\n  movv eax, 1\n  jnz top\n"
    r = CliRunner().invoke(main, ["loop", "-", "--cpu", "pentium2-233"], input=bad)
    assert post(server, body=bad, cpus=["pentium2-233"], status=400)["error"] == \
        r.output.strip().splitlines()[-1].replace("<stdin>", "<body>")


def test_missing_browser_fails_in_ci_and_skips_elsewhere(monkeypatch):
    monkeypatch.setattr(chromium, "CHROMIUM", "/nonexistent/chromium")
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match="cannot run in CI: /nonexistent/chromium is missing"):
        chromium.require()
    monkeypatch.delenv("CI")
    with pytest.raises(pytest.skip.Exception):
        chromium.require()


def test_long_timelines_are_capped(context, tmp_path):
    out = tmp_path / "long.html"
    r = CliRunner().invoke(main, ["loop", "-", "--cpu", "pentium2-233", "--timeline", "100", "--json", "--html",
                                  str(out)], input=BODY)
    assert r.exit_code == 0, r.output
    rows = len(json.loads(r.output)["results"][0]["timeline"])
    assert rows > pipeline_html.MAX_ROWS
    page = context.new_page()
    page.goto(out.as_uri())
    page.wait_for_selector("body[data-state=ready]")
    assert page.locator(".row").count() == pipeline_html.MAX_ROWS
    assert f"{rows - pipeline_html.MAX_ROWS} more rows not drawn" in page.locator(".more").inner_text()
    page.close()


def test_explain_page_on_each_family(context, tmp_path):
    for cpu in CPUS:
        out = tmp_path / f"{cpu}.html"
        r = CliRunner().invoke(main, ["explain", "convert/fp16z.S", "--entry", "fp16z_convert_array", "--args",
                                      "buf:u32:16:7,buf:u32:16,16,0,0", "--cpu", cpu, "--json", "--html", str(out)])
        assert r.exit_code == 0, r.output
        doc = json.loads(r.output)
        page = context.new_page()
        errors = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(out.as_uri())
        page.wait_for_selector("body[data-state=ready]")
        assert not errors, (cpu, errors)
        assert page.locator("#summary-table td.cycles").inner_text() == str(doc["summary"]["cycles"])
        assert page.locator("table.explain tr").count() == len(doc["instructions"]) + 1
        # the column of execution resources in the family's words: P6 ports p0-p4, K6 units X/Y/load/...
        heads = page.locator("table.explain th").all_inner_texts()
        assert {"pentium-mmx-233": "U", "pentium2-233": "ports", "k6-2-300": "units"}[cpu] in heads, (cpu, heads)
        page.close()


def test_fifty_concurrent_posts_are_all_answered(server):
    # issue 31: 15 of 50 were reset with a listen queue of 5; now each gets an answer: timed, or 503
    # with Retry-After when no slot frees within the server's --timeout (4 s here)
    from test_serve_security import burst

    port = int(server.rstrip("/").rsplit(":", 1)[1])
    for status, retry, answer in burst(port, {"body": BODY, "cpus": ["pentium2-233"]}):
        assert (status == 200 and answer["data"]["doc"]["results"][0]["cycles_per_iteration"] > 0) or \
            (status == 503 and retry and "busy" in answer["error"]), (status, answer)
