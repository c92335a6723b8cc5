"""Vertex-snapping scenes ([scene] kind = "snap"): load, run and report (workload.py has the
kernels' variants, the workloads, the exact reference and the error measures; sim.scenes.registry
puts this module behind the scene-kind interface, sim.scenes.kind).

Format::

    [scene]
    name = "vertex-snap"            # required; must equal the file stem
    kind = "snap"                   # required here
    description = "..."             # optional

    [workloads]
    names = ["screen", "ties"]      # required: sim.scenes.snap.workload.WORKLOADS
    vertices = 2048                 # required: (x, y) vertices per workload, at most 262,144
                                    #   (host memory: about 3.5 KB per vertex, under 1 GB)
    seed = 1998                     # required
    width = 640                     # optional (default 640): the screen the coordinates fall on
    height = 480                    # optional (default 480)

    [run]
    variants = ["trick-24", "portable-64"]   # required: sim.scenes.snap.workload.VARIANTS
    cpus = ["pentium-133", "k6-2-300"]       # required: CPU preset[:memory preset]
    timing_workload = "screen"      # optional (default the first of workloads.names): the cycles
                                    # are measured on it (the models' times do not depend on values)

    [[claims]]                      # optional, repeatable
    text = "..."                    # required
    expect = "slower"               # required: slower | faster (cycles per vertex of variants[0]
                                    #   against variants[1] on every covered machine), exact |
                                    #   inexact (every listed variant is / is not the nearest 1/16
                                    #   point on every coordinate of `workloads`), only-exact
                                    #   (variants[0] is exact there, every other listed one is not)
    variants = ["portable-64", "trick-24"]   # required: of run.variants (two for slower/faster)
    cpus = ["k6-2-300"]             # slower/faster: the machines it covers: presets and/or
    families = ["FAMILY"]           #   CPU families by name, see `retrosim cpus` (at least one in run.cpus)
    workloads = ["screen"]          # exact/inexact/only-exact: of workloads.names (default all)

A scene builds only what it names: the variants' entry points, its workloads, its presets. Every
problem is one SceneError naming the file, line and field.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from sim.cpus.machine import MachineKey
from sim.reports.render import FORMATS, add_label_column, console_label, md_table, timings_csv, wants_image, write_report_set
from sim.scenes.kind import BASELINE_COUNTERS, Timing
from sim.scenes.claims import Claim, report_head
from sim.scenes.schema import (CLAIM_CPUS, CLAIM_FAMILIES, CLAIM_TEXT, SCENE_DESCRIPTION, SCENE_KIND, SCENE_NAME,
                               SEED_RANGE, CpuChoice, Field, Validator, show)
from sim.scenes.snap import workload as snap

TIMED = ("slower", "faster")
NUMERIC = ("exact", "inexact", "only-exact")
# Host memory grows with the vertices (each variant's traced emulation and timing, the workloads):
# measured peak RSS (issue 26) with all 7 workloads and 5 variants on one CPU: 3.6 GB at 1,048,576
# vertices; one workload and one variant: 732 MB. At 2^18 (issue 31, `retrosim report` of the shipped
# scene at 262,144 vertices, -j 1): 1,126-1,145 MB on pentium2-233, k6-2-300 and pentium-mmx-233;
# 1,219 MB (1.19 GiB) on pentium-mmx-233 in a fresh clone's CI run, so the estimate keeps a margin.
MAX_VERTICES = 1 << 18
VERTEX_BYTES = 4_800  # peak bytes per vertex of the largest scene (above: 1,219 MB / 262,144 = 4,650)
REPEAT = 2  # calls in one machine state; the last is timed (caches warm)


SCENE = (SCENE_NAME, SCENE_KIND, SCENE_DESCRIPTION)
WORKLOADS = (
    Field("names", "strlist", True, nonempty=True, unique=True, choices=tuple(snap.WORKLOADS), noun="workload"),
    Field("vertices", "int", True, min=1, max=MAX_VERTICES, max_note=f" (host memory: about {VERTEX_BYTES:,} bytes per vertex)"),
    Field("seed", "int", True, span=SEED_RANGE),
    Field("width", "int", default=640, min=1, max=1 << 15, doc="the screen the coordinates fall on"),
    Field("height", "int", default=480, min=1, max=1 << 15))
RUN = (Field("variants", "strlist", True, nonempty=True, unique=True, choices=tuple(snap.VARIANTS), noun="variant"),
       Field("cpus", "strlist", True, nonempty=True, unique=True, doc="CPU preset[:memory preset]"),
       Field("timing_workload", "str", doc="default: the first of workloads.names"))
CLAIM = (CLAIM_TEXT, Field("expect", "str", True, choices=TIMED + NUMERIC, noun="expectation"),
         Field("variants", "strlist", True), CLAIM_CPUS, CLAIM_FAMILIES,
         Field("workloads", "strlist", doc="default: every workload"))


@dataclass(frozen=True)
class SnapClaim(Claim):
    workloads: tuple[str, ...] = ()  # exact / inexact / only-exact: the workloads checked


@dataclass(frozen=True)
class SnapScene:
    path: Path
    name: str
    description: str
    workloads: tuple[str, ...]
    vertices: int
    seed: int
    width: int
    height: int
    variants: tuple[str, ...]
    machines: tuple[CpuChoice, ...]
    timing_workload: str
    claims: tuple[SnapClaim, ...] = ()
    kind = "snap"

    @property
    def cpus(self) -> list[str]:
        return [m.label for m in self.machines]

    @property
    def needs(self) -> dict:
        """What running it builds: one kernel, the variants' entry points, the workloads, the presets."""
        return {"kernels": [str(snap.KERNEL.relative_to(snap.KERNEL.parents[2]))],
                "entries": list(dict.fromkeys(snap.VARIANTS[v].entry for v in self.variants)),
                "workloads": list(self.workloads), "cpus": list(dict.fromkeys(m.preset for m in self.machines))}


