"""`retrosim serve`: the pipeline view as a local web app (standard library only).

One page (sim/reports/pipeline_html.py, the same page `loop --html` writes, with a form): paste a
loop body, pick CPUs, memory, --data, --align/--offset, --reg and --set, and it draws what `retrosim
loop --json` gives (with a second body, B, what `loop A.s B.s --json` gives: both runs and their
comparison); the form travels in the URL's fragment, so a link reproduces the view.

Why it answers in milliseconds: the cost of `retrosim loop` is starting Python (imports) and loading
each family's compiled core; the timing itself takes tens of milliseconds. The server starts once,
times a small loop on one CPU of every family (compiling or loading each numba core, reading the
tables, priming the assembler's cache) and keeps that process as the warm parent.

Why one request cannot take it down: the parent never times a body itself. Each request forks a
child that inherits the warm parent (copy-on-write), sets its own address-space limit
(RLIMIT_AS: the parent's size plus ``--memory-mb``) and CPU-time limit, times the body and writes
the JSON answer into a pipe. The parent waits at most ``--timeout`` seconds for it, then kills it.
A semaphore bounds the children running at once (``--jobs``); a request waits at most ``--timeout``
for a free slot, else gets 503 with Retry-After, as does any request past MAX_WAITING served or
waiting at once; its own ``--timeout`` starts when it has a slot. Bad input gets the CLI's own one-line error (`retrosim: error: ...`) with a 4xx.

Why a client cannot read the server's files (docs/serve.md has the whole threat model): the body is
assembled under sim.guest.asm.served_sources, which allows only SERVED_DIRECTIVES (no .include or
.incbin), refuses an assembly that read any other file and never shows a message about one. Why a
web page the user visits cannot drive it: the Host header must name the address the client reached
(DNS rebinding names another), and a POST's Origin must be this server's own.

The parent serves requests in threads (http.server.ThreadingHTTPServer) and forks from them: the
child runs only code whose imports and compilation the warm-up finished, and writes nothing but
its pipe (another thread may hold the stderr lock at the fork); the timeout bounds the rest.
"""

from __future__ import annotations

import ipaddress
import json
import os
import re
import resource
import select
import shutil
import signal
import socket
import stat
import sys
import tempfile
import threading
import time

import click

from sim.cli.app import bounded, main, one_line
from sim.errors import ArgumentError, RetrosimError

BODY_B = "<body B>"  # how a line names the second body (the first is "<body>", as `loop -` names its own)
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
MAX_REQUEST_BYTES = (2 << 20) + (64 << 10)  # two bodies (A and B: loop_body.MAX_BODY_BYTES each) and options
MAX_CPUS = 32
MAX_OPTION_CHARS = 256  # one --set, --reg or CPU name
MAX_ANSWER_BYTES = 64 << 20
MAX_JSON_DEPTH = 8  # a request is an object of lists: 2 levels; json.loads recurses once per level
_JSON_TOKEN = re.compile(r'"(?:[^"\\]|\\.)*"|[\[\]{}]')
LISTEN_BACKLOG = 128  # connections the kernel holds before the server accepts them (http.server's 5 resets a burst)
MAX_WAITING = 64      # requests timed or waiting for a slot at once; the next ones get 503 at once
MAX_CONNECTIONS = 256  # connections with a thread at once (an idle one lets go after Handler.timeout)
RETRY_AFTER = 2       # seconds, in a 503's Retry-After


def error_line(message: str) -> str:
    """The CLI's one error line (sim.cli.app.print_error), without its newline."""
    return f"retrosim: error: {one_line(message)}"


