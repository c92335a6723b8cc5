"""`retrosim validate`: the published-timing cases, their sources, the report's arithmetic."""

from click.testing import CliRunner

from sim.studies import validation
from sim.cli import main
from sim.errors import RetrosimError

FORBIDDEN = ("gmp", "abrash", "black book", "zen of", "lmbench")


def test_at_least_25_cases_per_family_with_sources():
    fams = {f.family: f for f in validation.families()}
    assert {"p5", "p6", "k6"} <= set(fams)
    for fam in fams.values():
        assert len(fam.cases) >= 25
        for case in fam.cases:
            key = case.source.split()[0]
            assert key in fam.sources, f"{fam.path}: {case.name}: source key {key} not in [sources]"
            text = (case.source + " " + fam.sources[key].text + " " + case.note).lower()
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


def _write(tmp_path, text, name="bad.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


HEAD = 'family = "p5"\ncpu = "pentium-133"\n[sources]\nS = "a publication"\n'


def test_malformed_case_files_give_one_error_naming_file_case_and_field(tmp_path):
    bad = {
        '[[case]]\nname = "x"\nbody = "nop"\npublished = "3"\nsource = "S p. 1"\n': ("case 1 'x'", "published"),
        '[[case]]\nname = "x"\nbody = "nop"\npublished = 3\nsource = "T p. 1"\n': ("case 1 'x'", "'T'"),
        '[[case]]\nname = "x"\nbody = "nop"\npublished = 3\nsource = "S"\ncpu = "pentium-9000"\n': ("case 1 'x'", "pentium-9000"),
        '[[case]]\nname = "x"\nbody = "nop"\npublished = 3\nsource = "S"\npublishd = 4\n': ("case 1 'x'", "publishd"),
        '[[case]]\nname = "x"\nbody = "nop"\npublished = 3\nsource = "S"\nregs = "eax=1"\n': ("case 1 'x'", "regs"),
        '[[case]]\nname = "x"\nbody = "nop\npublished = 3\n': ("bad.toml:7:", "TOML syntax error"),
    }
    for text, (where, what) in bad.items():
        try:
            validation.load_family(_write(tmp_path, HEAD + text))
        except RetrosimError as e:
            msg = str(e)
            assert "bad.toml" in msg and where in msg and what in msg, (text, msg)
            assert "\n" not in msg.strip() and "Traceback" not in msg
        else:
            raise AssertionError(f"accepted: {text!r}")
    try:
        validation.load_family(_write(tmp_path, 'case = 3\n' + HEAD))
    except RetrosimError as e:
        assert "bad.toml" in str(e) and "array of tables" in str(e)
    else:
        raise AssertionError("case = 3 accepted")
    bad_source = 'family = "p5"\ncpu = "pentium-133"\n[sources.S]\ntext = "x"\nrow_keys = "AF9"\n[[case]]\nname = "x"\nbody = "nop"\npublished = 1\nsource = "S"\n'
    try:
        validation.load_family(_write(tmp_path, bad_source))
    except RetrosimError as e:
        assert "[sources] S" in str(e) and "row_keys" in str(e)
    else:
        raise AssertionError("row_keys given as a string accepted")


def test_citation_keys_match_whole_keys_only():
    assert validation.cites("AF28.2; OPCF (Pentium column)", "AF28.2")
    assert validation.cites("x (AF9 AGI)", "AF9")
    assert not validation.cites("AF99; AF9x", "AF9")
    assert not validation.cites("AF28.25", "AF28.2")
    assert validation.cites("IL-K6, IL-K62", "IL-") and validation.cites("InstLat-PII (L 3)", "InstLat")
    assert not validation.cites("UNIL-X", "IL-")


def test_dependence_comes_from_rows_and_machine_sources():
    rows = [{"row": "fadd st,m32fp", "source": "AF28.2; OPCF"}, {"row": "add r32,r32", "source": "OPC; INTEL-PAIR"}]
    assert validation.dependence(rows, [], ("AF28.2",)) == ["row fadd st,m32fp: AF28.2"]
    assert validation.dependence(rows, ["AF9 (AGI one clock)"], ("AF9",)) == ["machine: AF9"]
    assert validation.dependence(rows, ["AF9 (AGI one clock)"], ("INTEL-OPT32",)) == []
    # an InstLatX64 source without row_keys keeps the InstLat rule; a worked example names its own keys
    src = validation._source("IL", "InstLatX64 dump of some chip", validation.VALIDATION_DIR / "x.toml")
    assert set(src.row_keys) == set(validation.INSTLAT_KEYS)
    src = validation._source("AF", {"text": "Agner Fog, a loop example", "row_keys": []}, validation.VALIDATION_DIR / "x.toml")
    assert src.row_keys == ()


def test_independence_of_the_shipped_cases():
    """Cases from the new sources are recognised: the Pentium loop examples and Intel's listings are
    independent, the floating-point scheduling listings (whose figures the AF28.2 rows restate) and the
    InstLatX64 cases are not."""
    fams = {f.family: f for f in validation.families()}
    p5 = {c.name: c for c in fams["p5"].cases}
    picked = ["ChangeSign with pairable instructions only (example 2)", "Three FMULs separated by FLDs",
              "ChangeSign rolled out twice, AGI (example 7)", "array1[i] += array2[i], restructured loop"]
    sub = validation.Family("p5", fams["p5"].cpu, "", fams["p5"].sources, [p5[n] for n in picked], fams["p5"].path)
    res = {r.case.name: r for r in validation.run_family(sub).results}
    assert all(r.model is not None for r in res.values()), {n: r.error for n, r in res.items()}
    assert res[picked[0]].independent and res[picked[3]].independent
    assert any("AF28.2" in d for d in res[picked[1]].dependence)
    assert res[picked[2]].dependence == ["machine: AF9"]          # the figure includes an AGI (AF9)
    k6 = fams["k6"]
    il = next(c for c in k6.cases if c.source.startswith("IL-K6-7"))
    r = validation.run_case(il, k6.cpu, k6.keys_of(il), validation.machine_sources("k6"))
    assert not r.independent and any("IL-" in d or "InstLat" in d for d in r.dependence)


def test_p5_family_loads_and_times_on_its_presets():
    fam = next(f for f in validation.families(only=["p5"]))
    assert fam.cpu.startswith("pentium-") and len(fam.cases) >= 15
    assert {c.cpu for c in fam.cases if c.cpu} <= {"pentium-mmx-166", "pentium-mmx-233"}
    case = next(c for c in fam.cases if "example 1)" in c.name)          # LODSD/NEG/STOSD/LOOP
    r = validation.run_case(case, fam.cpu)
    assert r.error is None and r.model > 4        # non-pairable string ops and LOOP: well above the 4-clock pairable loop
    mmx = next(c for c in fam.cases if c.cpu)
    r = validation.run_case(mmx, fam.cpu)
    assert r.error is None and r.model > 0


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
    assert "same source" in text
    rows = [line for line in text.splitlines() if line.startswith("| ") and "IL-K6-7 #" in line]
    assert len(rows) >= 25
    assert CliRunner().invoke(main, ["validate", "--family", "k6", "--out", str(out), "--check"]).exit_code == 0
    out.write_text(text.replace("| 2 | 2.00 |", "| 2 | 9.00 |", 1))
    stale = CliRunner().invoke(main, ["validate", "--family", "k6", "--out", str(out), "--check"])
    assert stale.exit_code == 1 and "stale report" in stale.output


def test_unknown_family():
    result = CliRunner().invoke(main, ["validate", "--family", "z80"])
    assert result.exit_code == 2 and "no validation cases for z80" in result.output
