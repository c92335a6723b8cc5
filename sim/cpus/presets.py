"""CPU presets (sim/cpus/presets/*.toml): clocks, caches and default memory, each field sourced."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from sim.errors import RetrosimError
from sim.tomlfile import read_toml
from sim.cpus import record as families  # the record, not the registry (which imports the models)

PRESETS = Path(__file__).resolve().parent / "presets"


class UnknownPreset(RetrosimError):
    pass


@dataclass(frozen=True)
class CacheSpec:
    size_kb: int
    ways: int
    line_bytes: int
    latency_cycles: int | None = None  # load-to-use, core clocks (L1: total; L2: total from the load's start)
    speed_ratio: float = 1.0           # L2 clock / core clock
    estimated: bool = False

    @property
    def size_bytes(self) -> int:
        return self.size_kb * 1024

    def describe(self) -> str:
        speed = "" if self.speed_ratio == 1.0 else f", {self.speed_ratio:g}x clock"
        lat = f", {self.latency_cycles} clk" if self.latency_cycles is not None else ""
        return f"{self.size_kb} KB {self.ways}-way {self.line_bytes} B{lat}{speed}"


@dataclass(frozen=True)
class CpuPreset:
    name: str
    family: str          # timing model: "p6", "k6", ...
    core_mhz: float
    fsb_mhz: float
    l1i: CacheSpec
    l1d: CacheSpec
    l2: CacheSpec | None
    board_cache: CacheSpec | None
    memory: str          # default memory preset
    core: str = ""
    raw: dict = field(default_factory=dict, compare=False, hash=False, repr=False)
    # from the family's record (sim/cpus/families.py), for the layers that may not read it (sim/guest/isa.py)
    family_name: str = ""                    # "the P6 family"
    family_lacks: frozenset = frozenset()    # extensions no CPU of the family has

    @property
    def multiplier(self) -> float:
        return self.core_mhz / self.fsb_mhz


def _cache(section: dict | None) -> CacheSpec | None:
    if not section or not section.get("present", True):
        return None
    return CacheSpec(int(section["size_kb"]), int(section["ways"]), int(section["line_bytes"]),
                     section.get("latency_cycles"), float(section.get("speed_ratio", 1.0)),
                     bool(section.get("latency_estimated", False)))


def available() -> list[str]:
    return sorted(p.stem for p in PRESETS.glob("*.toml"))


def load(name: str) -> CpuPreset:
    if "{" in name:  # a machine label: the preset with its overrides (sim.cpus.machine_label)
        from sim.cpus import load_preset

        return load_preset(name)
    path = PRESETS / f"{name}.toml"
    # a name, never a path: `../../x` would read any .toml (a web request names CPUs too)
    if not path.is_file() or name != Path(name).name or name.startswith("."):
        raise UnknownPreset(f"unknown CPU preset '{name}' (choose one of: {', '.join(available())})")
    _, raw = read_toml(path, "CPU preset")  # a package file edited by hand: one error naming it
    return from_raw(raw, name, path)


def from_raw(raw: dict, name: str, where: str | Path) -> CpuPreset:
    """A :class:`CpuPreset` from a parsed preset file (also used for overridden copies)."""
    record = families.read(raw["cpu_model"]) if families.known(raw.get("cpu_model")) else None
    try:
        return CpuPreset(
            name=raw.get("name", name), family=raw["cpu_model"], core_mhz=float(raw["clock"]["core_mhz"]),
            fsb_mhz=float(raw["clock"]["fsb_mhz"]), l1i=_cache(raw["l1i"]), l1d=_cache(raw["l1d"]),
            l2=_cache(raw.get("l2")), board_cache=_cache(raw.get("board_cache") or raw.get("l3")),
            memory=raw["memory"]["default"], core=raw.get("core", ""), raw=raw,
            family_name=record.display_name if record else raw["cpu_model"],
            family_lacks=record.lacks if record else frozenset())
    except KeyError as e:
        raise RetrosimError(f"{where}: missing field {e}") from None


def dram_overhead(preset: CpuPreset, memory: str) -> float:
    """Bus clocks the board adds before the memory's first transfer (``[memory]
    overhead_bus_clocks``, calibrated per preset on a measured memory latency; a preset may give
    ``overhead_bus_clocks_by_memory = {name = ...}`` for a memory whose chipset differs)."""
    section = preset.raw.get("memory", {})
    by_memory = section.get("overhead_bus_clocks_by_memory", {})
    if memory in by_memory:
        return by_memory[memory]
    if "overhead_bus_clocks" not in section:
        raise RetrosimError(f"CPU preset '{preset.name}': no [memory] overhead_bus_clocks (the board's "
                            "bus clocks before the memory's first transfer)")
    return section["overhead_bus_clocks"]


def model_by_cpuid(preset: CpuPreset, models: dict, family: str, machine_file: str) -> str:
    """The key of the `[models]` entry (of a family's machine file) whose `models` list holds the
    preset's CPUID model number ('p54c', 'k6-2', ...), or one error naming the preset."""
    m = re.search(r"model\s+(\d+)", str(preset.raw.get("cpuid_signature", "")))
    if m:
        for key, info in models.items():
            if isinstance(info, dict) and int(m.group(1)) in info.get("models", ()):
                return key
    raise RetrosimError(f"CPU preset {preset.name}: cpuid_signature {preset.raw.get('cpuid_signature')!r} "
                        f"names no {family} model of {machine_file} [models]")
