"""The texture-mapping kind of scene ([scene] kind = "texture"): format, loader, runner and
reports in scene.py (the frame's model in frame.py), behind sim.scenes.kind.SceneKind."""

from __future__ import annotations

from pathlib import Path

from sim.reports.render import FORMATS
from sim.scenes.kind import SceneKind
from sim.scenes.texture import frame as F
from sim.scenes.texture import scene


class TextureKind(SceneKind):
    name = "texture"

    def load(self, path: Path, text: str, doc: dict) -> scene.TextureScene:
        return scene.load(path, text, doc)

    def run(self, s, cpus=None, progress=None, robustness=True, jobs=1) -> scene.TextureResult:
        return scene.run_scene(s, cpus, progress, robustness, jobs)

    def write_reports(self, result, out_dir: Path, formats: tuple[str, ...] = FORMATS) -> list[Path]:
        return scene.write_reports(result, out_dir, formats)

    def summary_tables(self, result) -> list:
        return scene.summary_tables(result)

    def baseline_entries(self, result) -> dict[str, dict[str, int]]:
        return scene.baseline_entries(result)

    def sweep_emulation(self, s, variant: str):
        """The variant drawing the timed spans (every timing_stride-th), as the scene's run times
        it; the units are the timed pixels."""
        timed = scene.timed_spans(s, F.span_params(s.build_geometry(), s.width, s.height))
        return scene.emulate_variant(variant, timed, s.width, s.height, F.texture()), timed.pixels


KIND = TextureKind()
