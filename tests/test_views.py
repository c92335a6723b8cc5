"""Terminal output a person can read: tables that fit 80 columns (and use a wide form when the
terminal is wider), each family's own words, a legend for every column."""

import io
import json

import pytest
from click.testing import CliRunner
from rich.console import Console

from sim import cli
from sim.guest import kernels
from sim.cpus import families, vocabulary

LOOP = ("convert/loops.S", "-e", "convert_plain", "--args", "buf:u32:64:4096,buf:u16:64,64")


@pytest.fixture
def shown(monkeypatch):
    """shown(width, *args) -> what `retrosim ARGS` prints on a terminal `width` columns wide."""

    def run(width, *args):
        console = Console(width=width, file=io.StringIO(), color_system=None)
        for module in (cli.kernel_cmds, cli.scene_cmds, cli.model_cmds):  # each command module prints through it
            monkeypatch.setattr(module, "console", console)
        r = CliRunner().invoke(cli.main, list(args), catch_exceptions=False)
        assert r.exit_code == 0, r.output
        return console.file.getvalue()

    return run


def assert_fits(text, width):
    assert "…" not in text, text  # Rich's ellipsis: a cut cell or header
    for line in text.splitlines():
        assert len(line.rstrip()) <= width, (width, len(line.rstrip()), line)


@pytest.mark.parametrize("width", [80, 200])
@pytest.mark.parametrize("cpu", ["pentium2-233", "k6-233"])
def test_explain_fits_the_terminal(shown, width, cpu):
    text = shown(width, "explain", *LOOP, "--cpu", cpu)
    assert_fits(text, width)
    for insn in ("bsr ecx, eax", "shrd edx, ecx, 0x15", "mov word ptr [edi], dx"):  # whole operands, no markup loss
        assert insn in text
    assert "timeline" in text and "table row" in text and "(est.)" in text
    # every column title and mark has its line in the legend under the tables
    for key in ("runs:", "dec:", "iss->ret:", "stall columns", "mispred:", "(est.):", "[cause]"):
        assert key in text, key
    if width == 200:  # wide: one table, every column side by side
        header = next(line for line in text.splitlines() if "iss->ret" in line)
        assert "table row" in header and "window" in header


def test_explain_speaks_each_familys_language(shown):
    p6 = shown(80, "explain", *LOOP, "--cpu", "pentium2-233")
    k6 = shown(80, "explain", *LOOP, "--cpu", "k6-233")
    assert "p0:" in p6 and "D0" in p6 and "decoder 0" in p6 and "uops" in p6
    # K6: units X / Y / load / store / branch, short (S1, S2), long (L) and vector (V) decode
    assert "X:" in k6 and "load:1" in k6 and "branch:1" in k6 and "RISC86 ops" in k6
    assert "p0" not in k6 and "p2:" not in k6 and "decoder 0" not in k6 and "decoder 2" not in k6
    bsr = next(line for line in k6.splitlines() if "bsr ecx, eax" in line and "0x4" in line)
    assert " V " in bsr and "short" in k6 and "vector" in k6
    rows = json.loads(CliRunner().invoke(cli.main, ["explain", *LOOP, "--cpu", "k6-233", "--json"]).output)
    by = {r["instruction"]: r for r in rows["instructions"]}
    assert by["bsr ecx, eax"]["decoder_class"] == "vector" and by["add esi, 4"]["decoder_class"] == "short"


def test_a_cpu_without_l2_says_so(shown):
    text = shown(80, "time", *LOOP, "--cpu", "celeron-266")
    assert_fits(text, 80)
    assert "no L2" in text and "what it counts" in text  # the stall table says what each kind counts
    assert "no L2" not in shown(80, "time", *LOOP, "--cpu", "celeron-300a")


def test_branch_stalls_are_explained_as_the_models_count_them():
    """The legend says P6 'branch' stall cycles include the bubble of every taken branch, K6's only
    the restarts after mispredictions: check that the models count what the legend says."""
    args = ["time", "micro/pipeline.S", "-e", "add_streams", "--args", "400", "--json"]
    p6 = json.loads(CliRunner().invoke(cli.main, args + ["--cpu", "pentium2-233"]).output)
    k6 = json.loads(CliRunner().invoke(cli.main, args + ["--cpu", "k6-233"]).output)
    assert p6["mispredicts"] <= 4 and p6["stall_mispredict"] >= 400  # a bubble per taken loop branch
    assert k6["mispredicts"] <= 4 and k6["stall_mispredict"] < 100
    assert "taken branch" in families.vocabulary_for("pentium2-233").stall_help["mispredict"]
    assert "taken" not in families.vocabulary_for("k6-233").stall_help["mispredict"]


@pytest.mark.parametrize("width", [80, 200])
def test_cpus_fits_the_terminal(shown, width):
    from sim.cpus import presets

    text = shown(width, "cpus")
    assert_fits(text, width)
    for name in presets.available():
        assert f" {name} " in text
    assert "no L2" in text and "edo" in text
    assert ("4-way" in text) == (width == 200)  # the wide form has every cache in full


