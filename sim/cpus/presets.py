"""CPU presets (sim/cpus/presets/*.toml): clocks, caches and default memory, each field sourced.

:func:`from_raw` turns a preset file's dict into a typed :class:`CpuPreset` (its caches with their
policies resolved against sim/memory/policies.toml, its instruction-set and assembler names, its
board overhead), and the layers read those fields, never the dict (``raw`` is kept for
:mod:`sim.cpus.overrides`, which lists the file's numeric fields as what may be overridden, and for
two family-only figures the P5 and K6 models read: a board cache's bus clocks). A preset with
overrides is :mod:`sim.cpus.overrides`'s; a whole machine is :mod:`sim.cpus.machine`'s.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from sim.errors import RetrosimError
from sim.memory.cache import CacheGeometry, WRITE_ALLOCATE_MODES
from sim.memory.dram import DramTiming, LineCosts, line_costs
from sim.memory.hierarchy import POLICIES_FILE, family_policies
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
    estimated: bool = False            # the latency is an estimate (latency_estimated)
    on_board: bool = False             # a motherboard cache (its location says so)
    # the data caches' policies (sim/memory/policies.toml, or the level's own override): the memory
    # layer builds its caches from these (:meth:`geometry`); the L1I's are the instruction side's
    replacement: str = "lru"
    write_back: bool = True
    write_allocate: bool | str = True

    @property
    def size_bytes(self) -> int:
        return self.size_kb * 1024

    def describe(self) -> str:
        speed = "" if self.speed_ratio == 1.0 else f", {self.speed_ratio:g}x clock"
        lat = f", {self.latency_cycles} clk" if self.latency_cycles is not None else ""
        return f"{self.size_kb} KB {self.ways}-way {self.line_bytes} B{lat}{speed}"

    def geometry(self, name: str) -> CacheGeometry:
        """The memory layer's geometry of this level (a ValueError if it is no cache: e.g. an
        overridden size that is not ways x line x a power-of-two number of sets)."""
        return CacheGeometry(name, self.size_bytes, self.ways, self.line_bytes, self.replacement, self.write_back,
                             self.write_allocate)


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
    # what the guest stages need (sim/guest/cpu.py, sim/guest/isa.py)
    isa_extensions: frozenset = frozenset()  # beyond i586
    gnu_march: str = ""                      # GNU as -march=
    zig_mcpu: str = ""                       # clang -mcpu=
    emulator_cpu: str | None = None          # a Unicorn CPU model, None: Unicorn's default
    cpuid_signature: str | None = None       # "family 6 model 5"
    # the board's bus clocks before the memory's first transfer ([memory] overhead_bus_clocks, None
    # if the preset gives none) and per memory preset where its chipset differs
    overhead_bus_clocks: float | None = None
    overhead_by_memory: tuple = ()           # ((memory preset, bus clocks), ...)
    overhead_estimated: bool = False         # carried over from another system, not calibrated on this one

    @property
    def multiplier(self) -> float:
        return self.core_mhz / self.fsb_mhz

    def data_caches(self) -> tuple[CacheGeometry, ...]:
        """The data side's levels (L1D, L2 unless absent, the board cache as L3), as the memory
        layer builds them; a ValueError names a level that is no cache."""
        levels = (("L1D", self.l1d), ("L2", self.l2), ("L3", self.board_cache))
        return tuple(spec.geometry(name) for name, spec in levels if spec is not None)

    def instruction_cache(self) -> CacheGeometry:
        """The instruction side: the L1I alone, LRU, never allocating on a write (an L1I miss is
        charged by the core but does not enter the data side's caches)."""
        i = self.l1i
        return CacheGeometry("L1I", i.size_bytes, i.ways, i.line_bytes, replacement="lru", write_allocate=False)


def _cache(section: dict | None, policy: dict | None = None) -> CacheSpec | None:
    """A cache level's section, with its data-cache `policy` (replacement, write_back, write_allocate:
    the family's defaults with the section's own overrides) when it is a data cache."""
    if not section or not section.get("present", True):
        return None
    return CacheSpec(int(section["size_kb"]), int(section["ways"]), int(section["line_bytes"]),
                     section.get("latency_cycles"), float(section.get("speed_ratio", 1.0)),
                     bool(section.get("latency_estimated", False)),
                     "motherboard" in str(section.get("location", "")), **(policy or {}))


def _policy(raw: dict, level: str, where) -> dict | None:
    """The data-cache policy of a level (section `level` of the preset): the family's
    (``cpu_model``) in sim/memory/policies.toml, which the section may override with
    ``replacement``, ``write_back``, ``write_allocate`` or ``write_policy = "write-back" |
    "write-through"``; a top-level ``[write_allocate] mode = "full" | "page+sector only" | "none"``
    sets the L1D's write allocation (the K6 presets)."""
    section = raw.get(level)
    if section is None or not section.get("present", True):
        return None
    family = raw.get("cpu_model")
    policies = family_policies()
    if family not in policies:
        raise RetrosimError(f"{where}: cpu_model {family!r} has no cache policies in {POLICIES_FILE.name} "
                            f"(known: {', '.join(sorted(policies))})")
    defaults = policies[family].get(level)
    if defaults is None:
        raise RetrosimError(f"{where}: [{level}] given but {POLICIES_FILE.name} has no [{family}.{level}] policy")
    out = {key: section.get(key, defaults[key]) for key in ("replacement", "write_back", "write_allocate")}
    if "write_policy" in section:
        out["write_back"] = _choice(where, f"[{level}] write_policy", section["write_policy"],
                                    {"write-back": True, "write-through": False})
    if level == "l1d" and "write_allocate" in raw:
        out["write_allocate"] = _choice(where, "[write_allocate] mode", raw["write_allocate"].get("mode"),
                                        WRITE_ALLOCATE_MODES)
    return out


def _choice(where, field: str, value, choices: dict):
    if value not in choices:
        raise RetrosimError(f"{where}: {field} = {value!r} is not one of {', '.join(repr(c) for c in choices)}")
    return choices[value]


def available() -> list[str]:
    return sorted(p.stem for p in PRESETS.glob("*.toml"))


def load(name: str) -> CpuPreset:
    """The preset file `name` (a preset's name; a machine label, with overrides, is resolved by
    sim.cpus.machine.load_preset)."""
    path = PRESETS / f"{name}.toml"
    # a name, never a path: `../../x` would read any .toml (a web request names CPUs too)
    if not path.is_file() or name != Path(name).name or name.startswith("."):
        raise UnknownPreset(f"unknown CPU preset '{name}' (choose one of: {', '.join(available())})")
    _, raw = read_toml(path, "CPU preset", shared=True)  # a package file edited by hand: one error naming it
    return from_raw(raw, name, path)


def from_raw(raw: dict, name: str, where: str | Path) -> CpuPreset:
    """A :class:`CpuPreset` from a parsed preset file (also used for overridden copies)."""
    record = families.read(raw["cpu_model"]) if families.known(raw.get("cpu_model")) else None
    try:
        memory = raw["memory"]
        return CpuPreset(
            name=raw.get("name", name), family=raw["cpu_model"], core_mhz=float(raw["clock"]["core_mhz"]),
            fsb_mhz=float(raw["clock"]["fsb_mhz"]), l1i=_cache(raw["l1i"]),
            l1d=_cache(raw["l1d"], _policy(raw, "l1d", where)), l2=_cache(raw.get("l2"), _policy(raw, "l2", where)),
            board_cache=_cache(raw.get("board_cache") or raw.get("l3"), _policy(raw, "l3", where)),
            memory=memory["default"], core=raw.get("core", ""), raw=raw,
            family_name=record.display_name if record else raw["cpu_model"],
            family_lacks=record.lacks if record else frozenset(),
            isa_extensions=frozenset(raw.get("isa_extensions", ())), gnu_march=raw.get("gnu_march") or "",
            zig_mcpu=raw.get("zig_mcpu") or "", emulator_cpu=raw.get("emulator_cpu"),
            cpuid_signature=raw.get("cpuid_signature"),
            overhead_bus_clocks=memory.get("overhead_bus_clocks"),
            overhead_by_memory=tuple(memory.get("overhead_bus_clocks_by_memory", {}).items()),
            overhead_estimated=bool(memory.get("overhead_estimated", False)))
    except KeyError as e:
        raise RetrosimError(f"{where}: missing field {e}") from None


def dram_overhead(preset: CpuPreset, memory: str) -> float:
    """Bus clocks the board adds before the memory's first transfer (``[memory]
    overhead_bus_clocks``, calibrated per preset on a measured memory latency; a preset may give
    ``overhead_bus_clocks_by_memory = {name = ...}`` for a memory whose chipset differs)."""
    by_memory = dict(preset.overhead_by_memory)
    if memory in by_memory:
        return by_memory[memory]
    if preset.overhead_bus_clocks is None:
        raise RetrosimError(f"CPU preset '{preset.name}': no [memory] overhead_bus_clocks (the board's "
                            "bus clocks before the memory's first transfer)")
    return preset.overhead_bus_clocks


def line_costs_on(preset: CpuPreset, memory: DramTiming) -> LineCosts:
    """A memory preset's line costs in core clocks on the preset's bus, with the board's overhead
    for that memory (:func:`dram_overhead`); a bus the memory cannot run on is one error naming both."""
    try:
        return line_costs(memory, preset.core_mhz, preset.fsb_mhz, dram_overhead(preset, memory.name))
    except ValueError as e:
        raise RetrosimError(f"{preset.name} with {memory.name}: {e}") from None


def model_by_cpuid(preset: CpuPreset, models: dict, family: str, machine_file: str) -> str:
    """The key of the `[models]` entry (of a family's machine file) whose `models` list holds the
    preset's CPUID model number ('p54c', 'k6-2', ...), or one error naming the preset."""
    m = re.search(r"model\s+(\d+)", str(preset.cpuid_signature or ""))
    if m:
        for key, info in models.items():
            if isinstance(info, dict) and int(m.group(1)) in info.get("models", ()):
                return key
    raise RetrosimError(f"CPU preset {preset.name}: cpuid_signature {preset.cpuid_signature!r} "
                        f"names no {family} model of {machine_file} [models]")
