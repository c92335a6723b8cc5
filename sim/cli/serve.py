"""`retrosim serve`: the pipeline view as a local web app (standard library only).

One page (sim/reports/pipeline_html.py, the same page `loop --html` writes, with a form): paste a
loop body, pick CPUs, --set overrides and memory, and it draws what `retrosim loop --json` gives.

Why it answers in milliseconds: the cost of `retrosim loop` is starting Python (imports) and loading
each family's compiled core; the timing itself takes tens of milliseconds. The server starts once,
times a small loop on one CPU of every family (compiling or loading each numba core, reading the
tables, priming the assembler's cache) and keeps that process as the warm parent.

Why one request cannot take it down: the parent never times a body itself. Each request forks a
child that inherits the warm parent (copy-on-write), sets its own address-space limit
(RLIMIT_AS: the parent's size plus ``--memory-mb``) and CPU-time limit, times the body and writes
the JSON answer into a pipe. The parent waits at most ``--timeout`` seconds for it, then kills it.
A semaphore bounds the children running at once (``--jobs``); a request waits for a free slot
within its timeout. Bad input gets the CLI's own one-line error (`retrosim: error: ...`).

The parent serves requests in threads (http.server.ThreadingHTTPServer) and forks from them: the
child runs only code whose imports and compilation the warm-up finished, and writes nothing but
its pipe (another thread may hold the stderr lock at the fork); the timeout bounds the rest.
"""

from __future__ import annotations

import json
import os
import resource
import select
import signal
import sys
import threading
import time

import click

from sim.cli.app import bounded, main, one_line
from sim.errors import ArgumentError, RetrosimError

DEFAULT_CPUS = ("pentium-mmx-233", "pentium2-233", "k6-2-300")  # one per family
EXAMPLE = """\
// a loop body: Intel or AT&T syntax; it ends with a jump back to its first line
top:
    mov   eax, [esi]
    add   eax, ebx
    mov   [edi], eax
    add   esi, 4
    add   edi, 4
    dec   edx
    jnz   top
"""
WARM_BODY = "top:\n  add eax, [esi]\n  imul ebx, ecx\n  add esi, 4\n  dec edx\n  jnz top\n"
MAX_REQUEST_BYTES = (1 << 20) + (64 << 10)  # a body (loop.MAX_BODY_BYTES) and its options
MAX_CPUS = 32
MAX_ANSWER_BYTES = 64 << 20


def error_line(message: str) -> str:
    """The CLI's one error line (sim.cli.app.print_error), without its newline."""
    return f"retrosim: error: {one_line(message)}"


def parse_request(req) -> dict:
    """The loop options of a request, checked as the CLI checks them; one ArgumentError otherwise."""
    if not isinstance(req, dict):
        raise ArgumentError("the request is not a JSON object")
    unknown = set(req) - {"body", "cpus", "sets", "memory", "syntax", "iterations", "regs", "align", "offset",
                          "timeline"}
    if unknown:
        raise ArgumentError(f"unknown request field(s): {', '.join(sorted(unknown))}")

    def text(key, default=None):
        v = req.get(key, default)
        if v is not None and not isinstance(v, str):
            raise ArgumentError(f"{key}: expected text")
        return v

    def texts(key, most):
        v = req.get(key) or []
        if not isinstance(v, list) or not all(isinstance(x, str) for x in v) or len(v) > most:
            raise ArgumentError(f"{key}: expected a list of at most {most} strings")
        return v

    def integer(key, default):
        v = req.get(key, default)
        if v is None:
            return default
        if isinstance(v, bool) or not isinstance(v, int):
            raise ArgumentError(f"{key}: expected an integer")
        return v

    body = text("body", "")
    if not body.strip():
        raise ArgumentError("<body>: no instructions in the body")
    syntax = text("syntax") or None
    if syntax is not None and syntax not in ("intel", "att"):
        raise ArgumentError(f"--syntax {syntax}: choose intel or att")
    timeline = integer("timeline", 3)
    if not 0 <= timeline <= 1000:
        raise ArgumentError(f"--timeline {timeline}: must be between 0 and 1,000")
    return {"text": body, "cpus": texts("cpus", MAX_CPUS) or list(DEFAULT_CPUS), "sets": texts("sets", 64),
            "memory": text("memory") or None, "syntax": syntax, "iterations": integer("iterations", 100),
            "regs": texts("regs", 16), "align": integer("align", 64), "offset": integer("offset", 0),
            "timeline": timeline}


