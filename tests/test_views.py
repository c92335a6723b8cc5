"""Terminal output a person can read: tables that fit 80 columns (and use a wide form when the
terminal is wider), each family's own words, a legend for every column."""

import io
import json

import pytest
from click.testing import CliRunner
from rich.console import Console

from sim import cli
from sim.guest import kernels
from sim.cpus import vocabulary

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
    assert "taken branch" in vocabulary.for_preset("pentium2-233").stall_help["mispredict"]
    assert "taken" not in vocabulary.for_preset("k6-233").stall_help["mispredict"]


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


def test_views_take_their_words_from_the_model():
    from sim.cpus import make_model

    assert vocabulary.of(make_model("k6-2-300")).ports == ("X", "Y", "load", "store", "branch")
    assert vocabulary.of(make_model("pentium3-500")).ports[0] == "p0"
    assert vocabulary.of(object()) is vocabulary.GENERIC  # a model that brings none gets neutral names


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
