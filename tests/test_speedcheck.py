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


def test_a_placement_is_the_same_core_compiled_apart(monkeypatch, tmp_path):
    """A copy of a core is a module of its own (its own compiled simulate) that times a trace to
    the same counters, and the model gets its own core back after the measurement swaps it in."""
    import numpy as np

    from sim.cpus.build import make_model
    from sim.cpus.p5 import core, model as p5_model
    from sim.guest.kernels import kernels_root
    from sim.timing.kernel import time_kernel

    monkeypatch.setattr(speedcheck, "PLACEMENT_DIR", tmp_path)
    package, copy = speedcheck.core_placements("p5", 2)
    assert package is core and copy is not core and copy.simulate is not core.simulate
    assert (tmp_path / "p5_core_1.py").read_text().endswith(open(core.__file__).read())

    def setup(m):
        return [m.arena.put(np.full(256, 0xFFFF, np.uint16)), m.arena.put(np.zeros(256, np.uint16)), 256,
                0x10000000, 0x100000, 0x1234]

    def counters(module):
        model = make_model("pentium-mmx-233")
        speedcheck._placed(model, module)
        try:
            return time_kernel(kernels_root() / "zbuffer/fp16z.S", "fp16z_span", setup, cpu=model).last
        finally:
            speedcheck._placed(model, core)

    assert not copy.simulate.signatures  # compiled only when a run reaches it
    assert counters(copy) == counters(core)
    assert copy.simulate.signatures  # the copy timed its run
    assert p5_model.core is core and p5_model.P5Session.CORE is core
