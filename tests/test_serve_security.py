"""`retrosim serve` as an attacker tries it (issue 31): a body reads no host file, by an error
message that quotes it or by counts that depend on its bytes; a page of another site (DNS rebinding,
a cross-site POST) cannot drive the server; a non-loopback address needs --allow-remote.

The request checks run on the handler with a stand-in worker (no fork, no timing); the bodies run
through serve.compute, what a forked child runs."""

from __future__ import annotations

import http.client
import json
import socket
import subprocess
import sys
import threading
import time

import pytest
from click.testing import CliRunner

from sim.cli import main, serve
from sim.guest import asm
from sim.guest import loop_body

SECRET = "SECRET-LINE-31:not-for-clients"
LOOP_TAIL = "  dec edx\n  jnz top\n"


@pytest.fixture
def secret(tmp_path):
    path = tmp_path / "secret.txt"
    path.write_text(SECRET + "\n")
    return path


def attacks(path) -> dict[str, str]:
    """The ways a body could name a host file: as found (include/incbin, absolute or relative), and
    around the first wall (a macro argument that becomes a statement, a directive's name built from a
    macro argument, AT&T's `;` separator, upper case, other file-naming directives)."""
    up = "../" * 12 + str(path).lstrip("/")
    return {
        "include": f'top:\n  .include "{path}"\n{LOOP_TAIL}',
        "include-relative": f'top:\n  .include "{up}"\n{LOOP_TAIL}',
        "incbin": f'top:\n{LOOP_TAIL}  .incbin "{path}", 0, 1\n',
        "incbin-upper": f'top:\n{LOOP_TAIL}  .INCBIN "{path}"\n',
        "macro-argument-statement": f'.macro m a\n  nop \\a\n.endm\ntop:\n  m "; .incbin ""{path}"""\n{LOOP_TAIL}',
        "macro-argument-name": f'.irp d, .incbin\n  \\d "{path}"\n.endr\ntop:\n{LOOP_TAIL}',
        "concatenated-name": f'.macro m x\n  .inc\\()\\x "{path}"\n.endm\ntop:\n  m bin\n{LOOP_TAIL}',
        "att-separator": f'top: nop; .incbin "{path}"\n  decl %edx\n  jnz top\n',
        "file": f'.file "{path}"\ntop:\n{LOOP_TAIL}',
        "loc": f'top:\n  .loc 1 1\n{LOOP_TAIL}',
    }


@pytest.mark.parametrize("kind", list(attacks("/x")))
def test_a_served_body_reads_no_host_file(kind, secret):
    answer = serve.compute({"body": attacks(secret)[kind], "cpus": ["pentium2-233"]})
    assert answer["status"] == 400 and answer["error"].startswith("retrosim: error: <body>:")
    assert SECRET not in answer["error"] and "not-for" not in answer["error"]
    assert "data" not in answer


def test_the_refusal_names_the_directive(secret):
    answer = serve.compute({"body": attacks(secret)["incbin"], "cpus": ["pentium2-233"]})
    assert "<body>:4: '.incbin' reads a file" in answer["error"]
    answer = serve.compute({"body": "top:\n  .section .foo\n" + LOOP_TAIL, "cpus": ["pentium2-233"]})
    assert "'.section'" in answer["error"]
    answer = serve.compute({"body": "top:\n  .altmacro\n" + LOOP_TAIL, "cpus": ["pentium2-233"]})
    assert "'.altmacro' is not a directive a body sent to the server may use" in answer["error"]


def test_incbin_bytes_cannot_leak_through_counts(secret):
    # the attack: an instruction count that depends on an .incbin'd byte; two files that differ in
    # that byte must give the same answer (a refusal), never two different counts
    body = (f"top:\n  movzx ecx, byte ptr [data]\n1:\n  dec ecx\n  jns 1b\n{LOOP_TAIL}"
            f"data:\n  .incbin \"{secret}\", 0, 1\n")
    from sim.cli.kernel_cmds import loop_document

    answers, own = [], []
    for first in ("A", "z"):
        secret.write_text(first)
        answers.append(serve.compute({"body": body, "cpus": ["pentium2-233"]}))
        # the same body on the command line (the user's own file) does read it: the attack is real
        doc, _ = loop_document(body, "own.s", ["pentium2-233"], None, (), None, 100, (), 64, 0, 3, None)
        own.append(doc["results"][0]["instructions_per_iteration"])
    assert own == [ord("A") * 2 + 5, ord("z") * 2 + 5]  # movzx, (byte + 1) x (dec, jns), dec, jnz
    assert answers[0] == answers[1] and "error" in answers[0] and "data" not in answers[0]


