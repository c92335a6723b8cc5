"""Z-buffer scene files (scenes/*.toml, [scene] kind = "zbuffer" or none): the format, a loader
that validates it, and what a scene needs. The kind's other parts: runner.py runs it, report.py
reports it; sim.scenes.registry joins them behind the scene-kind interface (sim.scenes.kind).

Format::

    [scene]
    kind = "zbuffer"                # optional (the default); another kind is loaded, run and
                                    #   reported by its own package (sim.scenes.registry.KINDS)
    name = "zbuffer-article"        # required; must equal the file stem
    description = "..."             # optional
    width = 640                     # required, pixels
    height = 480                    # required, pixels

    [geometry]
    generator = "random"            # random | coplanar_far | steep | near_far | tiny | triangles
    seed = 1998                     # every generator but "triangles" (required)
    triangles = 300                 # random (required), steep / near_far / tiny (optional)
    depth_complexity = 3.0          # random (required, > 0)
    z_range = [0.05, 0.95]          # random, coplanar_far, steep (optional; 0 <= lo < hi <= 1)
    pairs = 40                      # coplanar_far (optional)
    separation = 9.5367431640625e-07  # coplanar_far (optional): depth gap of each pair
    # generator = "triangles" takes [[geometry.triangle]] tables instead:
    #   xy = [[x, y], [x, y], [x, y]]   z = [a, b, c] (in [0, 1))   colour = 7 (optional, 1..65535;
    #   default: the triangle's index + 1)

    [run]
    variants = ["z32", "z16", "fp16z", "zf32"]     # required: z32 z16 fp16z fp16t zf32
    cpus = ["pentium2-233:edo", "celeron-300a"]    # required: CPU preset[:memory preset]
    metrics = ["visibility", "depth_error", "fp16_precision"]   # optional (default none)
    frames = 2                      # optional (default 1): frames drawn in one machine state,
                                    # the last one is reported. Host memory: frames x (pixel
                                    # visits + 4 x spans) at most RETROSIM_MAX_VISITS (8 M, ~1.8 GB)

    [[run.machine]]                 # optional, repeatable: a CPU preset with overrides, run after
    cpu = "k6-233"                  #   run.cpus; required: the CPU preset
    memory = "sdram-pc66"           #   optional (default: the preset's)
    set = { "write_allocate.mode" = "full", "l2.size_kb" = 256 }   # required: preset fields or
                                    #   estimates to change (sim.cpus.make_model's overrides, the
                                    #   names `retrosim time --set` takes; "l2.size_kb" = "none"
                                    #   removes the L2)
    # Its label, in the report, baselines and claims, is the preset with its overrides sorted by
    # key: "k6-233{l2.size_kb=256,write_allocate.mode=full}:sdram-pc66". run.cpus accepts such a
    # label as well. Claims naming a preset cover it with any overrides.

    [[claims]]                      # optional, repeatable: a published claim to check
    text = "..."                    # required
    variants = ["fp16z", "z32"]     # required: two of run.variants
    expect = "slower"               # required: similar | faster | slower (variants[0] than variants[1])
    tolerance = 0.0                 # optional fraction
    cpus = ["k6-2-300", "pentium2-233:edo"]   # the machines its words cover: presets (any memory)
    families = ["k6"]               # ... and/or whole families (p5 p6 k6)
    memories = ["sdram-pc100"]      # optional: only with these memory presets
    # (cpu = "..." is accepted as a one-entry cpus). Every entry of cpus and families must match a
    # machine of run.cpus or run.machine (within memories): a claim naming one the scene does not
    # run is refused, so no part of it goes unchecked (sim.scenes.claims.unrun).

Generators are those of sim.scenes.raster (random_scene, coplanar_far_scene, ...) with the keys above as
their arguments. Metrics: "visibility" (wrong winners), "depth_error" (stored vs exact depth),
"fp16_precision" (the format table, needs no frame), "z_fighting" (coplanar_far only).

Every problem raises one :class:`SceneError` (sim.scenes.schema) whose message names the file (with
a line when one can be found) and the dotted field: ``scenes/a.toml:12: run.variants[1]: unknown
variant 'z24' ...``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim.cpus.machine import MachineKey
from sim.errors import RetrosimError
from sim.scenes import raster
from sim.scenes.schema import CpuChoice, SceneError, Validator, show, toml_type

VARIANTS = raster.VARIANTS
METRICS = ("visibility", "depth_error", "fp16_precision", "z_fighting")
GENERATORS = ("random", "coplanar_far", "steep", "near_far", "tiny", "triangles")
SPAN_RECORD_BYTES = 32  # kernels/zbuffer/draw.inc: 8 dwords per span
ARENA_ALIGN = 64        # sim.guest.emu.Arena.alloc's default alignment
ZBUF_BYTES = {v: raster.ZBUF_DTYPE[v].itemsize for v in VARIANTS}
KERNEL_DIR = "kernels/zbuffer"
MAX_COORDINATE = 1 << 20  # screens are at most 32768 wide; the plane math stays exact far beyond
# Host memory a scene may take. Every frame is traced (about 14 instructions per pixel visit and 50
# per span for fp16t, the costliest variant, about 6.4 trace bytes each) and then timed, and the
# runner holds a few int64/float64 arrays per visit. Measured peak RSS (issue 26): 640x480 at depth
# complexity 8, fp16t, 1 frame (2.4 M visits, 20 k spans, 35 M instructions): 564 MB; 65,535
# explicit 15-pixel triangles (7.3 M visits, 1 M spans): 2.9 GB before the model limit refused it.
# So the limit counts work over all frames, a span as SPAN_VISITS visits: frames x (visits + 4 x
# spans) at most 8 M keeps a scene near 1.5 GB (about VISIT_BYTES each, estimate_bytes); the shipped
# scenes use at most 2.0 M. Raise it with RETROSIM_MAX_VISITS if the machine has the memory.
MAX_VISITS_ENV = "RETROSIM_MAX_VISITS"
DEFAULT_MAX_VISITS = 8_000_000
VISIT_BYTES = 220
SPAN_VISITS = 4  # a span's driver overhead (~50 instructions) in pixel visits (~14 each)

# key -> (kind, required) per table; kinds: int, number, str, strlist, range, tables
_SCENE_KEYS = {"kind": ("str", False), "name": ("str", True), "description": ("str", False), "width": ("int", True), "height": ("int", True)}
_GENERATOR_KEYS = {
    "random": {"seed": ("int", True), "triangles": ("int", True), "depth_complexity": ("number", True),
               "z_range": ("range", False)},
    "coplanar_far": {"seed": ("int", True), "pairs": ("int", False), "z_range": ("range", False),
                     "separation": ("number", False)},
    "steep": {"seed": ("int", True), "triangles": ("int", False), "z_range": ("range", False)},
    "near_far": {"seed": ("int", True), "triangles": ("int", False)},
    "tiny": {"seed": ("int", True), "triangles": ("int", False)},
    "triangles": {"triangle": ("tables", True)},
}
_TRIANGLE_KEYS = {"xy": ("any", True), "z": ("any", True), "colour": ("int", False)}
_RUN_KEYS = {"variants": ("strlist", True), "cpus": ("strlist", True), "metrics": ("strlist", False),
             "frames": ("int", False), "machine": ("tables", False)}
_MACHINE_KEYS = {"cpu": ("str", True), "memory": ("str", False), "set": ("any", True)}
_CLAIM_KEYS = {"text": ("str", True), "cpu": ("str", False), "cpus": ("strlist", False),
               "families": ("strlist", False), "memories": ("strlist", False), "variants": ("strlist", True),
               "expect": ("str", True), "tolerance": ("number", False)}
EXPECTATIONS = ("similar", "faster", "slower")


# ---------------------------------------------------------------------------------------------
# the parsed scene

@dataclass(frozen=True)
class TriangleSpec:
    xy: tuple[tuple[float, float], tuple[float, float], tuple[float, float]]
    z: tuple[float, float, float]
    colour: int | None = None


@dataclass(frozen=True)
class GeometrySpec:
    """[geometry]: the generator and its arguments (None: the generator's default)."""

    generator: str
    seed: int | None = None
    triangles: int | None = None
    depth_complexity: float | None = None
    z_range: tuple[float, float] | None = None
    pairs: int | None = None
    separation: float | None = None
    triangle_list: tuple[TriangleSpec, ...] = ()

    def build(self, width: int, height: int) -> raster.Geometry:
        g = self.generator
        opt = {k: v for k, v in (("z_range", self.z_range), ("separation", self.separation),
                                 ("pairs", self.pairs)) if v is not None}
        if g == "random":
            return raster.random_scene(width, height, self.triangles, self.depth_complexity, self.seed, **opt)
        if g == "coplanar_far":
            return raster.coplanar_far_scene(width, height, seed=self.seed, **opt)
        if g == "triangles":
            t = self.triangle_list
            colours = np.array([c.colour if c.colour is not None else i + 1 for i, c in enumerate(t)], np.int64)
            return raster.Geometry(np.array([c.xy for c in t], np.float64).reshape(-1, 3, 2),
                                   np.array([c.z for c in t], np.float64).reshape(-1, 3), colours)
        if self.triangles is not None:
            opt["triangles"] = self.triangles
        return raster.GENERATORS[g](width, height, seed=self.seed, **opt)


@dataclass(frozen=True)
class RunSpec:
    variants: tuple[str, ...]
    cpus: tuple[CpuChoice, ...]
    metrics: tuple[str, ...] = ()
    frames: int = 1


@dataclass(frozen=True)
class Needs:
    """What a scene needs, and nothing more ("build only what it asks for").

    kernels:       kernel sources, one per variant, relative to the repository (kernels/zbuffer/<v>.S);
    entries:       the frame entry point of each variant (<v>_frame, see kernels/zbuffer/draw.inc);
    cpus:          CPU presets; memories: the memory presets they run with; machines: the pairs;
    metrics:       the metrics to compute;
    reference:     whether the exact float64 reference (sim.scenes.raster.reference) is needed: only for
                   visibility, depth_error and z_fighting (fp16_precision is a property of the
                   formats and needs no frame at all);
    colour_buffer: whether any metric reads the frame buffer (visibility, z_fighting). When False
                   the builder does not read back, keep or compare fbuf. The kernels still store a
                   16-bit colour wherever the depth test passes, so they must still be given a
                   writable 2-byte-per-pixel target; the arena check counts it either way;
    zbuf_bytes:    bytes per depth-buffer pixel per variant (z32, zf32: 4; z16, fp16z, fp16t: 2);
    arena_bytes:   the most guest arena one frame of any requested variant takes (see
                   :func:`frame_arena_bytes`).
    """

    kernels: tuple[str, ...]
    entries: tuple[str, ...]
    cpus: tuple[str, ...]
    memories: tuple[str, ...]
    machines: tuple[CpuChoice, ...]
    metrics: tuple[str, ...]
    reference: bool
    colour_buffer: bool
    zbuf_bytes: dict
    arena_bytes: int

    def as_dict(self) -> dict:
        return {"kernels": list(self.kernels), "entries": list(self.entries), "cpus": list(self.cpus),
                "memories": list(self.memories), "machines": [m.label for m in self.machines],
                "metrics": list(self.metrics), "reference": self.reference, "colour_buffer": self.colour_buffer,
                "zbuf_bytes": dict(self.zbuf_bytes), "arena_bytes": self.arena_bytes}


def _align(n: int, a: int) -> int:
    return -(-n // a) * a


def frame_arena_bytes(width: int, height: int, spans: int, zbuf_bytes_per_pixel: int) -> dict:
    """Guest arena bytes one frame takes, allocation by allocation as sim.guest.emu.Arena lays them out
    (each aligned to 64 bytes): the depth buffer rounded up to whole 32-byte lines (the frame
    driver clears 8 dwords per iteration), the 16-bit colour buffer, and 32 bytes per span record."""
    pixels = width * height
    zbuf = _align(pixels * zbuf_bytes_per_pixel, 32)
    fbuf = pixels * 2
    recs = spans * SPAN_RECORD_BYTES
    total = sum(_align(n, ARENA_ALIGN) for n in (zbuf, fbuf, recs))
    return {"zbuf": zbuf, "fbuf": fbuf, "spans": recs, "span_count": spans, "total": total}


@dataclass(frozen=True)
class Claim:
    """A published claim the report checks: variants[0] is `expect` (similar / faster / slower)
    than variants[1], within `tolerance` (a fraction), on every machine its words cover.

    Coverage: ``cpus`` (``preset`` = that preset with any memory, or ``preset:memory``) and
    ``families`` (every preset whose cpu_model is one of them), narrowed by ``memories`` when
    given. The report checks the claim on each covered machine of the run and names the covered
    machines of the scene that the run left out ("not checked (CPU not in this run)")."""

    text: str
    variants: tuple[str, str]
    expect: str
    tolerance: float = 0.0
    cpus: tuple[str, ...] = ()
    families: tuple[str, ...] = ()
    memories: tuple[str, ...] = ()

    def covers(self, preset: str, memory: str, family: str) -> bool:
        if self.memories and memory not in self.memories:
            return False
        preset = MachineKey(preset).preset  # a preset with overrides (run.machine) is still that preset
        return (family in self.families or preset in self.cpus or f"{preset}:{memory}" in self.cpus)

    def describe_coverage(self) -> str:
        parts = list(self.cpus) + [f"every {f.upper()} preset" for f in self.families]
        text = ", ".join(parts)
        return text + (f" (memory {', '.join(self.memories)})" if self.memories else "")


@dataclass(frozen=True)
class Scene:
    path: Path
    name: str
    description: str
    width: int
    height: int
    geometry: GeometrySpec
    run: RunSpec
    span_bound: int  # at most this many spans per frame (rows crossed inside the screen)
    claims: tuple[Claim, ...] = ()
    kind = "zbuffer"

    # short names for what the runner and reports read
    @property
    def variants(self) -> tuple[str, ...]:
        return self.run.variants

    @property
    def metrics(self) -> tuple[str, ...]:
        return self.run.metrics

    @property
    def frames(self) -> int:
        return self.run.frames

    @property
    def cpus(self) -> list[str]:
        return [m.label for m in self.run.cpus]

    def build_geometry(self) -> raster.Geometry:
        return self.geometry.build(self.width, self.height)

    def rasterize(self) -> raster.Spans:
        return raster.rasterize(self.build_geometry(), self.width, self.height)

    @property
    def needs(self) -> Needs:
        variants = self.run.variants
        metrics = self.run.metrics
        machines = self.run.cpus
        zb = {v: ZBUF_BYTES[v] for v in variants}
        arena = frame_arena_bytes(self.width, self.height, self.span_bound, max(zb.values()))["total"]
        return Needs(
            kernels=tuple(f"{KERNEL_DIR}/{v}.S" for v in variants),
            entries=tuple(f"{v}_frame" for v in variants),
            cpus=tuple(dict.fromkeys(m.preset for m in machines)),
            memories=tuple(dict.fromkeys(m.memory for m in machines)),
            machines=machines,
            metrics=metrics,
            reference=any(m in metrics for m in ("visibility", "depth_error", "z_fighting")),
            colour_buffer=any(m in metrics for m in ("visibility", "z_fighting")),
            zbuf_bytes=zb,
            arena_bytes=arena,
        )


def _numbers(v, shape: tuple[int, ...]) -> bool:
    if len(shape) == 0:
        return not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)
    return isinstance(v, list) and len(v) == shape[0] and all(_numbers(x, shape[1:]) for x in v)


def max_visits() -> int:
    import os

    raw = os.environ.get(MAX_VISITS_ENV, "").strip()
    try:
        value = int(raw) if raw else DEFAULT_MAX_VISITS
    except ValueError:
        raise SceneError(f"{MAX_VISITS_ENV}={raw!r}: expected a whole number of pixel visits") from None
    return value


def frame_work(visits: int, spans: int, frames: int) -> int:
    """What RETROSIM_MAX_VISITS bounds: pixel visits of every traced frame, a span counted as SPAN_VISITS."""
    return frames * (visits + SPAN_VISITS * spans)


def estimate_bytes(work: int) -> int:
    """Host memory a scene of that much work (frame_work) takes at peak, about (see VISIT_BYTES)."""
    return work * VISIT_BYTES


def _check_visits(v: Validator, geometry: GeometrySpec, width: int, height: int, span_bound: int, frames: int) -> None:
    """Refuse a scene whose frames draw more than host memory can follow (see MAX_VISITS_ENV).
    Cheap bound first (rows x width); only above the limit is the geometry rasterized to count."""
    limit = max_visits()
    if frame_work(span_bound * width, span_bound, frames) <= limit:
        return
    try:
        spans = raster.rasterize(geometry.build(width, height), width, height)
    except ValueError as e:
        v.fail("geometry", f"cannot build the geometry: {e}", "geometry")
    visits = int(spans.count.sum(dtype=np.int64))
    work = frame_work(visits, int(spans.y.size), frames)
    if work > limit:
        v.fail("geometry", f"{frames} frame(s) of {visits:,} pixel visits ({visits / (width * height):.1f} per screen "
               f"pixel) and {int(spans.y.size):,} spans (each counted as {SPAN_VISITS} visits) make {work:,} visits, "
               f"more than the limit of {limit:,} (host memory: about {VISIT_BYTES} bytes each, "
               f"{estimate_bytes(work) / 2**30:.1f} GB here); lower run.frames or the geometry, or raise "
               f"{MAX_VISITS_ENV} if the machine has the memory", "geometry")


def load(path: Path, text: str, doc: dict) -> Scene:
    """Validate a parsed Z-buffer scene (sim.scenes.registry.load_scene reads the file and dispatches
    on [scene].kind); raises SceneError with one line naming file and field."""
    from sim.cpus import memory_presets
    from sim.cpus import presets as cpu_presets
    from sim.guest.emu import DEFAULT_ARENA

    v = Validator(path, text)
    # [scene]
    sc, name, description = v.scene_header(doc, "zbuffer", ("scene", "geometry", "run", "claims"), _SCENE_KEYS)
    width = v.typed(sc, "width", "int", "scene")
    height = v.typed(sc, "height", "int", "scene")
    v.at_least(width, 1, "scene.width", "scene", "width")
    v.at_least(height, 1, "scene.height", "scene", "height")
    v.at_most(width, 1 << 15, "scene.width", "scene", "width")
    v.at_most(height, 1 << 15, "scene.height", "scene", "height")

    # [geometry]
    ge = v.table(doc, "geometry")
    if "generator" not in ge:
        v.fail("geometry.generator", f"missing required field (one of: {', '.join(GENERATORS)})", "geometry")
    gen = v.typed(ge, "generator", "str", "geometry")
    if gen not in GENERATORS:
        v.fail("geometry.generator", f"unknown generator '{gen}' (known: {', '.join(GENERATORS)})",
               "geometry", "generator")
    allowed = {"generator": ("str", True), **_GENERATOR_KEYS[gen]}
    v.keys(ge, allowed, "geometry", note=f" for generator '{gen}'")
    vals = {k: v.typed(ge, k, kind, "geometry") for k, (kind, _) in _GENERATOR_KEYS[gen].items()}
    if vals.get("seed") is not None and not 0 <= vals["seed"] < 1 << 63:
        v.fail("geometry.seed", f"must be between 0 and 2^63 - 1, got {vals['seed']}", "geometry", "seed")
    max_tri = raster.MAX_TRIANGLES
    if vals.get("triangles") is not None:
        v.at_least(vals["triangles"], 1, "geometry.triangles", "geometry", "triangles")
        v.at_most(vals["triangles"], max_tri, "geometry.triangles", "geometry", "triangles",
                  " (colours are 16-bit: triangle index + 1)")
    if vals.get("pairs") is not None:
        v.at_least(vals["pairs"], 1, "geometry.pairs", "geometry", "pairs")
        v.at_most(vals["pairs"], max_tri // 2, "geometry.pairs", "geometry", "pairs")
    if vals.get("depth_complexity") is not None and not 0 < vals["depth_complexity"] <= max_tri:
        # a pixel is drawn at most once per triangle: beyond that the target is unreachable (and
        # near the float maximum the generator's area arithmetic overflows)
        v.fail("geometry.depth_complexity", f"must be > 0 and at most {max_tri} (a pixel is drawn at most once "
               f"per triangle), got {vals['depth_complexity']}", "geometry", "depth_complexity")
    if gen == "coplanar_far" and vals.get("separation") is not None:
        lo, hi = vals.get("z_range") or (0.85, 0.95)
        if not 0 < vals["separation"] < hi - lo:
            v.fail("geometry.separation", f"must be > 0 and smaller than the z range ({hi - lo:g}), "
                   f"got {vals['separation']}", "geometry", "separation")
    triangle_list: list[TriangleSpec] = []
    if gen == "triangles":
        tables = vals.pop("triangle")
        if not tables:
            v.fail("geometry.triangle", "needs at least one [[geometry.triangle]]", "geometry")
        if len(tables) > max_tri:
            v.fail("geometry.triangle", f"{len(tables)} triangles: at most {max_tri}", "geometry")
        for i, t in enumerate(tables):
            tname, field = "geometry.triangle", f"geometry.triangle[{i}]"
            v.keys(t, _TRIANGLE_KEYS, tname, i, field)
            if not _numbers(t["xy"], (3, 2)):
                v.fail(f"{field}.xy", f"expected three [x, y] pairs of finite numbers, got {show(t['xy'])}",
                       tname, "xy", i)
            if any(abs(float(c)) > MAX_COORDINATE for p in t["xy"] for c in p):
                # the plane setup multiplies coordinate differences: far beyond the screen they overflow
                v.fail(f"{field}.xy", f"coordinates must be within +-{MAX_COORDINATE:,} pixels, got {show(t['xy'])}",
                       tname, "xy", i)
            if not _numbers(t["z"], (3,)):
                v.fail(f"{field}.z", f"expected three finite numbers, got {show(t['z'])}", tname, "z", i)
            if not all(0.0 <= float(z) < 1.0 for z in t["z"]):
                v.fail(f"{field}.z", f"depths must be in [0, 1), got {show(t['z'])}", tname, "z", i)
            colour = v.typed(t, "colour", "int", tname, i, field)
            if colour is not None and not 1 <= colour <= 0xFFFF:
                v.fail(f"{field}.colour", f"must be 1..65535 (0 means 'no triangle'), got {colour}", tname, "colour", i)
            triangle_list.append(TriangleSpec(tuple(tuple(float(c) for c in p) for p in t["xy"]),
                                              tuple(float(z) for z in t["z"]), colour))
    geometry = GeometrySpec(gen, triangle_list=tuple(triangle_list), **vals)

    # [run]
    ru = v.table(doc, "run")
    v.keys(ru, _RUN_KEYS, "run")
    variants = v.typed(ru, "variants", "strlist", "run")
    cpus = v.typed(ru, "cpus", "strlist", "run")
    metrics = v.typed(ru, "metrics", "strlist", "run", default=())
    frames = v.typed(ru, "frames", "int", "run", default=1)
    for key, items in (("variants", variants), ("cpus", cpus)):
        if not items:
            v.fail(f"run.{key}", "must not be empty", "run", key)
    for key, items in (("variants", variants), ("cpus", cpus), ("metrics", metrics)):
        dup = [x for i, x in enumerate(items) if x in items[:i]]
        if dup:
            v.fail(f"run.{key}[{items.index(dup[0], items.index(dup[0]) + 1)}]", f"'{dup[0]}' is listed twice",
                   "run", key)
    for i, var in enumerate(variants):
        if var not in VARIANTS:
            v.fail(f"run.variants[{i}]", f"unknown variant '{var}' (known: {', '.join(VARIANTS)})", "run", "variants")
    for i, met in enumerate(metrics):
        if met not in METRICS:
            v.fail(f"run.metrics[{i}]", f"unknown metric '{met}' (known: {', '.join(METRICS)})", "run", "metrics")
        if met == "z_fighting" and gen != "coplanar_far":
            v.fail(f"run.metrics[{i}]", f"'z_fighting' needs coplanar pairs: generator 'coplanar_far', not '{gen}'",
                   "run", "metrics")
    from sim.cpus import machine_label

    known_cpus, known_mem = cpu_presets.available(), memory_presets()
    machines = []

    def machine(label: str, memory: str | None, field: str, table: str, key: str, index=None):
        v.machine(machines, label, memory, field, table, key, index)

    for i, entry in enumerate(cpus):
        key = MachineKey.parse(entry)
        machine(key.label, key.memory, f"run.cpus[{i}]", "run", "cpus")
    for i, table in enumerate(v.typed(ru, "machine", "tables", "run", default=[])):
        field = f"run.machine[{i}]"
        v.keys(table, _MACHINE_KEYS, "run.machine", i, field)
        cpu = v.typed(table, "cpu", "str", "run.machine", i, field)
        memory = v.typed(table, "memory", "str", "run.machine", i, field)
        sets = table["set"]
        if not isinstance(sets, dict) or not sets:
            v.fail(f"{field}.set", f"expected a non-empty table of overrides, got {toml_type(sets)} {show(sets)}",
                   "run.machine", "set", i)
        flat = {}

        def walk(d, prefix):  # set = { l2.size_kb = 256 } parses as nested tables: dotted keys again
            for k, x in d.items():
                if isinstance(x, dict):
                    walk(x, f"{prefix}{k}.")
                elif isinstance(x, list):
                    v.fail(f"{field}.set.{prefix}{k}", f"expected a number, a string or a boolean, got {show(x)}",
                           "run.machine", "set", i)
                else:
                    flat[f"{prefix}{k}"] = x

        walk(sets, "")
        sets = flat
        try:
            label = machine_label(cpu, sets)
        except RetrosimError as e:
            v.fail(f"{field}.set", str(e), "run.machine", "set", i)
        machine(label, memory, field, "run.machine", "set", i)
    v.at_least(frames, 1, "run.frames", "run", "frames")
    v.at_most(frames, 1000, "run.frames", "run", "frames")

    # does a frame fit in the guest arena? First with a bound needing no geometry (every triangle
    # spans every row); only when that is too much, count the rows the triangles actually cross.
    zbytes = max(ZBUF_BYTES[x] for x in variants)
    widest = next(x for x in variants if ZBUF_BYTES[x] == zbytes)
    ntri = len(triangle_list) if gen == "triangles" else (vals.get("triangles") or 0)
    if gen == "coplanar_far":
        ntri = 2 * (vals.get("pairs") or 40)
    elif not ntri:
        ntri = {"steep": 40, "near_far": 200, "tiny": 2000}[gen]
    span_bound = ntri * height
    need = frame_arena_bytes(width, height, span_bound, zbytes)
    if need["total"] > DEFAULT_ARENA:
        try:
            geometry_built = geometry.build(width, height)
        except ValueError as e:
            v.fail("geometry", f"cannot build the geometry: {e}", "geometry")
        span_bound = raster.count_rows(geometry_built, width, height)
        need = frame_arena_bytes(width, height, span_bound, zbytes)
    if need["total"] > DEFAULT_ARENA:
        v.fail("scene.width", f"a {width}x{height} frame does not fit in the guest arena: it needs {need['total']:,} "
               f"bytes ({widest} depth buffer {need['zbuf']:,} + colour buffer {need['fbuf']:,} + "
               f"{need['span_count']:,} span records x {SPAN_RECORD_BYTES} = {need['spans']:,}), "
               f"the arena has {DEFAULT_ARENA:,}", "scene", "width")

    _check_visits(v, geometry, width, height, span_bound, frames)

    # [[claims]]
    claims = []
    for i, c in enumerate(v.claim_tables(doc)):
        field = f"claims[{i}]"
        v.keys(c, _CLAIM_KEYS, "claims", i, field)
        text = v.typed(c, "text", "str", "claims", i, field)
        cpu = v.typed(c, "cpu", "str", "claims", i, field)
        cover = list(v.typed(c, "cpus", "strlist", "claims", i, field, default=()))
        families = v.typed(c, "families", "strlist", "claims", i, field, default=())
        memories = v.typed(c, "memories", "strlist", "claims", i, field, default=())
        pair = v.typed(c, "variants", "strlist", "claims", i, field)
        expect = v.typed(c, "expect", "str", "claims", i, field)
        tolerance = v.typed(c, "tolerance", "number", "claims", i, field, default=0.0)
        if cpu is not None:
            cover.insert(0, cpu)
        if not cover and not families:
            v.fail(field, "names no CPU: give cpus = [...] (presets or preset:memory) and/or families = [...]",
                   "claims", None, i)
        for entry in cover:
            key = MachineKey.parse(entry)
            if key.label not in known_cpus:
                v.fail(f"{field}.cpus", f"unknown CPU preset '{key.label}' (known: {', '.join(known_cpus)})",
                       "claims", "cpus" if "cpus" in c else "cpu", i)
            if key.memory is not None and key.memory not in known_mem:
                v.fail(f"{field}.cpus", f"unknown memory preset '{key.memory}' in '{entry}' (known: {', '.join(known_mem)})",
                       "claims", "cpus" if "cpus" in c else "cpu", i)
        v.families(field, families, i)
        for mem in memories:
            if mem not in known_mem:
                v.fail(f"{field}.memories", f"unknown memory preset '{mem}' (known: {', '.join(known_mem)})",
                       "claims", "memories", i)
        if len(pair) != 2 or any(x not in variants for x in pair):
            v.fail(f"{field}.variants", f"expected two of run.variants ({', '.join(variants)}), got {show(list(pair))}",
                   "claims", "variants", i)
        if expect not in EXPECTATIONS:
            v.fail(f"{field}.expect", f"unknown expectation '{expect}' (known: {', '.join(EXPECTATIONS)})",
                   "claims", "expect", i)
        if not 0 <= tolerance < 1:
            v.fail(f"{field}.tolerance", f"must be in [0, 1), got {tolerance}", "claims", "tolerance", i)
        claim = Claim(text, (pair[0], pair[1]), expect, tolerance, tuple(cover), tuple(families), tuple(memories))
        v.require_cover(field, i, machines, claim.covers, claim.cpus, claim.families, claim.memories)
        claims.append(claim)

    return Scene(path, name, description, width, height, geometry,
                 RunSpec(variants, tuple(machines), metrics, frames), span_bound, tuple(claims))
