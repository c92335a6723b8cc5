"""The Z-buffer kind of scene ([scene] kind = "zbuffer", the default): its file format and loader
(scene.py), its runner (runner.py) and its reports (report.py) behind sim.scenes.kind.SceneKind."""

from __future__ import annotations

from pathlib import Path

from sim.reports.render import FORMATS
from sim.scenes import raster
from sim.scenes.kind import BASELINE_COUNTERS, SceneKind
from sim.scenes.zbuffer import report, runner, scene
from sim.scenes.zbuffer.frames import draw_frames


class ZBufferKind(SceneKind):
    name = "zbuffer"

    def load(self, path: Path, text: str, doc: dict) -> scene.Scene:
        return scene.load(path, text, doc)

    def run(self, s, cpus=None, progress=None, robustness=True, jobs=1) -> runner.SceneResult:
        return runner.run_scene(s, cpus, progress, robustness, jobs)

    def write_reports(self, result, out_dir: Path, formats: tuple[str, ...] = FORMATS) -> list[Path]:
        return report.write_reports(result, out_dir, formats)

    def summary_tables(self, result) -> list:
        return report.summary_tables(result)

    def baseline_entries(self, result) -> dict[str, dict[str, int]]:
        return {f"{t.variant}@{t.key}": {c: int(t.counters[c]) for c in BASELINE_COUNTERS} for t in result.timings}

    def sweep_emulation(self, s, variant: str):
        """The variant's frames, as the runner draws them; the units are the pixels of a frame."""
        geometry = s.build_geometry()
        spans = raster.rasterize(geometry, s.width, s.height)
        run = draw_frames(spans, variant, s.width, s.height, s.frames, geometry.colour)
        return run.emulation, run.pixels


KIND = ZBufferKind()
