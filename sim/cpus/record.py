"""A CPU family's record: what its machine table (``sim/cpus/NAME/NAME_machine.toml``) says
about it, read without importing its model. Its ``[family]`` section (display name, plot marker,
lacking extensions, conformance preset, explain columns, instruction-table fields), its
``[estimates]`` (each with default, plausible range, mechanism counter and reason) and its
``[rules]`` (estimated rules that are not numbers).

The family's own modules and the shared ones below the registry (contract, table, presets) read
records here; the registry of families (:mod:`sim.cpus.families`) sits above the family packages,
since it names and imports their models.
"""

from __future__ import annotations

import functools
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from sim.errors import RetrosimError

CPUS = Path(__file__).resolve().parent  # each family's package: sim/cpus/NAME/
ALWAYS = "always"  # an estimate's mechanism when every run exercises it


def machine_path(name: str) -> Path:
    """A family's machine table: sim/cpus/NAME/NAME_machine.toml."""
    return CPUS / name / f"{name}_machine.toml"


def table_path(name: str) -> Path:
    """A family's instruction table: sim/cpus/NAME/NAME.toml."""
    return CPUS / name / f"{name}.toml"


@functools.cache
def machine_table(name: str) -> dict:
    """A family's machine table (sim/cpus/NAME/NAME_machine.toml), parsed once."""
    path = machine_path(name)
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
    # it sets what the machine learns from call to call (a predictor table's indexing), not only when
    # things happen: the claims re-time it over the whole emulation (sim/scenes/claims.py)
    structural: bool = False

    @property
    def key(self) -> str:
        """The make_model override key."""
        return f"estimates.{self.name}"

    def applies_to(self, preset) -> bool:
        return not self.only_with or getattr(preset, self.only_with) is not None


@dataclass(frozen=True)
class Family:
    name: str                   # the presets' cpu_model
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

    def defaults(self) -> dict:
        """Estimate name -> default value (what the model reads unless overridden)."""
        return {e.name: e.default for e in self.estimates.values()}

    def overridable(self) -> list[Estimate]:
        return [e for e in self.estimates.values() if e.overridable]


def _record(name: str) -> Family:
    table = machine_table(name)
    where = f"{machine_path(name)}"
    try:
        fam = table["family"]
        estimates = {}
        for est, e in table.get("estimates", {}).items():
            low, high = e["range"]
            estimates[est] = Estimate(est, e["default"], low, high, e["mechanism"], e["reason"], e["range_reason"],
                                      bool(e.get("overridable", True)), e.get("only_with", ""),
                                      bool(e.get("structural", False)))
        return Family(name, fam["display_name"], fam["marker"], frozenset(fam["lacks"]),
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




@functools.cache
def read(name: str) -> Family:
    """A family's record, from its machine table alone (checked): what the family's own modules and
    the layers below the registry read, so none of them imports the registry (which imports the
    models)."""
    return _check(_record(name))


def known(name: str) -> bool:
    """Whether `name` has a family package with a machine table (the registry lists each such)."""
    return bool(name) and name == Path(name).name and machine_path(name).is_file()
