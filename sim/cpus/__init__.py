"""CPU families: presets, instruction tables and timing models behind one factory."""

from __future__ import annotations

import tomllib

from ..errors import RetrosimError
from . import presets

MEMORY_PRESETS = presets.PRESETS / "memory"


def memory_presets() -> list[str]:
    return sorted(p.stem for p in MEMORY_PRESETS.glob("*.toml"))


def load_memory(name: str) -> dict:
    """The raw memory preset (for listings); timing models use sim.memory.dram."""
    path = MEMORY_PRESETS / f"{name}.toml"
    if not path.is_file():
        raise RetrosimError(f"unknown memory preset '{name}' (choose one of: {', '.join(memory_presets())})")
    with open(path, "rb") as f:
        return tomllib.load(f)


def load_dram(name: str):
    from ..memory.dram import load_memory_preset

    load_memory(name)  # the unknown-name error with the preset list
    try:
        return load_memory_preset(name)
    except ValueError as e:
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
    raise RetrosimError(f"CPU preset '{cpu}': no timing model for family '{preset.family}' yet")
