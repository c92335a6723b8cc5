"""Design-space sweeps (`retrosim sweep SPEC.toml`): scenes or kernels x CPUs x memories x preset
overrides, on Dask (an embedded LocalCluster, or an existing cluster), into one tidy table.

Spec format::

    [sweep]
    description = "..."                  # optional
    scenes = ["zbuffer-article"]         # shipped scene names or .toml paths, of any kind ... and/or kernels:
    variants = ["z32", "fp16z"]          # optional: these of each scene's variants (default all)
    cpus = ["pentium2-233"]              # required: CPU presets (or preset{key=value} labels)
    memories = ["edo", "sdram-pc100"]    # optional (default: each preset's own)
    compare = ["fp16z", "z32"]           # optional: state where variant 0 beats variant 1 along
                                         # the first grid parameter

    [[sweep.kernels]]                    # optional, repeatable: a kernel call, as `retrosim time`
    source = "zbuffer/fp16z.S"
    entry = "fp16z_span"
    args = "buf:u16:640:0xFFFF,buf:u16:640,640,0x10000000,0x100000,0x1234"
    repeat = 2                           # optional (default 2)

    [grid]                               # optional: override -> values; every combination is run
    "l2.size_kb" = ["none", 128, 256]    # keys as `retrosim time --set` ("none": no such cache)

    [[point]]                            # optional, repeatable: one more override set to run
    set = { "l2.latency_cycles" = 10 }   # (with neither [grid] nor [[point]]: the presets as they are)

A point is (scene variant or kernel, CPU, memory, overrides); its row holds the point's id, its
coordinates (`set.KEY` columns, as text), every counter of the last frame or call, `pixels` and
`cycles_per_pixel` for scenes (per unit of the scene's work: pixels, or vertices for a snap scene,
as its reports count them), and `error` (empty, or the one-line reason the point failed: a
failed point does not stop the sweep). Points whose id already has a row in the output are not
recomputed (failed ones are with --retry-failed), so an interrupted sweep resumes where it stopped.

Work is grouped by emulation (a scene's variant, or a kernel call): one task times one emulation on
every machine of its points, so a trace is emulated once per group, not per point. A scene's
variant is emulated by its kind (sim.scenes.kind.SceneKind.sweep_emulation), as its reports time it.
"""

from __future__ import annotations

import csv
import io
import itertools
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from sim.cpus.machine import MachineKey
from sim.errors import RetrosimError
from sim.reports.render import atomic_write
from sim.tomlfile import read_toml

_SWEEP_KEYS = {"description", "scenes", "kernels", "variants", "cpus", "memories", "compare"}
_KERNEL_KEYS = {"source", "entry", "args", "repeat"}
SCENES_DIR = Path(__file__).resolve().parent.parent / "scenes"
FIXED = ["point", "scene", "kernel", "variant", "cpu", "machine", "memory"]  # first columns, in order


class SweepError(RetrosimError):
    """A malformed sweep spec: `file: field: problem`."""


@dataclass
class Spec:
    path: Path
    groups: list[dict]               # emulation groups: {"kind", "what", "variant", "points": [...]}
    grid_keys: list[str]
    axes: dict                       # swept column -> values in spec order (as text)
    compare: tuple[str, str] | None = None
    description: str = ""

    @property
    def points(self) -> list[dict]:
        return [p for g in self.groups for p in g["points"]]


def _text(value) -> str:
    from sim.cpus import format_value

    return format_value(value)


