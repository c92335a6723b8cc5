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
or keys for a sort scene (its first distribution at its table_size), as its reports count them; the
plots, findings and table say which), and `error` (empty, or the one-line reason the point failed: a
failed point does not stop the sweep). Points whose id already has a row in the output are not
recomputed (failed ones are with --retry-failed), so an interrupted sweep resumes where it stopped.

A point's id (the `point` column) is the JSON of everything in the spec that determines its
counters: the scene (by name: two scene files of one name are refused) and variant, or the kernel
(source:entry) with its `args` and `repeat`; the CPU label, the memory and the overrides. Values
that name one machine twice (a grid's `128` and `128.0`, a CPU listed twice, a [[point]] equal to a
grid point) are refused, as are non-finite numbers. Beside the id, a row's `fingerprint` column holds
a hash of the files' contents that determine its counters: the scene file's bytes, or the kernel
source with its includes (as the assembler cache hashes them, sim.guest.asm.content_key), the
CPU and memory preset files, and the model itself (every .py and .toml file of the sim package:
a model change makes every stored point stale). A stored point whose fingerprint differs from the current one (or a
row without one, from a table written before fingerprints) is recomputed on resume, and the
command says how many were; the id itself is unchanged, so older tables stay resumable. Resuming merges only into a table this module
wrote: an unreadable or altered Parquet file (or a CSV without its Parquet file) is refused with
how to start over, never merged. One sweep at a time writes an output: it holds `BASE.lock` (an
flock, released if the process dies) and a second sweep into the same output is refused.

