"""retrosim sweep: a small kernel sweep on a 2-worker Dask LocalCluster equals the serial run
exactly; a resumed sweep recomputes nothing; a failed point is recorded and the rest still run."""

import pytest
from click.testing import CliRunner

from sim.cli import main
from sim.sweep import SweepError, load_spec, read_rows, run_sweep

SPEC = """[sweep]
cpus = ["pentium2-233", "k6-233"]
[[sweep.kernels]]
source = "zbuffer/fp16z.S"
entry = "fp16z_span"
args = "buf:u16:256:0xFFFF,buf:u16:256,256,0x10000000,0x100000,0x1234"
[[sweep.kernels]]
source = "zbuffer/z32.S"
entry = "z32_span"
args = "buf:u32:256:0xFFFFFFFF,buf:u16:256,256,0x10000000,0x100000,0x1234"
repeat = 2
[grid]
"l2.size_kb" = ["none", 128, 384]
"""


@pytest.fixture
def spec(tmp_path):
    path = tmp_path / "tiny.toml"
    path.write_text(SPEC)
    return load_spec(path)


def test_local_cluster_equals_serial_and_resume_recomputes_nothing(spec, tmp_path):
    serial = run_sweep(spec, tmp_path / "serial", "serial", plots=False)
    assert serial.computed == len(spec.points) == 2 * 2 * 3
    dask = run_sweep(spec, tmp_path / "dask", "local", jobs=2)
    assert dask.computed == len(spec.points)
    assert read_rows(tmp_path / "dask") == read_rows(tmp_path / "serial")
    assert (tmp_path / "dask.csv").read_bytes() == (tmp_path / "serial.csv").read_bytes()
    assert (tmp_path / "dask-l2-size_kb.png").is_file() and (tmp_path / "dask-cpu.png").is_file()

    before = (tmp_path / "serial.parquet").read_bytes()
    again = run_sweep(spec, tmp_path / "serial", "serial", plots=False)
    assert again.computed == 0 and again.rows == read_rows(tmp_path / "serial")
    assert (tmp_path / "serial.parquet").read_bytes() == before


def test_failed_point_is_recorded_and_the_sweep_goes_on(spec, tmp_path):
    rows = run_sweep(spec, tmp_path / "out", "serial", plots=False).rows
    failed = [r for r in rows if r["error"]]
    # 384 KB is no cache for the P6's 4-way or the K6-233 board's direct-mapped 32-byte-line L2
    assert {r["set.l2.size_kb"] for r in failed} == {"384"} and len(failed) == 4
    assert all("power-of-two" in r["error"] for r in failed)
    ok = [r for r in rows if not r["error"]]
    assert len(ok) == 8 and all(r["cycles"] > 0 for r in ok)
    assert {r["machine"] for r in ok} == {"pentium2-233{l2.present=false}", "pentium2-233{l2.size_kb=128}",
                                          "k6-233{l2.present=false}", "k6-233{l2.size_kb=128}"}
    # only the failed ones are run again on request
    assert run_sweep(spec, tmp_path / "out", "serial", plots=False, retry_failed=True).computed == 4


