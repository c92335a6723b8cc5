"""Texture-mapping scenes (``kind = "texture"``): the span renderers of "Texture Mapping
Optimization for Games" (John DiCamillo), step by step (kernels/texture/persp.S, the model of their
arithmetic in sim/scenes/texture/frame.py), on a perspective-correct textured frame; error against the
exact mapping, cycles per pixel per CPU, the article's component figures measured by probes, and
its claims checked.

Format::

    [scene]
    kind = "texture"                # required for this kind
    name = "texture-article"        # required; must equal the file stem
    description = "..."             # optional
    width = 640                     # required, pixels (at most 4096)
    height = 480                    # required, pixels (at most 4096)

    [geometry]
    generator = "grid"              # the screen tiled by a jittered grid, two triangles per cell
    seed = 1997                     # required
    columns = 5                     # required, 1..64
    rows = 4                        # required, 1..64
    w_range = [1.0, 3.0]            # optional: vertex depths (0 < lo <= hi)
    st_range = [40.0, 216.0]        # optional: vertex texture coordinates in texels (0 <= lo <= hi <= 256)

    [run]
    variants = ["a", "b", "c", "d", "e"]   # required: the article's steps (sim.scenes.texture.frame.VARIANTS)
    cpus = ["pentium-133", "k6-2-300"]     # required: CPU preset[:memory preset]
    timing_stride = 4               # optional (default 1): time every n-th span of the frame (a
                                    #   representative subset; every pixel is still checked)

    [[claims]]                      # optional, repeatable
    text = "..."                    # required: the article's words
    quantity = "cycles_per_pixel"   # required: see QUANTITIES
    variants = ["a"]                # one variant for cycles_per_pixel, two for cycles_ratio and
                                    #   cycles_saved; none for the probes
    expect = "about"                # required: about | at_most | at_least | between
    value = 28.0                    # about / at_most / at_least
    tolerance = 0.25                # about: a fraction of value (default 0.1) ...
    within = 2.0                    # ... or an absolute margin instead
    range = [0.0, 1.0]              # between
    cpus = ["pentium-133"]          # the machines its words cover (presets, any memory) ...
    families = ["FAMILY"]           # ... and/or whole CPU families by name (see `retrosim cpus`); at
                                    #   least one covered machine must run

Claims are checked on every covered machine of the run, each with the counters that explain it;
they are not re-timed over the models' estimates (sim.scenes.claims does that for Z-buffer scenes
only). This module loads, runs and reports; sim.scenes.registry puts it behind sim.scenes.kind.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from sim.cpus.machine import family_of
from sim.cpus.machine import MachineKey
from sim.cpus.families import FAMILIES, order as family_order
from sim.errors import RetrosimError
from sim.guest.kernels import kernels_root
from sim.reports.render import FORMATS, add_label_column, console_label, md_table, wants_image, write_report_set
from sim.scenes.claims import Claim, report_head
from sim.scenes.schema import (CLAIM_CPUS, CLAIM_FAMILIES, CLAIM_TEXT, SCENE_DESCRIPTION, SCENE_KIND, SCENE_NAME,
                               SEED_RANGE, CpuChoice, Field, Validator, show)
from sim.scenes.texture import frame as F

QUANTITIES = {
    "cycles_per_pixel": "cycles per pixel of a variant's frame",
    "cycles_ratio": "cycles per pixel of variants[0] / variants[1]",
    "cycles_saved": "cycles per pixel of variants[0] - variants[1]",
    "ftol_call": "clocks one _ftol conversion adds, call included, over FLD / FSTP ST(0)",
    "ftol_per_subspan": "clocks the two _ftol conversions of a 16-pixel sub-span add (twice ftol_call)",
    "fistp": "clocks one FISTP conversion adds over FLD / FSTP ST(0)",
    "fdiv_serial": "clocks a 16-pixel sub-span's FLD1 / FDIV / FSTP add when FSTP follows FDIV (64-bit precision)",
    "fdiv_serial_24": "the same at 24-bit precision",
    "fdiv_precision_saving": "fdiv_serial - fdiv_serial_24: what 24-bit precision saves on a waited-for divide",
    "fdiv_overlapped": "clocks FLD1 / FDIV before the inner loop and FSTP after it add (64-bit precision)",
    "timesnap_overhead": "stop - start of two back-to-back TIMESNAPs, from the model's RDTSC answers",
    "span_setup_saving": "clocks per span of b's set-up minus c's (spans of 0 pixels)",
}
VARIANT_QUANTITIES = {"cycles_per_pixel": 1, "cycles_ratio": 2, "cycles_saved": 2}
EXPECTATIONS = ("about", "at_most", "at_least", "between")
COUNTERS = ("cycles", "instructions", "uops", "decode_groups", "l1d_load_misses", "l1d_store_misses", "l2_misses",
            "dram_fills", "mispredicts")
MAX_SIDE = 4096
PROBE_N = 64        # probe loops: iterations at n and 2n, the difference per iteration
SETUP_SPANS = 16    # zero-pixel spans at n and 2n for the set-up probe

SCENE = (SCENE_KIND, SCENE_NAME, SCENE_DESCRIPTION,
         Field("width", "int", True, min=16, max=MAX_SIDE, doc="pixels"),
         Field("height", "int", True, min=16, max=MAX_SIDE, doc="pixels"))
GEOMETRY = (Field("generator", "str", True, choices=("grid",), noun="generator"),
            Field("seed", "int", True, span=SEED_RANGE),
            Field("columns", "int", True, min=1, max=64), Field("rows", "int", True, min=1, max=64),
            Field("w_range", "any", doc="vertex depths (0 < lo <= hi)"),
            Field("st_range", "any", doc="vertex texture coordinates in texels (0 <= lo <= hi <= 256)"))
TIMING_STRIDE = Field("timing_stride", "int", default=1, min=1, doc="time every n-th span of the frame")
RUN = (Field("variants", "strlist", True, nonempty=True, unique="bare", choices=F.VARIANTS, noun="variant"),
       Field("cpus", "strlist", True, nonempty=True, unique="bare", doc="CPU preset[:memory preset]"), TIMING_STRIDE)
CLAIM = (CLAIM_TEXT, Field("quantity", "str", True, choices=tuple(QUANTITIES), noun="quantity"),
         Field("variants", "strlist", default=()),
         Field("expect", "str", True, choices=EXPECTATIONS, noun="expectation"),
         Field("value", "number"), Field("tolerance", "number", span=(0, 1, "in [0, 1)")),
         Field("within", "number", min=0), Field("range", "any"), CLAIM_CPUS, CLAIM_FAMILIES)


# ---------------------------------------------------------------------------------------------
# the scene

@dataclass(frozen=True)
class TextureClaim(Claim):
    """A measured quantity (QUANTITIES) of `variants` on every covered machine: `expect` about
    `value` (within `tolerance` of it, a fraction, default 0.1, or `within` clocks), at most or at
    least `value`, or between `range`."""

    tolerance: float | None = None
    quantity: str = ""
    value: float | None = None
    within: float | None = None
    range: tuple[float, float] | None = None

    def holds(self, x: float) -> bool:
        if self.expect == "between":
            return self.range[0] <= x <= self.range[1]
        if self.expect == "at_most":
            return x <= self.value
        if self.expect == "at_least":
            return x >= self.value
        margin = self.within if self.within is not None else (self.tolerance if self.tolerance is not None else 0.1) * abs(self.value)
        return abs(x - self.value) <= margin

    def describe(self) -> str:
        what = self.quantity + (f" ({', '.join(self.variants)})" if self.variants else "")
        if self.expect == "between":
            return f"{what} between {self.range[0]:g} and {self.range[1]:g}"
        if self.expect in ("at_most", "at_least"):
            return f"{what} {self.expect.replace('_', ' ')} {self.value:g}"
        margin = f"+-{self.within:g}" if self.within is not None else f"+-{(self.tolerance if self.tolerance is not None else 0.1):.0%}"
        return f"{what} about {self.value:g} ({margin})"


@dataclass(frozen=True)
class TextureScene:
    path: Path
    name: str
    description: str
    width: int
    height: int
    seed: int
    columns: int
    rows: int
    w_range: tuple[float, float]
    st_range: tuple[float, float]
    variants: tuple[str, ...]
    machines: tuple[CpuChoice, ...]
    timing_stride: int = 1
    claims: tuple[TextureClaim, ...] = ()
    kind: str = "texture"

    @property
    def cpus(self) -> list[str]:
        return [m.label for m in self.machines]

    @property
    def frames(self) -> int:
        return 1

    def build_geometry(self) -> F.TexturedGeometry:
        return F.grid_scene(self.width, self.height, self.columns, self.rows, self.seed, self.w_range, self.st_range)


def _pair(v: Validator, table: dict, key: str, default, lo_min: float, hi_max: float, strict_lo: bool) -> tuple:
    if key not in table:
        return default
    x = table[key]
    if (not isinstance(x, list) or len(x) != 2 or any(isinstance(e, bool) or not isinstance(e, (int, float)) for e in x)
            or not all(math.isfinite(e) for e in x)):
        v.fail(f"geometry.{key}", f"expected an array of two numbers [lo, hi], got {show(x)}", "geometry", key)
    lo, hi = float(x[0]), float(x[1])
    if not ((lo > lo_min if strict_lo else lo >= lo_min) and lo <= hi <= hi_max):
        v.fail(f"geometry.{key}", f"need {lo_min:g} {'<' if strict_lo else '<='} lo <= hi <= {hi_max:g}, got {show(x)}",
               "geometry", key)
    return lo, hi


def load(path: Path, text: str, doc: dict) -> TextureScene:
    """Validate a parsed texture scene (sim.scenes.registry.load_scene dispatches here on [scene].kind)."""
    v = Validator(path, text)
    sc = v.scene_header(doc, "texture", ("scene", "geometry", "run", "claims"), SCENE)
    width, height = sc["width"], sc["height"]
    table = v.table(doc, "geometry")
    ge = v.section(table, GEOMETRY, "geometry", note=" for kind 'texture'")
    w_range = _pair(v, table, "w_range", (1.0, 3.0), 0.0, 1e6, True)
    st_range = _pair(v, table, "st_range", (40.0, 216.0), 0.0, 256.0, False)

    ru = v.section(v.table(doc, "run"), RUN, "run", note=" for kind 'texture'")
    variants, stride = ru["variants"], ru["timing_stride"]
    # the grid covers the screen, so a frame has at least one span per row: a larger stride could
    # time a single span (run_scene also checks MIN_TIMED_SPANS once the spans are known)
    v.check(replace(TIMING_STRIDE, max=height, max_note=" (the frame's height: at least one span per row)"), stride, "run")
    machines = v.machines(ru["cpus"])

    claims = []
    for i, c in enumerate(v.claim_tables(doc)):
        field_ = f"claims[{i}]"
        cl = v.section(c, CLAIM, "claims", i, field_)
        quantity, pair, expect, rng = cl["quantity"], cl["variants"], cl["expect"], cl["range"]
        need = VARIANT_QUANTITIES.get(quantity, 0)
        if len(pair) != need or any(x not in variants for x in pair):
            v.fail(f"{field_}.variants", f"{quantity} takes {need} of run.variants ({', '.join(variants)}), "
                   f"got {show(list(pair))}", "claims", "variants", i)
        if expect == "between":
            if (not isinstance(rng, list) or len(rng) != 2 or any(isinstance(e, bool) or not isinstance(e, (int, float))
                                                                 for e in rng) or not rng[0] <= rng[1]):
                v.fail(f"{field_}.range", f"'between' needs range = [lo, hi] with lo <= hi, got {show(rng)}",
                       "claims", "range" if "range" in c else None, i)
            rng = (float(rng[0]), float(rng[1]))
        elif cl["value"] is None:
            v.fail(f"{field_}.value", f"'{expect}' needs value = a number", "claims", None, i)
        if cl["tolerance"] is not None and cl["within"] is not None:
            v.fail(f"{field_}.within", "give tolerance (a fraction) or within (clocks), not both", "claims", "within", i)
        if not cl["cpus"] and not cl["families"]:
            v.fail(field_, "names no CPU: give cpus = [...] and/or families = [...]", "claims", None, i)
        v.claim_cpus(field_, i, cl["cpus"])
        v.families(field_, cl["families"], i)
        claim = TextureClaim(cl["text"], tuple(pair), expect, cl["tolerance"], cl["cpus"], cl["families"],
                             quantity=quantity, value=cl["value"], within=cl["within"],
                             range=rng if expect == "between" else None)
        v.require_cover(field_, i, machines, claim)
        claims.append(claim)

    scene = TextureScene(path, sc["name"], sc["description"], width, height, ge["seed"], ge["columns"], ge["rows"],
                         w_range, st_range, tuple(variants), tuple(machines), stride, tuple(claims))
    try:  # the 24.8 variant needs v inside the texture: say so now, not after the emulation
        params = F.span_params(scene.build_geometry(), width, height)
        for var in variants:
            F.variant_pixels(var, params)
    except F.TextureSceneError as e:
        v.fail("geometry", str(e), "geometry")
    return scene


# ---------------------------------------------------------------------------------------------
# running

@dataclass
class TextureResult:
    scene: TextureScene
    spans: int
    pixels: int
    timed_spans: int
    timed_pixels: int
    accuracy: dict = field(default_factory=dict)     # variant -> error metrics
    timings: dict = field(default_factory=dict)      # (variant, machine key) -> counters of the timed pass
    probes: dict = field(default_factory=dict)       # machine key -> {quantity: clocks, "explain": {...}}
    keys: list = field(default_factory=list)         # machine keys "preset:memory" in run order

    @property
    def cpu_keys(self) -> list[str]:
        return list(self.keys)

    def cycles_per_pixel(self, variant: str, key: str) -> float:
        return self.timings[(variant, key)]["cycles"] / self.timed_pixels if self.timed_pixels else 0.0

    def per_pixel(self, variant: str, key: str, counter: str) -> float:
        return self.timings[(variant, key)].get(counter, 0) / self.timed_pixels if self.timed_pixels else 0.0


def frame_setup(params: F.SpanParams, width: int, height: int, tex: np.ndarray, layout: list | None = None):
    """A sim.timing setup: span records, the texture on a 64 KB boundary, the 8-bit frame buffer."""

    def setup(m):
        recs = m.arena.alloc(F.RECORD_BYTES * max(1, len(params)), align=4096)
        t = m.arena.put(tex, align=1 << 16)
        fb = m.arena.alloc(width * height, align=4096)
        m.uc.mem_write(recs, F.span_records(params, fb, width))
        if layout is not None:
            layout.append(fb)
        return [recs, len(params), t]

    return setup


def draw_frame(variant: str, params: F.SpanParams, width: int, height: int, tex: np.ndarray) -> np.ndarray:
    """The frame buffer a variant's kernel leaves (untraced emulation)."""
    from sim.guest.emu import Machine

    m = Machine.from_source(kernels_root() / F.KERNEL)
    layout: list = []
    args = frame_setup(params, width, height, tex, layout)(m)
    m.call(f"frame_{variant}", *args)
    return m.arena.get(layout[0], np.uint8, width * height)