Limits: a sweep runs at most MAX_POINTS (10,000) points, counted before any is built, unless
`--max-points N` (load_spec's max_points) raises the limit; a kernel's `repeat` is at most
MAX_REPEAT (10,000), as `retrosim time --repeat`. The command prints the number of points and
kernel calls before it starts. A `--scheduler` is `tcp://HOST:PORT` (IPv6 in brackets); it must
answer Dask's identity request within CONNECT_TIMEOUT (10 s). A sweep with failed points exits 2
(the command prints the first errors); plots are drawn only from points that succeeded.

Work is grouped by emulation (a scene's variant, or a kernel call): one task times one emulation on
every machine of its points, so a trace is emulated once per group, not per point. A kernel is
assembled and emulated once per instruction set among its points' CPUs (sim.guest.cpu.GuestCpu:
extensions, assembler names, Unicorn model), as `retrosim time` builds it per preset, so MMX, 3DNow!
and SSE kernels sweep on the CPUs that have them. A scene's variant is emulated by its kind
(sim.scenes.kind.SceneKind.sweep_emulation), as its reports time it.

The report (`BASE.md`) holds the findings, the plots (legends name the scene or kernel call, the
variant and the other swept parameters) and a Markdown table of every point's result or error.
"""

from __future__ import annotations

import contextlib
import csv
import fcntl
import hashlib
import io
import os
import re
import stat
import itertools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

from sim.cpus.machine import MachineKey
from sim.errors import OutputError, RetrosimError
from sim.inputfile import files_hash
from sim.output import check_output_dir, check_output_file, file_mode
from sim.reports.render import atomic_write
from sim.tomlfile import read_toml

_SWEEP_KEYS = {"description", "scenes", "kernels", "variants", "cpus", "memories", "compare"}
MAX_POINTS = 10_000      # points a sweep runs unless --max-points raises it (10,000 kernel points of
                         # ~1 s each keep two cores busy for hours; a 10^6 grid is a typo more often than a plan)
MAX_REPEAT = 10_000      # a kernel's calls per point, as `retrosim time --repeat` (every call's trace is kept)
_KERNEL_KEYS = {"source", "entry", "args", "repeat"}
SCENES_DIR = Path(__file__).resolve().parent.parent / "scenes"
FIXED = ["point", "scene", "kernel", "variant", "cpu", "machine", "memory"]  # first columns, in order
CALL = ["args", "repeat"]  # a kernel call's arguments and calls: after FIXED, in tables with kernel points
FINGERPRINT = "fingerprint"  # hash of the input files' contents (after CALL); absent in older tables


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
    units: dict = field(default_factory=dict)  # scene name -> its kind's unit of work ("pixel", "key", ...)

    @property
    def points(self) -> list[dict]:
        return [p for g in self.groups for p in g["points"]]


def _text(value) -> str:
    from sim.cpus.overrides import format_value

    return format_value(value)


def fingerprint(subject: dict, cpu: str, memory: str | None, cache: dict | None = None) -> str:
    """Hash of the contents of the files that determine a point's counters besides its id: the
    scene file (a scene), or the kernel source and the includes the assembler cache follows
    (sim.guest.asm.content_key, a kernel); the CPU preset file; the memory preset file (the
    preset's own when `memory` is None); the model (:func:`model_hash`). "" when a file cannot be read: the point is then always
    recomputed, and fails with that file's error. `cache`: per-file hashes shared between points."""
    from sim.cpus import presets
    from sim.memory.dram import MEMORY_PRESETS_DIR

    cache = {} if cache is None else cache

    def once(key: tuple, compute: Callable[[], str]) -> str:
        if key not in cache:
            try:
                cache[key] = compute()
            except (RetrosimError, OSError):
                cache[key] = ""
        return cache[key]

    def file_hash(path: Path) -> str:  # a scene or preset file, already read and checked by its loader
        return hashlib.sha256(path.read_bytes()).hexdigest()

    def kernel_hash(source: str) -> str:
        from sim.guest import kernels
        from sim.guest.asm import content_key, get_assembler

        return content_key(kernels.resolve(source), get_assembler())

    preset = MachineKey(cpu).preset
    if subject["kind"] == "scene":
        what = once(("scene", subject["what"]), lambda: file_hash(Path(subject["what"])))
    else:
        what = once(("kernel", subject["what"]), lambda: kernel_hash(subject["what"]))
    cpu_hash = once(("cpu", preset), lambda: file_hash(presets.PRESETS / f"{preset}.toml"))
    mem = memory or once(("default memory", preset), lambda: presets.load(preset).memory)
    mem_hash = once(("memory", mem), lambda: file_hash(MEMORY_PRESETS_DIR / f"{mem}.toml")) if mem else ""
    if not (what and cpu_hash and mem_hash):
        return ""
    model = once(("model",), model_hash)
    return hashlib.sha256(f"{what} {cpu_hash} {mem_hash} {model}".encode()).hexdigest()


MODEL_DIR = Path(__file__).resolve().parent  # the sim package: the code and tables that time a point


def model_hash(root: Path | None = None) -> str:
    """Hash of the timing model itself: every .py and .toml file of the sim package (the cores,
    the instruction and machine tables, the memory model, the scene code), by path and content.
    A stored point timed by another version of the model is stale even when its scene and presets
    are unchanged (a sweep resumed after a model change would otherwise keep old counters)."""
    root = MODEL_DIR if root is None else root
    return files_hash((p for p in root.rglob("*") if p.suffix in (".py", ".toml") and p.is_file()), root)


def load_spec(path: str | Path, max_points: int = MAX_POINTS) -> Spec:
    """The spec at `path`, checked: one SweepError naming the file and field for anything wrong,
    including more than `max_points` points (counted before any is built)."""
    from sim.cpus import presets
    from sim.cpus.overrides import memory_presets

    path = Path(path)

    def fail(field: str, message: str):
        raise SweepError(f"{path}: {field}: {message}")

    def finite(field: str, value):
        if isinstance(value, float) and not math.isfinite(value):
            fail(field, f"{value!r} is not a finite number")

    def too_many(n: int, qualifier: str = "") -> str:
        return (f"{qualifier}{n:,} points to run, more than the limit of {max_points:,} (each point is one timing "
                "run); shrink the grid, or raise the limit with --max-points N")

    def unique(field: str, values: list[str]):
        for j, v in enumerate(values):
            if v in values[:j]:
                fail(f"{field}[{j}]", f"'{v}' is listed twice; list each once")

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
    unique("sweep.cpus", cpus)
    unique("sweep.memories", memories)
    unique("sweep.scenes", scenes)
    unique("sweep.variants", variants_wanted)
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
        seen = {}
        for j, x in enumerate(values):
            finite(f"grid.{key}[{j}]", x)
            if _text(x) in seen:  # 128 and 128.0 are one machine: a second row would repeat its id
                fail(f"grid.{key}[{j}]", f"value {x!r} repeats {seen[_text(x)]!r}; list each value once")
            seen[_text(x)] = x
    listed = doc.get("point", [])
    if not isinstance(listed, list):
        fail("point", "expected [[point]] tables")
    n_sets = (math.prod(len(v) for v in grid.values()) if grid else 0) + len(listed)
    n_subjects = len(kernels) + len(scenes)  # a scene's variants are counted once it is loaded
    if n_subjects * len(cpus) * max(len(memories), 1) * max(n_sets, 1) > max_points:  # before building them
        fail("sweep", too_many(n_subjects * len(cpus) * max(len(memories), 1) * max(n_sets, 1), "at least "))
    sets = [dict(zip(grid, combo)) for combo in itertools.product(*grid.values())] if grid else []
    for i, p in enumerate(listed):
        if not isinstance(p, dict) or set(p) != {"set"} or not isinstance(p["set"], dict):
            fail(f"point[{i}]", "expected exactly one key, set = { override = value, ... }")
        for key, x in p["set"].items():
            if isinstance(x, (dict, list)):
                fail(f"point[{i}].set.{key}", f"expected a value, got {x!r}")
            finite(f"point[{i}].set.{key}", x)
        sets.append(dict(p["set"]))
    sets = sets or [{}]
    keys = list(dict.fromkeys(k for s in sets for k in s))

    # what is emulated: scene variants and kernel calls
    subjects, units = [], {}
    for i, name in enumerate(scenes):
        from sim.scenes.registry import KINDS, load_scene

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
        units[scene.name] = KINDS[scene.kind].unit
    for i, k in enumerate(kernels):
        extra = set(k) - _KERNEL_KEYS
        if extra or "source" not in k or "entry" not in k:
            fail(f"sweep.kernels[{i}]", "expected keys source, entry, args, repeat (source and entry required)")
        repeat = k.get("repeat", 2)
        if not isinstance(repeat, int) or isinstance(repeat, bool) or not 1 <= repeat <= MAX_REPEAT:
            fail(f"sweep.kernels[{i}].repeat", f"expected an integer from 1 to {MAX_REPEAT:,} (as `retrosim time "
                                               f"--repeat`), got {repeat!r}")
        for key in ("source", "entry", "args"):
            if key in k and not isinstance(k[key], str):
                fail(f"sweep.kernels[{i}].{key}", f"expected a string, got {k[key]!r}")
        subjects.append({"kind": "kernel", "what": k["source"], "name": f"{k['source']}:{k['entry']}",
                         "variant": "", "entry": k["entry"], "args": k.get("args", ""), "repeat": repeat})
    named = {}
    for sub in subjects:  # two scene files of one name would share their points' ids
        if sub["kind"] == "scene" and named.setdefault(sub["name"], sub["what"]) != sub["what"]:
            fail("sweep.scenes", f"scenes {named[sub['name']]} and {sub['what']} are both named '{sub['name']}'")
    n_points = len(subjects) * len(cpus) * max(len(memories), 1) * len(sets)
    if n_points > max_points:
        fail("sweep", too_many(n_points))

    groups, ids, files = [], set(), {}
    for sub in subjects:
        pts = []
        for cpu in cpus:
            for memory in memories or [None]:
                for s in sets:
                    coords = {"scene": sub["name"] if sub["kind"] == "scene" else "",
                              "kernel": sub["name"] if sub["kind"] == "kernel" else "",
                              "variant": sub["variant"], "cpu": cpu, "memory": memory or "",
                              **{f"set.{k}": _text(s[k]) if k in s else "" for k in keys}}
                    if sub["kind"] == "kernel":  # the call's arguments and count determine its counters too
                        coords.update(args=sub["args"], repeat=str(sub["repeat"]))
                    point = json.dumps(coords, sort_keys=True)
                    if point in ids:  # a [[point]] equal to a grid point, or one kernel call listed twice
                        fail("point" if listed else "sweep.kernels", f"the point {point} is listed twice")
                    ids.add(point)
                    pts.append({"point": point, "coords": coords, "cpu": cpu, "memory": memory, "set": s,
                                "fingerprint": fingerprint(sub, cpu, memory, files)})
        groups.append({**sub, "points": pts})
    axes = {"cpu": cpus, "memory": memories}
    axes.update({f"set.{k}": list(dict.fromkeys(_text(s[k]) for s in sets if k in s)) for k in keys})
    axes = {k: v for k, v in axes.items() if len(v) > 1}
    return Spec(path, groups, keys, axes, tuple(compare) if compare else None, str(sw.get("description", "")), units)


# -- one group's work (runs on a Dask worker or in this process) ----------------------------------

def _emulation(group: dict, isa_cpu=None, scene=None):
    """(emulation, pixels or None) of a group: a scene variant's frames (`scene`: the group's scene,
    loaded) or a kernel's calls, the kernel assembled and emulated for `isa_cpu`'s instruction set
    (a sim.guest.cpu.GuestCpu)."""
    if group["kind"] == "scene":
        from sim.scenes.registry import kind_of

        return kind_of(scene).sweep_emulation(scene, group["variant"])
    from sim.guest import kernels
    from sim.guest.args import parse_args
    from sim.timing.kernel import emulate

    args = group["args"]
    return emulate(kernels.resolve(group["what"]), group["entry"], lambda m: parse_args(args, m)[0],
                   repeat=group["repeat"], isa_cpu=isa_cpu), None


def _instruction_set(cpu: str):
    """(key, GuestCpu) of a point's CPU: points whose CPUs share the key (extensions, assembler
    names, Unicorn model) share one emulation of a kernel, as `retrosim time` builds it per preset."""
    from sim.cpus import presets
    from sim.guest.cpu import GuestCpu

    guest = GuestCpu.from_preset(presets.load(MachineKey(cpu).preset))
    return (guest.extensions, guest.gnu_march, guest.zig_mcpu, guest.emulator_cpu), guest


def _error(e: Exception) -> str:
    return str(e) if isinstance(e, RetrosimError) else f"{type(e).__name__}: {e}"


def run_group(group: dict) -> list[dict]:
    """Rows of one group's points; a point that fails gets a row with its error. A kernel is
    emulated once per instruction set among the points' CPUs (MMX, 3DNow!, SSE kernels assemble
    only for CPUs that have them); a scene's variant once (its kind builds it for every CPU)."""
    from sim.cpus.build import make_model
    from sim.cpus.machine import resolve
    from sim.timing.kernel import time_emulation

    emulations: dict = {}  # instruction-set key (None for a scene) -> (emulation, pixels) or the error
    scene = None
    warm_start = False  # a scene's variant is timed as its reports time it
    if group["kind"] == "scene":
        from sim.scenes.registry import kind_of, load_scene

        scene = load_scene(group["what"])
        warm_start = kind_of(scene).warm_start

    def emulation_for(p):
        key, guest = (None, None)
        if group["kind"] == "kernel":
            key, guest = _instruction_set(p["cpu"])
        if key not in emulations:
            try:
                emulations[key] = _emulation(group, guest, scene)
            except Exception as e:  # every point of this instruction set fails the same way
                emulations[key] = e
        if isinstance(emulations[key], Exception):
            raise emulations[key]
        return emulations[key]

    from sim.memory.replay import AccessLogs

    # Points whose data caches decide alike (same family and data-side configuration: a grid over
    # latencies or estimates) share one walk of them, as the claims' re-timings do (sim/memory/replay.py):
    # the first records it, the others replay it (measured on the fp16z span: P6 0.87x, K6 0.78x the
    # time of a walk; recording costs 3-6 %, so a point alone in its configuration records nothing).
    # They run next to each other, one log at a time; rows keep the spec's order.
    rows: list = [None] * len(group["points"])
    planned = []
    for i, p in enumerate(group["points"]):
        try:
            machine = resolve(p["cpu"], p["set"], p["memory"])  # the point's text, resolved in its worker
            # what decides the data caches' walk: the family (its TLB), the caches, the DRAM pages
            planned.append((i, machine, (machine.family, machine.data_caches, machine.memory.pages)))
        except Exception as e:  # recorded, the sweep goes on
            rows[i] = _row(p, None, None, _error(e))
    sharing = {}
    for _, _, key in planned:
        sharing[key] = sharing.get(key, 0) + 1
    logs: dict = {}  # configuration -> AccessLogs, one alive at a time
    rank = {key: k for k, key in enumerate(sharing)}  # configurations in order of first appearance
    for i, machine, key in sorted(planned, key=lambda t: rank[t[2]]):
        p = group["points"][i]
        try:
            emulation, pixels = emulation_for(p)
            if key not in logs:
                logs.clear()
                logs[key] = AccessLogs() if sharing[key] > 1 else None
            counters = time_emulation(emulation, make_model(machine), access_logs=logs[key], warm_start=warm_start).last
            rows[i] = _row(p, {"machine": machine.label, "memory": machine.memory.name, "pixels": pixels}, counters, "")
        except Exception as e:  # recorded, the sweep goes on
            rows[i] = _row(p, None, None, _error(e))
    return rows


def _row(point: dict, info: dict | None, counters: dict | None, error: str) -> dict:
    row = {"point": point["point"], **point["coords"], "machine": "", "error": error,
           FINGERPRINT: point.get("fingerprint", "")}
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
    call = [c for c in CALL + [FINGERPRINT] if c in seen]
    sets = [c for c in seen if c.startswith("set.")]
    rest = [c for c in seen if c not in FIXED and c not in CALL and c != FINGERPRINT and not c.startswith("set.")
            and c not in ("error", "pixels", "cycles_per_pixel")]
    return FIXED + call + sets + ["error", "pixels", "cycles_per_pixel"] + rest


def _is_text(column: str) -> bool:
    return column in FIXED or column in CALL or column.startswith("set.") or column in ("error", FINGERPRINT)


MAX_TABLE_BYTES = 1 << 30  # a sweep's table: 10,000 points of ~100 counters are a few MB
# What a resumed table may decode to, checked from its footer before any row is decoded (a 1 MB file can
# hold 80 million repeated rows): 5 million cells are 50,000 points of 100 counters, five times the
# default point limit, a few hundred MB as Python rows; the decoded bytes are counted batch by batch
# (a dictionary-encoded string column can repeat one long string in every row).
MAX_TABLE_CELLS = 5_000_000
MAX_DECODED_BYTES = 256 << 20
_BATCH_ROWS = 64


class DamagedOutput(RetrosimError):
    """A sweep's existing output cannot be resumed from."""


def read_rows(base: Path) -> list[dict]:
    """The rows of `base`.parquet, the table a resumed sweep merges into: none if there is no
    output yet. Anything that is not a table this module wrote (unreadable, wrong or missing
    columns, repeated points, a CSV without its Parquet file) is refused, never merged: the
    message says how to start over."""
    path, csv_path = base.with_suffix(".parquet"), base.with_suffix(".csv")

    def damaged(problem: str):
        raise DamagedOutput(f"{path}: {problem}; not resuming from it: delete {path.name} and {csv_path.name} to start "
                            "the sweep over, or choose another --out")

    if not os.path.lexists(path):
        if os.path.lexists(csv_path):  # the Parquet file is the table; its CSV copy alone cannot be merged
            raise DamagedOutput(f"{csv_path}: a sweep table without its {path.name}; not overwriting it: delete "
                                f"{csv_path.name} to start the sweep over, or choose another --out")
        return []
    try:
        st = os.stat(path)
    except OSError as e:
        damaged(f"cannot read it: {e.strerror or e}")
    if not stat.S_ISREG(st.st_mode):
        damaged("not a regular file (a device, pipe or folder)")
    if st.st_size > MAX_TABLE_BYTES:
        damaged(f"{st.st_size:,} bytes, more than the {MAX_TABLE_BYTES >> 20} MB a sweep table may have")
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        table = pq.ParquetFile(path)
        schema, meta = table.schema_arrow, table.metadata
    except (pa.ArrowException, OSError, ValueError) as e:
        damaged(f"not a readable Parquet table ({one_line_of(e)})")
    for col in FIXED + ["error"]:
        if col not in schema.names:
            damaged(f"no column '{col}'")
    for f in schema:
        want = "string" if _is_text(f.name) else "double" if f.name == "cycles_per_pixel" else "int64"
        if str(f.type) != want:
            damaged(f"column '{f.name}' holds {f.type}, not {want}")
    if meta.num_rows * max(meta.num_columns, 1) > MAX_TABLE_CELLS:
        damaged(f"{meta.num_rows:,} rows of {meta.num_columns} columns, more than the {MAX_TABLE_CELLS:,} cells a "
                "sweep table may have")
    rows, decoded = [], 0
    try:
        for batch in table.iter_batches(batch_size=_BATCH_ROWS):
            decoded += batch.nbytes
            if decoded > MAX_DECODED_BYTES:
                damaged(f"more than {MAX_DECODED_BYTES >> 20} MB once decoded, more than a sweep table may have")
            rows += batch.to_pylist()
    except (pa.ArrowException, OSError, ValueError) as e:
        damaged(f"not a readable Parquet table ({one_line_of(e)})")
    counters = [f.name for f in schema if not _is_text(f.name)]
    seen = set()
    for i, r in enumerate(rows):
        try:
            coords = json.loads(r["point"])
        except (TypeError, ValueError):
            damaged(f"row {i}: point {r['point']!r} is not a point id")
        if not isinstance(coords, dict) or any(r.get(k) != v for k, v in coords.items() if k != "memory"):
            damaged(f"row {i}: point {r['point']!r} does not match the row's coordinates")
        if r["point"] in seen:
            damaged(f"row {i}: point {r['point']!r} appears twice")
        seen.add(r["point"])
        _check_counters(r, i, counters, damaged)
    return rows


def _check_counters(row: dict, i: int, counters: list[str], damaged) -> None:
    """A stored row's counters as this module writes them: a row without an error has its cycles, and
    every counter is empty (a counter another family's model has) or a count, never negative."""
    if not isinstance(row["error"], str):
        damaged(f"row {i}: its error column is empty (a timed row holds '')")
    if not row["error"] and row.get("cycles") is None:
        damaged(f"row {i}: point {row['point']!r} has no error and no cycles")
    for name in counters:
        value = row.get(name)
        if value is not None and not (value >= 0 and math.isfinite(value)):
            damaged(f"row {i}: point {row['point']!r} has {name} = {value}, not a count")


def one_line_of(e: Exception) -> str:
    text = " ".join(str(e).split())
    return text[:200] + ("..." if len(text) > 200 else "")


def write_rows(base: Path, rows: list[dict]) -> list[Path]:
    import pyarrow as pa
    import pyarrow.parquet as pq

    cols = _columns(rows)
    text = {c for c in cols if _is_text(c)}
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

class SweepLocked(RetrosimError):
    """Another sweep is writing the same output."""


@contextlib.contextmanager
def output_lock(base: Path) -> Iterator[Path]:
    """Hold `base`.lock (an flock: released by the kernel if this process dies, so a crash leaves no
    stale lock) while a sweep reads, merges and writes `base`.parquet/.csv: two sweeps into one
    output would otherwise each merge into what they read first, and the second's write would drop
    the first's rows. A second sweep is refused at once. The lock file is removed on release; a
    process that locked a file just removed retries on the new one."""
    path = base.parent / f"{base.name}.lock"
    check_output_dir(path.parent, "--out")
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, file_mode())
        except OSError as e:
            raise OutputError(f"{path}: cannot create the sweep's lock file: {e.strerror or e}") from None
        try:
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                raise OutputError(f"{path}: the sweep's lock file is not a regular file (a device, pipe or folder)")
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
                raise SweepLocked(f"{path}: another sweep{f' (process {holder})' if holder.isdigit() else ''} is "
                                  f"writing {base}.parquet; wait for it to finish, or choose another --out") from None
            try:
                same = os.stat(path, follow_symlinks=False).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
        except BaseException:
            os.close(fd)
            raise
        os.close(fd)  # the holder removed it between our open and our lock: take the new one
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        yield path
    finally:
        with contextlib.suppress(OSError):
            os.unlink(path)
        os.close(fd)


@dataclass
class SweepResult:
    rows: list[dict]
    computed: int                    # points run now (the rest came from the output)
    failed: int
    files: list[Path] = field(default_factory=list)
    changed: int = 0                 # of `computed`: points in the output recomputed because their input files changed


def _warm(spec: Spec) -> None:
    """Run each family's compiled core once here (sim.parallel.warm), so the on-disk numba cache is
    filled before several workers load it at once (a cold cache loaded concurrently has been seen
    to stall)."""
    from sim.cpus import presets
    from sim.cpus.build import make_model
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
              retry_failed: bool = False, lock: bool = True) -> SweepResult:
    """Run the spec's points not already in `base`.parquet (failed ones too with `retry_failed`);
    write the table after every group (so an interrupted sweep keeps what it finished), then the
    plots and findings. The output is locked meanwhile (:func:`output_lock`), unless the caller
    holds the lock already (`lock=False`)."""
    if not lock:
        return _run_sweep(spec, base, scheduler, jobs, progress, plots, retry_failed)
    with output_lock(base):
        return _run_sweep(spec, base, scheduler, jobs, progress, plots, retry_failed)