@pytest.mark.parametrize("width", [80, 200])
def test_kernels_lists_whole_descriptions(shown, width):
    text = shown(width, "kernels")
    assert_fits(text, width)
    flat = " ".join(text.split())
    # div_window's description continues on a second comment line; dst[i] is text, not markup
    assert "the 6-opquad scheduler fills behind the DIV" in flat
    assert "dst[i] = 16-bit float of src[i]" in flat


def test_entry_descriptions_continue_on_following_comment_lines(tmp_path):
    src = tmp_path / "k.S"
    src.write_text("# @entry f(a) -> first line, then\n#   the second line\n.globl f\nf: ret\n"
                   "# @entry g() -> one line\n# @entry h(x, y)\n# What h does\n\n# not h's\n")
    e = kernels.entry_points(src)
    assert e["f"].returns == "first line, then the second line"
    assert e["g"].returns == "one line"  # the next @entry is not a continuation
    assert e["h"].args == ("x", "y") and e["h"].returns == "What h does"


def test_views_take_their_words_from_the_family_view():
    assert families.view("k6").vocabulary.ports == ("X", "Y", "load", "store", "branch")
    assert families.view("p6").vocabulary.ports[0] == "p0"
    assert families.view("no-such").vocabulary is vocabulary.GENERIC  # no view of its own: neutral names


def test_bottleneck_names_the_limit_in_each_familys_words():
    """The bottleneck is the biggest limit of the counters, named as the family names its hardware:
    the P6's busiest ports, the P5's pairing or its own stall counters, the K6's decoders."""
    p6, p5, k6 = families.view("p6"), families.view("p5"), families.view("k6")
    ports = {"stall_port": 30, "stall_dependency": 10, "port0": 100, "port1": 95, "port2": 40, "port3": 0, "port4": 0}
    assert p6.bottleneck(ports) == "ports p0/p1 saturated"
    assert p6.bottleneck({**ports, "port1": 50}) == "ports p0 saturated"  # p1 well below p0
    # a bigger stall kind wins, in words that say what it is (a chain of operand latencies)
    assert p6.bottleneck({**ports, "stall_dependency": 31}) == "dependency chain"
    # a port busy on (nearly) every cycle is the throughput bound, whatever the stall counters say
    assert p6.bottleneck({**ports, "stall_dependency": 31, "cycles": 100}) == "ports p0/p1 saturated"
    assert p6.bottleneck({**ports, "stall_dependency": 31, "cycles": 200}) == "dependency chain"
    assert p6.bottleneck({"stall_partial_register": 9, "stall_dependency": 3}).startswith("partial-register stalls")
    assert k6.bottleneck({**ports, "port0": 10}) == "units Y saturated"  # the K6's words for port1
    assert k6.bottleneck({"stall_decode": 9, "vector_cycles": 4}) == "decode: vector-decoded"
    assert k6.bottleneck({"stall_decode": 9, "vector_cycles": 0}) == "decode: short/long decoders"
    assert p5.bottleneck({"instructions": 4, "alone": 2, "stall_write_buffer": 1}) == "U/V pairing: 2 of 4 alone"
    assert p5.bottleneck({"instructions": 4, "alone": 2, "stall_write_buffer": 3}) == "write buffer full"
    assert p5.bottleneck({"instructions": 4, "alone": 0, "stall_fpu": 0}) == "none"
    # all paired and no stall: the instructions' own clocks (gcc's sum loop: ADD r32,m32 takes 2)
    assert p5.bottleneck({"instructions": 4, "pairs": 2, "alone": 0, "cycles": 3}) == \
        "all paired; multi-clock instructions +1"
    assert p5.bottleneck({"instructions": 4, "pairs": 2, "alone": 0, "cycles": 2}) == "all paired, a pair per clock"
    assert families.view(None).bottleneck({"stall_rob": 0}) == "none"


def test_explain_help_is_the_legend_one_step_away():
    r = CliRunner().invoke(cli.main, ["explain", "--help"], terminal_width=80)
    assert r.exit_code == 0
    assert_fits(r.output, 80)
    for column in ("runs", "dec", "iss->ret", "dep", "port", "decode", "partial", "mem", "fwd", "window", "branch",
                   "mispred", "table row", "(est.)"):
        assert column in r.output, column


@pytest.mark.parametrize("width", [80, 200])
def test_p5_explain_fits_and_names_pipes(shown, width):
    """The P5 brings its own columns (pipes, pairing class, why an instruction ran alone): split to
    fit 80 columns like the other families, whole memory operands kept."""
    text = shown(width, "explain", *LOOP, "--cpu", "pentium-133")
    assert_fits(text, width)
    assert "mov word ptr [edi], dx" in text
    assert "class" in text and "alone because" in text and "table row" in text
    header = next(line for line in text.splitlines() if "class" in line and "instruction" in line)
    assert " U " in header + " " and " V " in header + " "


# -- honest output: estimated rows and behaviour the model does not implement (issue 20 item 7) --
from sim.cpus.table import TimingRow, load_table  # noqa: E402
from sim.reports import views  # noqa: E402
from sim.timing import loop  # noqa: E402


