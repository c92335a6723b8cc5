"""The CPU a kernel is built and run for, as the guest stages see it: the assembler's names for it,
the Unicorn CPU model that emulates it, and the instruction-set extensions it has.

The guest stages never read CPU presets (the emulator knows nothing about timing models). The
command or library entry that chose a preset resolves it once and hands down a :class:`GuestCpu`
(:meth:`GuestCpu.from_preset`); the preset fields it reads are documented in sim/guest/isa.py.
"""

from __future__ import annotations

from dataclasses import dataclass

from sim.errors import RetrosimError


@dataclass(frozen=True)
class GuestCpu:
    name: str                       # the preset's name, for messages
    family: str                     # its family (cpu_model), for the refusal messages of sim/guest/isa.py
    extensions: frozenset[str]      # isa_extensions: what it has beyond i586
    gnu_march: str = ""             # GNU as -march=
    zig_mcpu: str = ""              # clang -mcpu=
    emulator_cpu: str | None = None  # a Unicorn CPU model (UC_CPU_X86_<name>); None: Unicorn's default
    family_name: str = ""            # "the P6 family": a refusal of what no CPU of the family has names it
    family_lacks: frozenset[str] = frozenset()  # extensions no CPU of the family has (the family's record)

    @classmethod
    def from_preset(cls, preset) -> GuestCpu:
        """The guest's view of a CPU preset (a sim.cpus.presets.CpuPreset, or a resolved machine's
        ``.preset``: its name, family, the family record's display name and lacks, and its
        ``isa_extensions``, ``gnu_march``, ``zig_mcpu`` and ``emulator_cpu`` fields, typed)."""
        return cls(preset.name, preset.family, frozenset(preset.isa_extensions), preset.gnu_march or "",
                   preset.zig_mcpu or "", preset.emulator_cpu, preset.family_name or preset.family,
                   frozenset(preset.family_lacks))

    def march(self, assembler: str) -> str:
        """The assembler's CPU name (GNU as -march= / clang -mcpu=)."""
        key = "zig_mcpu" if assembler == "zig" else "gnu_march"
        value = getattr(self, key)
        if not value:
            raise RetrosimError(f"CPU preset '{self.name}': missing field '{key}' (the assembler's name for the CPU)")
        return value


def require(cpu) -> GuestCpu | None:
    """`cpu` itself if it is a GuestCpu or None; a preset name is refused (it is resolved by the
    caller, once: GuestCpu.from_preset(sim.cpus.presets.load(name)))."""
    if cpu is None or isinstance(cpu, GuestCpu):
        return cpu
    raise TypeError(f"expected a sim.guest.cpu.GuestCpu or None, got {cpu!r} (resolve a preset name with "
                    "GuestCpu.from_preset(sim.cpus.presets.load(name)))")