def preflight(base: Path, scheduler: str) -> None:
    """The checks of a sweep's inputs that need no work, so a command can report them before it
    starts its progress display: the output files, the existing table, the scheduler's answer."""
    for suffix in (".parquet", ".csv", ".md"):
        check_output_file(base.with_suffix(suffix), "--out")
    read_rows(base)
    where = check_scheduler(scheduler)
    if where is not None:
        _reach(scheduler, *where)
        _ask_identity(scheduler)


def _run_sweep(spec, base, scheduler, jobs, progress, plots, retry_failed) -> SweepResult:
    for suffix in (".parquet", ".csv", ".md"):  # before the work: a pipe or a read-only folder fails at once
        check_output_file(base.with_suffix(suffix), "--out")
    done = {r["point"]: r for r in read_rows(base) if not (retry_failed and r.get("error"))}
    wanted = {p["point"] for p in spec.points}

    def stale(p):  # stored, but its input files changed since (or it predates fingerprints, or one is unreadable)
        return p["point"] in done and (not p["fingerprint"] or done[p["point"]].get(FINGERPRINT) != p["fingerprint"])

    todo, changed = [], 0
    for g in spec.groups:
        pts = [p for p in g["points"] if p["point"] not in done or stale(p)]
        changed += sum(1 for p in pts if p["point"] in done)
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
    if plots and any(not r.get("error") for r in rows):  # a sweep with no result draws no empty plot
        files += write_plots(spec, base, rows)
    return SweepResult(rows, len(new), sum(1 for r in rows if r.get("error")), files, changed)