def load_spec(path: str | Path) -> Spec:
    from sim.cpus import memory_presets, presets

    path = Path(path)

    def fail(field: str, message: str):
        raise SweepError(f"{path}: {field}: {message}")

    _, doc = read_toml(path, "sweep spec", SweepError)
    for key in doc:
        if key not in ("sweep", "grid", "point"):
            fail(key, "unknown table (allowed: [sweep], [grid], [[point]])")
    sw = doc.get("sweep")
    if not isinstance(sw, dict):
        fail("sweep", "missing table [sweep]")
    for key in sw:
        if key not in _SWEEP_KEYS:
            fail(f"sweep.{key}", f"unknown key (allowed: {', '.join(sorted(_SWEEP_KEYS))})")

    def strlist(key, required=False):
        v = sw.get(key)
        if v is None:
            if required:
                fail(f"sweep.{key}", "missing required field")
            return []
        if not isinstance(v, list) or not v or not all(isinstance(x, str) for x in v):
            fail(f"sweep.{key}", f"expected a non-empty array of strings, got {v!r}")
        return v

    scenes, variants_wanted = strlist("scenes"), strlist("variants")
    cpus, memories = strlist("cpus", True), strlist("memories")
    for i, cpu in enumerate(cpus):
        if MachineKey(cpu).preset not in presets.available():
            fail(f"sweep.cpus[{i}]", f"unknown CPU preset '{cpu}' (known: {', '.join(presets.available())})")
    for i, m in enumerate(memories):
        if m not in memory_presets():
            fail(f"sweep.memories[{i}]", f"unknown memory preset '{m}' (known: {', '.join(memory_presets())})")
    kernels = sw.get("kernels", [])
    if not isinstance(kernels, list) or not all(isinstance(k, dict) for k in kernels):
        fail("sweep.kernels", "expected an array of tables {source, entry, args, repeat}")
    if not scenes and not kernels:
        fail("sweep", "names nothing to run: give scenes = [...] and/or kernels = [...]")
    compare = sw.get("compare")
    if compare is not None and (not isinstance(compare, list) or len(compare) != 2
                                or not all(isinstance(c, str) for c in compare)):
        fail("sweep.compare", f"expected two variant names, got {compare!r}")

    # override sets: the grid's combinations, then the listed points
    grid = doc.get("grid", {})
    if not isinstance(grid, dict):
        fail("grid", "expected a table of override -> array of values")
    for key, values in grid.items():
        if not isinstance(values, list) or not values or any(isinstance(x, (dict, list)) for x in values):
            fail(f"grid.{key}", f"expected a non-empty array of values, got {values!r} (quote dotted keys: "
                                '"l2.size_kb" = [...])')
    sets = [dict(zip(grid, combo)) for combo in itertools.product(*grid.values())] if grid else []
    listed = doc.get("point", [])
    if not isinstance(listed, list):
        fail("point", "expected [[point]] tables")
    for i, p in enumerate(listed):
        if not isinstance(p, dict) or set(p) != {"set"} or not isinstance(p["set"], dict):
            fail(f"point[{i}]", "expected exactly one key, set = { override = value, ... }")
        sets.append(dict(p["set"]))
    sets = sets or [{}]
    keys = list(dict.fromkeys(k for s in sets for k in s))

    # what is emulated: scene variants and kernel calls
    subjects = []
    for i, name in enumerate(scenes):
        from sim.scenes.registry import load_scene

        p = Path(name)
        p = p if p.suffix == ".toml" else SCENES_DIR / f"{name}.toml"
        if not p.is_file():
            fail(f"sweep.scenes[{i}]", f"no scene '{name}'")
        scene = load_scene(p)
        chosen = [v for v in scene.variants if not variants_wanted or v in variants_wanted]
        if not chosen:
            fail("sweep.variants", f"none of {variants_wanted} is a variant of scene '{scene.name}'")
        for v in chosen:
            subjects.append({"kind": "scene", "what": str(p), "name": scene.name, "variant": v})
    for i, k in enumerate(kernels):
        extra = set(k) - _KERNEL_KEYS
        if extra or "source" not in k or "entry" not in k:
            fail(f"sweep.kernels[{i}]", "expected keys source, entry, args, repeat (source and entry required)")
        repeat = k.get("repeat", 2)
        if not isinstance(repeat, int) or isinstance(repeat, bool) or repeat < 1:
            fail(f"sweep.kernels[{i}].repeat", f"expected an integer >= 1, got {repeat!r}")
        subjects.append({"kind": "kernel", "what": str(k["source"]), "name": f"{k['source']}:{k['entry']}",
                         "variant": "", "entry": str(k["entry"]), "args": str(k.get("args", "")), "repeat": repeat})

    groups = []
    for sub in subjects:
        pts = []
        for cpu in cpus:
            for memory in memories or [None]:
                for s in sets:
                    coords = {"scene": sub["name"] if sub["kind"] == "scene" else "",
                              "kernel": sub["name"] if sub["kind"] == "kernel" else "",
                              "variant": sub["variant"], "cpu": cpu, "memory": memory or "",
                              **{f"set.{k}": _text(s[k]) if k in s else "" for k in keys}}
                    point = json.dumps(coords, sort_keys=True)
                    pts.append({"point": point, "coords": coords, "cpu": cpu, "memory": memory, "set": s})
        groups.append({**sub, "points": pts})
    axes = {"cpu": cpus, "memory": memories}
    axes.update({f"set.{k}": list(dict.fromkeys(_text(s[k]) for s in sets if k in s)) for k in keys})
    axes = {k: v for k, v in axes.items() if len(v) > 1}
    return Spec(path, groups, keys, axes, tuple(compare) if compare else None, str(sw.get("description", "")))


