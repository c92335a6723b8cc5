"""The timing model of a machine: the family's model class (sim/cpus/families.py) built on a
resolved :class:`sim.cpus.machine.Machine`."""

from __future__ import annotations

from sim.errors import RetrosimError
from sim.cpus import families
from sim.cpus.machine import Machine, resolve


def make_model(machine: Machine | str, memory: str | None = None, overrides: dict | None = None):
    """The timing model of `machine` (a :class:`Machine`, from :func:`sim.cpus.machine.resolve`).

    A preset name or machine label (``"k6-233{write_allocate.mode=full}"``) with `memory` and
    `overrides` is resolved here first, for the callers that name a machine by text (tests,
    benchmarks, and the commands that still pass labels down): ``make_model(resolve(cpu,
    overrides, memory))``. An unknown name or an impossible value is one clear error."""
    if not isinstance(machine, Machine) or memory is not None or overrides:
        machine = resolve(machine, overrides, memory)
    preset = machine.preset
    if preset.family not in families.FAMILIES:
        raise RetrosimError(f"CPU preset '{machine.label}': no timing model for family '{preset.family}' yet")
    model = families.model_class(preset.family)
    try:
        return model(preset, machine.memory, dict(machine.estimates))
    except ValueError as e:
        raise RetrosimError(f"CPU preset '{machine.label}': {e}") from None