CONNECT_TIMEOUT = 10.0  # seconds to reach a --scheduler address and hear Dask answer


def check_scheduler(address: str) -> tuple[str, int] | None:
    """(host, port) of a `tcp://HOST:PORT` scheduler address, None for 'local' and 'serial'; anything
    else is refused with one line (Dask's own parser raises assorted exceptions on bad addresses)."""
    if address in ("local", "serial"):
        return None
    fail = f"--scheduler '{address}'"
    scheme, sep, rest = address.partition("://")
    if not sep:
        raise RetrosimError(f"{fail}: expected local, serial or tcp://HOST:PORT")
    if scheme != "tcp":
        why = {"tls": "TLS needs certificates, which retrosim does not pass to Dask",
               "inproc": "an in-process address names no scheduler this command can reach",
               "ucx": "UCX is not installed with retrosim"}.get(scheme, "not a transport retrosim supports")
        raise RetrosimError(f"{fail}: {scheme}:// is not supported ({why}); use tcp://HOST:PORT")
    m = re.fullmatch(r"(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9._-]+):([0-9]{1,5})/?", rest)
    if not m:
        raise RetrosimError(f"{fail}: expected tcp://HOST:PORT (an IPv6 host in brackets: tcp://[::1]:8786), "
                            "with nothing after the port")
    host, port = m.group(1).strip("[]"), int(m.group(2))
    if not 1 <= port <= 65535:
        raise RetrosimError(f"{fail}: port {port} is not between 1 and 65535")
    return host, port