def parse_request(req) -> dict:
    """The loop options of a request, checked as the CLI checks them; one ArgumentError otherwise."""
    from sim.guest import loop_program

    if not isinstance(req, dict):
        raise ArgumentError("the request is not a JSON object")
    unknown = set(req) - {"body", "body_b", "cpus", "sets", "memory", "syntax", "iterations", "regs", "align", "offset",
                          "timeline", "data"}
    if unknown:
        raise ArgumentError(f"unknown request field(s): {', '.join(sorted(unknown))}")

    def text(key, default=None):
        v = req.get(key, default)
        if v is not None and not isinstance(v, str):
            raise ArgumentError(f"{key}: expected text")
        return v and _unicode(key, v)

    def texts(key, most):
        v = req.get(key) or []
        if not isinstance(v, list) or not all(isinstance(x, str) and len(x) <= MAX_OPTION_CHARS for x in v) \
                or len(v) > most:
            raise ArgumentError(f"{key}: expected a list of at most {most} strings of at most {MAX_OPTION_CHARS} "
                                "characters")
        return [_unicode(key, x) for x in v]

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
    body_b = text("body_b")  # B, to compare (`loop A.s B.s`): the same bounds and checks as A's
    if body_b is not None and not body_b.strip():
        raise ArgumentError(f"{BODY_B}: no instructions in the body (leave body_b out to time A alone)")
    syntax = text("syntax") or None
    if syntax is not None and syntax not in ("intel", "att"):
        raise ArgumentError(f"--syntax {syntax}: choose intel or att")
    data = text("data") or None
    if data is not None and data not in ("cold", "warm"):
        raise ArgumentError(f"--data {data}: choose cold or warm")
    timeline = integer("timeline", 3)
    if not 0 <= timeline <= 1000:
        raise ArgumentError(f"--timeline {timeline}: must be between 0 and 1,000")
    # checked here, as the command line checks them, before any work: one line naming the option
    regs, align, offset = texts("regs", 16), integer("align", loop_program.DEFAULT_ALIGN), integer("offset", 0)
    loop_program.placement(align, offset)
    loop_program.parse_regs(regs)
    return {"text": body, "text_b": body_b, "cpus": texts("cpus", MAX_CPUS) or list(DEFAULT_CPUS),
            "sets": texts("sets", 64),
            "memory": text("memory") or None, "syntax": syntax, "iterations": integer("iterations", 100),
            "regs": regs, "align": align, "offset": offset, "timeline": timeline, "data": data}


def _unicode(key: str, value: str) -> str:
    """`value` if it can be written as UTF-8 (JSON's \\ud800 escapes a lone surrogate, which no file can
    hold): a client's text, refused as bad input rather than failing where the body is written."""
    try:
        value.encode("utf-8")
    except UnicodeEncodeError as e:
        names = {"body": "<body>", "body_b": BODY_B}
        where = (f"{names[key]}:{value.count(chr(10), 0, e.start) + 1}" if key in names
                 else f"{key}: character {e.start + 1}")
        raise ArgumentError(f"{where}: a lone UTF-16 surrogate ({value[e.start]!r}) is no character") from None
    return value


