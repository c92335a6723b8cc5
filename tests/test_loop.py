"""`retrosim loop`: bare loop bodies and blocks, their start-up-free cycles per iteration, errors."""

import json
import re
from pathlib import Path

import pytest
from click.testing import CliRunner

from sim.timing import loop
from sim.guest import loop_body, loop_program
from sim.cli import main
from sim.cpus import presets
from sim.errors import RetrosimError

# The reordered texture-mapping inner loop as printed in John DiCamillo's "Texture Mapping Optimization
# for Games" (its 5-cycle Pentium version with EBP as the counter), `//` comments kept.
TEXTURE_LOOP = """
ml5:

      mov   al, BYTE PTR [ebx]   // read from texture

      add   edx, esi             // update fractional part of u



      adc   bl,  dl              // update integral part of u

      add   eax, ecx             // update fractional part of v



      adc   bh,  dh              // update integral part of v

      mov   BYTE PTR [edi], al   // write to screen



      inc   edi                  // next pixel in screen

      dec   ebp                  // decrement count

      jnz   ml5                  // and do it again
"""

# the same loop as a MASM/TASM listing would print it
TEXTURE_LOOP_MASM = "\n".join(line.replace("//", ";") for line in TEXTURE_LOOP.splitlines())


def test_texture_loop_is_a_loop_of_nine_instructions():
    body = loop_body.parse_body(TEXTURE_LOOP, "texture")
    assert body.loop and body.instructions == 9 and body.head_labels == {"ml5"}


def test_texture_loop_on_every_preset():
    # the listing has nine instructions and one taken branch per pass, on any CPU
    results = loop.time_body(TEXTURE_LOOP, presets.available(), iterations=40)
    assert [r.cpu for r in results] == presets.available()
    for r in results:
        assert r.per_iteration["instructions"] == 9
        assert r.per_iteration["branches"] == 1
        assert r.per_iteration["l1d_loads"] == 1 and r.per_iteration["l1d_stores"] == 1
        assert r.cycles_per_iteration > 0


def test_start_up_cancels():
    # steady state: the same cycles per iteration whether 40 or 120 iterations are run
    cpus = ["pentium2-233", "k6-2-300"]
    short = loop.time_body(TEXTURE_LOOP, cpus, iterations=40)
    long = loop.time_body(TEXTURE_LOOP, cpus, iterations=120)
    assert [r.cycles_per_iteration for r in short] == [r.cycles_per_iteration for r in long]


def test_semicolon_comments_in_intel_syntax():
    cpus = ["pentium2-233", "k6-233"]
    a = loop.time_body(TEXTURE_LOOP, cpus, iterations=20)
    b = loop.time_body(TEXTURE_LOOP_MASM, cpus, iterations=20)
    assert [r.per_iteration for r in a] == [r.per_iteration for r in b]


def test_unconditional_back_edge_is_a_loop():
    body = loop_body.parse_body("top:\n  add eax, ebx\n  add ecx, ebx\n  jmp top\n")
    assert body.loop
    r, = loop.time_body("top:\n  add eax, ebx\n  add ecx, ebx\n  jmp top\n", ["k6-233"], iterations=20)
    assert r.per_iteration["instructions"] == 3 and r.per_iteration["branches"] == 1


def test_block_without_back_edge_is_repeated_without_a_counter():
    # four instructions, no branch: nothing is added to what is timed
    block = "add eax, ebx\nadd ecx, edx\nxor esi, edi\nmov ebp, eax\n"
    body = loop_body.parse_body(block)
    assert not body.loop
    for r in loop.time_body(block, ["pentium2-233", "k6-233"], iterations=40):
        assert r.per_iteration["instructions"] == 4
        assert r.per_iteration["branches"] == 0


def test_dependent_chain_costs_its_latency():
    # IMUL r32,r32 latency: 4 clocks on the P6 (Intel Architecture Optimization Manual, 1997, appendix C;
    # Agner Fog, Pentium Pro/II instruction list) - a chain of two per block costs 8 per block
    r, = loop.time_body("imul eax, eax\nimul eax, eax\n", ["pentium2-233"], iterations=40)
    assert r.cycles_per_iteration == pytest.approx(8, abs=0.05)


def test_demand_zero_data_and_reg_override():
    text = "mov eax, [esi+edx*4]\nadd ebx, eax\nmov [edi+ecx], bl\n"
    # default registers: every address is mapped on first use and reads zero
    r, = loop.time_body(text, ["pentium2-233"], iterations=20)
    assert r.per_iteration["l1d_loads"] == 1 and r.per_iteration["l1d_stores"] == 1
    regs = loop_program.parse_regs(["edx=0x10", "esi=0x3000000"])
    assert regs["edx"] == 0x10 and regs["esi"] == 0x3000000 and regs["edi"] == loop_program.REG_DEFAULTS["edi"]
    run = loop_program.run_body(loop_body.parse_body(text), 20, regs)
    assert int(run.trace.mem_addr[0]) == 0x3000000 + 0x40


