"""Machine keys: a CPU preset, its overrides and a memory preset as one string.

``pentium2-233``, ``pentium2-233:edo``, ``k6-233{l2.size_kb=256,write_allocate.mode=full}:sdram-pc66``:
the label (a preset with its overrides sorted by key, :func:`sim.cpus.machine_label`), then
``:memory`` when a memory preset is named. Labels never contain ':', so the first ':' is the
memory separator. Scene files, reports, baselines, claims and sweeps all name machines this way;
:class:`MachineKey` is the one place that takes the string apart.
"""

from __future__ import annotations

from dataclasses import dataclass


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
        from sim.cpus import presets

        return presets.load(self.preset).family
