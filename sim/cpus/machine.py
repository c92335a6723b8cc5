"""A machine: a CPU preset with its overrides and a memory preset, resolved once at the edge.

Text names a machine only at the edges (files, tables, worker pickling): a *label* is the preset
with its overrides sorted by key (``k6-233{l2.size_kb=256,write_allocate.mode=full}``,
sim.cpus.overrides.machine_label and split_label), a *key* adds ``:memory`` when a memory preset
is named (``pentium2-233:edo``; labels never contain ':', so the first ':' is the memory
separator). Scene files, reports, baselines, claims and sweeps all name machines this way;
:class:`MachineKey` is the one place that takes a key apart.

:func:`resolve` turns a label (or a preset name, with overrides and a memory) into a
:class:`Machine`: the preset with the overrides applied and validated, the memory preset with its
page overrides, the model estimates overridden, the memory's line costs on this bus, and the cache
geometries as plain data, checked (a size that is no cache, or a bus the memory cannot run on, is
refused here, before any work). The commands (sim.cli.app.resolve_machine) and sweep points (in
their worker) resolve once and hand the Machine down: sim.cpus.build.make_model builds its timing
model, sim.guest.cpu.GuestCpu.from_preset(machine.preset) is the guest's view of it.

Dependencies run one way: presets (a preset file) < overrides (a preset with overrides, labels) <
machine < build (the timing model).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from sim.errors import RetrosimError
from sim.memory.cache import CacheGeometry
from sim.memory.dram import DramTiming, LineCosts
from sim.cpus import presets
from sim.cpus.overrides import apply, load_dram, machine_label, normalize_overrides, split_label
from sim.cpus.presets import CpuPreset


@dataclass(frozen=True)
class Machine:
    """A resolved machine (see the module docstring). It pickles as its label and memory."""
    label: str                        # the preset's name, then "{overrides}" when it has any
    preset: CpuPreset                 # overrides applied: name, family, clocks, caches, guest fields
    memory: DramTiming                # the memory preset (the named one, or the preset's default), pages overridden
    memory_named: str | None = None   # the memory preset the edge named (None: the preset's default)
    overrides: tuple = ()             # ((key, value), ...) sorted by key, shorthands expanded
    estimates: tuple = ()             # ((estimate name, value), ...): the family model's overridden estimates
    data_caches: tuple[CacheGeometry, ...] = ()   # L1D, L2, L3 (board cache): what the memory layer builds
    instruction_cache: CacheGeometry | None = None  # the L1I
    line_costs: LineCosts | None = None  # the memory's line costs on this bus, in core clocks

    @property
    def name(self) -> str:
        return self.preset.name

    @property
    def family(self) -> str:
        return self.preset.family

    @property
    def key(self) -> MachineKey:
        return MachineKey(self.label, self.memory_named)

    def __reduce__(self):  # a worker gets the text and resolves it again (same files, same machine)
        return resolve, (self.label, None, self.memory_named)


def resolve(cpu: str | Machine, overrides: dict | None = None, memory: str | None = None) -> Machine:
    """The :class:`Machine` a preset name or machine label names, with `overrides` added to the
    label's own (see :func:`sim.cpus.overrides.overridable`) and `memory` (None: the preset's
    default). Every override is validated, then the bus and the cache geometry: an unknown name or
    an impossible value is one clear error naming the preset (an override) or the machine's label
    (its geometry). A Machine is returned as it is (a memory or overrides given with it resolve
    its label again)."""
    if isinstance(cpu, Machine):
        if not overrides and memory is None:
            return cpu
        cpu, memory = cpu.label, memory if memory is not None else cpu.memory_named
    base, given = split_label(cpu)
    merged = {**given, **normalize_overrides(overrides)}
    label = machine_label(base, merged)  # a value a label cannot hold is refused first, as the label's text
    preset, estimates, pages = apply(base, merged, memory)
    mem = load_dram(memory or preset.memory)
    if pages:  # a page figure replaced: the walk's page geometry and the hit costs follow it
        mem = dataclasses.replace(mem, pages=dataclasses.replace(mem.pages, **pages))
    costs = presets.line_costs_on(preset, mem)  # checked in the order the model would: the bus, then the caches
    try:
        data, instruction = preset.data_caches(), preset.instruction_cache()
    except ValueError as e:  # an overridden cache geometry that is no cache
        raise RetrosimError(f"CPU preset '{label}': {e}") from None
    return Machine(label, preset, mem, memory, tuple(sorted(merged.items())), tuple(sorted(estimates.items())),
                   data, instruction, costs)


def family_of(key: str) -> str:
    """The family (p5, p6, k6) of a machine key or label: 'preset', 'preset{overrides}', either
    with ':memory'. Overrides never change a preset's family, so they are not applied."""
    return MachineKey.parse(key).family


@dataclass(frozen=True)
class MachineKey:
    label: str                 # the preset, with "{overrides}" when it has any
    memory: str | None = None  # the memory preset; None when the key names none (the preset's default)

    @classmethod
    def parse(cls, text: str) -> MachineKey:
        """`label[:memory]`; a trailing ':' gives memory '' (which no memory preset is called)."""
        label, sep, memory = text.partition(":")
        return cls(label, memory if sep else None)

    def __str__(self) -> str:
        return self.label if self.memory is None else f"{self.label}:{self.memory}"

    @property
    def preset(self) -> str:
        """The CPU preset without its overrides (overrides never change which preset it is)."""
        return self.label.split("{", 1)[0]

    @property
    def overridden(self) -> bool:
        return self.label != self.preset

    @property
    def display(self) -> str:
        """`label (memory)`, as the reports' tables and legends name a machine."""
        return self.label if self.memory is None else f"{self.label} ({self.memory})"

    @property
    def family(self) -> str:
        """The family (p5, p6, k6) of the preset."""
        return presets.load(self.preset).family
