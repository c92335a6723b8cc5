"""Z-buffer scene reports: Markdown, self-contained HTML, JSON, CSV and a work-precision plot (PNG),
and the terminal summary. How files are written (atomically, deterministically) and the forms the
scenes' reports share are in sim.reports.render.
"""

from __future__ import annotations

import json
from pathlib import Path

from typing import TYPE_CHECKING

from sim.cpus.machine import MachineKey
from sim.reports.render import FORMATS, add_label_column, console_label, finish_rows, md_table, png_bytes, row_offset, timings_csv, wants_image, write_report_set
from sim.scenes.kind import BASELINE_COUNTERS
from sim.scenes.zbuffer.frames import VARIANT_LABELS

if TYPE_CHECKING:
    from sim.scenes.zbuffer.runner import SceneResult

PER_PIXEL = [  # (counter, column title) for the "where the cycles go" tables
    ("uops", "uops"), ("decode_groups", "decode groups"), ("l1d_load_misses", "L1D load misses"),
    ("l1d_store_misses", "L1D store misses"), ("l2_misses", "L2 misses"), ("dram_fills", "DRAM fills"),
    ("dram_bus_cycles", "DRAM bus cycles"),
]
STALL_COLUMNS = [("stall_dependency", "dep"), ("stall_port", "port"), ("stall_decode", "decode"),
                 ("stall_partial_register", "partial"), ("stall_memory", "memory"),
                 ("stall_store_forward", "fwd"), ("stall_mispredict", "branch")]
EXPLAIN_COUNTERS = ["uops", "msrom_uops", "decode_groups", "l1d_load_misses", "l1d_store_misses", "l2_misses", "dram_bus_cycles",
                    "stall_memory", "stall_partial_register", "mispredicts",
                    # the P5's (no other family counts them): 0F instructions such as BSR and SHRD pair on
                    # neither pipe of the P54C and cost it a prefix decode clock (docs/sources/p5.md:
                    # INTEL-PAIR, AF97-PFX)
                    "alone", "pairs", "stall_prefix", "stall_write_buffer"]
COUNTER_WORDS = {"alone": "instructions issued alone", "pairs": "pairs issued", "stall_prefix": "prefix stall"}


def _f(x: float, digits: int = 2) -> str:
    return f"{x:,.{digits}f}"


def _cpu_label(key: str) -> str:
    return MachineKey.parse(key).display


# -- claims ----------------------------------------------------------------------------------
def evaluate_claims(result: SceneResult) -> list[dict]:
    """Each `[[claims]]` entry of the scene checked on every machine of the run its words cover,
    with the counters that explain the outcome and its robustness to the model's estimates
    (sim.scenes.claims). A claim the model does not reproduce is reported as such, not tuned away."""
    from sim.scenes.claims import evaluate

    return evaluate(result, EXPLAIN_COUNTERS)


def _claim_sentence(c: dict) -> str:
    from sim.scenes.claims import sentence

    return sentence(c, _cpu_label, lambda n: COUNTER_WORDS.get(n, n.replace("_", " ")))


def checked_claims(result: SceneResult) -> tuple[list[dict], list[dict]]:
    """(claims checked on at least one machine of the run, claims none of whose machines ran): a run
    restricted with --cpu lists the second kind as not checked instead of failing the report."""
    claims = evaluate_claims(result)
    return [c for c in claims if c["per_cpu"]], [c for c in claims if not c["per_cpu"]]


# -- tables ------------------------------------------------------------------------------------
def cycles_table(result: SceneResult) -> tuple[list[str], list[list[str]]]:
    header = ["variant"] + [_cpu_label(k) for k in result.cpu_keys]
    rows = [[f"{v} ({VARIANT_LABELS[v]})"] + [_f(result.timing(v, k).per_pixel("cycles")) for k in result.cpu_keys]
            for v in result.scene.variants]
    return header, rows


def ns_table(result: SceneResult) -> tuple[list[str], list[list[str]]]:
    from sim.cpus.overrides import load_preset

    mhz = {k: load_preset(MachineKey.parse(k).label).core_mhz for k in result.cpu_keys}
    header = ["variant"] + [_cpu_label(k) for k in result.cpu_keys]
    rows = [[v] + [_f(1000.0 * result.timing(v, k).per_pixel("cycles") / mhz[k]) for k in result.cpu_keys]
            for v in result.scene.variants]
    return header, rows


