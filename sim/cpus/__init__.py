"""CPU families: presets, instruction tables and timing models behind one factory."""

from __future__ import annotations

import copy
import math

from ..errors import RetrosimError
from ..memory import dram
from . import presets


def memory_presets() -> list[str]:
    return dram.available_memory_presets()


def load_dram(name: str) -> dram.DramTiming:
    """A memory preset (sim/cpus/presets/memory/NAME.toml), or one clear error."""
    try:
        return dram.load_memory_preset(name)
    except ValueError as e:
        if name not in memory_presets():
            raise RetrosimError(f"unknown memory preset '{name}' (choose one of: {', '.join(memory_presets())})") from None
        raise RetrosimError(f"memory preset '{name}': {e}") from None


def _family_estimates(family: str) -> dict:
    """The family model's ESTIMATES (name -> (value, reason))."""
    if family == "p6":
        from .p6 import ESTIMATES
    elif family == "k6":
        from .k6 import ESTIMATES
    else:
        return {}
    return ESTIMATES


MODEL_FIELDS = ("clock.core_mhz", "clock.fsb_mhz", "memory.overhead_bus_clocks") + tuple(
    f"{level}.{f}" for level in ("l1i", "l1d", "l2", "l3", "board_cache")
    for f in ("size_kb", "ways", "line_bytes", "latency_cycles", "speed_ratio"))


def overridable(cpu: str) -> dict[str, float]:
    """Every parameter :func:`make_model` accepts in ``overrides`` for a CPU preset, with its value:
    numeric fields of the preset file by dotted path (``l2.latency_cycles``,
    ``memory.overhead_bus_clocks``, ``clock.core_mhz``, ...) and the family model's numeric
    estimates as ``estimates.NAME``."""
    preset = presets.load(cpu)
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
    out = {k: v for k, v in out.items() if k.startswith(MODEL_FIELDS)}
    for name, (value, _) in _family_estimates(preset.family).items():
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            out[f"estimates.{name}"] = value
    return out


def _check_value(cpu: str, key: str, value, old) -> float:
    """One override value: a finite number >= 0, whole where the field is whole, >= 1 for a latency,
    a count or a size (a zero there is no machine)."""
    where = f"CPU preset '{cpu}': override {key}"
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise RetrosimError(f"{where}: expected a finite number, got {value!r}")
    if value < 0:
        raise RetrosimError(f"{where}: must be >= 0, got {value}")
    if isinstance(old, int) and value != int(value):
        raise RetrosimError(f"{where}: must be a whole number (the preset's value is {old}), got {value}")
    leaf = key.rsplit(".", 1)[-1]
    if value == 0 and not leaf.startswith(("overhead", "partial", "static", "mispredict")):
        raise RetrosimError(f"{where}: must be > 0, got {value}")
    return int(value) if isinstance(old, int) else float(value)


def make_model(cpu: str, memory: str | None = None, overrides: dict | None = None):
    """The timing model for a CPU preset, with its default memory unless `memory` names another.

    `overrides` replaces preset fields or model estimates by name (see :func:`overridable`), e.g.
    ``{"l2.latency_cycles": 10, "memory.overhead_bus_clocks": 12, "estimates.uop_queue": 8}``;
    an unknown name or an impossible value is one clear error."""
    preset = presets.load(cpu)
    estimates = {}
    if overrides:
        allowed = overridable(cpu)
        raw = copy.deepcopy(preset.raw)
        for key, value in overrides.items():
            if key not in allowed:
                near = sorted(k for k in allowed if k.rsplit(".", 1)[-1] == str(key).rsplit(".", 1)[-1])
                hint = f" (did you mean {', '.join(near)}?)" if near else f" (known: {', '.join(sorted(allowed))})"
                raise RetrosimError(f"CPU preset '{cpu}': unknown override '{key}'{hint}")
            value = _check_value(cpu, key, value, allowed[key])
            if key.startswith("estimates."):
                estimates[key.split(".", 1)[1]] = value
                continue
            *path, leaf = key.split(".")
            section = raw
            for part in path:
                section = section[part]
            section[leaf] = value
        preset = presets.from_raw(raw, cpu, f"CPU preset '{cpu}' (overridden)")
    mem = load_dram(memory or preset.memory)
    try:
        if preset.family == "p6":
            from .p6 import P6Model

            return P6Model(preset, mem, estimates)
        if preset.family == "k6":
            from .k6 import K6Model

            return K6Model(preset, mem, estimates)
        if preset.family == "p5":
            from .p5 import P5Model

            return P5Model(preset, mem, estimates)
    except ValueError as e:  # e.g. an overridden cache geometry that is no cache
        raise RetrosimError(f"CPU preset '{cpu}': {e}") from None
    raise RetrosimError(f"CPU preset '{cpu}': no timing model for family '{preset.family}' yet")