def compute(req) -> dict:
    """Time one request's body (in the child): the page's data, or the one-line error."""
    from sim.cli.kernel_cmds import loop_document
    from sim.reports import pipeline_html

    try:
        o = parse_request(req)
        doc, timings = loop_document(o["text"], "<body>", o["cpus"], o["memory"], o["sets"], o["syntax"],
                                     o["iterations"], o["regs"], o["align"], o["offset"], o["timeline"], None)
        return {"data": pipeline_html.loop_data(doc, timings, o["text"])}
    except RetrosimError as e:
        return {"error": error_line(str(e))}
    except MemoryError:
        return {"error": error_line("the request ran out of the server's memory bound (--memory-mb)")}


def _vm_bytes() -> int:
    """This process's address-space size (what RLIMIT_AS counts)."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")


class Worker:
    """Runs each request in a forked child of this (warm) process, with bounds."""

    def __init__(self, timeout: float, memory_mb: int, jobs: int):
        self.timeout, self.memory_mb = timeout, memory_mb
        self.slots = threading.BoundedSemaphore(jobs)
        self.fork_lock = threading.Lock()

    def run(self, req) -> dict:
        start = time.monotonic()
        if not self.slots.acquire(timeout=self.timeout):
            return {"error": error_line(f"the server is busy: no free slot within {self.timeout:g} s (--jobs)")}
        try:
            return self._fork(req, start + self.timeout)
        finally:
            self.slots.release()

    def _fork(self, req, deadline: float) -> dict:
        r, w = os.pipe()
        with self.fork_lock:  # one fork at a time; the child's limit is from the parent's size now
            limit = _vm_bytes() + (self.memory_mb << 20)
            pid = os.fork()
        if pid == 0:  # the child: bounded, answers through the pipe, never returns
            code = 0
            try:
                os.close(r)
                os.setpgid(0, 0)  # its own group: a stop reaches the assembler it may be running too
                signal.signal(signal.SIGTERM, _stop)  # unwinds, so temporary files are removed
                signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the server's
                resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
                cpu = int(self.timeout) + 1
                resource.setrlimit(resource.RLIMIT_CPU, (cpu, cpu + 1))
                try:
                    answer = compute(req)
                except BaseException as e:  # noqa: BLE001  (the child must answer whatever happens)
                    answer = {"error": error_line(f"internal error: {type(e).__name__}: {e} (a library that cannot "
                                                  f"get memory fails so: the server's bound is --memory-mb "
                                                  f"{self.memory_mb})")}
                data = json.dumps(answer, separators=(",", ":")).encode()
                view = memoryview(data)
                while view:
                    view = view[os.write(w, view):]
            except BaseException:  # noqa: BLE001
                code = 1
            finally:
                os._exit(code)
        os.close(w)
        try:
            os.setpgid(pid, pid)  # as the child does (whichever runs first)
        except OSError:
            pass  # the child did it and may have exited already
        chunks, size, timed_out = [], 0, False
        try:
            while True:
                left = deadline - time.monotonic()
                if left <= 0:
                    timed_out = True
                    break
                ready, _, _ = select.select([r], [], [], left)
                if not ready:
                    continue
                chunk = os.read(r, 1 << 16)
                if not chunk:
                    break
                chunks.append(chunk)
                size += len(chunk)
                if size > MAX_ANSWER_BYTES:
                    break
        finally:
            os.close(r)
            if timed_out or size > MAX_ANSWER_BYTES:
                status = _stop_group(pid)
            else:
                _, status = os.waitpid(pid, 0)
        if timed_out:
            return {"error": error_line(f"the request took more than {self.timeout:g} s (the server's --timeout); "
                                        "a shorter body, fewer --iterations or fewer CPUs answer sooner")}
        if size > MAX_ANSWER_BYTES:
            return {"error": error_line(f"the answer has more than {MAX_ANSWER_BYTES >> 20} MB; time fewer CPUs")}
        try:
            return json.loads(b"".join(chunks))
        except ValueError:
            why = (f"signal {os.WTERMSIG(status)}" if os.WIFSIGNALED(status) else f"exit status {os.WEXITSTATUS(status)}")
            return {"error": error_line(f"the request stopped without an answer ({why}): it went past the server's "
                                        f"bounds (--memory-mb {self.memory_mb}, --timeout {self.timeout:g} s)")}


def _stop(signum, frame):
    raise SystemExit(128 + signum)


def _stop_group(pid: int, grace: float = 1.0) -> int:
    """Stop a child and its process group: SIGTERM (it unwinds and removes its temporary files),
    then SIGKILL after `grace` seconds. Returns its wait status."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(pid, sig)
        except ProcessLookupError:
            pass
        end = time.monotonic() + grace
        while time.monotonic() < end:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                if sig == signal.SIGTERM:  # what it started may still run: the group goes too
                    try:
                        os.killpg(pid, signal.SIGKILL)
                    except ProcessLookupError:
                        pass
                return status
            time.sleep(0.01)
    return os.waitpid(pid, 0)[1]


