"""The command line: listing, running, tracing, benchmarking, and one clean error line."""

import json

import numpy as np
from click.testing import CliRunner

from sim.cli import main
from sim.guest.trace import Trace


def run(*args):
    return CliRunner().invoke(main, list(args), catch_exceptions=False)


def test_kernels_lists_every_declared_entry():
    r = run("kernels", "--json")
    assert r.exit_code == 0
    listing = json.loads(r.output)
    assert any(sig.startswith("fp16z_span(zbuf, fbuf, count, z, dz, colour)") for sig in listing["zbuffer/fp16z.S"])
    assert len(listing["convert/fp16z.S"]) == 2


def test_run_kernel_with_buffers_reports_counts_and_results():
    r = run("run-kernel", "zbuffer/z32.S", "-e", "z32_span", "--json", "--args", "buf:u32:50:0xFFFFFFFF,buf:u16:50,50,1000,10,0x4242")
    assert r.exit_code == 0, r.output
    out = json.loads(r.output)
    assert out["eax"] == 1000 + 50 * 10
    zbuf, fbuf = out["buffers"]
    assert zbuf["first"][:3] == [1000, 1010, 1020]
    assert fbuf["sum"] == 50 * 0x4242
    assert out["writes"] == 4 + 2 * 50 and out["bytes_written"] == 16 + 50 * 6


def test_float_arguments(tmp_path):
    r = run("run-kernel", "zbuffer/zf32.S", "-e", "zf32_span", "--json", "--args", "buf:f32:8:inf,buf:u16:8,8,0.5f,0.25f,7")
    assert r.exit_code == 0, r.output
    out = json.loads(r.output)
    assert out["eax"] == 8 and out["buffers"][0]["first"] == [0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.25]


def test_trace_writes_loadable_npz(tmp_path):
    out = tmp_path / "t.npz"
    r = run("trace", "convert/fp16z.S", "--entry", "fp16z_convert", "--args", "1234", "--out", str(out))
    assert r.exit_code == 0, r.output
    t = Trace.load(out)
    assert t.instructions == 6 and t.accesses == 2
    assert np.all(~t.mem_write)


def test_errors_are_one_line_with_exit_status_2(tmp_path):
    bad = tmp_path / "bad.S"
    bad.write_text(".intel_syntax noprefix\n.text\n.globl f\nf:\n  mov eax, [0x7]\n  ret\n")
    cases = [
        (("run-kernel", "zbuffer/z32.S", "-e", "z32_span", "--args", "1,2"), "takes 6 argument(s), 2 given"),
        (("run-kernel", "no/such.S"), "no such kernel source file"),
        (("run-kernel", "convert/fp16z.S", "--args", "5"), "choose an entry point with --entry"),
        (("run-kernel", "zbuffer/z32.S", "-e", "z32_span", "--args", "buf:u99:4"), "expected buf:TYPE:COUNT"),
        (("run-kernel", "zbuffer/z32.S", "-e", "z32_span", "--args", "x1"), "not an integer"),
        (("run-kernel", str(bad)), "read of unmapped or protected address 0x00000007"),
        (("trace", "convert/fp16z.S", "-e", "fp16z_convert", "--args", "1", "-o", str(tmp_path / "no" / "t.npz")),
         "does not exist"),
    ]
    for args, message in cases:
        r = CliRunner().invoke(main, list(args))
        assert r.exit_code == 2, (args, r.output)
        lines = r.output.strip().splitlines()
        assert lines[0].startswith("retrosim: error:"), r.output
        assert message in r.output.replace("\n", " "), (message, r.output)


def test_bench_json_has_the_three_figures():
    r = run("bench", "--pixels", "20000", "--json")
    assert r.exit_code == 0
    out = json.loads(r.output)
    for key in ("unicorn_bare_ips", "python_hook_ips", "native_trace_ips", "end_to_end_ips", "model_only_ips",
                "k6_model_only_ips", "p5_model_only_ips"):
        assert out[key] > 0
    assert out["end_to_end_vs_native"] == out["end_to_end_ips"] / out["native_trace_ips"]
    for prefix in ("", "k6_", "p5_"):  # every family's model alone, measured the same way
        assert out[f"{prefix}model_only_vs_native"] == out[f"{prefix}model_only_ips"] / out["native_trace_ips"]
    assert out["instructions"] > 9 * 20000  # the span loop runs 9 or 11 instructions per pixel


def test_time_json_has_the_required_keys():
    r = run("time", "micro/pipeline.S", "-e", "imul_chain", "--args", "100", "--json")
    assert r.exit_code == 0, r.output
    out = json.loads(r.output)
    for key in ("cpu", "cycles", "instructions", "uops", "l1d_misses", "l2_misses", "dram_cycles", "port0",
                "stall_dependency", "decoder0"):
        assert key in out
    assert out["cpu"] == "pentium2-233" and out["cycles"] >= 0.95 * 4 * 8 * 100


def test_explain_shows_decoders_rows_and_timeline():
    args = ("explain", "convert/loops.S", "-e", "convert_plain", "--args", "buf:u32:64:4096,buf:u16:64,64")
    r = run(*args)
    assert r.exit_code == 0, r.output
    assert "bsr" in r.output and "shrd" in r.output and "timeline" in r.output
    out = json.loads(run(*args, "--json").output)
    rows = {row["instruction"].split()[0]: row for row in out["instructions"]}
    assert rows["bsr"]["row"] == "bsr r32,r32" and rows["bsr"]["decoder_class"] == "complex"  # the table row used
    assert rows["bsr"]["uops"] == 2 and "Agner" not in rows["bsr"]["row"] and rows["bsr"]["source"]
    assert out["timeline"] and {"decode", "dispatch", "retire", "cause"} <= set(out["timeline"][0])


def test_unknown_cpu_and_scene_are_clear_errors():
    r = CliRunner().invoke(main, ["time", "micro/pipeline.S", "-e", "imul_chain", "--args", "1", "--cpu", "pentium9"])
    assert r.exit_code == 2 and "unknown CPU preset 'pentium9'" in r.output
    r = CliRunner().invoke(main, ["report", "no-such-scene"])
    assert r.exit_code == 2 and "no scene 'no-such-scene'" in r.output


def test_cpus_lists_presets_and_memory():
    r = run("cpus", "--json")
    out = json.loads(r.output)
    assert out["cpus"]["celeron-266"]["l2"] is None
    assert "128 KB" in out["cpus"]["celeron-300a"]["l2"]
    assert set(out["memory"]) >= {"edo", "sdram-pc66", "sdram-pc100"}
