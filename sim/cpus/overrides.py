"""Overrides of a CPU preset: what may be overridden, the plausible range of each value, the
preset with its overrides applied, and its label (the preset with its overrides, as text).

Overrides (``--set KEY=VALUE``, machine labels, scene ``[[run.machine]] set = {...}``) replace a
preset field or a model estimate (:func:`overridable` lists them). Every value is checked before
any work against a finite, plausible range, so no cycle count in the cores can overflow (every
input is bounded) and no run is slowed without end by an absurd figure (:data:`RANGES`):

- ``clock.core_mhz`` 1..2000 MHz; ``clock.fsb_mhz`` 1..200 MHz; core/bus ratio 1..16 in steps
  of 1/4 (so a bus clock is a whole number of quarter core clocks), and the bus no faster than
  the memory preset is rated for;
- ``LEVEL.size_kb`` 1..65536 KB; ``LEVEL.ways`` 1..64; ``LEVEL.line_bytes`` 8..256, a power of
  two (the cache geometry itself must still be one: a power-of-two number of sets, one line
  size for every level); ``LEVEL.latency_cycles`` 1..1000 core clocks; ``LEVEL.speed_ratio``
  (cache clock / core clock) 1/8..1;
- ``memory.overhead_bus_clocks`` 0..1000 bus clocks;
- ``pages.FIELD``: the memory preset's ``[pages]`` figures (sim/memory/presets/NAME.toml, the
  machine's memory): ``open_pages`` 1..16 and ``page_bytes`` 512..65536, powers of two;
  ``hit_saving_bus_clocks`` and ``write_saving_bus_clocks`` 0..16 bus clocks;
- ``estimates.NAME``: the family machine table's stated plausible range
  (``[estimates.NAME] range``, with its ``range_reason``).
"""

from __future__ import annotations

import dataclasses
import math
import re
from fractions import Fraction

from sim.errors import RetrosimError
from sim.memory import dram
from sim.cpus import families, presets
from sim.memory.cache import WRITE_ALLOCATE_MODES


def memory_presets() -> list[str]:
    return dram.available_memory_presets()


def load_dram(name: str) -> dram.DramTiming:
    """A memory preset (sim/memory/presets/NAME.toml), or one clear error."""
    try:
        return dram.load_memory_preset(name)
    except ValueError as e:
        if name not in memory_presets():
            raise RetrosimError(f"unknown memory preset '{name}' (choose one of: {', '.join(memory_presets())})") from None
        raise RetrosimError(f"memory preset '{name}': {e}") from None


MODEL_FIELDS = ("clock.core_mhz", "clock.fsb_mhz", "memory.overhead_bus_clocks") + tuple(
    f"{level}.{f}" for level in ("l1i", "l1d", "l2", "l3", "board_cache")
    for f in ("size_kb", "ways", "line_bytes", "latency_cycles", "speed_ratio"))


def overridable(cpu: str, memory: str | None = None) -> dict[str, float]:
    """Every parameter :func:`make_model` accepts in ``overrides`` for a CPU preset, with its value:
    numeric fields of the preset file by dotted path (``l2.latency_cycles``,
    ``memory.overhead_bus_clocks``, ``clock.core_mhz``, ...), the family model's numeric
    estimates as ``estimates.NAME``, and the page figures of the memory preset (`memory`, or the
    CPU preset's default) as ``pages.FIELD`` where it has a ``[pages]`` table. `cpu` may be a
    machine label: the preset file's fields then have its overridden values."""
    base, given = split_label(cpu)
    preset = presets.load(base)
    out = {}

    def walk(d: dict, prefix: str):
        for k, v in d.items():
            if isinstance(v, dict):
                walk(v, f"{prefix}{k}.")
            elif isinstance(v, (int, float)) and not isinstance(v, bool):
                out[f"{prefix}{k}"] = v

    walk(preset.raw, "")
    # only what a model reads: a documentation field (a measured figure, a multiplier note) would
    # be overridden without any effect
    out = {k: v for k, v in out.items() if k in MODEL_FIELDS}
    out |= {k: v for k, v in checked(base, given).items() if k in out}  # a label's own values
    for key in CHOICES:  # non-numeric fields that may be overridden, where the preset has the section
        if key.split(".")[0] in preset.raw:
            out[key] = CHOICES[key][0]
    if preset.family in families.FAMILIES:  # the family's estimates (its machine table's [estimates])
        for est in families.family(preset.family).overridable():
            out[est.key] = est.default
    pages = load_dram(memory or preset.memory).pages
    if pages is not None:
        out |= {f"pages.{f}": getattr(pages, f) for f in dram.PAGE_FIELDS}
    return out