def test_att_gcc_loop_cycles_on_every_preset():
    att = ".L3:\n\tmovl\t(%esi,%eax,4), %edx\n\taddl\t%edx, %ecx\n\taddl\t$1, %eax\n\tcmpl\t%ebx, %eax\n\tjne\t.L3\n"
    body = loop_body.parse_body(att)
    assert body.syntax == "att" and body.loop
    for r in loop.time_body(att, presets.available(), iterations=20):
        assert r.per_iteration["instructions"] == 5 and r.cycles_per_iteration > 0


@pytest.mark.parametrize("text, regs, message", [
    ("top:\n  add eax, 1\n  jmp elsewhere\n  dec ecx\n  jnz top\n", [], "not a label of the body"),
    ("  mov eax, [esi]\n  ret\n", [], "leaves the body"),
    ("top:\n  mov eax, [esi]\n  dec ecx\n  jnz top\n", ["esi=4"], "null pointer"),
    ("top:\n  add eax, 1\n  dec ecx\n  jnz top\n", ["ecx=3"], "left through its back-edge"),
    ("top:\n  add eax, 1\n2: jmp 2b\n  dec ecx\n  jnz top\n", [], "never reached its back-edge"),
    ("top:\n  add eax, 1\n  jmp ebx\n  jnz top\n", [], "branches out of itself"),
])
def test_bad_bodies_get_one_error_line(tmp_path, text, regs, message):
    src = tmp_path / "body.s"
    src.write_text(text)
    args = ["loop", str(src), "--iterations", "8"] + [x for r in regs for x in ("--reg", r)]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and "body.s" in lines[0] and "Traceback" not in result.output


def test_too_many_iterations_of_a_long_body_say_so(tmp_path, monkeypatch):
    # a body that does iterate, but whose iterations asked for exceed the per-pass bound: the error
    # says so and how many would fit, not that the back-edge was never reached
    monkeypatch.setattr(loop_program, "MAX_INSTRUCTIONS", 5_000)
    src = tmp_path / "long.s"
    src.write_text("top:\n" + "  add eax, ebx\n" * 98 + "  dec ecx\n  jnz top\n")  # 100 per iteration
    result = CliRunner().invoke(main, ["loop", str(src), "--iterations", "100"])
    assert result.exit_code == 2, result.output
    line = result.output.strip()
    assert "--iterations" in line and "never reached" not in line
    fits = int(re.search(r"at most about ([\d,]+)", line).group(1).replace(",", ""))
    assert fits < 100
    ok = CliRunner().invoke(main, ["loop", str(src), "--iterations", str(fits), "--brief"])
    assert ok.exit_code == 0, ok.output


def test_main_stalls_are_named_in_each_familys_words():
    # the summary's stall column uses the words `retrosim time` uses per family: an address computed
    # the clock before its use is an AGI stall on the P5 (Intel's Pentium optimization manual), not
    # a P6-style "dependency"; the K6 has a scheduler, not a reorder buffer ("rob")
    agi = "top:\n  add esi, 4\n  mov eax, [esi]\n  add ebx, eax\n  dec ecx\n  jnz top\n"
    r = CliRunner().invoke(main, ["loop", "-", "--cpu", "pentium-mmx-233", "--brief"], input=agi, env={"COLUMNS": "120"})
    assert r.exit_code == 0, r.output
    row = next(line for line in r.output.splitlines() if "pentium-mmx-233" in line)
    assert "agi" in row and "dependency" not in row, row
    from sim.reports import views

    k6 = loop.time_body(agi, ["k6-2-300"], iterations=20)[0].result
    assert dict(views.stall_labels(k6, {"stall_rob": 2.0, "stall_dependency": 1.0})) == {
        "stall_rob": "window", "stall_dependency": "dependency"}


@pytest.mark.parametrize("columns", ["80", "200"])
def test_p5_tables_of_a_loop_speak_of_its_iterations_not_a_call(columns):
    # a loop body is not called: its P5 table (the family's own columns, shared with explain) is
    # titled by the measured iterations at any width
    body = "top:\n  add eax, [esi]\n  add esi, 4\n  dec ecx\n  jnz top\n"
    r = CliRunner().invoke(main, ["loop", "-", "--cpu", "pentium-mmx-233"], input=body, env={"COLUMNS": columns})
    assert r.exit_code == 0, r.output
    assert "last call" not in r.output and "pentium-mmx-233: per instruction, measured iterations" in r.output


