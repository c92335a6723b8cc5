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
                                    #   estimates to change (sim.cpus.build.make_model's overrides, the
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
    families = ["FAMILY"]           # ... and/or whole CPU families by name (see `retrosim cpus`)
    memories = ["sdram-pc100"]      # optional: only with these memory presets
    # (cpu = "..." is accepted as a one-entry cpus). Every entry of cpus and families must match a
    # machine of run.cpus or run.machine (within memories): a claim naming one the scene does not
    # run is refused, so no part of it goes unchecked (sim.scenes.claims.unrun).

Generators are those of sim.scenes.raster (random_scene, coplanar_far_scene, ...) with the keys above as
their arguments. [scene] and [geometry], the frame, are declared and read in sim.scenes.geometry (the
sort kind reads a Z-buffer scene's frame for its depth keys); [run] and [[claims]] here (the claims
are sim.scenes.claims.Claim). Metrics: "visibility" (wrong winners), "depth_error" (stored vs exact depth),
"fp16_precision" (the format table, needs no frame), "z_fighting" (coplanar_far only).

Every problem raises one :class:`SceneError` (sim.scenes.schema) whose message names the file (with
a line when one can be found) and the dotted field: ``scenes/a.toml:12: run.variants[1]: unknown
variant 'z24' ...``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from sim.cpus.machine import MachineKey
from sim.errors import RetrosimError
from sim.scenes import geometry as geometry_schema
from sim.scenes import raster
from sim.scenes.claims import Claim
from sim.scenes.geometry import GeometrySpec, read_geometry
from sim.scenes.schema import CLAIM_CPUS, CLAIM_FAMILIES, CLAIM_TEXT, CpuChoice, Field, SceneError, Validator, show, toml_type

VARIANTS = raster.VARIANTS
METRICS = ("visibility", "depth_error", "fp16_precision", "z_fighting")
SPAN_RECORD_BYTES = 32  # kernels/zbuffer/draw.inc: 8 dwords per span
ARENA_ALIGN = 64        # sim.guest.emu.Arena.alloc's default alignment
ZBUF_BYTES = {v: raster.ZBUF_DTYPE[v].itemsize for v in VARIANTS}
KERNEL_DIR = "kernels/zbuffer"
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

EXPECTATIONS = ("similar", "faster", "slower")
RUN = (Field("variants", "strlist", True, nonempty=True, unique=True, choices=VARIANTS, noun="variant"),
       Field("cpus", "strlist", True, nonempty=True, unique=True, doc="CPU preset[:memory preset]"),
       Field("metrics", "strlist", default=(), unique=True, choices=METRICS, noun="metric"),
       Field("frames", "int", default=1, min=1, max=1000, doc="frames drawn in one machine state"),
       Field("machine", "tables", default=(), doc="[[run.machine]]: a CPU preset with overrides"))
MACHINE = (Field("cpu", "str", True), Field("memory", "str"), Field("set", "any", True, doc="{ field = value }"))
CLAIM = (CLAIM_TEXT, Field("cpu", "str", doc="a one-entry cpus"),
         replace(CLAIM_CPUS, doc="presets (any memory) or preset:memory"), CLAIM_FAMILIES,
         Field("memories", "strlist", default=(), doc="only with these memory presets"),
         Field("variants", "strlist", True), Field("expect", "str", True, choices=EXPECTATIONS, noun="expectation"),
         Field("tolerance", "number", default=0.0, span=(0, 1, "in [0, 1)")))


# ---------------------------------------------------------------------------------------------
# the parsed scene

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
    from sim.cpus.overrides import memory_presets
    from sim.cpus import presets as cpu_presets
    from sim.guest.emu import DEFAULT_ARENA

    v = Validator(path, text)
    sc = v.scene_header(doc, geometry_schema.KIND, geometry_schema.TABLES, geometry_schema.SCENE)
    name, description, width, height = sc["name"], sc["description"], sc["width"], sc["height"]
    geometry = read_geometry(v, doc)
    gen, triangle_list = geometry.generator, geometry.triangle_list

    # [run]
    ru = v.section(v.table(doc, "run"), RUN, "run")
    variants, cpus, metrics, frames = ru["variants"], ru["cpus"], ru["metrics"], ru["frames"]
    for i, met in enumerate(metrics):
        if met == "z_fighting" and gen != "coplanar_far":
            v.fail(f"run.metrics[{i}]", f"'z_fighting' needs coplanar pairs: generator 'coplanar_far', not '{gen}'",
                   "run", "metrics")
    from sim.cpus.overrides import machine_label

    known_cpus, known_mem = cpu_presets.available(), memory_presets()
    machines = v.machines(cpus)
    for i, table in enumerate(ru["machine"]):
        field = f"run.machine[{i}]"
        m = v.section(table, MACHINE, "run.machine", i, field)
        cpu, memory, sets = m["cpu"], m["memory"], m["set"]
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
        v.machine(machines, label, memory, field, "run.machine", "set", i)

    # does a frame fit in the guest arena? First with a bound needing no geometry (every triangle
    # spans every row); only when that is too much, count the rows the triangles actually cross.
    zbytes = max(ZBUF_BYTES[x] for x in variants)
    widest = next(x for x in variants if ZBUF_BYTES[x] == zbytes)
    ntri = len(triangle_list) if gen == "triangles" else (geometry.triangles or 0)
    if gen == "coplanar_far":
        ntri = 2 * (geometry.pairs or 40)
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
        cl = v.section(c, CLAIM, "claims", i, field)
        cpu, cover, families, memories = cl["cpu"], list(cl["cpus"]), cl["families"], cl["memories"]
        pair, expect = cl["variants"], cl["expect"]
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
        claim = Claim(cl["text"], (pair[0], pair[1]), expect, cl["tolerance"], tuple(cover), families, memories)
        v.require_cover(field, i, machines, claim)
        claims.append(claim)

    return Scene(path, name, description, width, height, geometry,
                 RunSpec(variants, tuple(machines), metrics, frames), span_bound, tuple(claims))