def warm_up(say=lambda line: None) -> None:
    """Time a small loop on one CPU of every family in this process, so that children start warm."""
    from sim.cli.kernel_cmds import loop_document
    from sim.cpus import families, presets

    seen = {}
    for name in presets.available():
        seen.setdefault(presets.load(name).family, name)
    for family, cpu in sorted(seen.items(), key=lambda kv: families.order(kv[0])):
        t = time.monotonic()
        say(f"warming the {family.upper()} model on {cpu} ...")
        loop_document(WARM_BODY, "<warm-up>", [cpu], None, (), None, 100, (), 64, 0, 3, None)
        say(f"  ready in {time.monotonic() - t:.1f} s")


def app_config() -> dict:
    from sim.cpus import families, memory_presets, presets

    # the CPUs by family (P5, P6, K6: the order the page shows them in), then by name
    cpus = sorted(presets.available(), key=lambda c: (families.order(presets.load(c).family), c))
    return {"cpus": cpus, "memories": memory_presets(), "defaults": list(DEFAULT_CPUS), "example": EXAMPLE}


def make_handler(worker: Worker, page: bytes):
    from http.server import BaseHTTPRequestHandler  # here: every other command starts without it

    class Handler(BaseHTTPRequestHandler):
        server_version = "retrosim"
        quiet = False
        timeout = 60  # seconds a connection may idle (a client that never sends its request lets go)

        def log_message(self, fmt, *args):  # one line per request on stderr, as http.server does
            if not self.quiet:
                super().log_message(fmt, *args)

        def _send(self, status: int, body: bytes, ctype: str) -> None:
            self.send_response(status)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.send_header("X-Content-Type-Options", "nosniff")
            self.end_headers()
            self.wfile.write(body)

        def _json(self, status: int, answer: dict) -> None:
            self._send(status, json.dumps(answer, separators=(",", ":")).encode(), "application/json")

        def _host_ok(self) -> bool:
            """On a loopback address, only requests naming a loopback host (a page of another site
            that re-points its name at 127.0.0.1, DNS rebinding, names its own)."""
            if not self.server.loopback:
                return True
            raw = self.headers.get("Host") or ""
            host = raw.split("]")[0] + "]" if raw.startswith("[") else raw.rsplit(":", 1)[0]
            if host in ("localhost", "[::1]") or host.startswith("127."):
                return True
            self._json(403, {"error": error_line(f"Host {host!r}: this server answers 127.0.0.1 and localhost only")})
            return False

        def do_GET(self):
            if not self._host_ok():
                return
            path = self.path.split("?", 1)[0]
            if path in ("/", "/index.html"):
                self._send(200, page, "text/html; charset=utf-8")
            elif path == "/api/health":
                self._json(200, {"ok": True})
            else:
                self._json(404, {"error": error_line(f"{path}: no such page")})

        def do_POST(self):
            if not self._host_ok():
                return
            if self.path.split("?", 1)[0] != "/api/loop":
                self._json(404, {"error": error_line(f"{self.path}: no such endpoint (POST /api/loop)")})
                return
            # JSON only: a form on another site cannot send it without the browser asking first (CORS)
            if (self.headers.get("Content-Type") or "").split(";")[0].strip().lower() != "application/json":
                self._json(415, {"error": error_line("the request must be JSON (Content-Type: application/json)")})
                return
            try:
                n = int(self.headers.get("Content-Length", ""))
            except ValueError:
                self._json(411, {"error": error_line("the request has no Content-Length")})
                return
            if not 0 <= n <= MAX_REQUEST_BYTES:
                self._json(413, {"error": error_line(f"the request has more than {MAX_REQUEST_BYTES:,} bytes; "
                                                     "a loop body is instructions only")})
                return
            raw = self.rfile.read(n)
            try:
                req = json.loads(raw.decode("utf-8"))
            except (UnicodeDecodeError, ValueError) as e:
                self._json(400, {"error": error_line(f"the request is not JSON ({e})")})
                return
            t = time.monotonic()
            answer = worker.run(req)
            answer["ms"] = round(1000 * (time.monotonic() - t), 1)
            self._json(200, answer)

    return Handler