def test_bad_spec_is_one_error_line(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(SPEC.replace('cpus = ["pentium2-233", "k6-233"]', 'cpus = ["pentium9"]'))
    with pytest.raises(SweepError, match=r"bad\.toml: sweep\.cpus\[0\]: unknown CPU preset 'pentium9'"):
        load_spec(path)
    r = CliRunner().invoke(main, ["sweep", str(path), "--scheduler", "serial"], catch_exceptions=False)
    assert r.exit_code == 2


SNAP_SCENE = """[scene]
name = "snap-sweep"
kind = "snap"
[workloads]
names = ["screen"]
vertices = 32
seed = 7
[run]
variants = ["trick-24", "portable-64"]
cpus = ["pentium-133", "k6-2-300"]
"""


def test_a_snap_scene_sweeps_with_the_cycles_its_own_run_reports(tmp_path):
    """A sweep over a scene of another kind than Z-buffer times the same emulation the scene's run
    times: with no overrides its points' counters equal the scene's baseline entries."""
    from sim.scenes import baseline
    from sim.scenes.registry import load_scene, run_scene

    scene_path = tmp_path / "snap-sweep.toml"
    scene_path.write_text(SNAP_SCENE)
    spec_path = tmp_path / "s.toml"
    spec_path.write_text(f'[sweep]\nscenes = ["{scene_path}"]\nvariants = ["portable-64"]\n'
                         'cpus = ["pentium-133", "k6-2-300"]\n[grid]\n"l1d.latency_cycles" = [1, 3]\n'
                         '[[point]]\nset = {}\n')
    spec = load_spec(spec_path)
    rows = run_sweep(spec, tmp_path / "out", "serial", plots=False).rows
    assert len(rows) == 2 * 3 and not any(r["error"] for r in rows)
    assert {r["scene"] for r in rows} == {"snap-sweep"} and all(r["pixels"] == 32 for r in rows)
    cases = baseline.entries(run_scene(load_scene(scene_path), robustness=False))
    plain = {f"portable-64@{r['cpu']}:{r['memory']}": r for r in rows if r["machine"] == r["cpu"]}
    assert len(plain) == 2
    for case, row in plain.items():
        assert {c: row[c] for c in cases[case]} == cases[case]
    # the overridden points run on the overridden machines, and the override changes the count
    assert {r["machine"] for r in rows if r["set.l1d.latency_cycles"] == "3"} == {
        "pentium-133{l1d.latency_cycles=3}", "k6-2-300{l1d.latency_cycles=3}"}
    slow = {r["cpu"]: r["cycles"] for r in rows if r["set.l1d.latency_cycles"] == "3"}
    plain_cycles = {r["cpu"]: r["cycles"] for r in plain.values()}
    assert slow != plain_cycles


def test_a_sort_scene_sweep_says_cycles_per_key(tmp_path):
    """A sort scene's unit of work is a key: the table and the findings say cycles per key, never
    per pixel (its rows' `pixels` are keys)."""
    from sim.sweep import findings, results_table

    spec_path = tmp_path / "s.toml"
    spec_path.write_text('[sweep]\nscenes = ["sort"]\nvariants = ["radix8", "quicksort"]\ncpus = ["k6-2-300"]\n'
                         'compare = ["radix8", "quicksort"]\n[grid]\n"l1d.latency_cycles" = [1, 3]\n')
    spec = load_spec(spec_path)
    rows = run_sweep(spec, tmp_path / "out", "serial", plots=False).rows
    assert not any(r["error"] for r in rows)
    text = "\n".join(results_table(spec, rows) + findings(spec, rows))
    assert "cycles per key" in text and "pixel" not in text, text


def test_the_sweep_module_imports_without_the_command_line():
    """Dask workers import sim.sweep: it must not pull in click or rich (the CLI's libraries)."""
    import subprocess
    import sys

    code = "import sys, sim.sweep; print(sorted(m for m in ('click', 'rich', 'sim.cli') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


LATENCY_SPEC = """[sweep]
cpus = ["pentium2-233", "k6-233", "pentium-mmx-233"]
[[sweep.kernels]]
source = "zbuffer/fp16z.S"
entry = "fp16z_span"
args = "buf:u16:4096:0xFFFF,buf:u16:4096,4096,0x10000000,0x10000,0x1234"
[grid]
"memory.overhead_bus_clocks" = [4, 9, 14]
"""


def test_points_on_the_same_data_caches_share_one_walk_and_time_as_alone(tmp_path, monkeypatch):
    """A grid over a latency: each family's points replay the first one's cache walk (one record,
    two replays each for the P6 and the K6), and every point's counters equal its own run's."""
    from sim.cpus.build import make_model
    from sim.cpus.machine import resolve
    from sim.memory import replay
    from sim.sweep import _emulation, run_group
    from sim.timing.kernel import time_emulation

    path = tmp_path / "latency.toml"
    path.write_text(LATENCY_SPEC)
    spec = load_spec(path)
    starts = []
    real_start = replay.AccessLogs.start

    def start(self, *a):
        log = real_start(self, *a)
        starts.append((a[0], int(log[0])))
        return log

    monkeypatch.setattr(replay.AccessLogs, "start", start)
    (group,) = spec.groups
    rows = run_group(group)
    modes = {fam: [m for f, m in starts if f == fam] for fam in ("p6", "k6")}
    assert all(m == [replay.LOG_RECORD, replay.LOG_REPLAY, replay.LOG_REPLAY] for m in modes.values()), starts
    emulation, _ = _emulation(group)
    for p, row in zip(group["points"], rows):
        alone = time_emulation(emulation, make_model(resolve(p["cpu"], p["set"], p["memory"]))).last
        assert not row["error"] and all(row[k] == v for k, v in alone.items()), p