def load(path: Path, text: str, doc: dict) -> SnapScene:
    """Validate a parsed kind = "snap" scene (sim.scenes.registry.load_scene reads the file and dispatches)."""
    v = Validator(path, text)
    sc = v.scene_header(doc, "snap", ("scene", "workloads", "run", "claims"), SCENE)
    wl = v.section(v.table(doc, "workloads"), WORKLOADS, "workloads")
    names = wl["names"]
    ru = v.section(v.table(doc, "run"), RUN, "run")
    variants = ru["variants"]
    timing_workload = names[0] if ru["timing_workload"] is None else ru["timing_workload"]
    if timing_workload not in names:
        v.fail("run.timing_workload", f"'{timing_workload}' is not one of workloads.names ({', '.join(names)})",
               "run", "timing_workload")
    machines = v.machines(ru["cpus"])

    claims = []
    for i, c in enumerate(v.claim_tables(doc)):
        f = f"claims[{i}]"
        cl = v.section(c, CLAIM, "claims", i, f)
        expect, pair, works = cl["expect"], cl["variants"], tuple(names) if cl["workloads"] is None else cl["workloads"]
        if not works:  # a claim over no workload would be "reproduced" by any variant
            v.fail(f"{f}.workloads", "must not be empty (leave it out to check every workload)", "claims", "workloads", i)
        if not pair or any(x not in variants for x in pair) or (expect in TIMED + ("only-exact",) and len(pair) < 2) \
                or (expect in TIMED and len(pair) != 2):
            need = "two" if expect in TIMED else ("at least two" if expect == "only-exact" else "one or more")
            v.fail(f"{f}.variants", f"expected {need} of run.variants ({', '.join(variants)}), got {show(list(pair))}",
                   "claims", "variants", i)
        for w in works:
            if w not in names:
                v.fail(f"{f}.workloads", f"'{w}' is not one of workloads.names ({', '.join(names)})",
                       "claims", "workloads", i)
        v.claim_cpus(f, i, cl["cpus"])
        v.families(f, cl["families"], i)
        claim = SnapClaim(cl["text"], tuple(pair), expect, cpus=cl["cpus"], families=cl["families"], workloads=works)
        if expect in TIMED:
            if not claim.cpus and not claim.families:
                v.fail(f, "names no CPU: give cpus = [...] and/or families = [...]", "claims", None, i)
            v.require_cover(f, i, machines, claim)
        claims.append(claim)
    return SnapScene(path, sc["name"], sc["description"], tuple(names), wl["vertices"], wl["seed"], wl["width"],
                     wl["height"], tuple(variants), tuple(machines), timing_workload, tuple(claims))