# Overrides that are not numbers: key (dotted, as in the preset file) -> allowed values. The
# K6 presets' write allocation (sim.memory.cache.WRITE_ALLOCATE_MODES) and an L2 that is absent.
CHOICES = {"write_allocate.mode": ("full", "page+sector only", "none"), "l2.present": (True, False)}


# Plausible range of each numeric preset field an override may set (see the module docstring):
# field key, or LEVEL-less leaf for a cache level's field -> (low, high, what it is). Wide enough
# for any machine of the era and beyond (every shipped preset, scene and sweep lies inside), narrow
# enough that a cycle count stays far below 2^63: 1000-clock latencies x 16 x 1000 bus clocks of
# overhead x the trace limit's instructions.
RANGES = {
    "clock.core_mhz": (1, 2000, "core clock in MHz"),
    "clock.fsb_mhz": (1, 200, "front-side bus clock in MHz"),
    "memory.overhead_bus_clocks": (0, 1000, "board overhead of a memory access in bus clocks"),
    "size_kb": (1, 65536, "cache size in KB"),
    "ways": (1, 64, "associativity"),
    "line_bytes": (8, 256, "line size in bytes, a power of two"),
    "latency_cycles": (1, 1000, "load-to-use latency in core clocks"),
    "speed_ratio": (0.125, 1, "cache clock / core clock"),
    "pages.open_pages": (1, 16, "open DRAM pages (banks), a power of two"),  # hierarchy.MAX_OPEN_PAGES
    "pages.page_bytes": (512, 65536, "DRAM page (row) size in bytes, a power of two"),
    "pages.hit_saving_bus_clocks": (0, 16, "bus clocks a page hit saves against a page miss"),
    "pages.write_saving_bus_clocks": (0, 16, "bus clocks a line write saves against a read"),
}
POWER_OF_TWO = (".line_bytes", "pages.open_pages", "pages.page_bytes")
MAX_BUS_RATIO = 16  # core clock / bus clock (the era's multipliers were 1.5 to 5)


def value_range(cpu: str, key: str) -> tuple[float, float, str] | None:
    """(low, high, what) an override of `key` must lie in (None for a CHOICES key)."""
    if key.startswith("estimates."):
        family = load_preset(cpu).family
        est = families.family(family).estimates[key.split(".", 1)[1]]
        return est.low, est.high, f"the plausible range in {family}_machine.toml [estimates.{est.name}]"
    return RANGES.get(key) or RANGES.get(key.rsplit(".", 1)[-1])


