"""The CPU families: one registered record per family, the single place the rest of retrosim asks
what a family is called, how it is drawn, which instruction sets it lacks, which counters explain
its results, which estimates its model makes and which class times it.

A record is read from the family's machine table (``sim/cpus/tables/<name>_machine.toml``):
its ``[family]`` section (display name, plot marker, lacking extensions, conformance preset,
explain columns, instruction-table fields), its ``[estimates]`` (each with default, plausible
range, mechanism counter and reason) and its ``[rules]`` (estimated rules that are not numbers).
The model class is named here, one line per family (:data:`FAMILIES`), and imported only when a
model is made, so reading a record never loads a compiled core. A family's cache policies are in
sim/memory/policies.toml under its name (the memory layer reads them).

Adding a family: its own files (model, core, instruction table, machine table with [family] and
[estimates], presets), its policies in sim/memory/policies.toml and one line in :data:`FAMILIES`.
"""

from __future__ import annotations

import functools
import importlib
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from sim.errors import RetrosimError

TABLES = Path(__file__).resolve().parent / "tables"
ALWAYS = "always"  # an estimate's mechanism when every run exercises it


@functools.cache
def machine_table(name: str) -> dict:
    """A family's machine table (sim/cpus/tables/NAME_machine.toml), parsed once."""
    path = TABLES / f"{name}_machine.toml"
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise RetrosimError(f"{path}: {e}") from None


@dataclass(frozen=True)
class Estimate:
    """A model choice with no figure in the sources (a machine table's ``[estimates.NAME]``)."""

    name: str
    default: int | float
    low: int | float
    high: int | float
    mechanism: str          # the counter that must be non-zero for it to matter, or ALWAYS
    reason: str             # why the default is what it is
    range_reason: str       # why the range
    overridable: bool = True  # a make_model override (estimates.NAME) and re-timed by the claims
    only_with: str = ""     # a CpuPreset attribute (a cache level) without which the model never reads it

    @property
    def key(self) -> str:
        """The make_model override key."""
        return f"estimates.{self.name}"

    def applies_to(self, preset) -> bool:
        return not self.only_with or getattr(preset, self.only_with) is not None


@dataclass(frozen=True)
class Family:
    name: str                   # the presets' cpu_model
    model_path: str             # "module:Class" of the timing model
    display_name: str           # "the P6 family"
    marker: str                 # matplotlib marker of its presets in dot plots
    lacks: frozenset[str]       # extensions no CPU of the family has (sim/guest/isa.py)
    conformance_isa: str | None  # the preset whose instruction set has every table row (None: no conformance run)
    explain: tuple[str, ...]    # counters that explain a texture-scene result
    loop_counters: tuple[str, ...]  # counters of the texture-loops report
    table_fields: frozenset[str]  # the instruction table's family-specific row fields
    estimates: dict[str, Estimate]
    rules: dict[str, str]       # estimated rules that are not numbers: name -> reason
    conformance: dict = field(default_factory=dict)    # [family.conformance]: the conformance study's notes
    texture_loops: dict = field(default_factory=dict)  # [family.texture_loops]: the texture-loops report's lines

    @property
    def machine(self) -> dict:
        return machine_table(self.name)

    def model_class(self) -> type:
        module, cls = self.model_path.split(":")
        return getattr(importlib.import_module(module), cls)

    def defaults(self) -> dict:
        """Estimate name -> default value (what the model reads unless overridden)."""
        return {e.name: e.default for e in self.estimates.values()}

    def overridable(self) -> list[Estimate]:
        return [e for e in self.estimates.values() if e.overridable]


def _record(name: str, model_path: str) -> Family:
    table = machine_table(name)
    where = f"{TABLES / f'{name}_machine.toml'}"
    try:
        fam = table["family"]
        estimates = {}
        for est, e in table.get("estimates", {}).items():
            low, high = e["range"]
            estimates[est] = Estimate(est, e["default"], low, high, e["mechanism"], e["reason"], e["range_reason"],
                                      bool(e.get("overridable", True)), e.get("only_with", ""))
        return Family(name, model_path, fam["display_name"], fam["marker"], frozenset(fam["lacks"]),
                      fam.get("conformance_isa"), tuple(fam["explain"]), tuple(fam["loop_counters"]),
                      frozenset(fam["table_fields"]), estimates, dict(table.get("rules", {})),
                      dict(fam.get("conformance", {})), dict(fam.get("texture_loops", {})))
    except (KeyError, TypeError, ValueError) as e:
        raise RetrosimError(f"{where}: [family] or [estimates]: missing or bad field {e}") from None


def _check(f: Family) -> Family:
    for e in f.estimates.values():
        for v in (e.default, e.low, e.high):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise RetrosimError(f"{f.name}_machine.toml [estimates.{e.name}]: default and range must be numbers")
    return f


# The registry: one line per family, in the order reports list them.
FAMILIES: dict[str, Family] = {f.name: _check(f) for f in (
    _record("p5", "sim.cpus.p5:P5Model"),
    _record("p6", "sim.cpus.p6:P6Model"),
    _record("k6", "sim.cpus.k6:K6Model"),
)}


def family(name: str) -> Family:
    """The record of a registered family, or one clear error."""
    try:
        return FAMILIES[name]
    except KeyError:
        raise RetrosimError(f"unknown CPU family '{name}' (registered: {', '.join(FAMILIES)})") from None


def order(name: str) -> int:
    """A family's position in the registry (reports list p5, p6, k6 in this order); unknown last."""
    return list(FAMILIES).index(name) if name in FAMILIES else 9
