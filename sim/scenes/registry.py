"""The scene kinds by the name a scene file gives in ``[scene] kind``, and the entry points the
command line, the baselines and the sweeps use for a scene of any kind: each reads the kind of
its scene (or result) and hands over to it (sim.scenes.kind.SceneKind).

Adding a kind: a package sim/scenes/NAME/ whose kind.py defines ``KIND`` (a SceneKind with
``name = "NAME"``), and one line in :data:`KINDS` here.
"""

from __future__ import annotations

from pathlib import Path

from sim.reports.render import FORMATS
from sim.scenes.kind import SceneKind
from sim.scenes.schema import Validator, read_scene, show
from sim.scenes.snap.kind import KIND as SNAP
from sim.scenes.sort.kind import KIND as SORT
from sim.scenes.texture.kind import KIND as TEXTURE
from sim.scenes.zbuffer.kind import KIND as ZBUFFER

DEFAULT_KIND = ZBUFFER.name  # a scene file without [scene] kind
KINDS: dict[str, SceneKind] = {k.name: k for k in (ZBUFFER, TEXTURE, SNAP, SORT)}


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
