"""The vertex-snapping kind of scene ([scene] kind = "snap"): format, loader, runner and reports
in scene.py (variants, workloads and the exact reference in workload.py), behind
sim.scenes.kind.SceneKind."""

from __future__ import annotations

from pathlib import Path

from sim.reports.render import FORMATS
from sim.scenes.kind import SceneKind
from sim.scenes.snap import scene


class SnapKind(SceneKind):
    name = "snap"
    unit = "vertex"

    def load(self, path: Path, text: str, doc: dict) -> scene.SnapScene:
        return scene.load(path, text, doc)

    def run(self, s, cpus=None, progress=None, robustness=True, jobs=1) -> scene.SnapResult:
        return scene.run_scene(s, cpus, progress, robustness, jobs)

    def write_reports(self, result, out_dir: Path, formats: tuple[str, ...] = FORMATS) -> list[Path]:
        return scene.write_reports(result, out_dir, formats)

    def summary_tables(self, result) -> list:
        return scene.summary_tables(result)

    def baseline_entries(self, result) -> dict[str, dict[str, int]]:
        return scene.baseline_entries(result)

    def sweep_emulation(self, s, variant: str):
        """The variant snapping the timing workload, as the scene's run times it; the units are
        its vertices."""
        return scene.emulate_variant(s, variant), s.vertices


KIND = SnapKind()
