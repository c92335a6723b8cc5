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
    assert boxes[0]["y"] < boxes[1]["y"] < boxes[2]["y"]  # in the --cpu order, each as wide as the window allows
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


TEXTURE = (ROOT / "examples" / "texture-loop.s").read_text()
BAD = "top:\n  mov eax, [esi+]\n  add eax, esi esi\n  dec edx\n  jnz top\n"  # GNU as: 4 messages


def test_an_error_replaces_the_results_and_shows_every_assembler_message(context, server):
    # issue 32: the error stood above the last body's results, cut to "bad expression (+3 more)"
    a = post(server, body=BAD, cpus=["pentium2-233"], status=400)
    assert a["error"] == "retrosim: error: <body>:2: bad expression (+3 more)"
    assert a["messages"][-1] == "<body>:3: junk `esi' after expression" and len(a["messages"]) == 4
    page = context.new_page()
    page.goto(server)
    page.wait_for_selector("body[data-state=ready]")
    run_in_page(page, BODY, ["pentium2-233"])
    assert page.locator(".cpu").count() == 1 and page.locator("#summary-table").count() == 1
    run_in_page(page, BAD, ["pentium2-233"])
    shown = page.locator("#error").inner_text()
    assert shown.startswith(a["error"]) and all(m in shown for m in a["messages"])
    assert page.locator(".cpu").count() == 0 and page.locator("#summary-table").count() == 0  # nothing stale
    assert "HTTP 400" in page.locator("#status").inner_text()
    page.close()


def form_values(page) -> dict:
    return page.evaluate("""() => ({
        body: document.getElementById('body').value,
        cpus: Array.from(document.querySelectorAll('input[name=cpu]:checked')).map(b => b.value),
        ids: ['memory', 'syntax', 'data', 'iterations', 'align', 'offset', 'regs', 'sets']
             .map(id => document.getElementById(id).value)})""")


def test_a_link_reproduces_the_view_and_the_options_reach_the_server(context, server):
    cpus = ["pentium-mmx-233", "k6-2-300"]
    options = ["--align", "16", "--offset", "3", "--data", "warm", "--reg", "ebx=0x20000", "-n", "40"]
    doc = cli_json(TEXTURE, cpus, *options, "--set", "l1d.ways=4")
    cold = cli_json(TEXTURE, cpus)
    assert doc["results"][0]["cycles_per_iteration"] != cold["results"][0]["cycles_per_iteration"]  # --data matters
    page = context.new_page()
    page.goto(server)
    page.wait_for_selector("body[data-state=ready]")
    page.select_option("#align", "16")
    page.fill("#offset", "3")
    page.select_option("#data", "warm")
    page.fill("#regs", "ebx=0x20000")
    page.fill("#iterations", "40")
    page.fill("#sets", "l1d.ways=4")
    run_in_page(page, TEXTURE, cpus)
    assert page.locator("#error").is_hidden(), page.locator("#error").inner_text()
    assert shown_cycles(page) == {x["cpu"]: f"{x['cycles_per_iteration']:.2f}" for x in doc["results"]}
    settings = page.locator("#settings").inner_text()
    assert "--data warm" in settings and "--align 16 --offset 3" in settings and "ebx=0x00020000" in settings
    link = page.url
    assert "#" in link and "body=" in link.split("#", 1)[1]  # the fragment: never sent to the server
    assert page.locator("#share").get_attribute("href") == "#" + link.split("#", 1)[1]
    before = form_values(page)
    page.close()
    again = context.new_page()
    again.goto(link)
    again.wait_for_selector("body[data-state=done]")  # filled from the link and timed at once
    assert form_values(again) == before
    assert shown_cycles(again) == {x["cpu"]: f"{x['cycles_per_iteration']:.2f}" for x in doc["results"]}
    again.close()


def test_a_link_naming_what_the_server_lacks_says_so(context, server):
    page = context.new_page()
    page.goto(server + "#body=" + urllib.request.quote(BODY) + "&cpu=pentium2-233&cpu=no-such-cpu&memory=nowhere")
    page.wait_for_selector("body[data-state=done]")
    assert "does not have: memory nowhere, cpu no-such-cpu" in page.locator("#status").inner_text()
    assert list(shown_cycles(page)) == ["pentium2-233"]
    page.close()


def test_a_panel_fits_a_1280_px_window_and_its_timeline_scrolls_in_its_own_box(context, tmp_path):
    # issue 32: three panels side by side, each cut off, the timeline scrolling inside a 449 px panel
    out = tmp_path / "wide.html"
    r = CliRunner().invoke(main, ["loop", "-", "--cpu", ",".join(CPUS), "--timeline", "30", "--html", str(out)],
                           input=BODY)
    assert r.exit_code == 0, r.output
    page = context.new_page()
    page.set_viewport_size({"width": 1280, "height": 800})
    page.goto(out.as_uri())
    page.wait_for_selector("body[data-state=ready]")
    assert page.evaluate("document.documentElement.scrollWidth") <= 1280  # the page never scrolls sideways
    for cpu in CPUS:
        panel = page.locator(f".cpu[data-cpu='{cpu}']").bounding_box()
        assert panel["x"] >= 0 and panel["x"] + panel["width"] <= 1280 and panel["width"] > 1000, (cpu, panel)
        chart = page.locator(f".cpu[data-cpu='{cpu}'] .chart")
        box = chart.bounding_box()
        assert box["x"] + box["width"] <= panel["x"] + panel["width"]
        width, client, height, client_h = chart.evaluate("e => [e.scrollWidth, e.clientWidth, e.scrollHeight, "
                                                         "e.clientHeight]")
        assert width > client and height > client_h, cpu  # a long timeline scrolls inside its own box
        # its labels stay in view when it scrolls sideways
        chart.evaluate("e => { e.scrollLeft = e.scrollWidth; }")
        label = page.locator(f".cpu[data-cpu='{cpu}'] .row .lbl").first.bounding_box()
        assert box["x"] <= label["x"] <= box["x"] + 2, (cpu, label, box)
    page.close()