# -- running -----------------------------------------------------------------------------------
@dataclass
class SnapResult:
    scene: SnapScene
    vertices: int
    timings: list[Timing] = field(default_factory=list)   # per vertex: Timing.per_pixel counts vertices
    errors: dict = field(default_factory=dict)             # (variant, workload) -> snap.Errors
    failures: dict = field(default_factory=dict)           # (variant, workload) -> [failure dicts]

    @property
    def pixels(self) -> int:  # what the generic scene runner's callers read: the units of work
        return self.vertices

    @property
    def cpu_keys(self) -> list[str]:
        return list(dict.fromkeys(t.key for t in self.timings))

    def timing(self, variant: str, key: str) -> Timing:
        return next(t for t in self.timings if t.variant == variant and t.key == key)

    def cycles_per_vertex(self, variant: str, key: str) -> float:
        return self.timing(variant, key).per_pixel("cycles")


def emulate_variant(scene: SnapScene, name: str):
    """The traced emulation of a variant snapping the timing workload, REPEAT calls in one state."""
    from sim.timing.kernel import emulate

    variant = snap.VARIANTS[name]
    xy = snap.workload(scene.timing_workload, scene.vertices, scene.width, scene.height, scene.seed)
    return emulate(snap.KERNEL, variant.entry, snap.setup(variant, xy), repeat=REPEAT)


def _time_task(shared, i: int, what: str) -> dict:
    from sim.scenes.progress import timed_run

    emulation, models = shared
    return timed_run(what, emulation, models[i]).last


def run_scene(scene: SnapScene, cpus: list[str] | None = None, progress=None, robustness: bool = True,
              jobs: int = 1) -> SnapResult:
    """Snap every workload with every variant (untraced), compare with the exact reference, and time
    each variant on the timing workload on every machine (`jobs` forked workers share each
    emulation: sim.parallel; results do not depend on `jobs`). `robustness` is accepted for the
    generic runner's signature: no claim here depends on a model estimate's value alone."""
    from sim.cpus.build import make_model
    from sim.guest.emu import Machine
    from sim.parallel import SharedPool

    say = progress or (lambda *a, **kw: None)
    say(more=len(scene.variants) * len(cpus or scene.cpus))  # a timing of each variant on each machine
    result = SnapResult(scene, scene.vertices)
    machine = Machine.from_source(snap.KERNEL)
    coords = {w: snap.workload(w, scene.vertices, scene.width, scene.height, scene.seed) for w in scene.workloads}
    for name in scene.variants:
        variant = snap.VARIANTS[name]
        for w, xy in coords.items():
            out = snap.snap(machine, variant, xy)
            result.errors[(name, w)] = snap.errors(xy, out)
            result.failures[(name, w)] = snap.failures(xy, out)
    models = [(key.label, make_model(key.label, key.memory or None)) for key in map(MachineKey.parse, cpus or scene.cpus)]
    for name in scene.variants:
        say(f"{name}: emulating {scene.vertices:,} vertices")
        emu = emulate_variant(scene, name)
        shared = (emu, [m for _, m in models])
        with SharedPool(shared, jobs, shared[1], progress) as pool:
            futures = [pool.submit(_time_task, i, f"{name} on {cpu}") for i, (cpu, _) in enumerate(models)]
            pool.release()
            for (cpu, model), fut in zip(models, futures):
                result.timings.append(Timing(name, cpu, model.dram.name, scene.vertices, fut.result()))
    return result


