"""The scene-kind interface: what a kind of scene (Z-buffer, texture mapping, vertex snapping)
provides, so that the command line, the baselines and the sweeps handle every kind the same way.

A kind is a package under sim/scenes/ (zbuffer/, texture/, snap/) whose kind.py defines ``KIND``,
an instance of a :class:`SceneKind` subclass; sim.scenes.registry lists them by the name a scene
file gives in ``[scene] kind``. The kind's scene module documents its file format.

Also here: :class:`Timing`, the counters of one emulation on one machine that the Z-buffer and snap
results list, and the counters a baseline records (:data:`BASELINE_COUNTERS`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from sim.reports.render import FORMATS

Progress = Callable[[str], None]

# the counters reports/baselines.json records per case (sim.scenes.baseline)
BASELINE_COUNTERS = ("cycles", "instructions", "uops", "decode_groups", "l1d_load_misses", "l1d_store_misses",
                     "l2_misses", "dram_fills", "mispredicts")


@dataclass(frozen=True)
class Timing:
    variant: str
    cpu: str      # machine label: the preset, with {overrides} when it has any
    memory: str   # memory preset name
    pixels: int   # the units of work timed (pixels; vertices for a snap scene)
    counters: dict

    @property
    def key(self) -> str:
        return f"{self.cpu}:{self.memory}"

    def per_pixel(self, name: str) -> float:
        return self.counters[name] / self.pixels if self.pixels else 0.0


class SceneKind:
    """One kind of scene. Scenes (what `load` returns) have at least ``path``, ``name``, ``kind``,
    ``variants`` and ``cpus`` (machine keys); results (what `run` returns) have ``scene``,
    ``pixels`` (the units of work) and ``cpu_keys``."""

    name: str = ""
    unit: str = "pixel"  # what the units of work are (Timing.pixels counts them): sweeps label by it

    def load(self, path: Path, text: str, doc: dict):
        """The scene of a parsed file of this kind (sim.scenes.registry.load_scene reads the file and
        dispatches on [scene] kind); one SceneError naming file, line and field for any problem."""
        raise NotImplementedError

    def run(self, scene, cpus: list[str] | None = None, progress: Progress | None = None,
            robustness: bool = True, jobs: int = 1):
        """Run the scene on its machines (or `cpus`, machine keys), timing on `jobs` forked
        workers (sim.parallel); the result is the same for any `jobs`."""
        raise NotImplementedError

    def write_reports(self, result, out_dir: Path, formats: tuple[str, ...] = FORMATS) -> list[Path]:
        """Write the reports `formats` names (md, png, json, csv, html) into `out_dir`; the paths."""
        raise NotImplementedError

    def summary_tables(self, result) -> list:
        """What `retrosim report` prints for one result (rich renderables)."""
        raise NotImplementedError

    def baseline_entries(self, result) -> dict[str, dict[str, int]]:
        """reports/baselines.json cases of a result: case name -> {counter: integer}."""
        raise NotImplementedError

    def sweep_emulation(self, scene, variant: str):
        """(emulation, units of work) of one variant, as `run` times it: what a sweep times on each
        of its machines (sim.sweep)."""
        raise NotImplementedError