def test_p5_texture_loop_store_shows_its_write_buffer_stall(context, tmp_path):
    # issue 32: the store's main stall was hidden (its hover said only "paired")
    out = tmp_path / "texture.html"
    r = CliRunner().invoke(main, ["loop", "examples/texture-loop.s", "--cpu", "pentium-mmx-233", "--json", "--html",
                                  str(out)])
    assert r.exit_code == 0, r.output
    store = next(i for i in json.loads(r.output)["results"][0]["instructions"] if i["instruction"].startswith("mov byte ptr [edi]"))
    assert store["stall_write_buffer"] > 0
    page = context.new_page()
    page.goto(out.as_uri())
    page.wait_for_selector("body[data-state=ready]")
    rows = page.locator(".row[data-stall]")
    assert rows.count() > 0
    stalls = {rows.nth(k).locator(".lbl").evaluate("e => e.lastChild.textContent"): rows.nth(k).get_attribute("data-stall")
              for k in range(rows.count())}
    assert stalls == {store["instruction"]: "write buffer full"}  # the store pays it, not its pair's U instruction
    mark = page.locator(".row[data-stall] .stall").first
    assert mark.is_visible() and mark.inner_text() == f"write buffer full {store['stall_write_buffer']:g}"
    page.locator(".row[data-stall]").first.hover()
    assert f"main stall: write buffer full, {store['stall_write_buffer']:g} cycles per execution" in \
        page.locator("#tip").inner_text()
    cell = page.locator("table.explain tr", has_text="mov byte ptr [edi]").locator("td.stall-cell")
    assert cell.inner_text().startswith("write buffer full")
    page.close()


def test_a_second_body_shows_the_clis_comparison_above_both_runs_and_the_link_keeps_it(context, server):
    a, b = ROOT / "examples" / "texture-loop9.s", ROOT / "examples" / "texture-loop.s"
    loop9, loop5 = a.read_text(), b.read_text()
    cpus = ["pentium-mmx-233", "k6-2-300"]
    r = CliRunner().invoke(main, ["loop", str(a), str(b), "--cpu", ",".join(cpus), "--json"])
    assert r.exit_code == 0, r.output
    cli = json.loads(r.output)
    page = context.new_page()
    page.goto(server)
    page.wait_for_selector("body[data-state=ready]")
    page.fill("#body-b", loop5)
    run_in_page(page, loop9, cpus)
    assert page.locator("#error").is_hidden(), page.locator("#error").inner_text()

    def shown_ab(p) -> dict[str, list[str]]:  # cpu -> A, B, A/B, faster as on screen
        rows = p.locator("#compare table.ab tr[data-cpu]")
        return {rows.nth(i).get_attribute("data-cpu"): [rows.nth(i).locator("td").nth(k).inner_text()
                                                        for k in (1, 2, 3, 4)] for i in range(rows.count())}
    expected = {e["cpu"]: [f"{e['cycles_per_iteration'][0]:.2f}", f"{e['cycles_per_iteration'][1]:.2f}",
                           f"{e['ratio']:.3f}", {"same": "neither"}.get(e["faster"], e["faster"])]
                for e in cli["comparison"][0]["per_cpu"]}
    assert shown_ab(page) == expected
    # the table sits above both runs' panels, and each run's panels show its own cycles
    tops = page.evaluate("['compare', 'summary', 'cpus', 'summary-b', 'cpus-b'].map("
                         "id => document.getElementById(id).getBoundingClientRect().top)")
    assert tops == sorted(tops) and tops[0] < tops[1]
    assert shown_cycles(page) == {x["cpu"]: f"{x['cycles_per_iteration']:.2f}" for x in cli["a"]["results"]}
    rows_b = page.locator("#summary-table-b tr[data-cpu]")
    assert [rows_b.nth(i).locator("td.cycles").inner_text() for i in range(rows_b.count())] == \
        [f"{x['cycles_per_iteration']:.2f}" for x in cli["b"]["results"]]
    assert page.locator("#cpus-b .cpu").count() == len(cpus)
    link = page.url
    assert "body_b=" in link.split("#", 1)[1]
    page.close()
    again = context.new_page()
    again.goto(link)  # the link fills both boxes and times them at once
    again.wait_for_selector("body[data-state=done]")
    assert again.input_value("#body-b") == loop5 and shown_ab(again) == expected
    # B emptied: A alone, and no comparison or B panels stay on screen
    again.fill("#body-b", "")
    run_in_page(again, loop9, cpus)
    assert again.locator("#compare table").count() == 0 and again.locator("#cpus-b .cpu").count() == 0
    again.close()
