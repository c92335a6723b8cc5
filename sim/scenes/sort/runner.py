"""Running a sort scene: build the keys it names, emulate every run once (checking its output
against Python's sort), and time each emulation on every machine in forked workers
(sim.parallel.SharedPool, warmed before it forks); the result is the same for any `jobs`.

The runs of one variant are emulated together and timed while the next variant is emulated. A
variant whose instruction set a machine lacks (CMOV on the P5 and the K6) is not timed there: the
usual one-line refusal (sim.timing.kernel.check_isa) is recorded instead, once per variant and
machine. The faster/slower claims' runs are also re-timed with each estimated model parameter at
the ends of its range (sim.scenes.claims.perturbed_timings), on the machines the claims cover only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from sim.cpus.machine import MachineKey
from sim.scenes.sort import keys as K
from sim.scenes.sort import variants as V
from sim.scenes.sort.scene import TIMED, SortScene


@dataclass(frozen=True)
class SortTiming:
    variant: str
    distribution: str
    size: int
    cpu: str       # machine label
    memory: str
    counters: dict

    @property
    def key(self) -> str:
        return f"{self.cpu}:{self.memory}"

    @property
    def pixels(self) -> int:  # the units of work (keys), for the shared CSV writer
        return self.size

    def per_pixel(self, name: str) -> float:
        return self.counters[name] / self.size if self.size else 0.0

    per_key = per_pixel


@dataclass
class SortResult:
    scene: SortScene
    timings: list[SortTiming] = field(default_factory=list)
    refused: dict = field(default_factory=dict)       # (variant, machine key) -> the one-line refusal
    checked: list = field(default_factory=list)       # (variant, distribution, size) checked against sorted()
    sensitivity: dict = field(default_factory=dict)   # (variant, distribution, size, machine key) -> re-timings
    zbuffer: dict | None = None                       # where the Z-buffer keys came from, if used
    machine_keys: list = field(default_factory=list)  # every machine of the run, in order

    @property
    def pixels(self) -> int:
        """The units of work (the generic runner's name): keys sorted in the table's runs."""
        return self.scene.table_size * len(self.scene.distributions)

    @property
    def cpu_keys(self) -> list[str]:
        return list(self.machine_keys)

    def timing(self, variant: str, distribution: str, size: int, key: str) -> SortTiming | None:
        return self._index().get((variant, distribution, size, key))

    def _index(self) -> dict:
        if getattr(self, "_by_case", None) is None or len(self._by_case) != len(self.timings):
            self._by_case = {(t.variant, t.distribution, t.size, t.key): t for t in self.timings}
        return self._by_case

    def cycles_per_key(self, variant: str, distribution: str, size: int, key: str) -> float | None:
        t = self.timing(variant, distribution, size, key)
        return None if t is None else t.per_key("cycles")


class KeySource:
    """The keys of each (distribution, size), built on first use: the Z-buffer scene is loaded and
    rasterized only when a "zbuffer" run asks for keys."""

    def __init__(self, scene: SortScene):
        self.scene = scene
        self.depth: K.DepthKeys | None = None

    def keys(self, distribution: str, n: int):
        if distribution != K.ZBUFFER:
            return K.synthetic(distribution, n, self.scene.seed)
        if self.depth is None:
            self.depth = K.zbuffer_keys(self.scene.zbuffer_path)
        return self.depth.take(n)


def _robust_cases(scene: SortScene, models: list) -> set:
    """(variant, distribution, size, machine key) of every faster/slower claim's runs on the
    machines it covers."""
    out = set()
    for claim in scene.claims:
        if claim.expect not in TIMED:
            continue
        for key, model in models:
            if claim.covers(MachineKey.parse(key).label, None, model.preset.family):
                out.update((v, claim.distributions[0], claim.sizes[0], key) for v in claim.variants)
    return out


def _time_task(shared, c: int, i: int, robust: bool, what: str):
    """Counters of emulation `c`'s last call on machine `i`, and the claims' re-timings when `robust`."""
    from sim.scenes import claims as claim_checks

    emulations, models = shared
    key, model = models[i]
    return claim_checks.timed_with_robustness(emulations[c], model, key, robust, what)


def _refusal(emulation, model) -> str | None:
    """The one-line refusal of an emulation on a machine whose CPU lacks an instruction it ran."""
    from sim.errors import AssemblerError
    from sim.guest.cpu import GuestCpu
    from sim.guest.isa import IsaError
    from sim.guest.kernels import kernels_root
    from sim.timing.kernel import check_isa

    try:
        check_isa(emulation, GuestCpu.from_preset(model.preset))
    except (IsaError, AssemblerError) as e:  # named from the repository's root: the same text on any machine
        return str(e).replace(f"{kernels_root().parent}/", "")
    return None


def emulate_case(scene: SortScene, name: str, distribution: str, size: int):
    """The traced emulation of one run, as run_scene emulates it (its output checked)."""
    from sim.guest.emu import Machine

    variant = V.VARIANTS[name]
    keys = KeySource(scene).keys(distribution, size)
    emulation, out = V.emulate(Machine.from_source(variant.source), variant, keys, scene.clamp)
    V.check(variant, keys, out, scene.clamp, f"{size:,} {distribution} keys")
    return emulation


def run_scene(scene: SortScene, cpus: list[str] | None = None, progress=None, robustness: bool = True,
              jobs: int = 1) -> SortResult:
    from sim.cpus.build import make_model
    from sim.guest.emu import Machine
    from sim.parallel import SharedPool

    say = progress or (lambda *a, **kw: None)
    models = []
    for key in map(MachineKey.parse, cpus or scene.cpus):
        model = make_model(key.label, key.memory or None)
        models.append((f"{key.label}:{model.dram.name}", model))
    result = SortResult(scene, machine_keys=[k for k, _ in models])
    source = KeySource(scene)
    robust = _robust_cases(scene, models) if robustness else set()
    machines: dict = {}  # kernel file -> Machine, reused run after run (arena reset each time)
    cases = scene.cases()
    say(more=len(cases) * len(models))  # the nominal timings (fewer if refused; the re-timings add theirs)
    pending = []

    def collect(item):
        name, runs, pool, futures = item
        for i, (key, model) in enumerate(models):
            for (dist, n), fut in zip(runs, futures[i]):
                if fut is None:
                    continue
                counters, sens = fut.result()
                result.timings.append(SortTiming(name, dist, n, MachineKey.parse(key).label, model.dram.name, counters))
                if sens is not None:
                    result.sensitivity[(name, dist, n, key)] = sens
        pool.close()

    try:
        for name in scene.variants:
            variant = V.VARIANTS[name]
            runs = [(d, n) for v, d, n in cases if v == name]
            say(f"{name}: emulating {len(runs)} runs")
            machine = machines.get(variant.file) or machines.setdefault(variant.file, Machine.from_source(variant.source))
            emulations = []
            for dist, n in runs:
                keys = source.keys(dist, n)
                emulation, out = V.emulate(machine, variant, keys, scene.clamp)
                V.check(variant, keys, out, scene.clamp, f"{n:,} {dist} keys")
                result.checked.append((name, dist, n))
                emulations.append(emulation)
            while pending:  # the previous variant's timings ran while this one was emulated
                collect(pending.pop(0))
            for key, model in models:
                if variant.needs_cmov and emulations:
                    message = _refusal(emulations[0], model)
                    if message is not None:
                        result.refused[(name, key)] = message
                        say(more=-len(runs))  # not timed there
            shared = (emulations, models)
            pool = SharedPool(shared, jobs, [m for _, m in models], progress)
            futures = [[None if (name, key) in result.refused else
                        pool.submit(_time_task, c, i, (name, dist, n, key) in robust, f"{name} {n:,} {dist} on {MachineKey.parse(key).label}")
                        for c, (dist, n) in enumerate(runs)] for i, (key, _) in enumerate(models)]
            pool.release()
            pending.append((name, runs, pool, futures))
            del emulations, shared
        while pending:
            collect(pending.pop(0))
    finally:
        for item in pending:
            item[2].close()
    if source.depth is not None:
        d = source.depth
        result.zbuffer = {"scene": d.scene, "pixels": int(d.codes.size), "spans": d.spans, "triangles": d.triangles,
                          "distinct_codes": int(len(set(d.codes.tolist())))}
    return result


def sweep_emulation(scene: SortScene, variant: str):
    """The variant on the scene's first distribution at table_size, as run_scene emulates it; the
    units are its keys."""
    return emulate_case(scene, variant, scene.distributions[0], scene.table_size), scene.table_size