def test_fault_message_prints_the_whole_memory_operand(tmp_path):
    src = tmp_path / "null.s"
    src.write_text("top:\n  mul dword ptr [esi]\n  dec ecx\n  jnz top\n")
    result = CliRunner().invoke(main, ["loop", str(src), "--reg", "esi=0", "--iterations", "8"])
    assert result.exit_code == 2 and "mul dword ptr [esi]" in result.output


def test_assembler_errors_name_the_users_line(tmp_path):
    src = tmp_path / "typo.s"
    src.write_text("top:\n  add eax, 1\n  movv eax, ebx\n  dec ecx\n  jnz top\n")
    result = CliRunner().invoke(main, ["loop", str(src)])
    assert result.exit_code == 2 and f"{src}:3:" in result.output


def test_stdin_json_and_several_cpus():
    result = CliRunner().invoke(main, ["loop", "-", "--cpu", "pentium2-233,k6-233", "--iterations", "20", "--json"],
                                input=TEXTURE_LOOP)
    assert result.exit_code == 0, result.output
    data = json.loads(result.output)
    assert [r["cpu"] for r in data["results"]] == ["pentium2-233", "k6-233"]
    for r in data["results"]:
        assert {"cpu", "cycles_per_iteration", "uops_per_iteration", "instructions"} <= set(r)
        assert len(r["instructions"]) == 9 and r["instructions"][0]["instruction"] == "mov al, byte ptr [ebx]"


def test_cli_table_and_timeline(tmp_path):
    src = tmp_path / "t.s"
    src.write_text(TEXTURE_LOOP)
    # every CPU's detail on request (--detail): the last preset's timeline too; every CPU in the summary
    result = CliRunner().invoke(main, ["loop", str(src), "--cpu", "all", "--iterations", "20", "--detail"])
    assert result.exit_code == 0, result.output
    assert "timeline on k6-3-450" in result.output and "byte ptr [ebx]" in result.output
    for cpu in presets.available():
        assert cpu in result.output


def test_unknown_cpu_is_one_line():
    result = CliRunner().invoke(main, ["loop", "-", "--cpu", "pentium9"], input="nop\n")
    assert result.exit_code == 2 and "unknown CPU preset 'pentium9'" in result.output


def test_empty_body():
    with pytest.raises(RetrosimError, match="no instructions"):
        loop_body.parse_body("// nothing\n; nothing\n\n")


# -- harness artefacts (issue 20 item 4) ------------------------------------------------------
def test_no_phantom_mispredict_texture_loop_on_pentium():
    # DiCamillo's reordered loop is printed as a 5-cycle Pentium loop: its nine instructions issue as
    # (mov, add) (adc, add) (adc, mov) (inc, dec) (jnz): ADC r8,r8 is PU, pairing in the U pipe; a
    # correctly predicted JNZ costs one clock in a pipe (Intel, Pentium Processor Family Developer's
    # Manual vol. 3, 1995, 24.3 "Pairing"; Agner Fog, The microarchitecture of Intel, AMD and VIA
    # CPUs, Pentium chapter, "Pairing integer instructions"). The warm, always-taken back-edge is
    # never mispredicted, so the last iteration of the measured window must not be charged one.
    text = (Path(__file__).resolve().parents[1] / "examples" / "texture-loop.s").read_text()
    r, = loop.time_body(text, ["pentium-90"])  # the default iteration count, as `retrosim loop` runs it
    assert r.per_iteration["mispredicts"] == 0
    assert r.cycles_per_iteration == pytest.approx(5.0, abs=1e-9)


def test_no_phantom_mispredict_two_pairs():
    # ADD r,i / ADD r,i (independent, both UV) pair; DEC r32 (UV) pairs with JNZ (PV, V pipe only):
    # two clocks per iteration (same sources as above: Intel 24.3, Agner Fog's Pentium pairing rules)
    r, = loop.time_body("top:\n  add eax, 1\n  add ebx, 1\n  dec ecx\n  jnz top\n", ["pentium-90"])
    assert r.per_iteration["mispredicts"] == 0
    assert r.cycles_per_iteration == pytest.approx(2.0, abs=1e-9)


def test_block_last_copy_is_not_the_end_of_the_run():
    # a block repeated back to back: the copy after the measured window follows, so nothing drains in it
    run = loop_program.run_body(loop_body.parse_body("add eax, ebx\nadd ecx, edx\n"), 20)
    assert run.next_pc == run.machine.symbol("retrosim_iter_20")