def accuracy_table(result: SceneResult) -> tuple[list[str], list[list[str]]]:
    header = ["variant", "wrong visibility (pixels)", "wrong visibility (share)", "worst depth error",
              "mean depth error"]
    rows = []
    for v in result.scene.variants:
        acc = result.accuracy[v]
        vis, dep = acc.visibility or {}, acc.depth_error or {}
        rows.append([v, f"{vis['errors']:,}" if vis else "-",
                     f"{vis.get('fraction', 0):.4%}" if vis else "-",
                     f"{dep.get('worst', 0):.3g}" if dep else "-", f"{dep.get('mean', 0):.3g}" if dep else "-"])
    return header, rows


def breakdown_table(result: SceneResult, key: str) -> tuple[list[str], list[list[str]]]:
    """Where one CPU's cycles go, per pixel, in its family's words (P6 ports p0-p4, K6 units X, Y,
    load, store, branch and FPU); 'no L2' where the CPU has none."""
    from sim.cpus import families
    from sim.cpus.overrides import load_preset

    cpu = MachineKey.parse(key).label
    voc = families.vocabulary_for(cpu)
    has_l2 = load_preset(cpu).l2 is not None
    units = list(voc.ports) + [name for counter, name in voc.extra_units]
    unit_counters = [f"port{p}" for p in range(len(voc.ports))] + [counter for counter, _ in voc.extra_units]
    title = {"uops": voc.op + "s", "decode_groups": voc.group.split(" (")[0]}
    header = ["variant", "cycles"] + [title.get(c, t) for c, t in PER_PIXEL] + ["/".join(units)] + \
             ["stalls " + "/".join(t for _, t in STALL_COLUMNS)]
    rows = []
    for v in result.scene.variants:
        t = result.timing(v, key)
        ports = "/".join(_f(t.per_pixel(c), 1) if c in t.counters else "-" for c in unit_counters)
        stalls = "/".join(_f(t.per_pixel(c), 1) for c, _ in STALL_COLUMNS)
        cells = [("no L2" if c == "l2_misses" and not has_l2 else _f(t.per_pixel(c), 3)) for c, _ in PER_PIXEL]
        rows.append([v, _f(t.per_pixel("cycles"))] + cells + [ports, stalls])
    return header, rows


def breakdown_legend(key: str) -> str:
    """The family's words for one breakdown table, in one sentence under it."""
    from sim.cpus import families

    voc = families.vocabulary_for(MachineKey.parse(key).label)
    units = "; ".join(voc.port_help) + ("; " + ", ".join(f"{n}: x87 unit" for c, n in voc.extra_units)
                                        if voc.extra_units else "")
    return (f"{voc.op}s per pixel on each {voc.unit} ({units}). "
            f"Decode: {voc.group}. Branch stall: {voc.stall_help.get('mispredict', '')}.")


# -- plot --------------------------------------------------------------------------------------
# The scenes' plots share one form: a row per variant, cycles along x, a marker per machine.


def work_precision_png(result: SceneResult) -> bytes | None:
    fig = work_precision_figure(result)
    return None if fig is None else png_bytes(fig)