# -- one group's work (runs on a Dask worker or in this process) ----------------------------------

def _emulation(group: dict):
    """(emulation, pixels or None) of a group: a scene variant's frames or a kernel's calls."""
    if group["kind"] == "scene":
        from sim.scenes.registry import kind_of, load_scene

        scene = load_scene(group["what"])
        return kind_of(scene).sweep_emulation(scene, group["variant"])
    from sim.guest import kernels
    from sim.guest.args import parse_args
    from sim.timing.kernel import emulate

    args = group["args"]
    return emulate(kernels.resolve(group["what"]), group["entry"], lambda m: parse_args(args, m)[0],
                   repeat=group["repeat"]), None


def run_group(group: dict) -> list[dict]:
    """Rows of one group's points; a point that fails gets a row with its error."""
    from sim.cpus import machine_label, make_model
    from sim.timing.kernel import time_emulation

    rows = []
    try:
        emulation, pixels = _emulation(group)
    except Exception as e:  # every point of the group fails the same way
        return [_row(p, None, None, f"{type(e).__name__}: {e}" if not isinstance(e, RetrosimError) else str(e))
                for p in group["points"]]
    for p in group["points"]:
        try:
            label = machine_label(p["cpu"], p["set"])
            model = make_model(label, p["memory"])
            counters = time_emulation(emulation, model).last
            rows.append(_row(p, {"machine": label, "memory": model.dram.name, "pixels": pixels}, counters, ""))
        except Exception as e:  # recorded, the sweep goes on
            rows.append(_row(p, None, None, str(e) if isinstance(e, RetrosimError) else f"{type(e).__name__}: {e}"))
    return rows


def _row(point: dict, info: dict | None, counters: dict | None, error: str) -> dict:
    row = {"point": point["point"], **point["coords"], "machine": "", "error": error}
    if info:
        row.update(machine=info["machine"], memory=info["memory"])
        if info["pixels"] is not None:
            row["pixels"] = info["pixels"]
            row["cycles_per_pixel"] = counters["cycles"] / info["pixels"] if info["pixels"] else 0.0
    row.update(counters or {})
    return row


# -- the table: Parquet and CSV, written atomically -----------------------------------------------

def _columns(rows: list[dict]) -> list[str]:
    seen = list(dict.fromkeys(k for r in rows for k in r))
    sets = [c for c in seen if c.startswith("set.")]
    rest = [c for c in seen if c not in FIXED and not c.startswith("set.") and c not in ("error", "pixels",
                                                                                         "cycles_per_pixel")]
    return FIXED + sets + ["error", "pixels", "cycles_per_pixel"] + rest


def read_rows(base: Path) -> list[dict]:
    path = base.with_suffix(".parquet")
    if not path.is_file():
        return []
    import pyarrow.parquet as pq

    return pq.read_table(path).to_pylist()


def write_rows(base: Path, rows: list[dict]) -> list[Path]:
    import pyarrow as pa
    import pyarrow.parquet as pq

    cols = _columns(rows)
    text = {c for c in cols if c in FIXED or c.startswith("set.") or c == "error"}
    schema = pa.schema([(c, pa.string() if c in text else pa.float64() if c == "cycles_per_pixel" else pa.int64())
                        for c in cols])
    table = pa.Table.from_pylist([{c: r.get(c, "" if c in text else None) for c in cols} for r in rows], schema=schema)
    buf = io.BytesIO()
    pq.write_table(table, buf)
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(cols)
    for r in rows:
        w.writerow(["" if r.get(c) is None else (f"{r[c]:.6f}" if c == "cycles_per_pixel" else r[c]) for c in cols])
    atomic_write(base.with_suffix(".parquet"), buf.getvalue())
    atomic_write(base.with_suffix(".csv"), out.getvalue().encode())
    return [base.with_suffix(".parquet"), base.with_suffix(".csv")]


