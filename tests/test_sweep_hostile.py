"""Hostile and careless input to `retrosim sweep` (issues 25 and 26): bad specs, damaged outputs,
scheduler addresses, huge sweeps and concurrent runs each end with exit status 2 and one line on
stderr, within a bounded time; a point's id holds everything that determines its counters; kernels
with MMX/3DNow!/SSE sweep on the CPUs that have them; a sweep with failed points exits 2."""

from __future__ import annotations

import shutil
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from click.testing import CliRunner

from sim import sweep
from sim.cli import main

# a kernel whose cycles grow with its argument: two calls differing only in `args` must differ
COUNT = ".intel_syntax noprefix\n.text\n.globl count\ncount:\n    mov ecx, [esp+4]\n1:  dec ecx\n    jnz 1b\n" \
        "    ret\n"
MMX = ".intel_syntax noprefix\n.text\n.globl mmx\nmmx:\n    pxor mm0, mm0\n    movq mm1, mm0\n    paddw mm0, mm1\n" \
      "    emms\n    ret\n"


@pytest.fixture(autouse=True)
def own_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("RETROSIM_CACHE", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)


def fails(*args) -> str:
    """Run the CLI in-process: exit 2, no traceback, one stderr line, within 20 s. Returns it."""
    start = time.monotonic()
    r = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=True)
    assert time.monotonic() - start < 20
    assert r.exit_code == 2, (r.exit_code, r.output, r.exception)
    assert isinstance(r.exception, SystemExit), r.exception
    assert "Traceback" not in r.output
    lines = [ln for ln in r.stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("retrosim: error: "), r.stderr
    return lines[0]


def spec_file(tmp_path: Path, text: str, name: str = "s.toml") -> Path:
    (tmp_path / "count.S").write_text(COUNT)
    path = tmp_path / name
    path.write_text(text)
    return path


KERNEL = '[[sweep.kernels]]\nsource = "count.S"\nentry = "count"\nargs = "{n}"\nrepeat = 1\n'


def kernel_spec(tmp_path, cpus='["pentium-133"]', grid="", kernels=(5,), name="s.toml") -> Path:
    body = f"[sweep]\ncpus = {cpus}\n" + "".join(KERNEL.format(n=n) for n in kernels) + grid
    return spec_file(tmp_path, body, name)


# -- the spec ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("raw", [b"\xff\xfe\x00\x01binary\x00", "[sweep]\ncpus = [\"k6-233\"] # caf\xe9\n".encode("latin-1")])
def test_a_binary_or_latin1_spec_is_one_line(tmp_path, raw):
    path = tmp_path / "s.toml"
    path.write_bytes(raw)
    assert "s.toml: not UTF-8 text" in fails("sweep", path, "--scheduler", "serial")


@pytest.mark.parametrize("value", ["inf", "nan", "-inf"])
def test_a_non_finite_grid_value_is_one_line(tmp_path, value):
    path = kernel_spec(tmp_path, grid=f'[grid]\n"l2.size_kb" = [128, {value}]\n')
    assert f"grid.l2.size_kb[1]: {float(value)!r} is not a finite number" in fails("sweep", path)
    path = kernel_spec(tmp_path, grid=f'[[point]]\nset = {{ "l2.size_kb" = {value} }}\n')
    assert "point[0].set.l2.size_kb: " in fails("sweep", path)


def test_repeated_grid_values_cpus_and_points_are_refused(tmp_path):
    path = kernel_spec(tmp_path, grid='[grid]\n"l2.size_kb" = [128, 128, 128.0]\n')
    assert "grid.l2.size_kb[1]: value 128 repeats 128" in fails("sweep", path)
    path = kernel_spec(tmp_path, grid='[grid]\n"l2.size_kb" = [128, 128.0]\n')
    assert "grid.l2.size_kb[1]: value 128.0 repeats 128" in fails("sweep", path)
    path = kernel_spec(tmp_path, cpus='["k6-233", "pentium-133", "k6-233"]')
    assert "sweep.cpus[2]: 'k6-233' is listed twice" in fails("sweep", path)
    path = kernel_spec(tmp_path, kernels=(5, 5))
    assert "sweep.kernels: the point " in fails("sweep", path)
    path = kernel_spec(tmp_path, grid='[grid]\n"l2.size_kb" = [128]\n[[point]]\nset = { "l2.size_kb" = 128 }\n')
    assert "point: the point " in fails("sweep", path)


def test_huge_sweeps_are_refused_before_any_work_unless_asked(tmp_path):
    values = ", ".join(str(v) for v in range(1000))
    path = kernel_spec(tmp_path, grid=f'[grid]\n"l1d.latency_cycles" = [{values}]\n"l2.latency_cycles" = [{values}]\n')
    line = fails("sweep", path)
    assert "at least 1,000,000 points to run, more than the limit of 10,000" in line and "--max-points" in line
    path = kernel_spec(tmp_path, grid=f'[grid]\n"l1d.latency_cycles" = [{values}]\n'
                                      f'"l2.latency_cycles" = [{values}]\n')
    # a limit the user raises is honoured; still refused past it
    assert "limit of 999,999" in fails("sweep", path, "--max-points", 999_999)
    for repeat in (10**8, 10**12):
        path = spec_file(tmp_path, f'[sweep]\ncpus = ["k6-233"]\n[[sweep.kernels]]\nsource = "count.S"\n'
                                   f'entry = "count"\nargs = "5"\nrepeat = {repeat}\n')
        assert "sweep.kernels[0].repeat: expected an integer from 1 to 10,000" in fails("sweep", path)


# -- identity ----------------------------------------------------------------------------------------

def test_a_points_id_holds_the_kernels_arguments_and_repeat(tmp_path):
    spec = sweep.load_spec(kernel_spec(tmp_path, kernels=(5, 500)))
    assert len({p["point"] for p in spec.points}) == 2
    rows = sweep.run_sweep(spec, tmp_path / "out", "serial", plots=False).rows
    assert not any(r["error"] for r in rows)
    by_args = {r["args"]: r["cycles"] for r in rows}
    assert set(by_args) == {"5", "500"} and by_args["500"] > by_args["5"]
    # changing the arguments is a new point: computed, not served from the old row
    again = sweep.run_sweep(sweep.load_spec(kernel_spec(tmp_path, kernels=(50,))), tmp_path / "out", "serial",
                            plots=False)
    assert again.computed == 1
    new = next(r for r in again.rows if r["args"] == "50")
    assert by_args["5"] < new["cycles"] < by_args["500"]
    # and so is changing the number of calls
    text = (tmp_path / "s.toml").read_text().replace("repeat = 1", "repeat = 2")
    (tmp_path / "s.toml").write_text(text)
    assert sweep.run_sweep(sweep.load_spec(tmp_path / "s.toml"), tmp_path / "out", "serial",
                           plots=False).computed == 1


# -- damaged outputs -----------------------------------------------------------------------------------

def _damage(base: Path, how: str) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    parquet = base.with_suffix(".parquet")
    table = pq.read_table(parquet)
    if how == "truncated":
        parquet.write_bytes(parquet.read_bytes()[:len(parquet.read_bytes()) // 2])
    elif how == "garbage":
        parquet.write_bytes(b"PAR1" + bytes(range(256)) * 4)
    elif how == "wrong types":
        pq.write_table(table.set_column(table.schema.get_field_index("cycles"), "cycles",
                                        pa.array([str(v) for v in table["cycles"].to_pylist()])), parquet)
    elif how in ("no point", "no scene"):
        pq.write_table(table.drop([how.split()[1]]), parquet)
    elif how == "point not an id":
        pq.write_table(table.set_column(0, "point", pa.array(["x"] * table.num_rows)), parquet)
    elif how == "csv only":
        parquet.unlink()
    elif how in ("null cycles", "negative cycles", "negative instructions", "null error"):  # issue 31
        column = "error" if how == "null error" else how.split()[1]
        values = table[column].to_pylist()
        values[0] = None if how.startswith("null") else -1292
        pq.write_table(table.set_column(table.schema.get_field_index(column), column,
                                        pa.array(values, table.schema.field(column).type)), parquet)


@pytest.mark.parametrize("how", ["truncated", "garbage", "wrong types", "no point", "no scene", "point not an id",
                                 "csv only", "null cycles", "negative cycles", "negative instructions", "null error"])
def test_a_damaged_output_is_refused_with_how_to_start_over(tmp_path, how):
    path = kernel_spec(tmp_path)
    base = tmp_path / "s"
    sweep.run_sweep(sweep.load_spec(path), base, "serial", plots=False)
    _damage(base, how)
    before = {p.name: p.read_bytes() for p in tmp_path.glob("s.*")}
    line = fails("sweep", path, "--scheduler", "serial")
    assert "not resuming from it" in line or "not overwriting it" in line
    assert "to start the sweep over" in line
    assert {p.name: p.read_bytes() for p in tmp_path.glob("s.*")} == before  # nothing merged or replaced


def test_a_table_that_decodes_to_too_much_is_refused_before_decoding(tmp_path, monkeypatch):
    # issue 31: a 1 MB Parquet file of 80 million repeated rows took 3 GB to decode; the footer says
    # how many rows and columns it holds, so it is refused before a row is decoded
    import pyarrow.parquet as pq

    path = kernel_spec(tmp_path)
    base = tmp_path / "s"
    sweep.run_sweep(sweep.load_spec(path), base, "serial", plots=False)
    parquet = base.with_suffix(".parquet")
    table = pq.read_table(parquet)
    rows = sweep.MAX_TABLE_CELLS // table.num_columns + 1
    pq.write_table(table.take([0] * rows), parquet)
    assert parquet.stat().st_size < 1 << 20
    decoded, iter_batches = [], pq.ParquetFile.iter_batches
    monkeypatch.setattr(pq.ParquetFile, "iter_batches", lambda *a, **k: decoded.append(1) or iter(()))
    line = fails("sweep", path, "--scheduler", "serial")
    assert f"{rows:,} rows of {table.num_columns} columns" in line and "cells" in line
    assert not decoded
    monkeypatch.setattr(pq.ParquetFile, "iter_batches", iter_batches)
    # and the bytes it decodes to are counted as it goes (one long string in every row)
    pq.write_table(table, parquet)
    monkeypatch.setattr(sweep, "MAX_DECODED_BYTES", 64)
    assert "once decoded" in fails("sweep", path, "--scheduler", "serial")


# -- scheduler addresses ----------------------------------------------------------------------------------

@pytest.mark.parametrize("address,expected", [
    ("tls://127.0.0.1:8786", "tls:// is not supported"),
    ("inproc://x", "inproc:// is not supported"),
    ("tcp://", "expected tcp://HOST:PORT"),
    ("tcp://127.0.0.1", "expected tcp://HOST:PORT"),
    ("tcp://[::1", "expected tcp://HOST:PORT"),
    ("tcp://127.0.0.1:18765/../x", "with nothing after the port"),
    ("tcp://127.0.0.1:99999", "port 99999 is not between 1 and 65535"),
    ("http://127.0.0.1:80", "http:// is not supported"),
    ("127.0.0.1:8786", "expected local, serial or tcp://HOST:PORT"),
])
def test_bad_scheduler_addresses_are_one_line(tmp_path, address, expected):
    assert expected in fails("sweep", kernel_spec(tmp_path), "--scheduler", address)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_scheduler_where_nothing_listens_fails_at_once_naming_it(tmp_path):
    address = f"tcp://127.0.0.1:{_free_port()}"
    line = fails("sweep", kernel_spec(tmp_path), "--scheduler", address)
    assert f"--scheduler {address}: cannot connect" in line


@pytest.mark.parametrize("reply", [b"HTTP/1.0 400 Bad Request\r\n\r\n" * 4, b""])
def test_a_listener_that_is_not_dask_is_one_line_within_the_timeout(tmp_path, monkeypatch, reply):
    """A listener that answers garbage (struct.error in Dask's handshake), or says nothing."""
    monkeypatch.setattr(sweep, "CONNECT_TIMEOUT", 3.0)
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    stop = threading.Event()

    def serve():
        server.settimeout(0.2)
        conns = []
        while not stop.is_set():
            try:
                c, _ = server.accept()
            except OSError:
                continue
            conns.append(c)
            if reply:
                c.sendall(reply)
        for c in conns:
            c.close()

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    try:
        start = time.monotonic()
        line = fails("sweep", kernel_spec(tmp_path), "--scheduler", f"tcp://127.0.0.1:{port}")
        assert time.monotonic() - start < 15
        assert f"--scheduler tcp://127.0.0.1:{port}: no Dask scheduler answered there" in line
    finally:
        stop.set()
        t.join(5)
        server.close()


# -- concurrent sweeps ------------------------------------------------------------------------------------

def test_a_second_sweep_into_a_locked_output_is_refused_naming_the_lock(tmp_path):
    """Two processes: this one holds the output's lock, as a running sweep does; a second `retrosim
    sweep` into the same output refuses at once, and runs once the first has finished."""
    path = kernel_spec(tmp_path)
    cmd = [sys.executable, "-m", "sim.cli", "sweep", str(path), "--scheduler", "serial"]
    with sweep.output_lock(tmp_path / "s") as lock:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=tmp_path)
        assert r.returncode == 2, r.stderr
        lines = [ln for ln in r.stderr.splitlines() if ln.startswith("retrosim: error: ")]
        assert len(lines) == 1 and "Traceback" not in r.stderr
        assert f"{lock}: another sweep" in lines[0] and "wait for it to finish" in lines[0]
        assert not (tmp_path / "s.parquet").exists()
    assert not lock.exists()  # released and removed
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert len(sweep.read_rows(tmp_path / "s")) == 1


def test_two_concurrent_sweeps_keep_every_row_or_the_second_refuses(tmp_path):
    """Two sweeps of different points into one output started together: either both finish with
    every point in the table, or one refuses with the lock line (exit 2) and its points are absent."""
    first, second = kernel_spec(tmp_path, kernels=(5,), name="a.toml"), kernel_spec(tmp_path, kernels=(7,), name="b.toml")
    procs = [subprocess.Popen([sys.executable, "-m", "sim.cli", "sweep", str(p), "--scheduler", "serial", "--out",
                               str(tmp_path / "out")], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              cwd=tmp_path) for p in (first, second)]
    results = [(p.wait(timeout=180), p.stderr.read()) for p in procs]
    rows = {r["args"] for r in sweep.read_rows(tmp_path / "out")}
    for (code, err), n in zip(results, ("5", "7")):
        if code == 0:
            assert n in rows
        else:
            assert code == 2 and "another sweep" in err and n not in rows
    assert any(code == 0 for code, _ in results)


# -- instruction sets, failures and the report ------------------------------------------------------------------

def test_an_mmx_kernel_sweeps_on_the_cpus_that_have_mmx(tmp_path):
    (tmp_path / "mmx.S").write_text(MMX)
    path = tmp_path / "m.toml"
    path.write_text('[sweep]\ncpus = ["pentium-mmx-233", "k6-233", "pentium-133"]\n'
                    '[[sweep.kernels]]\nsource = "mmx.S"\nentry = "mmx"\n')
    rows = {r["cpu"]: r for r in sweep.run_sweep(sweep.load_spec(path), tmp_path / "m", "serial", plots=False).rows}
    assert rows["pentium-mmx-233"]["error"] == "" and rows["pentium-mmx-233"]["cycles"] > 0
    assert rows["k6-233"]["error"] == "" and rows["k6-233"]["cycles"] > 0
    assert "not supported" in rows["pentium-133"]["error"] or "mmx" in rows["pentium-133"]["error"].lower()


def test_a_sweep_with_failed_points_exits_2_with_the_first_errors_and_no_empty_plot(tmp_path):
    path = kernel_spec(tmp_path, grid='[grid]\n"l2.size_kb" = [384, 768]\n')  # no power-of-two cache: all fail
    r = CliRunner().invoke(main, ["sweep", str(path), "--scheduler", "serial"], catch_exceptions=True)
    assert r.exit_code == 2 and isinstance(r.exception, SystemExit)
    assert "Traceback" not in r.output and "warn" not in r.stderr.lower()
    assert r.stderr.count("failed: count.S:count pentium-133") == 2 and "power-of-two" in r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith("retrosim: error: 2 of 2 point(s) failed")
    assert not list(tmp_path.glob("*.png")) and not (tmp_path / "s.md").exists()
    assert all(row["error"] for row in sweep.read_rows(tmp_path / "s"))  # the reasons are kept in the table


def test_the_report_has_a_results_table_and_legends_naming_the_kernel(tmp_path, monkeypatch):
    path = kernel_spec(tmp_path, cpus='["pentium-133", "k6-233"]', kernels=(5, 50),
                       grid='[grid]\n"l2.size_kb" = [128, 384]\n')
    labels = []
    import matplotlib.axes

    real = matplotlib.axes.Axes.plot
    monkeypatch.setattr(matplotlib.axes.Axes, "plot",
                        lambda self, *a, **k: labels.append(k.get("label")) or real(self, *a, **k))
    result = sweep.run_sweep(sweep.load_spec(path), tmp_path / "s", "serial")
    md = (tmp_path / "s.md").read_text()
    assert "## Results" in md
    table = [ln for ln in md.splitlines() if ln.startswith("| count.S:count(")]
    assert len(table) == len(result.rows) == 8
    ok = [r for r in result.rows if not r["error"]]
    for r in ok:
        assert any(f"| {r['cycles']:,} |" in ln and f"({r['args']})" in ln and r["cpu"] in ln for ln in table)
    assert sum("power-of-two" in ln for ln in table) == 4
    assert labels and all(lab.startswith("count.S:count(") for lab in labels)


# -- a point's inputs: a changed file is recomputed, never served from the old row --------------------

INCLUDING = ".intel_syntax noprefix\n.text\n.globl count\ncount:\n    mov ecx, [esp+4]\n.include \"body.inc\"\n    ret\n"


def _run(tmp_path, spec_path):
    return sweep.run_sweep(sweep.load_spec(spec_path), tmp_path / "out", "serial", plots=False)


def test_editing_a_kernel_or_its_include_recomputes_its_points(tmp_path):
    path = kernel_spec(tmp_path, kernels=(200,))
    (tmp_path / "count.S").write_text(INCLUDING)
    (tmp_path / "body.inc").write_text("1:  dec ecx\n    jnz 1b\n")
    first = _run(tmp_path, path)
    assert first.computed == 1 and not first.rows[0]["error"] and first.rows[0]["fingerprint"]
    unchanged = _run(tmp_path, path)  # nothing edited: nothing computed
    assert (unchanged.computed, unchanged.changed) == (0, 0)
    assert unchanged.rows[0]["cycles"] == first.rows[0]["cycles"]
    # the include's loop now does twice the work per iteration: the old figure must not be served
    (tmp_path / "body.inc").write_text("1:  imul eax, eax\n    imul eax, eax\n    dec ecx\n    jnz 1b\n")
    edited = _run(tmp_path, path)
    assert (edited.computed, edited.changed) == (1, 1)
    assert edited.rows[0]["cycles"] > first.rows[0]["cycles"]
    assert edited.rows[0]["fingerprint"] != first.rows[0]["fingerprint"]
    # and an edit of the kernel source itself
    (tmp_path / "count.S").write_text(COUNT)
    source_edited = _run(tmp_path, path)
    assert (source_edited.computed, source_edited.changed) == (1, 1)
    assert source_edited.rows[0]["cycles"] < edited.rows[0]["cycles"]
    assert _run(tmp_path, path).computed == 0


def test_a_table_without_fingerprints_stays_readable_and_its_points_are_recomputed(tmp_path):
    import pyarrow.parquet as pq

    path = kernel_spec(tmp_path, kernels=(5, 50))
    _run(tmp_path, path)
    parquet = tmp_path / "out.parquet"
    pq.write_table(pq.read_table(parquet).drop(["fingerprint"]), parquet)  # as written before fingerprints
    assert len(sweep.read_rows(tmp_path / "out")) == 2
    again = _run(tmp_path, path)
    assert (again.computed, again.changed) == (2, 2)
    assert all(r["fingerprint"] for r in sweep.read_rows(tmp_path / "out"))


def test_the_committed_l2_sweep_table_is_still_readable():
    """This version reads the committed table as its own: one row per point of the spec beside it,
    each with the coordinates its id names, no error, whole-number counters and their per-pixel
    figure, and the CSV copy saying the same."""
    import csv

    root = Path(__file__).resolve().parent.parent / "sweeps"
    rows = sweep.read_rows(root / "l2-size")
    spec = sweep.load_spec(root / "l2-size.toml")
    assert sorted(r["point"] for r in rows) == sorted(p["point"] for p in spec.points)
    points = {p["point"]: p for p in spec.points}
    for r in rows:
        coords = points[r["point"]]["coords"]
        assert {k: str(r[k]) for k in coords} == {k: str(v) for k, v in coords.items()}, r["point"]
        assert not r["error"] and r["fingerprint"] and r["machine"].startswith(r["cpu"] + "{")
        assert isinstance(r["cycles"], int) and r["cycles"] > 0 and r["pixels"] > 0
        assert r["cycles_per_pixel"] == r["cycles"] / r["pixels"]
    with open(root / "l2-size.csv", newline="") as f:
        copy = list(csv.DictReader(f))
    assert [(c["point"], int(c["cycles"])) for c in copy] == [(r["point"], r["cycles"]) for r in rows]


def test_editing_a_scene_file_or_a_preset_changes_its_points_fingerprint(tmp_path, monkeypatch):
    from sim.cpus import presets

    scenes = Path(__file__).resolve().parent.parent / "scenes"
    scene = tmp_path / "zbuffer-small.toml"
    scene.write_bytes((scenes / "zbuffer-small.toml").read_bytes())
    spec = spec_file(tmp_path, f'[sweep]\nscenes = ["{scene}"]\ncpus = ["pentium2-233"]\n')
    before = {p["point"]: p["fingerprint"] for p in sweep.load_spec(spec).points}
    assert before and all(before.values())
    assert before == {p["point"]: p["fingerprint"] for p in sweep.load_spec(spec).points}  # deterministic
    scene.write_bytes(scene.read_bytes() + b"\n# edited\n")
    after = {p["point"]: p["fingerprint"] for p in sweep.load_spec(spec).points}
    assert after.keys() == before.keys() and all(after[k] != before[k] for k in before)
    # a CPU preset's file: a copy of the preset folder with one number changed
    shutil.copytree(presets.PRESETS, tmp_path / "presets")
    monkeypatch.setattr(presets, "PRESETS", tmp_path / "presets")
    assert {p["point"]: p["fingerprint"] for p in sweep.load_spec(spec).points} == after
    preset = tmp_path / "presets" / "pentium2-233.toml"
    preset.write_text(preset.read_text() + "\n# edited\n")
    assert all(p["fingerprint"] != after[p["point"]] for p in sweep.load_spec(spec).points)


def test_a_model_change_makes_stored_points_stale(tmp_path, monkeypatch):
    # the counters depend on the model's code and tables, not only on the scene and presets: a
    # sweep resumed after a model change must recompute (it once kept the old counters)
    model = tmp_path / "sim"
    shutil.copytree(sweep.MODEL_DIR, model, ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc"))
    before = sweep.model_hash(model)
    assert before == sweep.model_hash(model)  # deterministic
    table = model / "cpus" / "p6" / "p6_machine.toml"
    table.write_text(table.read_text().replace("entries = 40", "entries = 41", 1))
    assert sweep.model_hash(model) != before
    (model / "notes.txt").write_text("not part of the model")
    table.write_text(table.read_text().replace("entries = 41", "entries = 40", 1))
    assert sweep.model_hash(model) == before
    # a point stored by one model is recomputed by another, not served from the table
    path = kernel_spec(tmp_path, kernels=(50,))
    first = _run(tmp_path, path)
    assert first.computed == 1 and not first.rows[0]["error"]
    assert _run(tmp_path, path).computed == 0  # the same model: served
    table.write_text(table.read_text().replace("entries = 40", "entries = 41", 1))
    monkeypatch.setattr(sweep, "MODEL_DIR", model)  # the edited copy is the model now
    again = _run(tmp_path, path)
    assert (again.computed, again.changed) == (1, 1)
    assert again.rows[0]["fingerprint"] != first.rows[0]["fingerprint"]
    assert _run(tmp_path, path).computed == 0
