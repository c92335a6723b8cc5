"""The sort kind of scene ([scene] kind = "sort"): format and loader in scene.py, keys in keys.py,
kernels and the correctness check in variants.py, runner in runner.py, claims and reports in
report.py, behind sim.scenes.kind.SceneKind."""

from __future__ import annotations

from pathlib import Path

from sim.reports.render import FORMATS
from sim.scenes.kind import SceneKind
from sim.scenes.sort import report, runner, scene


class SortKind(SceneKind):
    name = "sort"
    unit = "key"

    def load(self, path: Path, text: str, doc: dict) -> scene.SortScene:
        return scene.load(path, text, doc)

    def run(self, s, cpus=None, progress=None, robustness=True, jobs=1) -> runner.SortResult:
        return runner.run_scene(s, cpus, progress, robustness, jobs)

    def write_reports(self, result, out_dir: Path, formats: tuple[str, ...] = FORMATS) -> list[Path]:
        return report.write_reports(result, out_dir, formats)

    def summary_tables(self, result) -> list:
        return report.summary_tables(result)

    def baseline_entries(self, result) -> dict[str, dict[str, int]]:
        return report.baseline_entries(result)

    def sweep_emulation(self, s, variant: str):
        """The variant on the scene's first distribution at table_size, as the scene's run emulates
        it; the units are its keys."""
        return runner.emulate_case(s, variant, s.distributions[0], s.table_size), s.table_size


KIND = SortKind()