# -- running ---------------------------------------------------------------------------------------

@dataclass
class SweepResult:
    rows: list[dict]
    computed: int                    # points run now (the rest came from the output)
    failed: int
    files: list[Path] = field(default_factory=list)


def _warm(spec: Spec) -> None:
    """Run each family's compiled core once here (sim.parallel.warm), so the on-disk numba cache is
    filled before several workers load it at once (a cold cache loaded concurrently has been seen
    to stall)."""
    from sim.cpus import make_model, presets
    from sim.parallel import warm

    families = {}
    for p in spec.points:
        preset = MachineKey(p["cpu"]).preset
        try:
            families.setdefault(presets.load(preset).family, preset)
        except RetrosimError:
            pass
    warm([make_model(cpu) for cpu in families.values()])


def run_sweep(spec: Spec, base: Path, scheduler: str = "local", jobs: int = 2,
              progress: Callable[[int, int], None] | None = None, plots: bool = True,
              retry_failed: bool = False) -> SweepResult:
    """Run the spec's points not already in `base`.parquet (failed ones too with `retry_failed`);
    write the table after every group (so an interrupted sweep keeps what it finished), then the
    plots and findings."""
    done = {r["point"]: r for r in read_rows(base) if not (retry_failed and r.get("error"))}
    wanted = {p["point"] for p in spec.points}
    todo = []
    for g in spec.groups:
        pts = [p for p in g["points"] if p["point"] not in done]
        if pts:
            todo.append({**g, "points": pts})
    total = sum(len(g["points"]) for g in todo)
    new: dict[str, dict] = {}
    say = progress or (lambda n, total: None)
    say(0, total)

    def finish():
        rows = [new.get(p["point"]) or done[p["point"]] for p in spec.points
                if p["point"] in new or p["point"] in done]
        # rows from the output that this spec does not name are kept (a spec may have shrunk)
        rows += [r for k, r in done.items() if k not in wanted]
        return rows

    if todo:
        if scheduler == "serial":
            for g in todo:
                for r in run_group(g):
                    new[r["point"]] = r
                write_rows(base, finish())
                say(len(new), total)
        else:
            _run_dask(spec, todo, scheduler, jobs, new, lambda: write_rows(base, finish()), lambda: say(len(new), total))
    rows = finish()
    files = write_rows(base, rows) if rows else []
    if plots and rows:
        files += write_plots(spec, base, rows)
    return SweepResult(rows, len(new), sum(1 for r in rows if r.get("error")), files)


def _run_dask(spec, todo, scheduler, jobs, new, checkpoint, tick):
    try:
        from distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise RetrosimError("sweep needs dask.distributed: pip install 'dask[distributed]'") from None
    cluster = None
    if scheduler == "local":
        _warm(spec)
        # loopback only: the embedded cluster is not reachable from other machines
        cluster = LocalCluster(n_workers=jobs, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address="127.0.0.1:0", worker_dashboard_address="127.0.0.1:0",
                               silence_logs=40)
        address = cluster
    else:
        address = scheduler
    try:
        try:
            client = Client(address, timeout=30) if cluster is None else Client(cluster)
        except OSError as e:
            raise RetrosimError(f"--scheduler {scheduler}: cannot connect: {e}") from None
        with client:
            futures = [client.submit(run_group, g, pure=False) for g in todo]
            for fut in as_completed(futures):
                try:
                    rows = fut.result()
                except Exception as e:  # the worker itself died: the group's points fail
                    g = todo[futures.index(fut)]
                    rows = [_row(p, None, None, f"worker failed: {type(e).__name__}: {e}") for p in g["points"]]
                for r in rows:
                    new[r["point"]] = r
                checkpoint()
                tick()
    finally:
        if cluster is not None:
            cluster.close()


# -- plots and findings ------------------------------------------------------------------------------

def _metric(rows) -> tuple[str, str]:
    if any(r.get("scene") for r in rows):
        return "cycles_per_pixel", "cycles per pixel (last frame)"
    return "cycles", "cycles (last call)"


