"""The conformance benchmarks: generated chains and independent copies, judged against table rows."""

import pytest

from sim.reports.conformance import render
from sim.studies.conformance import METHOD, RowResult, _judge, _operands, run_family
from sim.cpus.table import load_table


@pytest.mark.table_check
def test_benchmarks_reproduce_rows_the_models_implement():
    # InstLatX64 Deschutes: IMUL r32,r32 L 4 T 1; ADD r32,r32 L 1 T 0.5; PADDW mm,mm L 1
    results, presets = run_family("p6", only={"imul r32,r32", "add r32,r32", "paddw mm,mm"})
    assert {r.row.key for r in results if r.ok} == {"imul r32,r32", "add r32,r32", "paddw mm,mm"}
    by_key = {r.row.key: r for r in results}
    assert set(by_key["paddw mm,mm"].measured) == {p for p in presets if p != "pentium-pro-200"}  # no MMX
    assert by_key["imul r32,r32"].measured["pentium2-233"] == pytest.approx((4, 1), abs=0.05)


def test_3dnow_rows_run_only_on_the_models_that_have_them():
    results, _ = run_family("k6", only={"pfadd mm,mm"})
    assert set(results[0].measured) == {"k6-2-300", "k6-3-450"}


def test_a_row_off_by_more_than_the_tolerance_is_listed_with_its_figures():
    row = load_table("p6").rows[("add", "r32,r32")]
    res = RowResult(row, checked=True, measured={"pentium2-233": (1.0, 0.6)}, expected={"pentium2-233": (1.0, 0.5)})
    _judge(res)
    assert not res.ok and "pentium2-233: throughput 0.60 vs 0.5" in res.reason
    res = RowResult(row, checked=True, measured={"pentium2-233": (1.04, 0.46)}, expected={"pentium2-233": (1.0, 0.5)})
    _judge(res)
    assert res.ok


def test_chains_avoid_zero_idioms_and_copies_are_independent():
    rows = load_table("p6").rows
    assert _operands(rows[("xor", "r32,r32")], 0, True) == "eax, ebx"  # XOR EAX,EAX would break the chain
    assert _operands(rows[("imul", "r32,r32,i8")], 0, True) == "eax, eax, 3"
    dests = {_operands(rows[("add", "r32,r32")], k, False).split(",")[0] for k in range(10)}
    assert "ecx" not in dests and len(dests) == 5  # the source register is never written


def test_report_counts_estimated_rows_apart():
    results, presets = run_family("k6", only={"add r32,r32", "clc"})
    text = render({"k6": (results, presets)}, METHOD)
    est = sum(r.row.estimated for r in results)
    assert f"| k6 | 2 | 2 | {sum(r.ok for r in results if not r.row.estimated)} / {2 - est} " in text


@pytest.mark.table_check
def test_k6_divide_benchmarks_reproduce_the_rows():
    # the chain divides its own result and copies reload the dividend with MOVs, which read nothing
    # (IL-all: DIV r32 20 / 20, DIV r16 13 / 13, as the rows say)
    results, _ = run_family("k6", only={"div r32", "div r16"})
    by_key = {r.row.key: r for r in results}
    assert by_key["div r32"].measured["k6-2-300"] == pytest.approx((20, 20), abs=0.05)
    assert by_key["div r16"].measured["k6-233"] == pytest.approx((13, 13), abs=0.05)


@pytest.mark.table_check
def test_a_decode_bound_chain_is_judged_against_the_measured_chain():
    # ADD r16,imm16: execution latency 1, but the chain runs at the 2-clock decode rate of 0x66 + imm16
    # (IL-all L 2.0 T 2.00): the row's measured_latency is what the chain is compared with
    results, presets = run_family("k6", only={"add r16,i16"})
    res = results[0]
    assert res.row.latency == 1 and res.ok
    assert all(res.expected[p][0] == 2.0 and res.measured[p][0] == pytest.approx(2.0, abs=0.05) for p in presets)


def test_rows_below_the_k6_decode_rate_are_listed_with_the_reason_and_counted():
    # ADD r32,imm8: IL-all T 0.56, the model's two short decodes per clock give 0.50
    results, presets = run_family("k6", only={"add r32,i8", "add r32,r32"})
    by_key = {r.row.key: r for r in results}
    assert by_key["add r32,r32"].ok and not by_key["add r32,i8"].ok
    assert "length-determining bytes inside one line" in by_key["add r32,i8"].reason
    text = render({"k6": (results, presets)}, METHOD)
    line = next(ln for ln in text.splitlines() if ln.startswith("| K6 front end"))
    assert line.endswith("| 1 | 0 |")


