"""CPU families: presets, instruction tables and timing models behind one factory."""

from __future__ import annotations

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


def make_model(cpu: str, memory: str | None = None):
    """The timing model for a CPU preset, with its default memory unless `memory` names another."""
    preset = presets.load(cpu)
    mem = load_dram(memory or preset.memory)
    if preset.family == "p6":
        from .p6 import P6Model

        return P6Model(preset, mem)
    if preset.family == "k6":
        from .k6 import K6Model

        return K6Model(preset, mem)
    if preset.family == "p5":
        from .p5 import P5Model

        return P5Model(preset, mem)
    raise RetrosimError(f"CPU preset '{cpu}': no timing model for family '{preset.family}' yet")