def write_plots(spec: Spec, base: Path, rows: list[dict]) -> list[Path]:
    """One PNG per swept parameter: the metric against its values, a line per combination of the
    variant, the subject and the other swept parameters; and `base`.md with the findings."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [r for r in rows if not r.get("error") and r["point"] in {p["point"] for p in spec.points}]
    metric, ylabel = _metric(ok)
    files = []
    for axis, values in spec.axes.items():
        others = [a for a in spec.axes if a != axis]
        series: dict[tuple, dict] = {}
        for r in ok:
            tag = (r["scene"] or r["kernel"], r["variant"], *(r[a] for a in others))
            series.setdefault(tag, {})[r[axis]] = r[metric]
        fig, ax = plt.subplots(figsize=(8, 5))
        xs = list(range(len(values)))
        for tag, ys in series.items():
            label = " ".join(str(t) for t in tag[1:] if t) or str(tag[0])
            ax.plot([x for x, v in zip(xs, values) if v in ys], [ys[v] for v in values if v in ys], marker="o",
                    label=label)
        ax.set_xticks(xs, values)
        ax.set_xlabel(axis)
        ax.set_ylabel(ylabel)
        ax.set_title(f"{base.name}: {ylabel} against {axis}")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=90, metadata={"Software": None})
        plt.close(fig)
        path = base.parent / f"{base.name}-{axis.replace('set.', '').replace('.', '-')}.png"
        atomic_write(path, buf.getvalue())
        files.append(path)
    md = findings_markdown(spec, base, ok, files)
    path = base.with_suffix(".md")
    atomic_write(path, md.encode())
    return files + [path]


def findings(spec: Spec, rows: list[dict]) -> list[str]:
    """Where compare[0] is faster than compare[1] along the first grid parameter, per combination of
    the other swept parameters (generated from the table, never written by hand)."""
    if not spec.compare or not spec.grid_keys:
        return []
    a, b = spec.compare
    axis = f"set.{spec.grid_keys[0]}"
    values = spec.axes.get(axis) or list(dict.fromkeys(r[axis] for r in rows))
    metric, _ = _metric(rows)
    others = [x for x in spec.axes if x != axis]
    table: dict[tuple, dict] = {}
    for r in rows:
        if r["variant"] in (a, b):
            table.setdefault((r["scene"] or r["kernel"], *(r[x] for x in others)), {}).setdefault(r[axis], {})[r["variant"]] = r[metric]
    out = []
    for ctx, by_x in table.items():
        pairs = [(x, by_x[x][a] / by_x[x][b]) for x in values if x in by_x and a in by_x[x] and b in by_x[x]]
        if not pairs:
            continue
        where = ", ".join(f"{k.replace('set.', '')} {v}" for k, v in zip(others, ctx[1:])) or "every point"
        wins = [x for x, q in pairs if q < 1]
        ratios = "; ".join(f"{x}: {q:.3f}" for x, q in pairs)
        if not wins:
            verdict = f"{a} never pays: it is slower than {b} at every {axis[4:]}"
        elif len(wins) == len(pairs):
            verdict = f"{a} pays at every {axis[4:]}"
        else:
            changes = [f"{'starts' if q1 < 1 else 'stops'} paying at {axis[4:]} = {x1} (after {x0})"
                       for (x0, q0), (x1, q1) in zip(pairs, pairs[1:]) if (q0 < 1) != (q1 < 1)]
            verdict = f"{a} " + ", then ".join(changes)
        out.append(f"{ctx[0]}, {where}: {verdict} ({a}/{b} {metric.replace('_', ' ')} ratio by {axis[4:]}: {ratios}).")
    return out


def findings_markdown(spec: Spec, base: Path, rows: list[dict], plots: list[Path]) -> str:
    lines = [f"# Sweep {base.name}", "", f"Generated by `retrosim sweep {spec.path.name}` from `{base.name}.parquet` "
             f"({len(rows)} points); do not edit.", ""]
    if spec.description:
        lines += [spec.description.strip(), ""]
    found = findings(spec, rows)
    if found:
        lines += ["## Findings", ""] + [f"- {f}" for f in found] + [""]
    lines += [f"![{p.stem}]({p.name})" for p in plots] + [""]
    return "\n".join(lines)