def compute(req) -> dict:
    """Time one request's body, or its two (A and B, compared as `retrosim loop A.s B.s` compares
    them), in the child: the page's data, or the one-line error and its HTTP status. A body is a
    client's, not the user's: it may read no file (asm.served_sources)."""
    from sim.cli.kernel_cmds import loop_document, page_section
    from sim.guest import asm
    from sim.reports import compare, pipeline_html

    try:
        o = parse_request(req)
        bodies = [("<body>", o["text"])] + ([(BODY_B, o["text_b"])] if o["text_b"] is not None else [])
        runs = []
        # its objects go to a folder of its own, removed with it: a client fills no disk of the user's
        # cache (an object may have 64 MB) and never meets an object the user assembled
        with asm.served_sources(), tempfile.TemporaryDirectory(prefix="retrosim-serve-") as cache:
            before = os.environ.get(asm.CACHE_ENV)
            os.environ[asm.CACHE_ENV] = cache
            try:
                for name, text in bodies:
                    _, sections = loop_document(text, name, o["cpus"], o["memory"], o["sets"], o["syntax"],
                                                o["iterations"], o["regs"], o["align"], o["offset"], o["timeline"],
                                                None, data=o["data"])
                    runs.append((name, text, sections))
            finally:
                if before is None:
                    del os.environ[asm.CACHE_ENV]
                else:
                    os.environ[asm.CACHE_ENV] = before
        answer = {}
        for key, (_, text, sections) in zip(("data", "data_b"), runs):
            doc, timings = page_section(sections)  # a whole output: its first region
            answer[key] = pipeline_html.loop_data(doc, timings, text)
        if len(runs) == 2:
            (name_a, _, sections_a), (name_b, _, sections_b) = runs
            answer["comparison"] = compare.loop_comparison(name_a, sections_a, name_b, sections_b)
        return answer
    except RetrosimError as e:
        # the command line's one line, and every assembler message in full (the line says "(+1 more)")
        messages = [one_line(m) for m in getattr(e, "messages", ())]
        return {"error": error_line(str(e)), "status": 400, **({"messages": messages} if len(messages) > 1 else {})}
    except MemoryError:
        return {"error": error_line("the request ran out of the server's memory bound (--memory-mb)"), "status": 422}


