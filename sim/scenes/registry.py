"""The scene kinds by the name a scene file gives in ``[scene] kind``, and the entry points the
command line, the baselines and the sweeps use for a scene of any kind: each reads the kind of
its scene (or result) and hands over to it (sim.scenes.kind.SceneKind).

Adding a kind: a package sim/scenes/NAME/ (its scene module declares the file's schema and loads
it through sim.scenes.schema; its runner and report modules run and report it), and one entry in
:data:`KINDS` here naming those functions.
"""

from __future__ import annotations

from pathlib import Path

from sim.reports.render import FORMATS
from sim.scenes.kind import SceneKind
from sim.scenes.schema import Validator, read_scene, show
from sim.scenes.snap import scene as snap
from sim.scenes.sort import report as sort_report
from sim.scenes.sort import runner as sort_runner
from sim.scenes.sort import scene as sort_scene
from sim.scenes.texture import scene as texture
from sim.scenes.zbuffer import report as zbuffer_report
from sim.scenes.zbuffer import runner as zbuffer_runner
from sim.scenes.zbuffer import scene as zbuffer_scene

KINDS: dict[str, SceneKind] = {k.name: k for k in (
    SceneKind("zbuffer", zbuffer_scene.load, zbuffer_runner.run_scene, zbuffer_report.write_reports,
              zbuffer_report.summary_tables, zbuffer_report.baseline_entries, zbuffer_runner.sweep_emulation,
              warm_start=zbuffer_runner.WARM_START),
    SceneKind("texture", texture.load, texture.run_scene, texture.write_reports, texture.summary_tables,
              texture.baseline_entries, texture.sweep_emulation),
    SceneKind("snap", snap.load, snap.run_scene, snap.write_reports, snap.summary_tables, snap.baseline_entries,
              snap.sweep_emulation, unit="vertex"),
    SceneKind("sort", sort_scene.load, sort_runner.run_scene, sort_report.write_reports, sort_report.summary_tables,
              sort_report.baseline_entries, sort_runner.sweep_emulation, unit="key"),
)}
DEFAULT_KIND = "zbuffer"  # a scene file without [scene] kind


def kind_of(item) -> SceneKind:
    """The kind of a scene, or of a result (which has its scene)."""
    scene = getattr(item, "scene", item)
    return KINDS[scene.kind]


def load_scene(path: str | Path):
    """Read, parse and validate a scene file of any kind; one SceneError naming file and field."""
    path = Path(path)
    text, doc = read_scene(path)
    kind = doc["scene"].get("kind", DEFAULT_KIND) if isinstance(doc.get("scene"), dict) else DEFAULT_KIND
    if not isinstance(kind, str) or kind not in KINDS:
        Validator(path, text).fail("scene.kind", f"unknown kind {show(kind)} (known: {', '.join(KINDS)})",
                                   "scene", "kind")
    return KINDS[kind].load(path, text, doc)


def run_scene(scene, cpus: list[str] | None = None, progress=None, robustness: bool = True, jobs: int = 1):
    """Run a scene of any kind (see SceneKind.run)."""
    return kind_of(scene).run(scene, cpus, progress, robustness, jobs)


def write_reports(result, out_dir: Path, formats: tuple[str, ...] = FORMATS) -> list[Path]:
    return kind_of(result).write_reports(result, Path(out_dir), formats)


def summary_tables(results: list) -> list:
    """What `retrosim report` prints: each result's summary in turn."""
    return [part for r in results for part in kind_of(r).summary_tables(r)]


def baseline_entries(result) -> dict[str, dict[str, int]]:
    return kind_of(result).baseline_entries(result)