def test_allowed_directives_still_time():
    body = "top:\n  nop\n  .rept 2\n  add eax, 1\n  .endr\n  .byte 0x90\n" + LOOP_TAIL  # 0x90: a nop
    answer = serve.compute({"body": body, "cpus": ["pentium2-233"]})
    assert "error" not in answer, answer
    assert answer["data"]["doc"]["results"][0]["instructions_per_iteration"] == 6


@pytest.mark.parametrize("kind", ["include", "incbin", "macro-argument-statement"])
def test_the_assembler_wall_holds_without_the_directive_check(kind, secret, monkeypatch):
    # second wall: with the allow-list and the text scan taken away, an assembly that read another
    # file is refused without a word of it, and no message about another file is shown
    monkeypatch.setattr(loop_body, "check_served_line", lambda line, where: None)
    monkeypatch.setattr(asm, "_refuse_served_reads", lambda text, source: None)
    secret.write_text(SECRET + "\n" + SECRET + "\n")
    answer = serve.compute({"body": attacks(secret)[kind], "cpus": ["pentium2-233"]})
    assert "error" in answer and SECRET not in answer["error"] and "not-for" not in answer["error"], answer
    assert "data" not in answer


def test_messages_about_another_file_are_not_shown_when_serving(tmp_path):
    src = tmp_path / "loop.S"
    stderr = f"/etc/passwd:1: Error: no such instruction: `{SECRET}'\n"
    assert SECRET in asm.format_diagnostics(stderr, src)  # the command line: the user's own files
    with asm.served_sources():
        shown = asm.format_diagnostics(stderr, src)
    assert SECRET not in shown and "another file" in shown


