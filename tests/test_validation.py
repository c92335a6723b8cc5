"""`retrosim validate`: the published-timing cases, their sources, the report's arithmetic."""

from click.testing import CliRunner

from sim import validation
from sim.cli import main
from sim.errors import RetrosimError

FORBIDDEN = ("gmp", "abrash", "black book", "zen of", "lmbench")


def test_at_least_25_cases_per_family_with_sources():
    fams = {f.family: f for f in validation.families()}
    assert {"p6", "k6"} <= set(fams)
    for fam in fams.values():
        assert len(fam.cases) >= 25
        for case in fam.cases:
            key = case.source.split()[0]
            assert key in fam.sources, f"{fam.path}: {case.name}: source key {key} not in [sources]"
            text = (case.source + " " + fam.sources[key]).lower()
            assert not any(word in text for word in FORBIDDEN), case.name  # kept for an independent check
            assert case.body.strip() and case.published > 0


def test_arithmetic_of_mape_and_within_one():
    fam = validation.Family("x", "pentium2-233", "", {}, [], None)
    cases = [validation.Case(f"c{i}", "nop", p, "S") for i, p in enumerate((2.0, 4.0, 10.0))]
    results = [validation.CaseResult(cases[0], 2.0), validation.CaseResult(cases[1], 5.0),
               validation.CaseResult(cases[2], 8.0), validation.CaseResult(cases[0], error="boom")]
    fr = validation.FamilyResult(fam, results, 0.0)
    assert len(fr.timed) == 3
    assert abs(fr.mape() - 100 * (0 + 0.25 + 0.2) / 3) < 1e-9
    assert abs(fr.within_one() - 2 / 3) < 1e-9


def test_bad_case_file_is_one_clear_error(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('family = "p6"\ncpu = "pentium2-233"\n[[case]]\nname = "x"\nbody = "nop"\nsource = "S"\n')
    try:
        validation.load_family(bad)
    except RetrosimError as e:
        assert "bad.toml" in str(e) and "published" in str(e)
    else:
        raise AssertionError("missing 'published' accepted")


def test_validate_writes_checks_and_detects_stale(tmp_path):
    out = tmp_path / "validation.md"
    result = CliRunner().invoke(main, ["validate", "--family", "k6", "--out", str(out)])
    assert result.exit_code == 0, result.output
    text = out.read_text()
    assert "## K6 on k6-233" in text and "The ten worst K6 cases" in text and "MAPE" in text
    rows = [line for line in text.splitlines() if line.startswith("| ") and "IL-K6-7 #" in line]
    assert len(rows) >= 25
    assert CliRunner().invoke(main, ["validate", "--family", "k6", "--out", str(out), "--check"]).exit_code == 0
    out.write_text(text.replace("| 2 | 2.00 |", "| 2 | 9.00 |", 1))
    stale = CliRunner().invoke(main, ["validate", "--family", "k6", "--out", str(out), "--check"])
    assert stale.exit_code == 1 and "stale report" in stale.output


def test_unknown_family():
    result = CliRunner().invoke(main, ["validate", "--family", "z80"])
    assert result.exit_code == 2 and "no validation cases for z80" in result.output