# -- claims ------------------------------------------------------------------------------------
def evaluate_claims(result: SnapResult) -> list[dict]:
    """Each claim's verdict ('reproduced' or 'not reproduced') with the numbers behind it."""
    from sim.cpus.machine import family_of

    out = []
    for c in result.scene.claims:
        entry = {"text": c.text, "expect": c.expect, "variants": list(c.variants)}
        if c.expect in TIMED:
            per = []
            for key in result.cpu_keys:
                cpu = MachineKey.parse(key).label
                if not c.covers(cpu, None, family_of(cpu)):
                    continue
                a, b = (result.cycles_per_vertex(v, key) for v in c.variants)
                held = a > b if c.expect == "slower" else a < b
                per.append({"cpu": key, "cycles_per_vertex": [round(a, 4), round(b, 4)],
                            "ratio": round(a / b, 4) if b else None, "held": held})
            entry["per_cpu"] = per
            entry["verdict"] = "reproduced" if per and all(p["held"] for p in per) else \
                ("not checked (no covered CPU in this run)" if not per else "not reproduced")
        else:
            wrong = {v: sum(result.errors[(v, w)].wrong for w in c.workloads) for v in c.variants}
            total = sum(result.errors[(c.variants[0], w)].coordinates for w in c.workloads)
            if c.expect == "exact":
                held = all(n == 0 for n in wrong.values())
            elif c.expect == "inexact":
                held = all(n > 0 for n in wrong.values())
            else:
                held = wrong[c.variants[0]] == 0 and all(wrong[v] > 0 for v in c.variants[1:])
            entry.update(workloads=list(c.workloads), coordinates=total, wrong=wrong,
                         verdict="reproduced" if held else "not reproduced")
        out.append(entry)
    return out


def claim_sentence(c: dict) -> str:
    if c["expect"] in TIMED:
        detail = "; ".join(f"{p['cpu']} {p['cycles_per_vertex'][0]:.2f} against {p['cycles_per_vertex'][1]:.2f}"
                           + ("" if p["held"] else " (does not hold)") for p in c["per_cpu"])
        return (f"- **{c['text']}** ({c['variants'][0]} {c['expect']} than {c['variants'][1]}, cycles per vertex): "
                f"{c['verdict']}. {detail}.")
    counts = ", ".join(f"{v} {n:,} wrong" for v, n in c["wrong"].items())
    return (f"- **{c['text']}** ({c['expect']} over {c['coordinates']:,} coordinates of "
            f"{', '.join(c['workloads'])}): {c['verdict']}. {counts}.")


# -- reports -----------------------------------------------------------------------------------
def _share(n: int, total: int) -> str:
    if n == 0:
        return "0"
    f = n / total
    return f"{f:.1%}" if f >= 0.001 else f"{f:.3%}"


def _num(x: float) -> str:
    """A coordinate exactly enough to see its sixteenths (float32 values print exactly in 10 digits)."""
    return f"{x:.10g}"


def cycles_rows(result: SnapResult) -> tuple[list[str], list[list[str]]]:
    header = ["CPU (memory)"] + list(result.scene.variants)
    rows = [[MachineKey.parse(k).display]
            + [f"{result.cycles_per_vertex(v, k):.2f}" for v in result.scene.variants] for k in result.cpu_keys]
    return header, rows


def error_rows(result: SnapResult) -> tuple[list[str], list[list[str]]]:
    s = result.scene
    header = ["variant"] + list(s.workloads)
    rows = []
    for v in s.variants:
        cells = []
        for w in s.workloads:
            e = result.errors[(v, w)]
            cells.append("exact" if e.wrong == 0 else
                         f"{_share(e.wrong, e.coordinates)} wrong, {_share(e.off_grid, e.coordinates)} off grid, "
                         f"worst {e.worst:.4g}")
        rows.append([v] + cells)
    return header, rows


