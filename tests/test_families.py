"""The family registry (sim/cpus/families.py) is the single source of what a family is: every
registered family has a model, tables and a machine table whose estimates are complete and
consistent; every place that lists families reads the registry; and no family's module reaches
into another family's (they share only sim/cpus/contract.py and sim/cpus/shared_core.py)."""

import ast
import json
import string
import tomllib
from pathlib import Path

import pytest
from click.testing import CliRunner

from sim import cli
from sim.cpus import families, presets
from sim.cpus.build import make_model
from sim.cpus.overrides import overridable
from sim.cpus.contract import C_NAMES, FamilyModel
from sim.cpus.families import ALWAYS, FAMILIES
from sim.cpus.record import machine_path, table_path
from sim.guest.isa import EXTENSIONS

SIM = Path(__file__).resolve().parents[1] / "sim"


def _first_preset(name: str) -> str:
    return next(p for p in presets.available() if presets.load(p).family == name)


@pytest.fixture(scope="module")
def counters() -> dict[str, set[str]]:
    """Each family's counter names, as `retrosim time --json` gives them for a short kernel."""
    out = {}
    for name in FAMILIES:
        args = ["time", "micro/pipeline.S", "-e", "add_streams", "--args", "40", "--json", "--cpu", _first_preset(name)]
        result = CliRunner().invoke(cli.main, args)
        assert result.exit_code == 0, result.output
        out[name] = set(json.loads(result.output))
    return out


def test_every_preset_belongs_to_a_registered_family():
    for p in presets.available():
        assert presets.load(p).family in FAMILIES, p


@pytest.mark.parametrize("name", list(FAMILIES))
def test_a_registered_family_has_a_model_and_tables(name):
    f = families.family(name)
    model = make_model(_first_preset(name))
    assert isinstance(model, families.model_class(name)) and isinstance(model, FamilyModel) and model.family == name
    assert table_path(name).is_file() and machine_path(name).is_file()
    assert table_path(name).parent == SIM / "cpus" / name  # the family is one package
    assert model.table.rows  # its instruction table loads (the loader refuses a field not in table_fields)
    assert f.lacks <= set(EXTENSIONS), f.lacks - set(EXTENSIONS)
    assert f.marker and f.display_name
    if f.conformance_isa:
        assert presets.load(f.conformance_isa).family == name


@pytest.mark.parametrize("name", list(FAMILIES))
def test_every_estimate_is_complete_in_the_machine_table(name, counters):
    with open(machine_path(name), "rb") as fh:
        raw = tomllib.load(fh)
    assert raw["estimates"], f"{name}_machine.toml has no [estimates]"
    for est, fields in raw["estimates"].items():
        where = f"{name}_machine.toml [estimates.{est}]"
        for key in ("default", "range", "mechanism", "reason", "range_reason"):
            assert key in fields, f"{where}: no {key}"
        low, high = fields["range"]
        assert low < high, where
        assert low <= fields["default"] <= high, f"{where}: default {fields['default']} outside [{low}, {high}]"
        assert fields["mechanism"] == ALWAYS or fields["mechanism"] in counters[name], \
            f"{where}: mechanism {fields['mechanism']!r} is no counter of the {name} model"
        assert fields["reason"].strip() and fields["range_reason"].strip(), where


@pytest.mark.parametrize("name", list(FAMILIES))
def test_explain_columns_are_counters_of_the_family(name, counters):
    f = families.family(name)
    for column in f.explain + f.loop_counters:
        assert column in counters[name], f"{name}: {column!r} is no counter of its model"
    # the texture-loops report's line templates ([family.texture_loops]) fill in counters of the run
    # (a misspelt one would read 0, the value of a counter the run did not record)
    for key in ("tex5", "pairing"):
        fields = {f_name for _, f_name, _, _ in string.Formatter().parse(f.texture_loops.get(key, "")) if f_name}
        assert fields - {"name"} <= counters[name], f"{name}: [family.texture_loops] {key} names {fields - counters[name]}"


def test_overrides_are_the_registered_estimates():
    for name, f in FAMILIES.items():
        cpu = _first_preset(name)
        keys = {k for k in overridable(cpu) if k.startswith("estimates.")}
        assert keys == {e.key for e in f.overridable()}, name
        for e in f.overridable():
            assert make_model(cpu).estimates[e.name] == e.default
            assert make_model(cpu, overrides={e.key: e.high}).estimates[e.name] == e.high


def test_the_contract_counters_are_in_every_familys_run(counters):
    for name, names in counters.items():
        assert set(C_NAMES) <= names, (name, set(C_NAMES) - names)


def test_family_lists_read_the_registry():
    from sim.studies import conformance
    from sim.scenes.texture import scene as texture_scene
    from sim.scenes import schema
    from sim.reports import render

    assert schema.FAMILIES == tuple(FAMILIES)
    assert render.FAMILY_MARKERS == {n: f.marker for n, f in FAMILIES.items()}
    assert set(texture_scene.EXPLAIN) == set(FAMILIES)
    assert conformance.FAMILY_ISA == {n: f.conformance_isa for n, f in FAMILIES.items() if f.conformance_isa}


def _imports(path: Path) -> set[str]:
    """Modules `path` imports (absolute names; `from sim.cpus import p6` gives sim.cpus.p6)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
            out |= {f"{node.module}.{a.name}" for a in node.names}
    return out


def _family_modules(name: str) -> set[str]:
    return {f"sim.cpus.{name}.{m}" for m in ("model", "core", "view")} | {f"sim.cpus.{name}"}


def test_no_module_reaches_into_a_familys_module():
    """A family's model and core import only the contract and shared modules, never another family's;
    no other module of sim imports a family module at all (it asks the registry for the model and
    the view)."""
    own = {m: name for name in FAMILIES for m in _family_modules(name)}
    checked = 0
    for path in SIM.rglob("*.py"):
        module = ".".join(path.relative_to(SIM.parent).with_suffix("").parts)
        module = module.removesuffix(".__init__")
        allowed = _family_modules(own[module]) if module in own else set()
        reached = {m for m in _imports(path) if m in own and m not in allowed}
        assert not reached, f"{module} imports {', '.join(sorted(reached))}"
        checked += 1
    assert checked > 40 and all((SIM / "cpus" / m.split(".")[2] / f"{m.split('.')[3]}.py").is_file()
                                for m in own if m.count(".") == 3)