def expected_frame(pixels: F.VariantPixels, params: F.SpanParams, width: int, height: int, tex) -> np.ndarray:
    span, off = F.pixel_index(params)
    out = np.zeros(width * height, np.uint8)
    out[params.y[span] * width + params.x0[span] + off] = pixels.texels(tex)
    return out


def _probe_kernel_cycles(cpu: str, memory: str, entry: str, setup_for) -> tuple[dict, dict]:
    from sim.timing.kernel import time_kernel

    path = kernels_root() / F.KERNEL
    return tuple(time_kernel(path, entry, setup_for(n), cpu=cpu, memory=memory, repeat=2).last
                 for n in (PROBE_N, 2 * PROBE_N))


def _diff(runs: tuple[dict, dict], per: int) -> dict:
    a, b = runs
    return {k: (b[k] - a[k]) / per for k in a if isinstance(a[k], (int, np.integer)) and k in b}


def measure_probes(cpu: str, memory: str, first_span: F.SpanParams) -> dict:
    """The article's component figures on one machine, each the difference of two runs."""
    from sim.studies import texture_loops as texture
    from sim.timing.kernel import time_kernel

    path = kernels_root() / F.KERNEL

    def conv(n):
        return lambda m: [n, m.arena.put(np.array([12345.75], np.float64))]

    per = {name: _diff(_probe_kernel_cycles(cpu, memory, f"probe_{name}", conv), PROBE_N)
           for name in ("ftol", "fistp", "none")}
    out = {"ftol_call": per["ftol"]["cycles"] - per["none"]["cycles"],
           "fistp": per["fistp"]["cycles"] - per["none"]["cycles"]}
    out["ftol_per_subspan"] = 2 * out["ftol_call"]
    names = ("instructions",) + EXPLAIN[family_of(cpu)]
    explain = {q: {k: round(per[name][k] - per["none"][k], 2) for k in names
                   if k in per["none"] and abs(per[name][k] - per["none"][k]) >= 0.5}
               for q, name in (("ftol_call", "ftol"), ("fistp", "fistp"))}

    # FDIV in a 16-pixel sub-span (kernels/texture/fdiv.S), per sub-span over the loop without it
    fd, fdc = {}, {}
    n = 256
    for entry in ("sub16", "sub16_overlap", "sub16_serial", "sub16_serial_single"):
        runs = tuple(time_kernel(kernels_root() / texture.FDIV_KERNEL, entry, texture.fdiv_setup(k), cpu=cpu,
                                 memory=memory, repeat=2).last for k in (n, 2 * n))
        fdc[entry] = _diff(runs, n // 16)
        fd[entry] = fdc[entry]["cycles"]
    explain["fdiv_overlapped"] = {k: round(fdc["sub16_overlap"][k] - fdc["sub16"][k], 1) for k in names
                                  if k in fdc["sub16"] and abs(fdc["sub16_overlap"][k] - fdc["sub16"][k]) >= 0.5}
    out["fdiv_overlapped"] = fd["sub16_overlap"] - fd["sub16"]
    out["fdiv_serial"] = fd["sub16_serial"] - fd["sub16"]
    out["fdiv_serial_24"] = fd["sub16_serial_single"] - fd["sub16"]
    out["fdiv_precision_saving"] = out["fdiv_serial"] - out["fdiv_serial_24"]

    # TIMESNAP: the model's RDTSC answers, around nothing and around one _ftol conversion
    snaps = {}
    for entry, setup in (("snap_none", None), ("snap_ftol", lambda m: [m.arena.put(np.array([12345.75], np.float64))])):
        r = time_kernel(path, entry, setup, cpu=cpu, memory=memory, repeat=2).run.rdtsc
        snaps[entry] = int(r[-1] - r[-2])
    out["timesnap_overhead"] = snaps["snap_none"]
    out["timesnap_ftol"] = snaps["snap_ftol"]

    # per-span set-up: spans of 0 pixels (the set-up runs, the sub-span loop does not)
    def spans(k):
        recs = first_span.select(np.zeros(k, np.int64))
        recs = F.SpanParams(recs.y, recs.x0, np.zeros(k, np.int64), recs.tri, recs.start, recs.step)
        return frame_setup(recs, 64, 1, F.texture())

    setup_cost = {}
    for var in ("b", "c"):
        c = [time_kernel(path, f"frame_{var}", spans(k), cpu=cpu, memory=memory, repeat=2).last["cycles"]
             for k in (SETUP_SPANS, 2 * SETUP_SPANS)]
        setup_cost[var] = (c[1] - c[0]) / SETUP_SPANS
    out["span_setup_b"], out["span_setup_c"] = setup_cost["b"], setup_cost["c"]
    out["span_setup_saving"] = setup_cost["b"] - setup_cost["c"]
    out["explain"] = explain
    return out


MIN_TIMED_SPANS = 100  # the timed subset stands for the frame's span lengths (the article frame times 660)


def timed_spans(scene: TextureScene, params: F.SpanParams) -> F.SpanParams:
    """The spans the timing draws: every timing_stride-th span of the frame, at least
    MIN_TIMED_SPANS of them (or every span of a smaller frame)."""
    timed = -(-len(params) // scene.timing_stride)
    if timed < min(MIN_TIMED_SPANS, len(params)):
        most = max(1, len(params) // MIN_TIMED_SPANS)
        raise RetrosimError(f"{scene.path}: run.timing_stride = {scene.timing_stride} times {timed} of the frame's "
                            f"{len(params):,} spans; at most {most} keeps {MIN_TIMED_SPANS} or more timed, so that "
                            "they have the frame's distribution of span lengths")
    return params.select(np.arange(len(params)) % scene.timing_stride == 0)


def emulate_variant(variant: str, timed: F.SpanParams, width: int, height: int, tex: np.ndarray):
    """The traced emulation of a variant drawing the timed spans twice in one machine state."""
    from sim.timing.kernel import emulate

    return emulate(kernels_root() / F.KERNEL, f"frame_{variant}", frame_setup(timed, width, height, tex), repeat=2)


def _time_task(shared, variant: str, index: int, what: str) -> dict:
    from sim.scenes.progress import timed_run

    emulations, models = shared[0], shared[1]
    return timed_run(what, emulations[variant], models[index]).last


def _probe_task(shared, cpu: str, memory: str, what: str) -> dict:
    from sim.parallel import report

    _, _, first = shared
    report(what)
    probes = measure_probes(cpu, memory, first)
    report(done=1)  # a machine's probes count as one machine run
    return probes


def run_scene(scene: TextureScene, cpus: list[str] | None = None, progress=None, robustness: bool = True,
              jobs: int = 1) -> TextureResult:
    """Check every pixel of the frame against the model of each variant, measure the error against
    the exact mapping, time every timing_stride-th span on each machine, and run the probes."""
    from sim.cpus.build import make_model
    from sim.parallel import SharedPool

    say = progress or (lambda *a, **kw: None)
    say(more=len(cpus or scene.cpus) * (len(scene.variants) + 1))  # each variant's timing, and the probes, per machine
    w, h = scene.width, scene.height
    geometry = scene.build_geometry()
    params = F.span_params(geometry, w, h)
    tex = F.texture()
    timed = timed_spans(scene, params)
    result = TextureResult(scene, len(params), params.pixels, len(timed), timed.pixels)
    u_exact, v_exact = F.exact_coordinates(geometry, params)
    emulations = {}
    for variant in scene.variants:
        say(f"variant {variant}: drawing and checking {params.pixels:,} pixels")
        model_pixels = F.variant_pixels(variant, params)
        got = draw_frame(variant, params, w, h, tex)
        if not np.array_equal(got, expected_frame(model_pixels, params, w, h, tex)):
            raise RetrosimError(f"{scene.path}: variant {variant}: the emulated frame differs from the model of the "
                                "kernel's arithmetic (sim/scenes/texture/frame.py): a kernel or emulator bug")
        result.accuracy[variant] = F.error_metrics(model_pixels, variant, u_exact, v_exact)
        emulations[variant] = emulate_variant(variant, timed, w, h, tex)
    machines = [MachineKey.parse(spec) for spec in cpus or scene.cpus]
    models = [make_model(m.label, m.memory or None) for m in machines]
    keys = [str(MachineKey(m.label, model.dram.name)) for m, model in zip(machines, models)]
    result.keys = keys
    shared = (emulations, models, params.select(np.arange(len(params)) == 0))
    pool = SharedPool(shared, jobs, models, progress)
    futures = []
    for i, key in enumerate(keys):
        for variant in scene.variants:
            futures.append(("t", variant, i, pool.submit(_time_task, variant, i, f"variant {variant} on {key}")))
        machine = MachineKey.parse(key)
        futures.append(("p", None, i, pool.submit(_probe_task, machine.label, machine.memory, f"probes on {key}")))
    try:
        for kind, variant, i, fut in futures:
            if kind == "t":
                result.timings[(variant, keys[i])] = {k: int(v) for k, v in fut.result().items()
                                                      if isinstance(v, (int, np.integer))}
            else:
                result.probes[keys[i]] = fut.result()
    finally:
        pool.close()
    # the same order for any `jobs`
    result.timings = {(v, k): result.timings[(v, k)] for v in scene.variants for k in keys}
    return result


# ---------------------------------------------------------------------------------------------
# claims

def quantity(result: TextureResult, claim: TextureClaim, key: str) -> float:
    if claim.quantity == "cycles_per_pixel":
        return result.cycles_per_pixel(claim.variants[0], key)
    if claim.quantity in ("cycles_ratio", "cycles_saved"):
        a, b = (result.cycles_per_pixel(x, key) for x in claim.variants)
        return (a / b if b else float("inf")) if claim.quantity == "cycles_ratio" else a - b
    return float(result.probes[key][claim.quantity])


EXPLAIN = {name: f.explain for name, f in FAMILIES.items()}  # per family: its record's explain columns


def explanation(result: TextureResult, claim: TextureClaim, key: str) -> dict:
    """The counters behind a measured quantity: per pixel for a variant (the difference for two),
    the probe's counter differences for _ftol, the set-up and the parts for the others."""
    fam = family_of(key)
    if claim.variants:
        names = [n for n in EXPLAIN[fam] if any(n in result.timings[(v, key)] for v in claim.variants)]
        if len(claim.variants) == 1:
            return {n: round(result.per_pixel(claim.variants[0], key, n), 3) for n in names}
        a, b = claim.variants
        return {n: round(result.per_pixel(a, key, n) - result.per_pixel(b, key, n), 3) for n in names
                if abs(result.per_pixel(a, key, n) - result.per_pixel(b, key, n)) >= 0.005}
    p = result.probes[key]
    if claim.quantity in ("ftol_call", "ftol_per_subspan", "fistp"):
        return dict(p["explain"]["fistp" if claim.quantity == "fistp" else "ftol_call"])
    if claim.quantity == "span_setup_saving":
        return {"set-up b": round(p["span_setup_b"], 1), "set-up c": round(p["span_setup_c"], 1)}
    if claim.quantity == "timesnap_overhead":  # the RDTSC row the model charges
        from sim.cpus.table import load_table

        row = load_table(fam).lookup("rdtsc", "").row
        return {"RDTSC uops": row.uops, **({"RDTSC clocks": row.extra["cycles"]} if "cycles" in row.extra else {})}
    if claim.quantity.startswith("fdiv"):
        parts = {"serial": round(p["fdiv_serial"], 1), "serial 24-bit": round(p["fdiv_serial_24"], 1),
                 "overlapped": round(p["fdiv_overlapped"], 1)}
        if claim.quantity == "fdiv_overlapped":  # what the overlapped divide's sub-span adds, by counter
            parts.update(p["explain"]["fdiv_overlapped"])
        return parts
    return {}


def evaluate(result: TextureResult) -> list[dict]:
    out = []
    for claim in result.scene.claims:
        per_cpu = []
        for key in result.keys:
            if not claim.covers(MachineKey.parse(key).label, None, family_of(key)):
                continue
            x = quantity(result, claim, key)
            ok = claim.holds(x)
            per_cpu.append({"cpu": key, "measured": round(x, 4), "holds": ok,
                            "verdict": "reproduced" if ok else "not reproduced",
                            "explanation": explanation(result, claim, key)})
        verdicts = {e["verdict"] for e in per_cpu}
        overall = verdicts.pop() if len(verdicts) == 1 else ("mixed (see each machine)" if per_cpu else "not checked")
        run_presets = {MachineKey.parse(k).label for k in result.keys}
        missing = [m.label for m in result.scene.machines if m.preset not in run_presets
                   and claim.covers(m.preset, None, family_of(m.label))]
        out.append({"text": claim.text, "quantity": claim.quantity, "claim": claim.describe(),
                    "covers": claim.describe_coverage(), "verdict": overall, "holds": bool(per_cpu) and all(e["holds"] for e in per_cpu),
                    "per_cpu": per_cpu, "not_checked": missing})
    return out


# ---------------------------------------------------------------------------------------------
# reports

def baseline_entries(result: TextureResult) -> dict[str, dict[str, int]]:
    """reports/baselines.json cases: each variant's timed pass per machine, and the probes'
    figures (cycles, rounded to whole clocks x 100 so the integer comparison keeps fractions)."""
    out = {f"{v}@{key}": {c: int(t[c]) for c in COUNTERS if c in t} for (v, key), t in result.timings.items()}
    for key, p in result.probes.items():
        out[f"probes@{key}"] = {q: round(100 * float(p[q])) for q in sorted(p) if q != "explain"}
    return out


def _f(x: float, digits: int = 2) -> str:
    return f"{x:,.{digits}f}"


def _label(key: str) -> str:
    return MachineKey.parse(key).display


def _ordered_keys(result: TextureResult) -> list[str]:
    return sorted(result.keys, key=lambda k: (family_order(family_of(k)), result.keys.index(k)))


def claim_lines(c: dict) -> list[str]:
    lines = [f"- {c['text']} — **{c['verdict']}**. Checked: {c['claim']}, on {c['covers']}."]
    for e in c["per_cpu"]:
        why = ", ".join(f"{n.replace('stall_', '')} {v:g}" for n, v in e["explanation"].items())
        lines.append(f"  - {_label(e['cpu'])}: **{e['verdict']}** — measured {e['measured']:g}"
                     + (f"; {why}" if why else "") + ".")
    lines += [f"  - {_label(k) if ':' in k else k}: not checked (CPU not in this run)." for k in c["not_checked"]]
    return lines


def _short(counter: str) -> str:
    return counter.replace("stall_", "")


def findings(result: TextureResult) -> list[str]:
    out = []
    acc = result.accuracy
    if "d" in acc and "e" in acc:
        d, e = acc["d"], acc["e"]
        out.append(f"24.8 instead of 16.16 (e against d, same outer loop): mean coordinate error "
                   f"{e['mean_coordinate_error']:.4f} against {d['mean_coordinate_error']:.4f} texels, largest "
                   f"{e['max_coordinate_error']:.3f} against {d['max_coordinate_error']:.3f}; "
                   f"{e['wrong_texel_share']:.2%} of pixels read another texel than the exact mapping against "
                   f"{d['wrong_texel_share']:.2%} (the 16-pixel sub-spans' affine error is common to both).")
    if "a" in acc and "b" in acc:
        a, b = acc["a"], acc["b"]
        changed = abs(b["wrong_texel"] - a["wrong_texel"])
        out.append(f"24-bit precision (b against a) changes the share of wrong texels by {changed:,} pixels of "
                   f"{a['pixels']:,}; the mean coordinate error moves from {a['mean_coordinate_error']:.7f} to "
                   f"{b['mean_coordinate_error']:.7f} texels.")
    steps = [("a", "b", "the overlapped divide and 24-bit precision"), ("b", "c", "FISTP, the reordered loop and set-up"),
             ("c", "d", "the 4-clock loop"), ("c", "e", "24.8 instead of 16.16")]
    for x, y, what in steps:
        if x not in acc or y not in acc:
            continue
        parts = []
        for key in _ordered_keys(result):
            diff = {n: result.per_pixel(x, key, n) - result.per_pixel(y, key, n) for n in EXPLAIN[family_of(key)]
                    if n.startswith("stall_") or n in ("alone", "uops")}
            top = sorted(diff, key=lambda n: (-abs(diff[n]), n))[:2]
            parts.append(f"{MachineKey.parse(key).label} {result.cycles_per_pixel(x, key) - result.cycles_per_pixel(y, key):.2f} "
                         f"({', '.join(_short(n) + f' {diff[n]:+.2f}' for n in top)})")
        out.append(f"Cycles per pixel {what} ({y}) saves over {x}, with the two counters that differ most ({x} minus "
                   f"{y}, per pixel): " + "; ".join(parts) + ".")
    return out


def to_markdown(result: TextureResult, png_name: str | None) -> str:
    s = result.scene
    keys = _ordered_keys(result)
    parts = report_head(s, evaluate(result), _label, findings(result)[:2])
    parts += [f"Workload: {s.width}x{s.height} pixels, {s.columns}x{s.rows} jittered grid cells of two perspective "
             f"textured triangles each (vertex depths {s.w_range[0]:g}..{s.w_range[1]:g}, texture coordinates "
             f"{s.st_range[0]:g}..{s.st_range[1]:g} texels), a 256x256 8-bit texture, {result.spans:,} spans, "
             f"{result.pixels:,} pixels, no overdraw (the article's span sorter hands the renderer visible spans "
             f"only). Every pixel of every variant is checked against the model of its arithmetic "
             f"(sim/scenes/texture/frame.py). Timed: every {s.timing_stride}th span ({result.timed_spans:,} spans, "
             f"{result.timed_pixels:,} pixels, the same distribution of span lengths), drawn twice in one machine "
             "state; the second pass is reported (caches and predictors warm).", "",
             "Variants (kernels/texture/persp.S):", ""]
    parts += [f"- **{v}**: {F.VARIANT_LABELS[v]}" for v in s.variants] + [""]
    parts += ["## Cycles per pixel", "",
              md_table(["CPU (memory)"] + list(s.variants),
                        [[_label(k)] + [_f(result.cycles_per_pixel(v, k)) for v in s.variants] for k in keys]), ""]
    parts += ["## Error against the exact mapping", "",
              "Against u = (u/w) / (1/w), v likewise, in float64 at every pixel's centre. A pixel is wrong when "
              "it reads another texel than floor(u), floor(v); the coordinate error is the larger of |u - u_exact| "
              "and |v - v_exact| in texels. Every variant interpolates linearly across 16-pixel sub-spans, which "
              "is most of the error; the variants differ by their float precision, their conversion (_ftol "
              "truncates, FISTP rounds) and their fixed point.", "",
              md_table(["variant", "wrong texel (pixels)", "wrong texel (share)", "largest coordinate error",
                         "mean coordinate error"],
                        [[v, f"{a['wrong_texel']:,}", f"{a['wrong_texel_share']:.3%}", f"{a['max_coordinate_error']:.4f}",
                          f"{a['mean_coordinate_error']:.5f}"] for v, a in ((v, result.accuracy[v]) for v in s.variants)]),
              ""]
    if png_name:
        parts += ["## Error against cycles", "", f"![error against cycles]({png_name})", ""]
    parts += ["## The article's component figures, measured", "",
              "Each the difference of two runs of a probe (kernels/texture/persp.S, fdiv.S): _ftol and FISTP "
              f"loops of {PROBE_N} and {2 * PROBE_N} conversions against the same loop with FLD / FSTP ST(0); "
              "16-pixel sub-spans with and without FLD1 / FDIV / FSTP (serial: FSTP right after FDIV; overlapped: "
              "FDIV before the inner loop, FSTP after it; 64-bit precision unless marked 24-bit, each set by FLDCW "
              "of a constant word); spans of 0 pixels through b's and c's set-up; TIMESNAP from the model's "
              "RDTSC answers (stop - start around nothing, and around one _ftol conversion, which the article "
              "would print minus 16).", "",
              md_table(["CPU (memory)", "_ftol call", "FISTP", "FDIV serial", "FDIV serial 24-bit", "FDIV overlapped",
                         "set-up b", "set-up c", "TIMESNAP overhead", "TIMESNAP around _ftol"],
                        [[_label(k)] + [_f(result.probes[k][q], 1) for q in
                                        ("ftol_call", "fistp", "fdiv_serial", "fdiv_serial_24", "fdiv_overlapped",
                                         "span_setup_b", "span_setup_c")]
                         + [str(result.probes[k]["timesnap_overhead"]), str(result.probes[k]["timesnap_ftol"])]
                         for k in keys]), "",
              "Self-timing: the article subtracts 16 from a TIMESNAP reading. With each model's own overhead (the "
              "'TIMESNAP overhead' column) the reading around one _ftol gives "
              + "; ".join(f"{_label(k)} {result.probes[k]['timesnap_ftol'] - result.probes[k]['timesnap_overhead']} "
                          f"(minus 16: {result.probes[k]['timesnap_ftol'] - 16}) against the probe's "
                          f"{result.probes[k]['ftol_call']:.1f}" for k in keys) + ".", ""]
    claims = evaluate(result)
    if claims:
        parts += ["## The article's claims, checked", "",
                  "Not re-timed over the models' estimates (unlike the Z-buffer scenes' claims). Counters are per "
                  "pixel of the timed pass (the difference of the two variants for a ratio or a saving), or the "
                  "probe's parts.", ""]
        for c in claims:
            parts += claim_lines(c)
        parts.append("")
    parts += ["## Findings", ""] + [f"- {f}" for f in findings(result)] + [""]
    parts += ["## Where the cycles go", "", "Per pixel of the timed pass.", ""]
    for k in keys:
        fam = family_of(k)
        names = [n for n in EXPLAIN[fam] if any(n in result.timings[(v, k)] for v in s.variants)]
        parts += [f"### {_label(k)}", "",
                  md_table(["variant", "cycles", "instructions"] + [n.replace("stall_", "stall ") for n in names],
                            [[v, _f(result.cycles_per_pixel(v, k)), _f(result.per_pixel(v, k, "instructions"))]
                             + [_f(result.per_pixel(v, k, n)) for n in names] for v in s.variants]), ""]
    return "\n".join(parts).rstrip() + "\n"


def to_json(result: TextureResult) -> dict:
    s = result.scene
    return {"scene": s.name, "kind": s.kind, "description": s.description, "width": s.width, "height": s.height,
            "spans": result.spans, "pixels": result.pixels, "timed_spans": result.timed_spans,
            "timed_pixels": result.timed_pixels,
            "timings": [{"variant": v, "cpu": key, "cycles_per_pixel": round(result.cycles_per_pixel(v, key), 4), **t}
                        for (v, key), t in result.timings.items()],
            "accuracy": {v: {k: (round(x, 8) if isinstance(x, float) else x) for k, x in a.items()}
                         for v, a in result.accuracy.items()},
            "probes": {k: {q: (round(float(x), 4) if q != "explain" else x) for q, x in p.items()}
                       for k, p in result.probes.items()},
            "claims": evaluate(result), "findings": findings(result)}


def to_csv(result: TextureResult) -> str:
    import csv
    import io

    buf = io.StringIO()
    counters = list(dict.fromkeys(c for t in result.timings.values() for c in t))
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["scene", "variant", "cpu", "timed_pixels", "cycles_per_pixel", "wrong_texel_share",
                "mean_coordinate_error"] + counters)
    for (v, key), t in result.timings.items():
        a = result.accuracy[v]
        w.writerow([result.scene.name, v, key, result.timed_pixels, f"{result.cycles_per_pixel(v, key):.4f}",
                    f"{a['wrong_texel_share']:.6f}", f"{a['mean_coordinate_error']:.6f}"] + [t.get(c, "") for c in counters])
    return buf.getvalue()


def error_cycles_png(result: TextureResult) -> bytes:
    """Error against work as the Z-buffer reports' dot plot: one row per variant, ordered by its
    mean coordinate error (the same on every CPU, written in the row's label with its share of
    wrong texels), cycles per pixel along x, one marker per CPU (offset within the row so none
    hides another; the same colours as the Z-buffer plots, a shape per family)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sim.cpus import presets
    from sim.reports.render import finish_rows, png_bytes, row_offset
    from sim.reports.render import FAMILY_MARKERS

    names = presets.available()
    palette = plt.get_cmap("tab10" if len(names) <= 10 else "tab20")
    acc = result.accuracy
    rows = sorted(result.scene.variants, key=lambda v: (-acc[v]["mean_coordinate_error"], v))  # top to bottom
    keys = _ordered_keys(result)
    fig, ax = plt.subplots(figsize=(8, 1.6 + 0.6 * len(rows) + 0.22 * -(-len(keys) // 3)), dpi=100,
                           layout="constrained")
    spread = min(0.7, 0.08 * len(keys))
    ypos = {v: len(rows) - 1 - i for i, v in enumerate(rows)}
    for i, key in enumerate(keys):
        offset = row_offset(i, len(keys), spread)
        base = MachineKey.parse(key).preset
        colour = palette(names.index(base) % palette.N) if base in names else "0.5"
        ax.scatter([result.cycles_per_pixel(v, key) for v in rows], [ypos[v] - offset for v in rows],
                   marker=FAMILY_MARKERS.get(family_of(key), "o"), s=40, color=colour, edgecolors="black", linewidths=0.4,
                   label=_label(key), zorder=3)
    labels = [f"{v}: mean error {acc[v]['mean_coordinate_error']:.5f} texel, {acc[v]['wrong_texel_share']:.2%} "
              f"wrong texels\n{F.VARIANT_LABELS[v]}" for v in rows]
    finish_rows(fig, ax, rows, ypos, labels, "cycles per pixel (timed pass, caches warm); fewer is faster",
                f"{result.scene.name}: cycles per pixel of the article's steps on each CPU\n"
                "(rows from most to least error against the exact mapping)", 8, 3)
    return png_bytes(fig)


def write_reports(result: TextureResult, out_dir: Path, formats: tuple[str, ...] = FORMATS) -> list[Path]:
    import json

    name = result.scene.name
    png = error_cycles_png(result) if wants_image(formats) else None
    md = to_markdown(result, f"{name}.png")
    return write_report_set(out_dir, name, md, png, json.dumps(to_json(result), indent=2) + "\n", to_csv(result),
                            formats)


def summary_tables(result: TextureResult) -> list:
    """What `retrosim report` prints for a texture scene: cycles per pixel (CPUs as rows), the
    share of wrong texels, how many claims held."""
    from rich import box
    from rich.markup import escape
    from rich.padding import Padding
    from rich.table import Table
    from rich.text import Text

    t = Table(title=f"{escape(result.scene.name)}: cycles per pixel", title_justify="left", box=box.SIMPLE_HEAD,
              pad_edge=False)
    add_label_column(t, "CPU (memory)", [console_label(m.label, m.memory) for m in map(MachineKey.parse, _ordered_keys(result))])
    for v in result.scene.variants:
        t.add_column(v, justify="right", no_wrap=True, min_width=6)
    for key in _ordered_keys(result):
        machine = MachineKey.parse(key)
        t.add_row(escape(console_label(machine.label, machine.memory)), *[f"{result.cycles_per_pixel(v, key):.2f}" for v in result.scene.variants])
    t.add_section()
    t.add_row("wrong texel", *[f"{result.accuracy[v]['wrong_texel_share']:.1%}" for v in result.scene.variants])
    out = [t]
    claims = [c for c in evaluate(result) if c["per_cpu"]]
    if claims:
        # a claim is checked on every family; say how it fares on each, not only where it holds everywhere
        held = sum(c["verdict"] == "reproduced" for c in claims)
        fams = {}
        for c in claims:
            for e in c["per_cpu"]:
                n = fams.setdefault(family_of(e["cpu"]), [0, 0])
                n[0] += e["holds"]
                n[1] += 1
        out.append(Padding(Text(f"claims: {held} of {len(claims)} reproduced on every machine they cover; checks "
                                "reproduced per family: " + ", ".join(f"{f.upper()} {a} of {b}" for f, (a, b)
                                                                       in sorted(fams.items()))), (0, 0, 0, 1)))
        for c in claims:
            counts = {}
            for e in c["per_cpu"]:
                n = counts.setdefault(family_of(e["cpu"]), [0, 0])
                n[0] += e["holds"]
                n[1] += 1
            per = ", ".join(f"{f.upper()} {a}/{b}" for f, (a, b) in sorted(counts.items()))
            out.append(Padding(Text(f"- {per}: {c['text']}"), (0, 0, 0, 3)))  # counts first: the text wraps
    return out


def sweep_emulation(scene: TextureScene, variant: str):
    """The variant drawing the timed spans (every timing_stride-th), as run_scene times it; the units
    are the timed pixels."""
    timed = timed_spans(scene, F.span_params(scene.build_geometry(), scene.width, scene.height))
    return emulate_variant(variant, timed, scene.width, scene.height, F.texture()), timed.pixels