def failure_rows(result: SnapResult) -> tuple[list[str], list[list[str]]]:
    header = ["variant", "workload", "wrong", "off grid", "worst distance (px)", "examples: input -> result (nearest)"]
    rows = []
    for v in result.scene.variants:
        for w in result.scene.workloads:
            e = result.errors[(v, w)]
            if not e.wrong:
                continue
            ex = "; ".join(f"{_num(f['input'])} -> {_num(f['result'])} ({_num(f['nearest'])})"
                           for f in result.failures[(v, w)][:2])
            rows.append([v, w, f"{e.wrong:,} of {e.coordinates:,}", f"{e.off_grid:,}", f"{e.worst:.6g}", ex])
    return header, rows


def findings(result: SnapResult) -> list[str]:
    """Plain statements computed from the results."""
    from sim.cpus.machine import family_of

    s, out = result.scene, []
    in_range = [w for w in s.workloads if w in snap.IN_RANGE]
    for v in s.variants:
        wrong = sum(result.errors[(v, w)].wrong for w in in_range)
        total = sum(result.errors[(v, w)].coordinates for w in in_range)
        off = sum(result.errors[(v, w)].off_grid for w in in_range)
        out.append(f"{v}: {wrong:,} of {total:,} coordinates below 2^18 ({', '.join(in_range)}) are not the nearest "
                   f"1/16 point, {off:,} of them off the grid; over every workload "
                   f"{sum(result.errors[(v, w)].wrong for w in s.workloads):,} of "
                   f"{sum(result.errors[(v, w)].coordinates for w in s.workloads):,}.")
    by_family: dict = {}
    for key in result.cpu_keys:
        fam = family_of(key)
        by_family.setdefault(fam, []).append(key)
    for fam, keys in by_family.items():
        parts = []
        for v in s.variants:
            vals = [result.cycles_per_vertex(v, k) for k in keys]
            parts.append(f"{v} {min(vals):.2f}" + (f"-{max(vals):.2f}" if max(vals) != min(vals) else ""))
        out.append(f"{fam.upper()} ({len(keys)} machine(s)), cycles per vertex: " + ", ".join(parts) + ".")
    return out


def to_json(result: SnapResult) -> dict:
    s = result.scene
    return {
        "scene": s.name, "kind": s.kind, "description": s.description, "vertices": s.vertices, "seed": s.seed,
        "screen": [s.width, s.height], "workloads": {w: snap.WORKLOADS[w] for w in s.workloads},
        "timing_workload": s.timing_workload,
        "variants": {v: {"entry": snap.VARIANTS[v].entry, "precision": snap.VARIANTS[v].precision,
                         "label": snap.VARIANTS[v].label} for v in s.variants},
        "timings": [{"variant": t.variant, "cpu": t.cpu, "memory": t.memory, "vertices": t.pixels,
                     "cycles_per_vertex": round(t.per_pixel("cycles"), 4), **t.counters} for t in result.timings],
        "errors": {v: {w: result.errors[(v, w)].as_dict() for w in s.workloads} for v in s.variants},
        "failures": {v: {w: result.failures[(v, w)] for w in s.workloads if result.failures[(v, w)]}
                     for v in s.variants},
        "claims": evaluate_claims(result),
        "findings": findings(result),
    }


def to_csv(result: SnapResult) -> str:
    """The Z-buffer scenes' timings table, counted in vertices."""
    return timings_csv(result.scene.name, result.timings, ("vertices", "cycles_per_vertex"))