def _reach(address: str, host: str, port: int) -> None:
    """Connect once with a timeout, so an address where nothing listens fails at once with its name
    (Dask's client retries for a long time)."""
    import socket

    try:
        socket.create_connection((host, port), timeout=CONNECT_TIMEOUT).close()
    except socket.timeout:
        raise RetrosimError(f"--scheduler {address}: no answer within {CONNECT_TIMEOUT:g} s") from None
    except OSError as e:
        raise RetrosimError(f"--scheduler {address}: cannot connect: {e.strerror or e}") from None


def _ask_identity(address: str) -> None:
    """Ask the scheduler who it is, within CONNECT_TIMEOUT: a listener that is not Dask answers
    garbage (Dask's handshake raises struct.error) or nothing (Dask's client would wait forever)."""
    import asyncio

    from distributed.core import rpc

    async def identity():
        async with rpc(address, timeout=CONNECT_TIMEOUT) as scheduler:
            return await scheduler.identity()

    try:
        answer = asyncio.run(asyncio.wait_for(identity(), CONNECT_TIMEOUT))
    except (asyncio.TimeoutError, TimeoutError):
        raise RetrosimError(f"--scheduler {address}: no Dask scheduler answered there within "
                            f"{CONNECT_TIMEOUT:g} s") from None
    except Exception as e:  # struct.error, OSError, a closed comm, ...
        raise RetrosimError(f"--scheduler {address}: no Dask scheduler answered there "
                            f"({type(e).__name__}: {one_line_of(e)})") from None
    if not isinstance(answer, dict) or answer.get("type") != "Scheduler":
        raise RetrosimError(f"--scheduler {address}: no Dask scheduler answered there (it answered {answer!r:.80})")


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
        host, port = check_scheduler(scheduler)
        _reach(scheduler, host, port)
        address = scheduler
    try:
        if cluster is not None:
            client = Client(cluster)
        else:
            _ask_identity(scheduler)
            client = Client(address, timeout=CONNECT_TIMEOUT)
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

