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