def test_measured_latency_is_a_k6_field_only(tmp_path):
    from sim.cpus.table import InstructionTable
    from sim.errors import RetrosimError
    path = tmp_path / "p6.toml"
    path.write_text('[[insn]]\nmnemonic = "add"\nsignature = "r16,i16"\nuops = 1\nlatency = 1\n'
                    'measured_latency = 2.0\nsource = "x"\n')
    with pytest.raises(RetrosimError, match="unknown field 'measured_latency'"):
        InstructionTable(path)
    assert InstructionTable(path, family="k6").rows[("add", "r16,i16")].extra["measured_latency"] == 2.0


def test_benchmarks_follow_the_published_methods():
    # 6-byte ADD r32,imm32 (IFETCH blocks from an instruction boundary); DIV r32 "(full)" chain
    # L 39 with the divider's 1/37 for independent copies (AF29, InstLat-PII); XCHG copies on
    # disjoint registers (T 1.5 = 3 uops on two ALU ports); FSQRT copies alternated with FXCH (T 68);
    # ADD r16,imm16 chain no faster than the length-changing-prefix decode (InstLat L 2.2 T 2.17)
    keys = {"add r32,i32", "div r32", "div r8", "xchg r32,r32", "fsqrt", "add r16,i16"}
    results, _ = run_family("p6", only=keys)
    assert {r.row.key for r in results if r.ok} == keys
    by_key = {r.row.key: r for r in results}
    assert by_key["div r32"].measured["pentium2-233"] == pytest.approx((39, 37), abs=0.05)
    assert by_key["fsqrt"].measured["pentium2-233"] == pytest.approx((69, 68), abs=0.05)


def test_memory_forms_are_benchmarked_for_throughput():
    # InstLat-PII: ADD r32,[m32] T 1.00; ADD [m32],r32 T 1.75; MOV [m32],r32 T 1.00 (one store per clock)
    keys = {"add r32,m32", "add m32,r32", "mov m32,r32"}
    results, _ = run_family("p6", only=keys | {"fadd m32fp"})
    by_key = {r.row.key: r for r in results}
    assert all(by_key[k].checked for k in keys) and not by_key["fadd m32fp"].checked
    assert {k for k in keys if by_key[k].ok} == keys
    assert by_key["add m32,r32"].measured["pentium2-233"][1] == pytest.approx(1.75, abs=0.05)


def test_k6_rows_are_timed_in_instlat_loop_and_the_line_crossing_rule_reproduces_them():
    # InstLatX64 K6/K6-2/K6-III: 12 copies per iteration of a 32-byte-aligned loop. ADD r16,r16
    # (3 bytes, one 0x66 decode per clock) L 1.1 T 1.08 = 13/12: the copy at offset 30 has its
    # ModRM in the next line (k6_machine.toml [decode.line_crossing], inferred); SHL r16,imm8
    # (4 bytes, no copy across) and INC r16 (2 bytes) 1.00; the K6 model 6 decodes MMX in one
    # decoder only, PADDB mm,mm (3 bytes) 1.08 there, 0.59 on the K6-2 and K6-III
    keys = {"add r16,r16", "shl r16,i8", "inc r16", "paddb mm,mm"}
    results, _ = run_family("k6", only=keys)
    by_key = {r.row.key: r for r in results}
    assert all(by_key[k].ok for k in keys), [(k, by_key[k].reason) for k in keys]
    assert abs(by_key["add r16,r16"].measured["k6-2-300"][1] - 13 / 12) < 0.01
    assert abs(by_key["shl r16,i8"].measured["k6-2-300"][1] - 1.0) < 0.01
    assert abs(by_key["paddb mm,mm"].measured["k6-233"][1] - 13 / 12) < 0.01
    from sim.studies.conformance import _source
    text, _ = _source([by_key["add r16,r16"].row], instlat=True)
    assert text.count(".p2align 5, 0x90") == 4  # every loop start aligned
    # the subtracted loop skips its first dozen (never executed), so the timed dozen keeps InstLat's addresses
    lat_a = text.split(".globl lat0a")[1].split(".globl")[0]
    skipped, looped = lat_a.split(".p2align 5, 0x90")[1].split("1:")
    assert skipped.count("add ax, ax") == 12 and looped.count("add ax, ax") == 12