def _vm_bytes() -> int:
    """This process's address-space size (what RLIMIT_AS counts)."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")


def memory_limit_problem(memory_mb: int) -> str | None:
    """Why a child of this process cannot be given --memory-mb more address space (a hard RLIMIT_AS,
    `ulimit -v`, below what it needs: a process can lower its hard limit, never raise it), or None."""
    hard = resource.getrlimit(resource.RLIMIT_AS)[1]
    if hard == resource.RLIM_INFINITY or _vm_bytes() + (memory_mb << 20) <= hard:
        return None
    return (f"--memory-mb {memory_mb} cannot be given to a request: the server's hard address-space limit "
            f"(ulimit -v) is {hard >> 20} MB and the warm server already uses {_vm_bytes() >> 20} MB; start it "
            f"with --memory-mb {max((hard - _vm_bytes()) >> 20, 0)} or less, or under a larger ulimit -v")


def _close_sockets() -> None:
    """In a child: close every socket inherited from the server (its listening socket and other
    requests' connections), so a child the server outlives for a moment never holds its port."""
    for name in os.listdir("/proc/self/fd"):
        fd = int(name)
        try:
            if stat.S_ISSOCK(os.fstat(fd).st_mode):
                os.close(fd)
        except OSError:
            pass  # the directory's own descriptor, closed by now


class Busy(Exception):
    """No slot within the wait the server allows: answered 503 with Retry-After."""


class Worker:
    """Runs each request in a forked child of this (warm) process, with bounds."""

    def __init__(self, timeout: float, memory_mb: int, jobs: int):
        self.timeout, self.memory_mb, self.jobs = timeout, memory_mb, jobs
        self.slots = threading.BoundedSemaphore(jobs)
        self.fork_lock = threading.Lock()
        self.children: set[int] = set()  # pids of the children running (their process groups)
        self.stopping = False

    def run(self, req) -> dict:
        if not self.slots.acquire(timeout=self.timeout):
            raise Busy(f"the server is busy: no free slot within {self.timeout:g} s (--jobs {self.jobs}); "
                       "try again shortly")
        try:
            # its own --timeout from here: a body stopped at its deadline is the body's fault (422), never
            # the burst's it waited behind (that is a 503)
            return self._fork(req, time.monotonic() + self.timeout)
        finally:
            self.slots.release()

    def stop_all(self, grace: float = 1.0) -> None:
        """Stop every running child and its process group (the server is stopping): SIGTERM, so each
        removes its scratch folder and exits, then SIGKILL to what is left of each group (the
        assembler it may run) after `grace` seconds.
        The request threads reap them."""
        with self.fork_lock:
            self.stopping = True
        for sig in (signal.SIGTERM, signal.SIGKILL):
            with self.fork_lock:
                children = list(self.children)
            for pid in children:
                try:
                    os.killpg(pid, sig)
                except (ProcessLookupError, PermissionError):
                    pass
            end = time.monotonic() + grace
            while self.children and time.monotonic() < end:
                time.sleep(0.01)

    def _fork(self, req, deadline: float) -> dict:
        r, w = os.pipe()
        with self.fork_lock:  # one fork at a time; the child's limit is from the parent's size now
            if self.stopping:
                os.close(r)
                os.close(w)
                raise Busy("the server is stopping")
            limit = _vm_bytes() + (self.memory_mb << 20)
            # a stop signal must not reach the child before it has its own handlers: inherited, the
            # server's would raise inside fork's after-fork hooks (a traceback from logging's lock)
            blocked = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
            pid = os.fork()
            if pid:
                signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
                self.children.add(pid)
        if pid == 0:  # the child: bounded, answers through the pipe, never returns
            code, scratch = 0, None
            try:
                os.close(r)
                os.setpgid(0, 0)  # its own group: a stop reaches the assembler it may be running too
                # every temporary file of the request lives in one folder, which a stop removes whole
                scratch = tempfile.mkdtemp(prefix="retrosim-request-")
                tempfile.tempdir = scratch
                signal.signal(signal.SIGTERM, lambda signum, frame: _stop(scratch, signum))
                signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the server's
                signal.pthread_sigmask(signal.SIG_SETMASK, blocked)  # a stop sent meanwhile arrives now
                _close_sockets()
                try:
                    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
                    cpu = int(self.timeout) + 1
                    resource.setrlimit(resource.RLIMIT_CPU, (cpu, cpu + 1))
                    limited = None
                except ValueError as e:  # above a hard limit, which a process can lower but never raise
                    limited = memory_limit_problem(self.memory_mb) or f"cannot set the request's limits: {e}"
                try:
                    answer = compute(req) if limited is None else {"error": error_line(limited), "status": 500}
                except BaseException as e:  # noqa: BLE001  (the child must answer whatever happens)
                    answer = {"error": error_line(f"internal error: {type(e).__name__}: {e} (a library that cannot "
                                                  f"get memory fails so: the server's bound is --memory-mb "
                                                  f"{self.memory_mb})"), "status": 500}
                data = json.dumps(answer, separators=(",", ":")).encode()
                view = memoryview(data)
                while view:
                    view = view[os.write(w, view):]
            except BaseException:  # noqa: BLE001
                code = 1
            finally:
                if scratch:
                    shutil.rmtree(scratch, ignore_errors=True)
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
            try:
                if timed_out or size > MAX_ANSWER_BYTES:
                    status = _stop_group(pid)
                else:
                    _, status = os.waitpid(pid, 0)
            finally:
                with self.fork_lock:
                    self.children.discard(pid)
        if timed_out:
            return {"error": error_line(f"the request took more than {self.timeout:g} s (the server's --timeout); "
                                        "a shorter body, fewer --iterations or fewer CPUs answer sooner"),
                    "status": 422}
        if size > MAX_ANSWER_BYTES:
            return {"error": error_line(f"the answer has more than {MAX_ANSWER_BYTES >> 20} MB; time fewer CPUs"),
                    "status": 422}
        try:
            return json.loads(b"".join(chunks))
        except ValueError:
            why = (f"signal {os.WTERMSIG(status)}" if os.WIFSIGNALED(status) else f"exit status {os.WEXITSTATUS(status)}")
            return {"error": error_line(f"the request stopped without an answer ({why}): it went past the server's "
                                        f"bounds (--memory-mb {self.memory_mb}, --timeout {self.timeout:g} s)"),
                    "status": 422}


STOP_SIGNALS = {signal.SIGTERM, signal.SIGINT}


def _stop(scratch: str, signum: int) -> None:
    """A stopped request: its temporary files go and it exits at once. (Not an exception to unwind:
    one raised inside an at-fork hook, such as logging's when the child starts the assembler, is
    only printed and dropped.)"""
    shutil.rmtree(scratch, ignore_errors=True)
    os._exit(128 + signum)


def _stop_group(pid: int, grace: float = 1.0) -> int:
    """Stop a child and its process group: SIGTERM (it removes its scratch folder and exits),
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
    """Time a small loop on one CPU of every family in this process, so that children start warm
    (and load each compiled version of a core: sim.parallel.warm)."""
    from sim.cli.kernel_cmds import loop_document
    from sim.cpus import families, presets
    from sim.cpus.build import make_model
    from sim.parallel import warm

    seen = {}
    for name in presets.available():
        seen.setdefault(presets.load(name).family, name)
    for family, cpu in sorted(seen.items(), key=lambda kv: families.order(kv[0])):
        t = time.monotonic()
        say(f"warming the {family.upper()} model on {cpu} ...")
        loop_document(WARM_BODY, "<warm-up>", [cpu], None, (), None, 100, (), 64, 0, 3, None)
        warm([make_model(cpu)])
        say(f"  ready in {time.monotonic() - t:.1f} s")


def app_config() -> dict:
    from sim.cpus import families, presets
    from sim.cpus.overrides import memory_presets
    from sim.guest import loop_program
    from sim.timing import loop

    # the CPUs by family (P5, P6, K6: the order the page shows them in), then by name
    cpus = sorted(presets.available(), key=lambda c: (families.order(presets.load(c).family), c))
    return {"cpus": cpus, "memories": memory_presets(), "defaults": list(DEFAULT_CPUS), "example": EXAMPLE,
            "data": list(loop.DATA_STATES), "default_data": loop.DEFAULT_DATA,
            "aligns": [1 << k for k in range(loop_program.ALIGN_SPAN.bit_length())],
            "default_align": loop_program.DEFAULT_ALIGN}


def json_depth_problem(text: str) -> str | None:
    """One line when the request nests arrays or objects deeper than MAX_JSON_DEPTH (json.loads
    recurses once per level: 100,000 '[' would overflow the stack), else None."""
    depth = 0
    for m in _JSON_TOKEN.finditer(text):
        token = m.group(0)
        if token in ("[", "{"):
            depth += 1
            if depth > MAX_JSON_DEPTH:
                return f"the request nests arrays or objects more than {MAX_JSON_DEPTH} deep; a loop request is flat"
        elif token in ("]", "}"):
            depth -= 1
    return None


def allowed_hosts(local: tuple) -> set[str]:
    """The Host values a request to the local address `local` (the socket's own) may carry: that
    address with its port, or `localhost` with it when the address is a loopback one. A name that
    only resolves to it (a rebinding name such as 127.0.0.1.rebind.example) is never one of them."""
    address, port = local[0], local[1]
    names = {f"[{address}]" if ":" in address else address}
    if ipaddress.ip_address(address).is_loopback:
        names.add("localhost")
    return {f"{n}:{port}" for n in names} | (names if port == 80 else set())


def make_handler(worker: Worker, page: bytes):
    from http.server import BaseHTTPRequestHandler  # here: every other command starts without it

    waiting = threading.BoundedSemaphore(MAX_WAITING)  # requests timed or waiting for a slot

    class Handler(BaseHTTPRequestHandler):
        server_version = "retrosim"
        quiet = False
        timeout = 60  # seconds a connection may idle (a client that never sends its request lets go)

        def log_message(self, fmt, *args):  # one line per request on stderr, as http.server does
            if not self.quiet:
                super().log_message(fmt, *args)

        def handle(self):
            try:
                super().handle()
            except (ConnectionError, TimeoutError) as e:  # the client went away: a line, not a traceback
                self.log_message("client went away (%s)", type(e).__name__)

        def _send(self, status: int, body: bytes, ctype: str, headers: dict | None = None) -> None:
            self.send_response(status)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.send_header("X-Content-Type-Options", "nosniff")
            for k, v in (headers or {}).items():
                self.send_header(k, v)
            self.end_headers()
            self.wfile.write(body)

        def _json(self, status: int, answer: dict, headers: dict | None = None) -> None:
            self._send(status, json.dumps(answer, separators=(",", ":")).encode(), "application/json", headers)

        def _origin_ok(self) -> bool:
            """The Host must name this server (DNS rebinding: a page of another site that re-points
            its own name at this address still names its own name); a POST's Origin, when the
            browser sends one, must be this server's own page (a cross-site request is refused)."""
            ok = allowed_hosts(self.connection.getsockname())
            host = (self.headers.get("Host") or "").strip().lower()
            if host not in ok:
                self._json(403, {"error": error_line(f"Host {host!r}: this server answers {' or '.join(sorted(ok))} "
                                                     "only")})
                return False
            origin = self.headers.get("Origin")
            own = {f"http://{h}" for h in ok}
            if self.command == "POST" and origin is not None and origin.strip().lower() not in own:
                self._json(403, {"error": error_line(f"Origin {origin!r}: only this server's own page may post to it")})
                return False
            return True

        def do_GET(self):
            if not self._origin_ok():
                return
            path = self.path.split("?", 1)[0]
            if path in ("/", "/index.html"):
                self._send(200, page, "text/html; charset=utf-8")
            elif path == "/api/health":
                self._json(200, {"ok": True})
            else:
                self._json(404, {"error": error_line(f"{path}: no such page")})

        def do_POST(self):
            if not self._origin_ok():
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
                text = raw.decode("utf-8")
                problem = json_depth_problem(text)
                req = None if problem else json.loads(text)
            except (UnicodeDecodeError, ValueError) as e:
                problem = f"the request is not JSON ({e})"
            if problem:
                self._json(400, {"error": error_line(problem)})
                return
            t = time.monotonic()
            if not waiting.acquire(blocking=False):
                self._json(503, {"error": error_line(f"the server is busy: {MAX_WAITING} requests are timed or "
                                                     "waiting; try again shortly")}, {"Retry-After": str(RETRY_AFTER)})
                return
            try:
                answer = worker.run(req)
            except Busy as e:
                self._json(503, {"error": error_line(str(e))}, {"Retry-After": str(RETRY_AFTER)})
                return
            finally:
                waiting.release()
            answer["ms"] = round(1000 * (time.monotonic() - t), 1)
            status = answer.pop("status", 200)
            if status >= 500:  # the server's fault, not the body's: said in its log too
                self.log_error("%s", answer.get("error"))
            self._json(status, answer)

    return Handler


def _bounded_server(host: str, port: int, handler):
    """The HTTP server: a listen queue that holds a burst of connections (the default of 5 resets
    the rest), and a thread for each of at most MAX_CONNECTIONS connections at once (the next get 503
    and are closed at once; below that, a request past MAX_WAITING gets its 503 from the handler)."""
    from http.server import ThreadingHTTPServer

    class Server(ThreadingHTTPServer):
        request_queue_size = LISTEN_BACKLOG
        address_family = socket.AF_INET6 if ":" in host else socket.AF_INET
        daemon_threads = True
        allow_reuse_address = True  # SO_REUSEADDR: a restart binds at once, whatever TIME_WAIT the last run left

        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.waiting = threading.BoundedSemaphore(MAX_CONNECTIONS)

        def process_request(self, request, client_address):
            if not self.waiting.acquire(blocking=False):
                _refuse_busy(request)
                self.shutdown_request(request)
                return
            super().process_request(request, client_address)

        def process_request_thread(self, request, client_address):
            try:
                super().process_request_thread(request, client_address)
            finally:
                self.waiting.release()

    return Server((host, port), handler, bind_and_activate=False)


def _refuse_busy(request) -> None:
    body = json.dumps({"error": error_line(f"the server is busy: {MAX_CONNECTIONS} connections are open; "
                                           "try again shortly")}).encode()
    head = (f"HTTP/1.0 503 Service Unavailable\r\nContent-Type: application/json\r\nContent-Length: {len(body)}\r\n"
            f"Retry-After: {RETRY_AFTER}\r\nConnection: close\r\n\r\n").encode()
    try:
        request.settimeout(1)
        request.sendall(head + body)
    except OSError:
        pass


def serve(host: str, port: int, timeout: float, memory_mb: int, jobs: int, quiet: bool = False,
          say=lambda line: None, allow_remote: bool = False) -> None:
    from sim.reports import pipeline_html

    worker = Worker(timeout, memory_mb, jobs)
    page = pipeline_html.page(None, app=app_config()).encode()
    handler = make_handler(worker, page)
    handler.quiet = quiet
    # listen before the warm-up (up to a minute while numba compiles): a port in use fails at once
    try:
        httpd = _bounded_server(host, port, handler)
        httpd.server_bind()
    except OSError as e:
        raise RetrosimError(f"cannot listen on {host}:{port}: {e.strerror or e}") from None
    try:
        address = httpd.socket.getsockname()[0]
        if not ipaddress.ip_address(address).is_loopback:
            if not allow_remote:
                raise ArgumentError(f"--host {host!r} listens on {address}, which other machines can reach: anyone "
                                    "who can reach it may time bodies on this machine's CPU and memory; add "
                                    "--allow-remote if that is what you want")
            click.echo(f"retrosim: warning: --allow-remote: listening on {address}: every machine that can reach "
                       f"it may time bodies here ({jobs} at a time, {timeout:g} s and {memory_mb} MB each), with no "
                       "password and no encryption; a body still reads no file", err=True)
        httpd.server_activate()
    except BaseException:
        httpd.server_close()
        raise
    url_host = f"[{host}]" if ":" in host else host or address
    try:
        warm_up(say)  # requests wait in the listen queue meanwhile; the address is printed once warm
        problem = memory_limit_problem(memory_mb)
        if problem:
            raise RetrosimError(problem)
        click.echo(f"retrosim serve: http://{url_host}:{httpd.server_address[1]}/ (Ctrl-C stops it)")
        sys.stdout.flush()
        httpd.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        httpd.server_close()  # the port is free once this returns: no child holds it (_close_sockets)
        worker.stop_all()


@main.command("serve")
@click.option("--host", default="127.0.0.1", show_default=True,
              help="address to listen on (the default answers this machine only; any other needs --allow-remote)")
@click.option("--allow-remote", is_flag=True,
              help="allow an address other machines can reach (they may then time bodies here; no password)")
@click.option("--port", default=8022, show_default=True, callback=bounded(0, 65535), help="TCP port (0: any free one)")
@click.option("--timeout", default=20.0, show_default=True, type=float,
              help="seconds one request may run, after waiting at most as long for a slot (else 503); then it is "
                   "stopped")
@click.option("--memory-mb", default=2048, show_default=True, callback=bounded(64, 1 << 20),
              help="address space one request may add to the warm server (MB)")
@click.option("--jobs", default=2, show_default=True, callback=bounded(1, 64), help="requests timed at once")
@click.option("--quiet", is_flag=True, help="no line per request on stderr")
def serve_cmd(host, allow_remote, port, timeout, memory_mb, jobs, quiet):
    """A local web app: paste a loop body, pick CPUs, see the pipeline view (warm models, ms answers)."""
    from sim.cli.app import say

    if not 0.1 <= timeout <= 3600:
        raise ArgumentError(f"--timeout {timeout:g}: must be between 0.1 and 3,600 seconds")
    serve(host, port, timeout, memory_mb, jobs, quiet, say, allow_remote)
