"""The models' speed check (sim/timing/speedcheck.py): the comparison with the recorded ratios and
the baseline file. No timing is asserted here (a timed test flakes on a loaded machine): the
measured figures are `retrosim bench --check`'s, which compares ratios measured in one process."""

import json

import pytest

from sim.timing import speedcheck
from tests.conftest import cli_fails

BASE = {"ratios": {"pentium2-233": 0.40, "k6-233": 0.50, "pentium-mmx-233": 0.60}}


def result(**ratios):
    return {"models": {cpu: {"ratio": r, "ips": 1.0} for cpu, r in ratios.items()}}


def test_a_ratio_more_than_15_percent_below_fails_with_its_figures():
    failed = speedcheck.regressions(result(**{"pentium2-233": 0.33, "k6-233": 0.50, "pentium-mmx-233": 0.70}), BASE)
    assert len(failed) == 1
    assert failed[0].startswith("pentium2-233: 0.330 of the native trace's rate, recorded 0.400 (-18%")


def test_within_15_percent_or_faster_passes():
    assert speedcheck.regressions(result(**{"pentium2-233": 0.35, "k6-233": 0.43, "pentium-mmx-233": 0.9}), BASE) == []


def test_the_committed_baseline_names_its_machine_and_every_family():
    doc = speedcheck.load(speedcheck.BASELINE_FILE)
    assert set(doc["ratios"]) == set(speedcheck.CPUS)
    assert all(0 < r < 10 for r in doc["ratios"].values())
    assert {"cpu", "cores", "python", "numba"} <= set(doc["machine"])


def test_record_then_load_round_trips(tmp_path):
    measured = {"pixels": 4096, "rounds": 2, "models": {"k6-233": {"ratio": 0.123456, "ips": 1e6}}}
    path = tmp_path / "speed.json"
    speedcheck.record(measured, path)
    doc = speedcheck.load(path)
    assert doc["ratios"] == {"k6-233": 0.1235}
    assert doc["pixels"] == 4096


@pytest.mark.parametrize("text", ["{", "[]", json.dumps({"ratios": {"k6-233": "fast"}})])
def test_a_malformed_baseline_is_one_error(tmp_path, text):
    path = tmp_path / "speed.json"
    path.write_text(text)
    with pytest.raises(Exception, match="not a speed baseline"):
        speedcheck.load(path)


def test_check_and_record_together_are_refused():
    assert "choose one" in cli_fails("bench", "--check", "--record")


def test_a_regression_exits_1_with_its_figures(monkeypatch):
    from click.testing import CliRunner

    from sim.cli import main

    measured = {"pixels": 4096, "rounds": 1, "instructions": 10, "native_ips": 1e7,
                "models": {"k6-233": {"ratio": 0.2, "ips": 2e6}}}
    monkeypatch.setattr(speedcheck, "load", lambda path: {"ratios": {"k6-233": 0.3}})
    monkeypatch.setattr(speedcheck, "measure", lambda **kw: measured)
    monkeypatch.setattr(speedcheck, "measure_fresh", lambda **kw: measured)
    r = CliRunner().invoke(main, ["bench", "--check"])
    assert r.exit_code == 1, r.output
    assert "speed regression: k6-233: 0.200 of the native trace's rate, recorded 0.300 (-33%" in r.stderr
