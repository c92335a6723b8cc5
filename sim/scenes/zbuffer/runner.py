"""Run a Z-buffer scene: rasterize, draw its frames with each Z-buffer variant under Unicorn, time the last
frame on each CPU preset, and measure each variant's error against the exact reference.

Only what the scene asks for is built: its variants' kernels, its presets, its metrics.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import numpy as np

from sim.cpus.build import make_model
from sim.cpus.machine import MachineKey
from sim.errors import RetrosimError
from sim.parallel import SharedPool
from sim.scenes import raster
from sim.scenes.kind import Timing
from sim.scenes.progress import Progress
from sim.scenes.zbuffer import metrics
from sim.scenes.zbuffer.frames import VARIANT_LABELS, draw_frames
from sim.scenes.zbuffer.scene import Scene


@dataclass(frozen=True)
class Accuracy:
    variant: str
    matches_reference_model: bool  # Unicorn's buffers equal sim.scenes.raster.simulate_frame bit for bit
    visibility: dict | None
    depth_error: dict | None
    z_fighting: dict | None = None


@dataclass
class SceneResult:
    scene: Scene
    width: int
    height: int
    triangles: int
    spans: int
    pixels: int
    depth_complexity: float
    zero_spans: int = 0
    single_spans: int = 0
    hazard_pixels: dict | None = None  # fp16z: pixels whose interpolated depth is below 2048, or 0
    timings: list[Timing] = field(default_factory=list)
    accuracy: dict[str, Accuracy] = field(default_factory=dict)
    precision: dict | None = None
    # (variant, cpu key) -> {(parameter, value): counters of the last call}: the claims' robustness
    # to the model's estimates (sim.scenes.claims.perturbed_timings); empty when not measured
    sensitivity: dict = field(default_factory=dict)

    def timing(self, variant: str, key: str) -> Timing:
        for t in self.timings:
            if t.variant == variant and t.key == key:
                return t
        raise KeyError((variant, key))

    @property
    def cpu_keys(self) -> list[str]:
        return list(dict.fromkeys(t.key for t in self.timings))


def fp16z_hazards(spans) -> dict:
    """Pixels where the article's conversion meets its documented hazards: a 32-bit depth below
    2048 (stale EDX bits in the mantissa) and exactly 0 (BSR leaves ECX unchanged)."""
    z0, dz = raster.span_parameters(spans, "fp16z")
    counts = spans.count.astype(np.int64)
    k = np.arange(int(counts.sum()), dtype=np.int64) - np.repeat(np.cumsum(counts) - counts, counts)
    z = (np.repeat(z0.astype(np.int64), counts) + k * np.repeat(dz.astype(np.int64), counts)) & 0xFFFFFFFF
    return {"below_2048": int(np.count_nonzero(z < 2048)), "zero": int(np.count_nonzero(z == 0))}


def _cpu_keys(cpus: list[str]) -> list[tuple[str, str | None]]:
    return [(key.label, key.memory or None) for key in map(MachineKey.parse, cpus)]


def _claim_machines(scene: Scene, models: dict) -> dict[str, set]:
    """variant -> machine keys of this run on which some claim about that variant is checked."""
    out: dict[str, set] = {}
    for claim in scene.claims:
        for (cpu, _), model in models.items():
            if claim.covers(cpu, model.dram.name, model.preset.family):
                for v in claim.variants:
                    out.setdefault(v, set()).add(f"{cpu}:{model.dram.name}")
    return out


# a frame's timing: the frames before the last only warm the machine, the last is timed from an
# empty pipeline (sim.timing.kernel time_emulation's `warm_start`; sweeps read it: SceneKind.warm_start)
WARM_START = True


def _time_task(shared, i: int, key: str, robust: bool, what: str) -> tuple[dict, dict | None]:
    """Counters of the last frame of the shared emulation on machine `i`, the frames before it a
    warm-up (sim.timing.kernel time_emulation's `warm_start`), and the claims' robustness
    re-timings when `robust` (sim.scenes.claims.timed_with_robustness)."""
    from sim.scenes import claims as claim_checks

    emulation, models = shared
    return claim_checks.timed_with_robustness(emulation, models[i], key, robust, what, warm_start=WARM_START)


def run_scene(scene: Scene, cpus: list[str] | None = None, progress: Progress | None = None,
              robustness: bool = True, jobs: int = 1) -> SceneResult:
    """Run a scene. With `robustness` (default), the claims' verdicts are also re-timed with each
    estimated model parameter at the ends of its plausible range (sim.scenes.claims), on the machines the
    claims cover only; a scene without claims costs nothing more.

    `jobs` > 1 times each variant's emulation on the machines in that many forked processes
    sharing the trace (sim.parallel), while this process emulates the next variant; the result is
    the same for any `jobs`."""
    say = progress or (lambda *a, **kw: None)
    geometry = scene.build_geometry()
    w, h = scene.width, scene.height
    spans = raster.rasterize(geometry, w, h)
    pixels = int(spans.count.sum())
    result = SceneResult(scene, w, h, int(geometry.z.shape[0]), int(spans.y.size), pixels, pixels / (w * h),
                         int(np.count_nonzero(spans.count == 0)), int(np.count_nonzero(spans.count == 1)))
    if "fp16z" in scene.variants:
        result.hazard_pixels = fp16z_hazards(spans)
    wanted = set(scene.metrics)
    ref_depth = ref_owner = None
    if scene.needs.reference:
        ref_depth, ref_owner = raster.reference(spans, w, h)
    models = {}
    for cpu, memory in _cpu_keys(cpus or scene.cpus):
        models[(cpu, memory)] = make_model(cpu, memory)
    say(more=len(scene.variants) * len(models))  # the nominal timings (the re-timings add theirs: claims.py)
    robust = _claim_machines(scene, models) if robustness else {}
    pending = []  # (variant, pixels, pool, [(cpu, memory name, future)]): collected in this order

    def collect(item):
        variant, npix, pool, futures = item
        for cpu, mem, fut in futures:
            counters, sens = fut.result()
            result.timings.append(Timing(variant, cpu, mem, npix, counters))
            if sens is not None:
                result.sensitivity[(variant, f"{cpu}:{mem}")] = sens
        pool.close()

    try:
        for variant in scene.variants:
            say(f"{VARIANT_LABELS[variant]}: emulating {scene.frames} frame(s) of {pixels:,} pixels")
            run = draw_frames(spans, variant, w, h, scene.frames, geometry.colour)
            expect_z, expect_f = raster.simulate_frame(spans, variant, w, h)
            same = bool(np.array_equal(run.zbuf.view(np.uint8), expect_z.view(np.uint8)) and np.array_equal(run.fbuf, expect_f))
            if not same:
                raise RetrosimError(f"{scene.path}: variant {variant}: the emulated frame differs from the numpy "
                                    "reference model of the kernel (a kernel or emulator bug)")
            vis = depth = fight = None
            if "visibility" in wanted:
                vis = metrics.visibility_errors(run.fbuf, ref_owner, geometry.colour, run.zbuf, variant).as_dict()
            if "depth_error" in wanted:
                depth = metrics.depth_error(run.zbuf, variant, ref_depth, ref_owner).as_dict()
            if "z_fighting" in wanted:
                fight = metrics.z_fighting(run.fbuf, spans, geometry.pairs, ref_owner, geometry.colour).as_dict()
            result.accuracy[variant] = Accuracy(variant, same, vis, depth, fight)
            del expect_z, expect_f
            shared = (run.emulation, list(models.values()))
            futures = []
            for i, ((cpu, _), model) in enumerate(models.items()):
                key = f"{cpu}:{model.dram.name}"
                futures.append([cpu, model.dram.name, (i, key, key in robust.get(variant, ()), f"{variant} on {key}")])
            while pending:  # the previous variant's timings ran while this one was emulated
                collect(pending.pop(0))
            pool = SharedPool(shared, jobs, models.values(), progress)
            # the machines with claims' re-timings (many times the work of one timing) start first,
            # so that no core is left waiting on one long task at the end; results keep their order
            for f in sorted(futures, key=lambda f: not f[2][2]):
                f[2] = pool.submit(_time_task, *f[2])
            pool.release()  # only the workers keep this variant's trace now
            pending.append((variant, run.pixels, pool, futures))
            del run, shared
        while pending:
            collect(pending.pop(0))
    finally:
        for item in pending:
            item[2].close()
    if "fp16_precision" in wanted:
        table = metrics.fp16_precision(2.0 ** -24, 1.0, 12)
        result.precision = {"rows": [{"depth from": r["depth_lo"], "depth to": r["depth_hi"],
                                      **{f"{f} step/depth": r[f"{f}_worst_relative"] for f in table.step}}
                                     for r in table.rows()]}
    return result


def sweep_emulation(scene: Scene, variant: str):
    """The variant's frames, as run_scene draws them; the units are the pixels of a frame."""
    geometry = scene.build_geometry()
    spans = raster.rasterize(geometry, scene.width, scene.height)
    run = draw_frames(spans, variant, scene.width, scene.height, scene.frames, geometry.colour)
    return run.emulation, run.pixels