def check_value(cpu: str, key: str, value, old) -> float | str | bool:
    """One override value: a finite number >= 0, whole where the field is whole, >= 1 for a latency,
    a count or a size (a zero there is no machine), inside the field's plausible range
    (:func:`value_range`); or one of CHOICES[key]."""
    where = f"CPU preset '{cpu}': override {key}"
    if key in CHOICES:
        if value not in CHOICES[key] or type(value) is not type(CHOICES[key][0]):
            shown = ", ".join(format_value(c) for c in CHOICES[key])
            raise RetrosimError(f"{where}: expected one of {shown}, got {format_value(value)}")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise RetrosimError(f"{where}: expected a finite number, got {value!r}")
    if value < 0:
        raise RetrosimError(f"{where}: must be >= 0, got {value}")
    if isinstance(old, int) and value != int(value):
        raise RetrosimError(f"{where}: must be a whole number (the preset's value is {old}), got {value}")
    leaf = key.rsplit(".", 1)[-1]
    if value == 0 and not leaf.startswith(("overhead", "partial", "static", "mispredict", "hit_saving", "write_saving")):
        raise RetrosimError(f"{where}: must be > 0, got {value}")
    bounds = value_range(cpu, key)
    if bounds is not None:
        low, high, what = bounds
        if not low <= value <= high:
            raise RetrosimError(f"{where}: must be between {format_value(low)} and {format_value(high)} "
                                f"({what}), got {format_value(value)}")
        if key.endswith(POWER_OF_TWO) and int(value) & (int(value) - 1):
            raise RetrosimError(f"{where}: must be a power of two ({what}), got {format_value(value)}")
    return int(value) if isinstance(old, int) else float(value)


def check_clocks(cpu: str, core: float, fsb: float) -> None:
    """The core/bus ratio of an overridden preset: 1..MAX_BUS_RATIO in steps of 1/4 (checked before any
    work: a bus clock of a millionth of the core's would make every memory access last for ever)."""
    ratio = Fraction(str(core)) / Fraction(str(fsb))
    if not 1 <= ratio <= MAX_BUS_RATIO:
        raise RetrosimError(f"CPU preset '{cpu}': override clock: core {format_value(core)} MHz / bus "
                            f"{format_value(fsb)} MHz = {float(ratio):.4g} is outside 1..{MAX_BUS_RATIO} "
                            "(core clocks per bus clock)")


def format_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and math.isfinite(value) and value == int(value):
        return str(int(value)) if abs(value) < 1e15 else repr(value)
    return str(value)


def parse_value(text: str):
    """A command-line or label override value: true/false, an integer, a number, or a string."""
    t = text.strip()
    if t.lower() in ("true", "false"):
        return t.lower() == "true"
    for conv in (lambda x: int(x, 0), float):
        try:
            return conv(t)
        except ValueError:
            pass
    return t


def normalize_overrides(overrides: dict | None) -> dict:
    """Overrides with the shorthands expanded: ``SECTION.size_kb = "none"`` means the cache level is
    absent (``SECTION.present = false``)."""
    out = {}
    for key, value in (overrides or {}).items():
        key = str(key)
        if key.endswith(".size_kb") and isinstance(value, str) and value.lower() == "none":
            out[key[: -len("size_kb")] + "present"] = False
        else:
            out[key] = value
    return out


def checked(cpu: str, overrides: dict, memory: str | None = None) -> dict:
    """`overrides` of the preset `cpu` with every value checked (:func:`check_value`; a
    ``pages.FIELD`` against `memory`, or the preset's default memory), or one error naming it."""
    if not overrides:
        return {}
    allowed = overridable(cpu, memory)
    out = {}
    for key, value in overrides.items():
        if key not in allowed:
            near = sorted(k for k in allowed if k.rsplit(".", 1)[-1] == str(key).rsplit(".", 1)[-1])
            hint = f" (did you mean {', '.join(near)}?)" if near else f" (known: {', '.join(sorted(allowed))})"
            raise RetrosimError(f"CPU preset '{cpu}': unknown override '{key}'{hint}")
        out[key] = check_value(cpu, key, value, allowed[key])
    return out


# The typed field of a CpuPreset each preset-file override replaces: a section's cache level, or
# one of these (a [write_allocate] mode is the L1D's write allocation).
TOP_FIELDS = {"clock.core_mhz": "core_mhz", "clock.fsb_mhz": "fsb_mhz", "memory.overhead_bus_clocks": "overhead_bus_clocks"}
LEVEL_FIELDS = {"l1i": "l1i", "l1d": "l1d", "l2": "l2", "l3": "board_cache", "board_cache": "board_cache"}
CAST = {"size_kb": int, "ways": int, "line_bytes": int, "speed_ratio": float, "latency_cycles": lambda v: v,
        "core_mhz": float, "fsb_mhz": float, "overhead_bus_clocks": lambda v: v}  # as presets.from_raw reads them