def _metric(rows, units: dict | None = None) -> tuple[str, str]:
    """(column, label) of what the plots and findings compare: cycles per unit of a scene's work
    (the column keeps its name cycles_per_pixel for every kind: pixels, a snap scene's vertices, a
    sort scene's keys), or a kernel call's cycles."""
    scenes = {r["scene"] for r in rows if r.get("scene")}
    if scenes:
        kinds = sorted({(units or {}).get(s, "pixel") for s in scenes})
        if kinds == ["pixel"]:
            return "cycles_per_pixel", "cycles per pixel (last frame)"
        return "cycles_per_pixel", f"cycles per {' or '.join(kinds)}"
    return "cycles", "cycles (last call)"


def write_plots(spec: Spec, base: Path, rows: list[dict]) -> list[Path]:
    """One PNG per swept parameter: the metric against its values, a line per combination of the
    variant, the subject and the other swept parameters; and `base`.md with the findings."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    named = {p["point"] for p in spec.points}
    mine = [r for r in rows if r["point"] in named]
    ok = [r for r in mine if not r.get("error")]
    metric, ylabel = _metric(ok, spec.units)
    files = []
    for axis, values in spec.axes.items():
        others = [a for a in spec.axes if a != axis]
        series: dict[tuple, dict] = {}
        for r in ok:
            tag = (_subject(r), r["variant"], *(r[a] for a in others))
            series.setdefault(tag, {})[r[axis]] = r[metric]
        if not series:
            continue
        fig, ax = plt.subplots(figsize=(8, 5))
        xs = list(range(len(values)))
        for tag, ys in series.items():
            # the legend names the scene or kernel call, then the variant and the other parameters
            label = " ".join(str(t) for t in tag if t)
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
    md = findings_markdown(spec, base, ok, files, mine)
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
    metric, what = _metric(rows, spec.units)
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
        out.append(f"{ctx[0]}, {where}: {verdict} ({a}/{b} {what.split(' (')[0]} ratio by {axis[4:]}: {ratios}).")
    return out


def _subject(row: dict) -> str:
    """What a row times: the scene's name, or the kernel call (source:entry, with its arguments)."""
    if row["scene"]:
        return row["scene"]
    args = row.get("args", "")
    return f"{row['kernel']}({args})" if args else row["kernel"]