REP_FIRST = "top:\n  rep stosd\n  mov ecx, 64\n  sub edi, 256\n  dec ebx\n  jnz top\n"


@pytest.mark.parametrize("cpu", ["pentium-90", "pentium2-233", "k6-233"])
def test_rep_first_body_is_counted_per_iteration(cpu):
    # the trace holds one REP STOSD execution per element at the same PC: the 64 elements (64 stores)
    # belong to one iteration, and a NOP put first costs about one NOP (at most a clock), not a
    # factor of 64
    regs = loop_program.parse_regs(["ecx=64"])
    rep, = loop.time_body(REP_FIRST, [cpu], regs=regs, iterations=20)
    nop, = loop.time_body(REP_FIRST.replace("top:\n", "top:\n  nop\n"), [cpu], regs=regs, iterations=20)
    assert rep.iterations == nop.iterations == 10
    assert rep.per_iteration["l1d_stores"] == nop.per_iteration["l1d_stores"] == 64
    assert nop.per_iteration["instructions"] == rep.per_iteration["instructions"] + 1 > 64
    assert abs(nop.cycles_per_iteration - rep.cycles_per_iteration) <= 1.0


def test_one_instruction_loop_still_counts_each_pass():
    # `l: loop l` runs the same PC every iteration (no REP prefix): each pass is an iteration
    r, = loop.time_body("top:\n  loop top\n", ["pentium2-233"], iterations=20)
    assert r.per_iteration["instructions"] == 1 and r.per_iteration["branches"] == 1


# P6 front end: after a taken branch only the aligned 16-byte chunk holding the target is there for
# the first decode group (Intel IA-32 optimization manual, cited in p6_machine.toml [fetch]); with
# the loop head 8 bytes into a chunk, the 6-byte MOV fits and the 6-byte ADD after it does not.
FETCH_BOUND = ("top:\n  mov eax, [esi+0x1000]\n  add ebx, 0x12345678\n  mov [edi+0x1000], eax\n"
               "  add edx, 0x12345678\n  dec ecx\n  jnz top\n")


def test_placement_is_reported_and_chosen():
    body = loop_body.parse_body(FETCH_BOUND)
    default = loop_program.run_body(body, 20)
    assert default.address % 64 == 0 and default.alignment == 64  # the default: unchanged from before
    run = loop_program.run_body(body, 20, align=16, offset=3)
    assert run.address % 64 == 19 and run.alignment == 1
    assert loop_program.run_body(body, 20, align=16).address % 64 == 16
    assert loop_program.run_body(body, 20, align=8).alignment == 8


def test_alignment_changes_a_front_end_bound_loop():
    aligned, = loop.time_body(FETCH_BOUND, ["pentium2-233"], iterations=40)
    late, = loop.time_body(FETCH_BOUND, ["pentium2-233"], iterations=40, align=8)
    assert late.address % 16 == 8 and aligned.address % 16 == 0
    assert late.cycles_per_iteration >= aligned.cycles_per_iteration + 0.5
    assert late.per_iteration["stall_decode"] > aligned.per_iteration["stall_decode"]


@pytest.mark.parametrize("args, message", [
    (["--align", "3"], "--align 3: must be a power of two"),
    (["--align", "128"], "--align 128: must be a power of two"),
    (["--align", "16", "--offset", "16"], "--offset 16: must be from 0 to 15"),
])
def test_bad_placement_is_one_line(args, message):
    result = CliRunner().invoke(main, ["loop", "-"] + args, input="nop\n")
    assert result.exit_code == 2 and message in result.output and len(result.output.strip().splitlines()) == 1


def test_cli_shows_placement_text_and_json():
    args = ["loop", "-", "--cpu", "pentium2-233", "--iterations", "20", "--align", "16", "--offset", "3"]
    text = CliRunner().invoke(main, args + ["--brief"], input=FETCH_BOUND)
    assert text.exit_code == 0, text.output
    words = " ".join(text.output.split())  # the line wraps at the terminal's width
    assert "body at 0x00400013" in words and "--align 16 --offset 3" in words
    data = json.loads(CliRunner().invoke(main, args + ["--json"], input=FETCH_BOUND).output)
    assert data["placement"] == {"address": "0x00400013", "align": 16, "offset": 3, "alignment": 1,
                                 "past_boundary": 19}


STORE_STREAM = "top:\n  mov [edi], eax\n  add edi, 4\n  dec ecx\n  jnz top\n"


def _loop_json(*args, body=STORE_STREAM):
    result = CliRunner().invoke(main, ["loop", "-", "--iterations", "40", "--json", *args], input=body)
    assert result.exit_code == 0, result.output
    return json.loads(result.output)