def work_precision_figure(result: SceneResult):
    """Work against precision as a dot plot: one row per variant (ordered by its share of pixels with
    wrong visibility, which is the same on every CPU and is written in the row's label), cycles per
    pixel along x, one marker per CPU (offset within the row so none hides another). Exact variants
    sit in their own shaded band: zero is not a small error, and a log axis has no place for it."""
    if not any(a.visibility for a in result.accuracy.values()):
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    variants = [v for v in result.scene.variants if result.accuracy[v].visibility]
    share = {v: result.accuracy[v].visibility["fraction"] for v in variants}
    exact = [v for v in variants if result.accuracy[v].visibility["errors"] == 0]
    wrong = sorted((v for v in variants if v not in exact), key=lambda v: -share[v])
    rows = wrong + exact  # top to bottom
    keys = result.cpu_keys
    ncol = 2 if any(len(_cpu_label(k)) > 28 for k in keys) else 3  # long override labels: two columns
    legend_rows = -(-(len(keys) + bool(exact)) // ncol)
    fig_h = 1.3 + 0.22 * legend_rows + 0.45 * len(rows) * max(1.0, len(keys) / 4)
    fig, ax = plt.subplots(figsize=(8, fig_h), dpi=100, layout="constrained")
    # the same CPU has the same colour in every plot, the same memory the same marker
    from sim.cpus import presets
    from sim.cpus.overrides import memory_presets

    cpu_names, memories = presets.available(), memory_presets()
    palette = plt.get_cmap("tab10" if len(cpu_names) <= 10 else "tab20")
    markers = "osD^vP*Xh<>"
    spread = min(0.7, 0.12 * len(keys))
    ypos = {v: len(rows) - 1 - i for i, v in enumerate(rows)}
    if exact:
        ax.axhspan(-0.5, len(exact) - 0.5, color="#dcefdc", zorder=0, label="exact: no pixel with wrong visibility")
    overridden = 0
    for i, key in enumerate(keys):
        offset = row_offset(i, len(keys), spread)
        xs = [result.timing(v, key).per_pixel("cycles") for v in rows]
        ys = [ypos[v] - offset for v in rows]
        machine = MachineKey.parse(key)
        base = machine.preset  # a preset with overrides keeps its preset's colour
        colour = palette(cpu_names.index(base) % palette.N) if base in cpu_names else "0.5"
        m = memories.index(machine.memory) if machine.memory in memories else len(markers) - 1
        if not machine.overridden:
            ax.scatter(xs, ys, marker=markers[m % len(markers)], s=46, color=colour, label=_cpu_label(key),
                       zorder=3, edgecolors="black", linewidths=0.4)
        else:  # overridden: hollow, and a shape of its own, so two variants of one preset differ
            overridden += 1
            ax.scatter(xs, ys, marker=markers[(m + overridden) % len(markers)], s=52, facecolors="none",
                       edgecolors=colour, linewidths=1.6, label=_cpu_label(key), zorder=3)
    labels = []
    for v in rows:
        f = share[v]
        text = "exact" if v in exact else (f"{f:.2%} wrong" if f >= 0.001 else f"{f:.4%} wrong")
        labels.append(f"{v}: {text}\n{VARIANT_LABELS[v]}")
    finish_rows(fig, ax, rows, ypos, labels, "cycles per pixel (last frame, caches warm); fewer is faster",
                f"{result.scene.name}: cycles per pixel of each depth format on each CPU\n"
                "(rows from most to fewest pixels with wrong visibility)", 9, ncol)
    return fig


# -- documents ---------------------------------------------------------------------------------
def to_json(result: SceneResult) -> dict:
    s = result.scene
    return {
        "scene": s.name, "description": s.description, "width": result.width, "height": result.height,
        "triangles": result.triangles, "spans": result.spans, "pixels_per_frame": result.pixels,
        "depth_complexity": round(result.depth_complexity, 4), "frames": s.frames,
        "timings": [{"variant": t.variant, "cpu": t.cpu, "memory": t.memory, "pixels": t.pixels,
                     "cycles_per_pixel": round(t.per_pixel("cycles"), 4), **t.counters} for t in result.timings],
        "accuracy": {v: {"matches_reference_model": a.matches_reference_model, "visibility": a.visibility,
                         "depth_error": a.depth_error} for v, a in result.accuracy.items()},
        "precision": result.precision,
        "claims": evaluate_claims(result),
        "findings": findings(result),
        "hazard_pixels": result.hazard_pixels, "zero_length_spans": result.zero_spans,
        "single_pixel_spans": result.single_spans,
    }


def to_csv(result: SceneResult) -> str:
    """One row per (variant, CPU): sim.reports.render.timings_csv."""
    return timings_csv(result.scene.name, result.timings)


# -- terminal summary --------------------------------------------------------------------------
def summary_tables(r: SceneResult) -> list:
    """What `retrosim report` prints for a Z-buffer scene: one table with the CPUs as rows and the
    variants as columns (cycles per pixel), a row of wrong-visibility shares, and how many claims
    held. Variant names are short, so a table fits 80 columns for any number of CPUs."""
    from rich import box
    from rich.markup import escape
    from rich.table import Table

    out = []
    claims, unchecked = checked_claims(r)
    held = sum(1 for c in claims if c["verdict"] == "reproduced")
    t = Table(title=f"{escape(r.scene.name)}: cycles per pixel, last frame", title_justify="left",
              box=box.SIMPLE_HEAD, pad_edge=False)
    # a machine with overrides has a long label: it folds, the numbers keep their width
    add_label_column(t, "CPU (memory)", [console_label(m.label, m.memory) for m in map(MachineKey.parse, r.cpu_keys)])
    for v in r.scene.variants:
        t.add_column(v, justify="right", no_wrap=True, min_width=max(len(v), 6))
    for key in r.cpu_keys:
        cells = []
        for v in r.scene.variants:
            try:
                cells.append(f"{r.timing(v, key).per_pixel('cycles'):.2f}")
            except KeyError:
                cells.append("-")
        machine = MachineKey.parse(key)
        t.add_row(escape(console_label(machine.label, machine.memory)), *cells)
    if any(r.accuracy[v].visibility for v in r.scene.variants):
        t.add_section()
        t.add_row("wrong visibility", *[_share(r.accuracy[v].visibility) for v in r.scene.variants])
    out.append(t)
    if claims or unchecked:
        from rich.padding import Padding
        from rich.text import Text

        wrong = [c for c in claims if c["verdict"] != "reproduced"]
        lines = [f"claims: {held} of {len(claims)} reproduced" + (", the others:" if wrong else "")
                 + (f" ({len(unchecked)} not checked: their CPU was not run)" if unchecked else "")]
        out.append(Padding(Text(lines[0]), (0, 0, 0, 1)))
        out += [Padding(Text(f"- {c['text']} — {c['verdict']}"), (0, 0, 0, 3)) for c in wrong]  # as the .md
    return out


def _share(vis: dict | None) -> str:
    """A share of pixels for the terminal: exact zero is written 'exact', never 0.000%."""
    if not vis:
        return "-"
    if vis["errors"] == 0:
        return "exact"
    f = vis["fraction"]
    return f"{f:.1%}" if f >= 0.001 else f"{f:.3%}"


def findings(result: SceneResult) -> list[str]:
    """Plain statements of what this scene shows, computed from its results (never hand-written)."""
    out = []
    acc = result.accuracy
    if any(a.visibility for a in acc.values()):
        exact = [v for v, a in acc.items() if a.visibility and a.visibility["errors"] == 0]
        wrong = sorted((a.visibility["errors"], v) for v, a in acc.items() if a.visibility and a.visibility["errors"])
        parts = [f"exact visibility: {', '.join(exact)}" if exact else "no variant is exact"]
        for n, v in wrong:
            a = acc[v].visibility
            parts.append(f"{v} gets {n:,} of {a['covered']:,} covered pixels wrong ({a['fraction']:.3%})"
                         + (f", {a['unwritten']:,} of them never written (a depth that rounds to the clear value "
                            "ties with it, and ties fail)" if a.get("unwritten") else ""))
        out.append("; ".join(parts) + ".")
    fights = [(v, a.z_fighting) for v, a in acc.items() if a.z_fighting]
    if fights:
        f0 = fights[0][1]
        out.append(f"Z-fighting over {f0['contested']:,} contested pixels of {f0['pairs']} coplanar pairs: "
                   + "; ".join(f"{v} loses the nearer surface on {f['fraction']:.1%} "
                               f"({f['far_first_fraction']:.1%} where the far surface is drawn first)"
                               for v, f in fights) + ".")
    if any(a.depth_error for a in acc.values()):
        out.append("Worst stored-depth error, in units of the scene's depth range: "
                   + ", ".join(f"{v} {a.depth_error['worst']:.3g}" for v, a in acc.items() if a.depth_error) + ".")
    hz = result.hazard_pixels
    if hz is not None:
        if hz["below_2048"]:
            out.append(f"{hz['below_2048']:,} pixels have a 32-bit depth below 2048, where the 16-bit float's mantissa "
                       f"takes bits from a stale EDX, and {hz['zero']:,} a depth of exactly 0, where BSR keeps the "
                       "previous exponent; the emulated frame equals the bit-exact model of these hazards, and the "
                       "visibility errors above include their effect.")
        else:
            out.append("No pixel has a 32-bit depth below 2048: the 16-bit float conversion's stale-register "
                       "hazards cannot occur in this scene.")
    if result.zero_spans + result.single_spans > result.spans // 4:
        out.append(f"{result.zero_spans:,} zero-length and {result.single_spans:,} single-pixel spans of "
                   f"{result.spans:,}: per-span set-up dominates the cost per pixel.")
    for key in result.cpu_keys:
        ranked = sorted((result.timing(v, key).per_pixel("cycles"), v) for v in result.scene.variants)
        out.append(f"On {_cpu_label(key)} the cheapest format is {ranked[0][1]} ({ranked[0][0]:.2f} cycles/pixel), "
                   f"the dearest {ranked[-1][1]} ({ranked[-1][0]:.2f}).")
    return out


def to_markdown(result: SceneResult, png_name: str | None, findings: list[str]) -> str:
    from sim.scenes.claims import report_head

    s = result.scene
    claims = evaluate_claims(result)  # each says on which machines it held, and which were not run
    parts = report_head(s, claims, _cpu_label, findings[:2])
    parts += [f"Workload: {result.width}x{result.height} pixels, {result.triangles:,} triangles, {result.spans:,} spans, "
              f"{result.pixels:,} pixels drawn per frame (depth complexity {result.depth_complexity:.2f}). "
              f"{s.frames} frame(s) are drawn in one machine state (clear the depth buffer, then every span); "
              "the last frame is reported, with caches and predictors warm: the frames before it only warm the "
              "machine (caches, TLB, DRAM pages, branch predictors) and the last is timed from an empty pipeline.", ""]
    if result.timings:
        parts += ["## Cycles per pixel", "", md_table(*cycles_table(result)), "",
                  "The same in nanoseconds per pixel at each preset's clock:", "", md_table(*ns_table(result)), ""]
    if any(a.visibility or a.depth_error for a in result.accuracy.values()):
        parts += ["## Error against the exact reference", "",
                  "Against a float64 Z-buffer of the same spans. Depth errors are in units of the scene's exact "
                  "depth range.", "", md_table(*accuracy_table(result)), ""]
    if png_name:
        parts += ["## Work against precision", "", f"![work-precision plot]({png_name})", ""]
    if claims:
        parts += ["## The article's claims, checked", ""] + [_claim_sentence(c) for c in claims] + [""]
    if findings:
        parts += ["## Findings", ""] + [f"- {f}" for f in findings] + [""]
    if result.timings:
        parts += ["## Where the cycles go", "",
                  "Per pixel, last frame. Stall columns are uop-stall cycles (a uop waiting for a dependency, "
                  "a port, the decoders, a partial-register merge, memory, a store forward, a branch restart); "
                  "they overlap, so they do not add up to the cycle count.", ""]
        for key in result.cpu_keys:
            parts += [f"### {_cpu_label(key)}", "", md_table(*breakdown_table(result, key)), "",
                      breakdown_legend(key), ""]
    if result.precision:
        parts += ["## Precision of the stored depth formats", "",
                  "Relative quantization step (distance to the next representable depth, divided by the depth) "
                  "across the depth range.", "", _precision_md(result.precision), ""]
    return "\n".join(parts).rstrip() + "\n"


def _precision_md(precision: dict) -> str:
    rows = precision.get("rows", [])
    if not rows:
        return "(none)"
    header = list(rows[0].keys())
    return md_table(header, [[f"{r[h]:.3g}" if isinstance(r[h], float) else str(r[h]) for h in header]
                              for r in rows])


def write_reports(result: SceneResult, out_dir: Path, formats: tuple[str, ...] = FORMATS) -> list[Path]:
    name = result.scene.name
    has_plot = any(a.visibility for a in result.accuracy.values())
    png = work_precision_png(result) if has_plot and wants_image(formats) else None
    md = to_markdown(result, f"{name}.png" if has_plot else None, findings(result))
    return write_report_set(out_dir, name, md, png, json.dumps(to_json(result), indent=2, sort_keys=False) + "\n",
                            to_csv(result), formats)


def baseline_entries(result: SceneResult) -> dict[str, dict[str, int]]:
    """reports/baselines.json cases: one per variant and machine."""
    return {f"{t.variant}@{t.key}": {c: int(t.counters[c]) for c in BASELINE_COUNTERS} for t in result.timings}