def to_markdown(result: SnapResult, png_name: str | None) -> str:
    s = result.scene
    parts = report_head(s, evaluate_claims(result), lambda k: MachineKey.parse(k).display, findings(result)[:2])
    parts += ["Variants (`kernels/snap/snap.S`):", ""]
    parts += [f"- `{v}`: {snap.VARIANTS[v].label}" for v in s.variants] + [""]
    parts += [f"Workloads: {s.vertices:,} (x, y) vertices each (seed {s.seed}, screen {s.width}x{s.height}):", ""]
    parts += [f"- `{w}`: {snap.WORKLOADS[w]}" for w in s.workloads] + [""]
    parts += ["The exact reference is the nearest multiple of 1/16 of each float32 coordinate, computed in "
              "float64 (exact), ties to the even multiple as the x87 rounds in its default rounding mode. "
              "'Wrong' means not that point; 'off grid' means not a multiple of 1/16 at all; distances are in "
              "pixels.", ""]
    if result.timings:
        parts += ["## Cycles per vertex", "",
                  f"Two coordinates per vertex, measured on the `{s.timing_workload}` workload, last of "
                  f"{REPEAT} calls (caches warm); the control word is loaded once per call. The models' times do not "
                  "depend on the values (denormal operands, which real x87s handle slowly, are not modelled).", "",
                  md_table(*cycles_rows(result)), ""]
    parts += ["## Error against the exact grid", "", md_table(*error_rows(result)), ""]
    if png_name:
        parts += ["## Work against error", "", f"![cycles per vertex against error]({png_name})", ""]
    parts += ["## Failure cases", "",
              "Every variant and workload with a wrong coordinate: how many, how many off the grid, the largest "
              "distance from the nearest grid point, and the two farthest examples.", ""]
    rows = failure_rows(result)
    parts += [md_table(*rows) if rows[1] else "(none)", ""]
    claims = evaluate_claims(result)
    if claims:
        parts += ["## The guide's claims, checked", ""] + [claim_sentence(c) for c in claims] + [""]
    parts += ["## Findings", ""] + [f"- {f}" for f in findings(result)] + [""]
    parts += ["## Notes", "",
              "- The guide's portable listing assigns `tmp` for y before x uses it, so both coordinates would get "
              "y's value; `snap_portable` does what the listing evidently means.",
              "- The trick is only defined for |x| < 2^18 (the sum's last 24-bit mantissa bit is worth 1/16 "
              "there); the `limit` and `huge` workloads show what happens beyond it. The portable variant's "
              "`long` overflows at |x| >= 2^27.",
              "- The trick costs the same at every precision: FADD and FSUB times do not depend on the precision "
              "control in any family's sources; the portable variant's FDIV does (every family times it at the "
              "precision in force, `sim/cpus/precision.py`).",
              "- On the P6 a divide by a power of two (here 16.0) takes 9 clocks whatever the precision (Agner "
              "Fog's instruction tables, note h; InstLatX64 Pentium II, x/2.0); the models do not see operand "
              "values, so the P6 presets time it at the full FDIV latency and overstate the portable variant's "
              "cost by up to 2 x 29 clocks per vertex at 64-bit precision (38 against 9 for the divide) and 2 x 9 "
              "at 24-bit (18 against 9). The K6 has no "
              "such shortcut (InstLatX64 K6: x/2.0 40 clocks).", ""]
    return "\n".join(parts).rstrip() + "\n"