def test_labelled_cpu_and_set_agree():
    # the K6-233's board has no write allocation: a store stream misses L1 every store; with
    # full write allocation (a machine label, or --set as for `retrosim time`) the lines are allocated
    plain, = _loop_json("--cpu", "k6-233")["results"]
    label, = _loop_json("--cpu", "k6-233{write_allocate.mode=full}")["results"]
    sets, = _loop_json("--cpu", "k6-233", "--set", "write_allocate.mode=full")["results"]
    assert label["cpu"] == sets["cpu"] == "k6-233{write_allocate.mode=full}"
    assert label["per_iteration"] == sets["per_iteration"]
    assert label["per_iteration"]["l1d_store_misses"] < plain["per_iteration"]["l1d_store_misses"]


def test_several_labels_with_commas_inside_braces():
    data = _loop_json("--cpu", "pentium2-233{l2.size_kb=256,l2.latency_cycles=10},k6-233")
    assert [r["cpu"] for r in data["results"]] == ["pentium2-233{l2.latency_cycles=10,l2.size_kb=256}", "k6-233"]


def test_memory_option_and_set_memory():
    default, = _loop_json("--cpu", "k6-233")["results"]
    other, = _loop_json("--cpu", "k6-233", "--memory", "sdram-pc100")["results"]
    via_set, = _loop_json("--cpu", "k6-233", "--set", "memory=sdram-pc100")["results"]
    assert default["memory"] != "sdram-pc100" and other["memory"] == via_set["memory"] == "sdram-pc100"
    result = CliRunner().invoke(main, ["loop", "-", "--memory", "dram9"], input="nop\n")
    assert result.exit_code == 2 and "unknown memory preset 'dram9'" in result.output


def test_bad_set_is_one_line():
    result = CliRunner().invoke(main, ["loop", "-", "--cpu", "k6-233", "--set", "no.such=1"], input="nop\n")
    assert result.exit_code == 2 and "unknown override 'no.such'" in result.output


MMX_BODY = "top:\n  paddw mm0, mm1\n  dec ecx\n  jnz top\n"


def test_cpu_all_times_the_cpus_with_the_instruction_set():
    data = _loop_json("--cpu", "all", body=MMX_BODY)
    timed = [r["cpu"] for r in data["results"]]
    no_mmx = [c for c in presets.available() if "mmx" not in presets.load(c).raw.get("isa_extensions", ())]
    assert no_mmx and data["not_timed"] == {"MMX": no_mmx}
    assert timed == [c for c in presets.available() if c not in no_mmx]
    text = CliRunner().invoke(main, ["loop", "-", "--cpu", "all", "--iterations", "20", "--brief"], input=MMX_BODY)
    assert text.exit_code == 0 and f"not timed (no MMX): {', '.join(no_mmx)}" in " ".join(text.output.split())


def test_sse_body_on_cpus_of_which_one_has_it():
    data = _loop_json("--cpu", "pentium-90,k6-2-300,pentium3-500", body="top:\n  addps xmm0, xmm1\n  dec ecx\n  jnz top\n")
    assert [r["cpu"] for r in data["results"]] == ["pentium3-500"]
    assert data["not_timed"] == {"SSE": ["pentium-90", "k6-2-300"]}


def test_no_cpu_with_the_instruction_set_is_one_error():
    result = CliRunner().invoke(main, ["loop", "-", "--cpu", "pentium-90,pentium-133"], input=MMX_BODY)
    assert result.exit_code == 2 and "not available on pentium-90" in result.output
    assert len(result.output.strip().splitlines()) == 1
    with pytest.raises(RetrosimError, match="not available on k6-233"):  # the library call stays strict
        loop.time_body(MMX_BODY.replace("paddw mm0, mm1", "pfadd mm0, mm1"), ["k6-2-300", "k6-233"], iterations=8)


def test_loop_output_says_what_the_figures_rest_on():
    body = "top:\n  bsf ax, bx\n  cwde\n  dec ecx\n  jnz top\n"
    data = _loop_json("--cpu", "pentium2-233", body=body)
    limits = data["results"][0]["model_limits"]
    assert limits["estimated_instructions"] > 0 and limits["not_modelled"][0]["row"] == "bsf r16,r16"
    text = CliRunner().invoke(main, ["loop", "-", "--cpu", "pentium2-233", "--iterations", "20", "--brief"], input=body)
    words = " ".join(text.output.split())
    assert "est." in words and "pentium2-233: relies on behaviour not modelled: bsf r16,r16" in words