def _cell(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def results_table(spec: Spec, rows: list[dict]) -> list[str]:
    """The table's rows as Markdown, in spec order: what was timed, the swept coordinates, the
    metric and the cycles (or the point's error)."""
    metric, label = _metric([r for r in rows if not r.get("error")] or rows, spec.units)
    coords = ["variant", "cpu", "memory"] + (["repeat"] if any(r.get("repeat") for r in rows) else []) \
        + [f"set.{k}" for k in spec.grid_keys]
    coords = [c for c in coords if any(r.get(c) for r in rows)]
    heads = ["scene or kernel"] + [c.replace("set.", "") for c in coords]
    heads += [label] + (["cycles"] if metric != "cycles" else [])
    failed = any(r.get("error") for r in rows)
    heads += ["error"] if failed else []
    out = ["| " + " | ".join(heads) + " |", "|" + "|".join("---" if i <= len(coords) else "---:"
                                                          for i in range(len(heads) - failed)) + ("|---|" if failed else "|")]
    order = {p["point"]: i for i, p in enumerate(spec.points)}
    for r in sorted(rows, key=lambda r: order.get(r["point"], len(order))):
        cells = [_subject(r)] + [r.get(c, "") for c in coords]
        if r.get("error"):
            cells += ["-"] + (["-"] if metric != "cycles" else []) + [r["error"]]
        else:
            cells += [f"{r[metric]:,.3f}" if metric == "cycles_per_pixel" else f"{r[metric]:,}"]
            cells += [f"{r['cycles']:,}"] if metric != "cycles" else []
            cells += [""] if failed else []
        out.append("| " + " | ".join(_cell(c) for c in cells) + " |")
    return out


def findings_markdown(spec: Spec, base: Path, rows: list[dict], plots: list[Path],
                      table_rows: list[dict] | None = None) -> str:
    """`rows`: the points that succeeded (findings); `table_rows`: every point the spec names."""
    table_rows = rows if table_rows is None else table_rows
    lines = [f"# Sweep {base.name}", "", f"Generated by `retrosim sweep {spec.path.name}` from `{base.name}.parquet` "
             f"({len(table_rows)} points"
             + (f", {len(table_rows) - len(rows)} failed" if len(table_rows) > len(rows) else "")
             + "); do not edit.", ""]
    if spec.description:
        lines += [spec.description.strip(), ""]
    found = findings(spec, rows)
    if found:
        lines += ["## Findings", ""] + [f"- {f}" for f in found] + [""]
    lines += [f"![{p.stem}]({p.name})" for p in plots] + [""]
    lines += ["## Results", ""] + results_table(spec, table_rows) + [""]
    return "\n".join(lines)
