"""The scene-kind interface: what a kind of scene (Z-buffer, texture mapping, vertex snapping,
sorting) provides, so that the command line, the baselines and the sweeps handle every kind the same
way.

A kind is a package under sim/scenes/ (zbuffer/, texture/, snap/, sort/); sim.scenes.registry
names, for each, the functions of its modules that make up a :class:`SceneKind`, by the name a
scene file gives in ``[scene] kind``. The kind's scene module documents its file format.

Also here: :class:`Timing`, the counters of one emulation on one machine that the Z-buffer and snap
results list, and the counters a baseline records (:data:`BASELINE_COUNTERS`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

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


@dataclass(frozen=True)
class SceneKind:
    """One kind of scene: its name and the functions of its own modules that load, run and report
    it (sim.scenes.registry lists one per kind; nothing forwards to them). Scenes (what `load`
    returns) have at least ``path``, ``name``, ``kind``, ``variants`` and ``cpus`` (machine keys);
    results (what `run` returns) have ``scene``, ``pixels`` (the units of work) and ``cpu_keys``.

    load(path, text, doc):     the scene of a parsed file of this kind (sim.scenes.registry.load_scene
                               reads the file and dispatches on [scene] kind); one SceneError naming
                               file, line and field for any problem (sim.scenes.schema);
    run(scene, cpus, progress, robustness, jobs):  run the scene on its machines (or `cpus`, machine
                               keys), timing on `jobs` forked workers (sim.parallel); the result is the
                               same for any `jobs`; `progress` (None, or a sim.scenes.progress.Progress)
                               hears of every machine run, planned and done;
    write_reports(result, out_dir, formats):  write the reports `formats` names (md, png, json, csv,
                               html) into `out_dir`; the paths;
    summary_tables(result):    what `retrosim report` prints for one result (rich renderables);
    baseline_entries(result):  reports/baselines.json cases of a result: case -> {counter: integer};
    sweep_emulation(scene, variant):  (emulation, units of work) of one variant, as `run` times it:
                               what a sweep times on each of its machines (sim.sweep), from a
                               warm start where `warm_start` says `run` times so.
    """

    name: str
    load: Callable
    run: Callable
    write_reports: Callable
    summary_tables: Callable
    baseline_entries: Callable
    sweep_emulation: Callable
    unit: str = "pixel"  # what the units of work are (Timing.pixels counts them): sweeps label by it
    # the last call timed from a warm start (sim.timing.kernel time_emulation): a Z-buffer scene's frames
    warm_start: bool = False