def test_the_command_line_keeps_include_for_the_users_own_files(tmp_path):
    # (a name relative to the working folder, or absolute, as GNU as looks for it)
    (tmp_path / "step.inc").write_text("  add eax, 1\n")
    (tmp_path / "data.bin").write_bytes(b"\x90")
    body = tmp_path / "body.S"
    body.write_text(f'top:\n  .include "{tmp_path}/step.inc"\n  dec edx\n  jnz top\n  .incbin "{tmp_path}/data.bin"\n')
    r = CliRunner().invoke(main, ["loop", str(body), "--cpu", "pentium2-233", "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["results"][0]["instructions_per_iteration"] == 3


# -- the HTTP side: Host, Origin, JSON bounds, bursts ---------------------------------------------
class StandIn:
    """A worker that answers at once (or after `delay`), counting what reached it."""

    def __init__(self, delay: float = 0.0):
        self.delay, self.calls = delay, 0

    def run(self, req):
        self.calls += 1
        time.sleep(self.delay)
        return {"data": {"echo": req}}


@pytest.fixture
def app():
    def start(worker=None, host="127.0.0.1"):
        worker = worker or StandIn()
        handler = serve.make_handler(worker, b"<html></html>")
        handler.quiet = True
        httpd = serve._bounded_server(host, 0, handler)
        httpd.server_bind()
        httpd.server_activate()
        threading.Thread(target=httpd.serve_forever, daemon=True).start()
        started.append(httpd)
        return httpd.server_address[1], worker
    started = []
    yield start
    for httpd in started:
        httpd.shutdown()
        httpd.server_close()


def request(port, method="GET", path="/", body=None, headers=None, host=None):
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    h = {"Host": f"127.0.0.1:{port}" if host is None else host, **(headers or {})}
    if body is not None:
        h.setdefault("Content-Type", "application/json")
    conn.request(method, path, body=body, headers=h)
    r = conn.getresponse()
    out = r.status, dict(r.getheaders()), r.read()
    conn.close()
    return out


def test_host_must_name_the_listening_address(app):
    port, worker = app()
    for host in (f"127.0.0.1.rebind.example:{port}", f"127.0.0.2:{port}", f"attacker.example:{port}",
                 f"localhost.attacker.example:{port}", "127.0.0.1", f"127.0.0.1:{port + 1}", ""):
        status, _, body = request(port, host=host)
        assert status == 403, host
        status, _, _ = request(port, "POST", "/api/loop", json.dumps({"body": "nop"}), host=host)
        assert status == 403, host
    assert worker.calls == 0
    for host in (f"127.0.0.1:{port}", f"localhost:{port}", f"LOCALHOST:{port}"):
        assert request(port, host=host)[0] == 200, host


def test_a_cross_site_post_is_refused(app):
    port, worker = app()
    data = json.dumps({"body": "nop"})
    for origin in ("http://attacker.example", "null", f"http://127.0.0.1.rebind.example:{port}",
                   f"https://127.0.0.1:{port}"):
        status, _, body = request(port, "POST", "/api/loop", data, {"Origin": origin})
        assert status == 403 and b"Origin" in body, origin
    assert worker.calls == 0
    for origin in (f"http://127.0.0.1:{port}", f"http://localhost:{port}", None):
        headers = {"Origin": origin} if origin else {}
        assert request(port, "POST", "/api/loop", data, headers)[0] == 200, origin
    assert worker.calls == 3


@pytest.mark.parametrize("raw, message", [
    ("[" * 100_000, "more than 8 deep"),
    ('{"body": ' + "[" * 50_000 + "]" * 50_000 + "}", "more than 8 deep"),
    ('{"body": "[[[[[[[[[[[[[[[[[["}', None),  # brackets in a string are text
])
def test_json_depth_is_bounded(app, raw, message):
    port, worker = app()
    status, _, body = request(port, "POST", "/api/loop", raw)
    if message is None:
        assert status == 200
        return
    assert status == 400 and message in json.loads(body)["error"]
    assert worker.calls == 0


def test_json_size_is_bounded(app):
    port, worker = app()
    # the header is enough: the body is never read
    status, _, body = request(port, "POST", "/api/loop", "[]", {"Content-Length": str(serve.MAX_REQUEST_BYTES + 1)})
    assert status == 413 and "bytes" in json.loads(body)["error"] and worker.calls == 0


def burst(port: int, body: dict, n: int = 50, host: str = "127.0.0.1") -> list[tuple[int, str | None, dict]]:
    """`n` POSTs of `body` at once: (status, Retry-After, answer) of each; none may fail to connect or be reset."""
    results, errors = [], []

    def post():
        try:
            status, headers, raw = request(port, "POST", "/api/loop", json.dumps(body), host=f"{host}:{port}")
            results.append((status, headers.get("Retry-After"), json.loads(raw)))
        except OSError as e:
            errors.append(repr(e))
    threads = [threading.Thread(target=post) for _ in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert not errors
    assert len(results) == n
    return results


def test_a_burst_of_posts_is_answered_not_reset(app):
    port, worker = app(StandIn(delay=0.05))
    statuses = burst(port, {"body": "nop"})
    assert all(s == 200 or (s == 503 and ra) for s, ra, _ in statuses), statuses


def test_past_max_waiting_the_answer_is_503_with_retry_after(app, monkeypatch):
    monkeypatch.setattr(serve, "MAX_WAITING", 1)
    port, worker = app(StandIn(delay=2.0))
    first = threading.Thread(target=request, args=(port, "POST", "/api/loop", json.dumps({"body": "nop"})))
    first.start()
    end = time.monotonic() + 10
    while not worker.calls and time.monotonic() < end:  # the first is being timed
        time.sleep(0.01)
    status, headers, body = request(port, "POST", "/api/loop", json.dumps({"body": "nop"}))
    first.join(10)
    assert status == 503 and headers["Retry-After"] == str(serve.RETRY_AFTER) and b"busy" in body


def python(code: str) -> subprocess.CompletedProcess:
    """`code` run by a Python of its own (a server's stderr to read, a hard limit this one must not get)."""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    return r


def test_a_client_that_goes_away_leaves_no_traceback(tmp_path):
    # the server's stderr after a client that sends half a request and one that leaves before the answer
    code = (
        "import socket, sys, threading, time\n"
        "from sim.cli import serve\n"
        "class W:\n"
        "    def run(self, req):\n"
        "        time.sleep(0.5); return {'data': 'x' * 1000000}\n"
        "h = serve.make_handler(W(), b'x')\n"
        "s = serve._bounded_server('127.0.0.1', 0, h); s.server_bind(); s.server_activate()\n"
        "threading.Thread(target=s.serve_forever, daemon=True).start()\n"
        "port = s.server_address[1]\n"
        "for half in (True, False):\n"
        "    c = socket.create_connection(('127.0.0.1', port))\n"
        "    body = b'{\"body\": \"nop\"}'\n"
        "    head = f'POST /api/loop HTTP/1.1\\r\\nHost: 127.0.0.1:{port}\\r\\nContent-Type: application/json\\r\\n'\n"
        "    c.sendall(head.encode() + f'Content-Length: {len(body) + (100 if half else 0)}\\r\\n\\r\\n'.encode() + body)\n"
        "    c.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b'\\x01\\x00\\x00\\x00\\x00\\x00\\x00\\x00')\n"
        "    c.close()\n"
        "time.sleep(3)\n"
    )
    r = python(code)
    assert "Traceback" not in r.stderr, r.stderr
    assert "client went away" in r.stderr


def test_a_non_loopback_address_needs_allow_remote(monkeypatch):
    warmed = []
    monkeypatch.setattr(serve, "warm_up", lambda say=None: warmed.append(True) or (_ for _ in ()).throw(
        KeyboardInterrupt))
    for host in ("0.0.0.0", ""):
        r = CliRunner().invoke(main, ["serve", "--host", host, "--port", "0"])
        assert r.exit_code == 2 and "--allow-remote" in r.output and "other machines can reach" in r.output, r.output
    assert not warmed  # refused before the warm-up, and it never listened
    r = CliRunner().invoke(main, ["serve", "--host", "0.0.0.0", "--port", "0", "--allow-remote"])
    assert r.exit_code == 0 and "warning: --allow-remote" in r.output and "no password" in r.output, r.output
    assert warmed == [True]


def test_a_remote_bound_server_still_checks_host(app):
    # on 0.0.0.0 the Host must name the address the client reached (here 127.0.0.1), not any name
    port, worker = app(host="0.0.0.0")
    assert request(port, host=f"attacker.example:{port}")[0] == 403
    assert request(port, host=f"127.0.0.1:{port}")[0] == 200


def test_a_memory_limit_the_child_cannot_set_is_said(tmp_path):
    # under a hard `ulimit -v` below what --memory-mb needs, each request says so (not "past its bounds")
    code = (
        "import resource, json\n"
        "from sim.cli import serve\n"
        "hard = serve._vm_bytes() + (512 << 20)\n"
        "resource.setrlimit(resource.RLIMIT_AS, (hard, hard))\n"
        "print(json.dumps([serve.memory_limit_problem(2048), serve.memory_limit_problem(64),\n"
        "    serve.Worker(timeout=20, memory_mb=2048, jobs=1).run({'body': 'nop'})]))\n"
    )
    problem, fits, answer = json.loads(python(code).stdout)
    assert "ulimit -v" in problem and "--memory-mb 2048 cannot be given" in problem
    assert fits is None
    assert answer["status"] == 500 and "ulimit -v" in answer["error"] and "went past" not in answer["error"]


@pytest.mark.parametrize("stop", ["SIGINT", "SIGTERM"])  # Ctrl-C, and a service manager's stop
def test_stopping_the_server_stops_its_children_and_frees_the_port(tmp_path, stop):
    import signal

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    log = tmp_path / "stderr.txt"  # a file: a pipe's reader would wait for every child holding it
    # start the server as a terminal would: a test run in the background (nohup, `&` in a script) ignores
    # SIGINT, and an ignored signal stays ignored through exec, so the server would rightly ignore Ctrl-C
    ignored = signal.getsignal(signal.SIGINT) == signal.SIG_IGN
    if ignored:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        proc = subprocess.Popen([sys.executable, "-m", "sim.cli", "serve", "--port", str(port), "--timeout", "60",
                                 "--quiet"], stdout=subprocess.PIPE, stderr=log.open("w"), text=True)
    finally:
        if ignored:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        assert "http://" in proc.stdout.readline()
        # a runaway request (40,000 block copies take GNU as far longer than the test waits)
        body = json.dumps({"body": "add eax, 1\n", "cpus": ["pentium2-233"], "iterations": 39_999})
        threading.Thread(target=lambda: _quiet_post(port, body), daemon=True).start()
        children = []
        for _ in range(400):
            children = _children(proc.pid)
            if children:
                break
            time.sleep(0.05)
        assert children, "the request started no child"
        proc.send_signal(getattr(signal, stop))
        proc.wait(10)
        with socket.socket() as again:  # the port is free at once (no child holds it)
            again.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            again.bind(("127.0.0.1", port))
            again.listen()
        end = time.monotonic() + 3  # (the server waited for them: they are gone or going)
        while [pid for pid in children if _alive(pid)] and time.monotonic() < end:
            time.sleep(0.05)
        assert not [pid for pid in children if _alive(pid)]
        assert "Traceback" not in log.read_text()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def _quiet_post(port, body):
    try:
        request(port, "POST", "/api/loop", body)
    except OSError:
        pass


def _children(pid: int) -> list[int]:
    import os

    out = []
    for task in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{task}/children") as f:
                out += [int(x) for x in f.read().split()]
        except OSError:
            pass
    return out


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ", 1)[1][0] != "Z"
    except OSError:
        return False


def test_a_burst_while_the_server_is_busy_is_queued_not_dropped():
    # while the accepting thread is busy (here: not yet serving), the kernel holds a burst of 50
    # connections (http.server's listen queue of 5 drops the rest); each is answered afterwards
    handler = serve.make_handler(StandIn(), b"x")
    handler.quiet = True
    httpd = serve._bounded_server("127.0.0.1", 0, handler)
    httpd.server_bind()
    httpd.server_activate()
    port = httpd.server_address[1]
    conns, serving = [], threading.Thread(target=httpd.serve_forever, daemon=True)
    try:
        for _ in range(50):
            c = socket.create_connection(("127.0.0.1", port), timeout=2)
            c.sendall(f"GET /api/health HTTP/1.0\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode())
            conns.append(c)
        serving.start()
        end = time.monotonic() + 5  # a dropped connection waits for TCP's retries: seconds each
        for c in conns:
            c.settimeout(max(end - time.monotonic(), 0.01))
            assert c.recv(64).startswith(b"HTTP/1.0 200")
    finally:
        for c in conns:
            c.close()
        if serving.is_alive():
            httpd.shutdown()  # (waits for ever on a server that never served)
        httpd.server_close()


def test_preset_names_are_names_not_paths(tmp_path):
    # a request names its CPUs and memory: `../../x` must not read x.toml from anywhere, even a valid preset
    import shutil

    from sim.cpus import presets

    from sim.cpus.overrides import load_dram
    from sim.errors import RetrosimError
    from sim.memory import dram

    shutil.copy(dram.MEMORY_PRESETS_DIR / "edo.toml", tmp_path / "mem.toml")
    shutil.copy(presets.PRESETS / "pentium2-233.toml", tmp_path / "cpu.toml")
    up = "../" * 16 + str(tmp_path).lstrip("/")
    with pytest.raises(RetrosimError, match="unknown memory preset"):
        load_dram(f"{up}/mem")
    with pytest.raises(RetrosimError, match="unknown CPU preset"):
        presets.load(f"{up}/cpu")
    answer = serve.compute({"body": "top:\n" + LOOP_TAIL, "cpus": ["pentium2-233"], "memory": f"{up}/mem"})
    assert answer["status"] == 400 and "unknown memory preset" in answer["error"]


def test_a_served_body_assembles_into_a_folder_of_its_own(tmp_path, monkeypatch):
    # a client's objects (up to 64 MB each) never land in the user's assembler cache, and the folder goes
    monkeypatch.setenv("RETROSIM_CACHE", str(tmp_path / "users-cache"))
    answer = serve.compute({"body": "top:\n  add eax, 7\n" + LOOP_TAIL, "cpus": ["pentium2-233"]})
    assert "error" not in answer, answer
    assert not list((tmp_path / "users-cache").rglob("*.o"))
    import os
    assert os.environ["RETROSIM_CACHE"] == str(tmp_path / "users-cache")


@pytest.mark.parametrize("example", ["sum-att.s", "texture-loop.s"])
def test_the_examples_time_the_same_served_and_on_the_command_line(example):
    # the allow-list takes nothing away from a real loop body
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "examples" / example
    answer = serve.compute({"body": path.read_text(), "cpus": ["pentium2-233"]})
    assert "error" not in answer, answer
    r = CliRunner().invoke(main, ["loop", str(path), "--cpu", "pentium2-233", "--json"])
    assert r.exit_code == 0, r.output
    assert answer["data"]["doc"]["results"][0]["cycles_per_iteration"] == \
        json.loads(r.output)["results"][0]["cycles_per_iteration"]


def test_a_message_about_the_body_as_a_whole_is_kept_when_serving(tmp_path):
    src = tmp_path / "loop.S"
    with asm.served_sources():
        assert asm.format_diagnostics(f"Assembler messages:\n{src}: Error: bad size\n", src) == f"{src}: Error: bad size"
        assert "/etc/shadow" not in asm.format_diagnostics("as: can't open /etc/shadow for reading\n", src)


@pytest.mark.parametrize("options", [["--align", "3"], ["--align", "16", "--offset", "16"], ["--reg", "eax=zz"],
                                     ["--reg", "xmm0=1"], ["--reg", "eax=0x100000000"]])
def test_the_forms_options_are_refused_as_the_command_line_refuses_them(options):
    # every field is a client's: the same one line the CLI gives, a 400, before anything is assembled
    r = CliRunner().invoke(main, ["loop", "-", "--cpu", "pentium2-233", *options], input="top:\n" + LOOP_TAIL)
    assert r.exit_code == 2
    cli = r.output.strip().splitlines()[-1]
    key = {"--align": "align", "--offset": "offset", "--reg": "regs"}
    req = {"body": "top:\n" + LOOP_TAIL, "cpus": ["pentium2-233"]}
    for flag, value in zip(options[::2], options[1::2]):
        req[key[flag]] = [value] if flag == "--reg" else int(value)
    answer = serve.compute(req)
    assert answer["status"] == 400 and answer["error"] == cli, (answer, cli)


@pytest.mark.parametrize("field, value, words", [
    ("body", "top:\n  add eax, 1 \ud800\n" + LOOP_TAIL, "<body>:2: a lone UTF-16 surrogate ('\\ud800') is no character"),
    ("regs", ["eax=" + "1" * 300], "regs: expected a list of at most 16 strings of at most 256 characters"),
    ("sets", ["\udfff"], "sets: character 1: a lone UTF-16 surrogate"),
    ("align", "16", "align: expected an integer"), ("data", "hot", "--data hot: choose cold or warm")])
def test_bad_fields_are_a_400_not_a_server_fault(field, value, words):
    # a lone surrogate (JSON's "\ud800") used to reach the file the body is written to: a 500
    answer = serve.compute({"body": "top:\n" + LOOP_TAIL, "cpus": ["pentium2-233"], field: value})
    assert answer["status"] == 400 and words in answer["error"], answer


def test_every_assembler_message_reaches_the_page():
    # the command line's one line says "(+3 more)"; the answer carries them all (GNU as's `junk ...`)
    answer = serve.compute({"body": "top:\n  mov eax, [esi+]\n  add eax, esi esi\n" + LOOP_TAIL,
                            "cpus": ["pentium2-233"]})
    assert answer["status"] == 400 and answer["error"].endswith("<body>:2: bad expression (+3 more)")
    assert answer["messages"][0] == "<body>:2: bad expression" and len(answer["messages"]) == 4
    assert "<body>:3: junk `esi' after expression" in answer["messages"]
    one = serve.compute({"body": "top:\n  movv eax, 1\n" + LOOP_TAIL, "cpus": ["pentium2-233"]})
    assert one["status"] == 400 and "messages" not in one  # one message: the line says it all