def apply(cpu: str, overrides: dict, memory: str | None = None):
    """(preset with `overrides` applied, estimate overrides, memory page overrides), every override
    validated (:func:`checked`). The preset's typed fields are replaced (its file's dict is not
    copied or changed: the models read the typed fields)."""
    preset = presets.load(cpu)
    estimates, pages, top, levels = {}, {}, {}, {}
    for key, value in checked(cpu, overrides, memory).items():
        if key.startswith("estimates."):
            estimates[key.split(".", 1)[1]] = value
        elif key.startswith("pages."):
            pages[key.split(".", 1)[1]] = value
        elif key in TOP_FIELDS:
            top[TOP_FIELDS[key]] = CAST[TOP_FIELDS[key]](value)
        elif key == "write_allocate.mode":
            levels.setdefault("l1d", {})["write_allocate"] = WRITE_ALLOCATE_MODES[value]
        else:
            section, leaf = key.split(".")
            levels.setdefault(section, {})[leaf] = value
    for section, fields in levels.items():
        name, present = LEVEL_FIELDS[section], fields.pop("present", True)
        spec = getattr(preset, name)
        if not present:
            top[name] = None
            continue
        if spec is None:  # turned on where the preset file turns it off: its section's own figures
            on = {**preset.raw, section: {**preset.raw[section], "present": True}}
            spec = getattr(presets.from_raw(on, cpu, f"CPU preset '{cpu}' (overridden)"), name)
        top[name] = dataclasses.replace(spec, **{k: CAST.get(k, lambda v: v)(v) for k, v in fields.items()})
    preset = dataclasses.replace(preset, **top) if top else preset
    if any(k.startswith("clock.") for k in overrides):
        check_clocks(cpu, preset.core_mhz, preset.fsb_mhz)
    return preset, estimates, pages


# -- machine labels: a preset with overrides, as one string --------------------------------------
# "k6-233{write_allocate.mode=full}" or "pentium2-233{l2.latency_cycles=10,l2.size_kb=256}": the
# preset name, then the overrides sorted by key. Labels name machines in reports, baselines and
# sweeps, so they say exactly what was changed; they never contain ':' (the memory separator).
_LABEL = re.compile(r"^([A-Za-z0-9._-]+)(?:\{(.*)\})?$")
_FORBIDDEN = set(":{},=")


def machine_label(cpu: str, overrides: dict | None = None) -> str:
    """The label of a preset with overrides (just the preset's name without any)."""
    base, given = split_label(cpu)
    merged = {**given, **normalize_overrides(overrides)}
    if not merged:
        return base
    for k, v in merged.items():
        if _FORBIDDEN & set(format_value(v)):
            raise RetrosimError(f"CPU preset '{base}': override {k}: value {format_value(v)!r} may not contain "
                                f"any of {' '.join(sorted(_FORBIDDEN))}")
    return base + "{" + ",".join(f"{k}={format_value(merged[k])}" for k in sorted(merged)) + "}"


def split_label(label: str) -> tuple[str, dict]:
    """(preset name, overrides) of a machine label (see :func:`machine_label`)."""
    m = _LABEL.match(label.strip())
    if not m:
        raise RetrosimError(f"malformed CPU '{label}': expected PRESET or PRESET{{key=value,...}}")
    overrides = {}
    for item in filter(None, (m.group(2) or "").split(",")):
        key, eq, value = item.partition("=")
        if not eq or not key.strip():
            raise RetrosimError(f"malformed CPU '{label}': '{item}' is not key=value")
        overrides[key.strip()] = parse_value(value)
    return m.group(1), normalize_overrides(overrides)


def load_preset(label: str):
    """The preset a machine label names, with its overrides applied and validated."""
    base, overrides = split_label(label)
    preset, _, _ = apply(base, overrides)
    return preset
