"""The registry of CPU families: one line per family (:data:`FAMILIES`), the single place the rest
of retrosim asks which families exist, in which order reports list them, which class times each and
how each is shown (its :class:`~sim.cpus.view.FamilyView`).

A family is one package, ``sim/cpus/NAME/``: its model and core, its lowering rules, its instruction
table (NAME.toml), its machine table (NAME_machine.toml, read by :mod:`sim.cpus.record`) and its
view. The model and the view are named here as "module:Class" and imported only when first needed,
so listing the families never loads a compiled core. A family's cache policies are in
sim/memory/policies.toml under its name (the memory layer reads them); its CPU presets in
sim/cpus/presets/.

Adding a family: its package, its policies and presets, and one line in :data:`FAMILIES`.
"""

from __future__ import annotations

import functools
import importlib
from dataclasses import dataclass

from sim.errors import RetrosimError
from sim.cpus import presets, vocabulary
from sim.cpus.view import FamilyView
from sim.cpus.record import ALWAYS, CPUS, Estimate, Family, machine_table, read  # noqa: F401  (re-exported)


@dataclass(frozen=True)
class Registered:
    """A registry line: the family's name and where its model and view classes are."""

    name: str
    model: str  # "module:Class" of the timing model
    view: str   # "module:Class" of its FamilyView


# The registry: one line per family, in the order reports list them.
REGISTRY: tuple[Registered, ...] = (
    Registered("p5", "sim.cpus.p5.model:P5Model", "sim.cpus.p5.view:P5View"),
    Registered("p6", "sim.cpus.p6.model:P6Model", "sim.cpus.p6.view:P6View"),
    Registered("k6", "sim.cpus.k6.model:K6Model", "sim.cpus.k6.view:K6View"),
)
FAMILIES: dict[str, Family] = {r.name: read(r.name) for r in REGISTRY}
_LINES = {r.name: r for r in REGISTRY}


def family(name: str) -> Family:
    """The record of a registered family, or one clear error."""
    try:
        return FAMILIES[name]
    except KeyError:
        raise RetrosimError(f"unknown CPU family '{name}' (registered: {', '.join(FAMILIES)})") from None


def order(name: str) -> int:
    """A family's position in the registry (reports list p5, p6, k6 in this order); unknown last."""
    return list(FAMILIES).index(name) if name in FAMILIES else 9


def _load(path: str):
    module, cls = path.split(":")
    return getattr(importlib.import_module(module), cls)


def model_class(name: str) -> type:
    """The timing model class of a registered family."""
    family(name)
    return _load(_LINES[name].model)


@functools.cache
def view(name: str | None) -> FamilyView:
    """The FamilyView of a family (the family-neutral base view for an unregistered or no family)."""
    if name not in _LINES:
        return FamilyView()
    return _load(_LINES[name].view)()


@functools.cache
def vocabulary_for(cpu: str) -> vocabulary.Vocabulary:
    """The words of a CPU preset's (or machine label's) family: its view's vocabulary (GENERIC for
    a family with no view of its own, an unregistered one or an unknown preset)."""
    try:
        return view(presets.load(cpu.partition("{")[0]).family).vocabulary
    except RetrosimError:
        return vocabulary.GENERIC