def _estimated(family, key):
    mnemonic, _, signature = key.partition(" ")
    return load_table(family).rows[(mnemonic, signature)].estimated


def test_only_sourced_rows_report_zero_estimated():
    assert not any(_estimated("p6", k) for k in ("add r32,r32", "dec r32", "jcc rel32"))  # the premise
    t, = loop.time_body("top:\n  add eax, ebx\n  dec ecx\n  jnz top\n", ["pentium2-233"], iterations=20)
    c = views.caveats(t.result)
    assert c["instructions"] == 30 and c["estimated_instructions"] == 0 and c["estimated_rows"] == []
    assert views.caveat_lines(t.result) == ["estimated rows: 0 of 30 executed instructions (0 %)"]


def test_an_estimated_row_is_counted_per_execution():
    assert _estimated("p6", "cwde") and not _estimated("p6", "add r32,r32")  # the premise
    t, = loop.time_body("top:\n  cwde\n  add eax, ebx\n  dec ecx\n  jnz top\n", ["pentium2-233"], iterations=20)
    c = views.caveats(t.result)
    assert c["instructions"] == 40 and c["estimated_instructions"] == 10  # one CWDE in each of 10 iterations
    assert c["estimated_rows"] == [{"row": "cwde", "executions": 10}] and c["estimated_share"] == 0.25
    assert "10 of 40 executed instructions (25 %) use 1 table row marked estimated" in views.caveat_lines(t.result)[0]


def test_a_row_the_model_does_not_reproduce_is_named_with_its_reason():
    row = load_table("p6").rows[("bsf", "r16,r16")]
    assert row.extra.get("unreproduced")  # the premise: the table says why the model differs
    t, = loop.time_body("top:\n  bsf ax, bx\n  dec ecx\n  jnz top\n", ["pentium2-233"], iterations=20)
    limits = views.caveats(t.result)["not_modelled"]
    assert limits == [{"row": "bsf r16,r16", "instructions": ["bsf ax, bx"], "executions": 10,
                       "why": [row.extra["unreproduced"]]}]
    assert views.caveat_lines(t.result)[1].startswith("relies on behaviour not modelled: bsf r16,r16 (10 executions)")


def test_row_limits_reads_note_sentences_that_name_what_is_not_modelled():
    row = TimingRow("x", "", 1, (), "simple", 1, 1, "src",
                    note="Unpipelined divider. Not modelled: a power-of-2 divisor L 9 (p6_machine.toml). "
                         "Start-up cost not modelled separately.")
    assert views.row_limits(row) == ["Not modelled: a power-of-2 divisor L 9 (p6_machine.toml).",
                                     "Start-up cost not modelled separately."]
    assert views.row_limits(TimingRow("x", "", 1, (), "simple", 1, 1, "src", note="Measured in a loop.")) == []


def test_time_reports_estimated_executions(shown, write_kernel):
    # NEG r32 is an estimated row on the P5 and a sourced one on the P6 (the premise)
    assert _estimated("p5", "neg r32") and not _estimated("p6", "neg r32")
    src = write_kernel("    mov ecx, [esp+4]\n1:  neg eax\n    neg edx\n    dec ecx\n    jnz 1b\n    ret\n",
                       "neg.S", "negs")
    args = ("time", str(src), "-e", "negs", "--args", "100")
    p5 = json.loads(CliRunner().invoke(cli.main, [*args, "--cpu", "pentium-90", "--json"]).output)
    p6 = json.loads(CliRunner().invoke(cli.main, [*args, "--cpu", "pentium2-233", "--json"]).output)
    assert p5["model_limits"]["instructions"] == p5["instructions"]
    assert p5["model_limits"]["estimated_instructions"] >= 200  # 2 NEGs x 100 iterations
    assert p6["model_limits"]["estimated_instructions"] == 0
    text = shown(80, *args, "--cpu", "pentium2-233")
    assert f"estimated rows: 0 of {p6['instructions']:,} executed instructions (0 %)" in text


LCP_KERNEL = """.intel_syntax noprefix
.text
# @entry lcp(n) -> a MOV r16,imm16 per iteration
.globl lcp
lcp:
    mov ecx, [esp+4]
1:  mov ax, 0x1234
    dec ecx
    jnz 1b
    ret
"""


def test_explain_lists_the_not_modelled_rows_with_why(shown, tmp_path):
    src = tmp_path / "lcp.S"
    src.write_text(LCP_KERNEL)
    row = load_table("p6").rows[("mov", "r16,i16")]
    text = shown(80, "explain", str(src), "--args", "50", "--cpu", "pentium2-233")
    assert_fits(text, 80)
    words = " ".join(text.split())
    assert "relies on behaviour not modelled: mov r16,i16 (50 executions)" in words
    assert "not modelled, mov r16,i16 (mov ax, 0x1234): " + row.extra["unreproduced"] in words
    out = json.loads(CliRunner().invoke(cli.main, ["explain", str(src), "--args", "50", "--json"]).output)
    assert out["summary"]["model_limits"]["not_modelled"][0]["why"] == [row.extra["unreproduced"]]