def figure(result: SnapResult):
    """Cycles per vertex (x) of each variant (rows, labelled with its share of wrong coordinates
    below 2^18) on each CPU (markers, the same colours as the other reports' plots)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sim.cpus import presets

    from sim.cpus.machine import family_of
    from sim.reports.render import row_offset
    from sim.reports.render import FAMILY_MARKERS

    s = result.scene
    in_range = [w for w in s.workloads if w in snap.IN_RANGE] or list(s.workloads)
    share = {v: sum(result.errors[(v, w)].wrong for w in in_range)
             / max(1, sum(result.errors[(v, w)].coordinates for w in in_range)) for v in s.variants}
    rows = sorted(s.variants, key=lambda v: (-share[v], v))
    keys = result.cpu_keys
    names = presets.available()
    palette = plt.get_cmap("tab20")
    fig, ax = plt.subplots(figsize=(8, 1.8 + 0.5 * len(rows) + 0.12 * len(keys)), dpi=100, layout="constrained")
    for i, key in enumerate(keys):
        cpu = MachineKey.parse(key).label
        base = MachineKey(cpu).preset
        offset = row_offset(i, len(keys), 0.6)
        fam = family_of(base)
        ax.scatter([result.cycles_per_vertex(v, key) for v in rows], [len(rows) - 1 - j - offset for j in range(len(rows))],
                   s=36, color=palette(names.index(base) % palette.N) if base in names else "0.5",
                   marker=FAMILY_MARKERS.get(fam, "o"), edgecolors="black", linewidths=0.4,
                   label=cpu, zorder=3)
    ax.set_yticks(range(len(rows)), [f"{v}: {'exact' if share[v] == 0 else f'{share[v]:.1%} wrong'}"
                                     for v in reversed(rows)], fontsize=9)
    for k in range(len(rows) - 1):
        ax.axhline(k + 0.5, color="0.85", lw=0.8, zorder=1)
    ax.set_xlabel("cycles per vertex (two coordinates; fewer is faster)", fontsize=10)
    ax.set_title(f"{s.name}: cost of each snapping variant on each CPU\n(label: share of coordinates below 2^18 "
                 "not on the nearest 1/16 point)", fontsize=10)
    ax.grid(axis="x", color="0.9", zorder=0)
    fig.legend(fontsize=8, loc="outside lower center", ncol=4, frameon=False)
    return fig


def png(result: SnapResult) -> bytes | None:
    if not result.timings:
        return None
    from sim.reports.render import png_bytes

    return png_bytes(figure(result))


def write_reports(result: SnapResult, out_dir: Path, formats: tuple[str, ...] = FORMATS) -> list[Path]:
    name = result.scene.name
    image = png(result) if wants_image(formats) else None
    md = to_markdown(result, f"{name}.png" if result.timings else None)
    return write_report_set(out_dir, name, md, image, json.dumps(to_json(result), indent=2) + "\n", to_csv(result),
                            formats)


def baseline_entries(result: SnapResult) -> dict[str, dict[str, int]]:
    """The recorded cycle counts: one case per variant and machine, the Z-buffer scenes' counters."""
    return {f"{t.variant}@{t.key}": {c: int(t.counters[c]) for c in BASELINE_COUNTERS} for t in result.timings}


def summary_tables(result: SnapResult) -> list:
    """The terminal summary: cycles per vertex with the CPUs as rows, the share of wrong coordinates
    below 2^18 per variant, and how many claims held."""
    from rich import box
    from rich.markup import escape
    from rich.padding import Padding
    from rich.table import Table
    from rich.text import Text

    out = []
    for r in [result]:
        s = r.scene
        t = Table(title=f"{escape(s.name)}: cycles per vertex", title_justify="left", box=box.SIMPLE_HEAD,
                  pad_edge=False)
        add_label_column(t, "CPU (memory)", [console_label(m.label, m.memory) for m in map(MachineKey.parse, r.cpu_keys)])
        for v in s.variants:
            t.add_column(v, justify="right", no_wrap=True)
        for key in r.cpu_keys:
            machine = MachineKey.parse(key)
            t.add_row(escape(console_label(machine.label, machine.memory)), *[f"{r.cycles_per_vertex(v, key):.2f}" for v in s.variants])
        in_range = [w for w in s.workloads if w in snap.IN_RANGE]
        if in_range:
            t.add_section()
            t.add_row("wrong below 2^18", *[_share(sum(r.errors[(v, w)].wrong for w in in_range),
                                                   sum(r.errors[(v, w)].coordinates for w in in_range))
                                            for v in s.variants])
        out.append(t)
        claims = evaluate_claims(r)
        if claims:
            held = sum(1 for c in claims if c["verdict"] == "reproduced")
            out.append(Padding(Text(f"claims: {held} of {len(claims)} reproduced"), (0, 0, 0, 1)))
            out += [Padding(Text(f"- {c['text']}: {c['verdict']}"), (0, 0, 0, 3))
                    for c in claims if c["verdict"] != "reproduced"]
    return out


def sweep_emulation(scene: SnapScene, variant: str):
    """The variant snapping the timing workload, as run_scene times it; the units are its vertices."""
    return emulate_variant(scene, variant), scene.vertices