def serve(host: str, port: int, timeout: float, memory_mb: int, jobs: int, quiet: bool = False,
          say=lambda line: None) -> None:
    from http.server import ThreadingHTTPServer

    from sim.reports import pipeline_html

    worker = Worker(timeout, memory_mb, jobs)
    page = pipeline_html.page(None, app=app_config()).encode()
    handler = make_handler(worker, page)
    handler.quiet = quiet
    # listen before the warm-up (up to a minute while numba compiles): a port in use fails at once
    try:
        httpd = ThreadingHTTPServer((host, port), handler)
    except OSError as e:
        raise RetrosimError(f"cannot listen on {host}:{port}: {e.strerror or e}") from None
    httpd.daemon_threads = True
    httpd.loopback = host in ("127.0.0.1", "localhost", "::1") or host.startswith("127.")
    url_host = f"[{host}]" if ":" in host else host
    try:
        warm_up(say)  # requests wait in the listen queue meanwhile; the address is printed once warm
        click.echo(f"retrosim serve: http://{url_host}:{httpd.server_address[1]}/ (Ctrl-C stops it)")
        sys.stdout.flush()
        httpd.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        httpd.server_close()


@main.command("serve")
@click.option("--host", default="127.0.0.1", show_default=True,
              help="address to listen on (the default answers this machine only)")
@click.option("--port", default=8022, show_default=True, callback=bounded(0, 65535), help="TCP port (0: any free one)")
@click.option("--timeout", default=20.0, show_default=True, type=float,
              help="seconds one request may take, waiting for a slot included; then it is stopped")
@click.option("--memory-mb", default=2048, show_default=True, callback=bounded(64, 1 << 20),
              help="address space one request may add to the warm server (MB)")
@click.option("--jobs", default=2, show_default=True, callback=bounded(1, 64), help="requests timed at once")
@click.option("--quiet", is_flag=True, help="no line per request on stderr")
def serve_cmd(host, port, timeout, memory_mb, jobs, quiet):
    """A local web app: paste a loop body, pick CPUs, see the pipeline view (warm models, ms answers)."""
    from sim.cli.app import say

    if not 0.1 <= timeout <= 3600:
        raise ArgumentError(f"--timeout {timeout:g}: must be between 0.1 and 3,600 seconds")
    serve(host, port, timeout, memory_mb, jobs, quiet, say)
