"""Sort scenes ([scene] kind = "sort"): the format and its loader. The kind's other parts: keys.py
(the key distributions), variants.py (the kernels and the correctness check), runner.py (runs
it), report.py (claims and reports); sim.scenes.registry joins them (sim.scenes.kind).

Format::

    [scene]
    name = "sort"                   # required; must equal the file stem
    kind = "sort"                   # required here
    description = "..."             # optional

    [keys]
    distributions = ["uniform", "sorted", "zbuffer"]   # required: sim.scenes.sort.keys.DISTRIBUTIONS
    seed = 2011                     # required
    zbuffer_scene = "zbuffer-article"   # required with "zbuffer": a Z-buffer scene file in this
                                    #   file's folder, whose frame's depth codes are the keys
    table_size = 1024               # required: every variant on every distribution at this size
    sizes = [256, 1024, 4096]       # optional (default [table_size]): the size sweep, 1..65,536
    sweep_distributions = ["uniform"]   # optional (default the first distribution): the sweep's

    [clamp]                         # optional: the clamp variants' bounds (0 <= lo <= hi <= 65535)
    lo = 16384                      #   (default 16384)
    hi = 49152                      #   (default 49152)

    [run]
    variants = ["quicksort", "radix8"]       # required: sim.scenes.sort.variants.VARIANTS
    cpus = ["pentium-mmx-166", "k6-2-300"]   # required: CPU preset[:memory preset]
    max_size = { insertion = 1024 }          # optional: the largest size a variant is run at
                                             #   (the sweep's other sizes skip it); table_size
                                             #   must not exceed it
    limits = "..."                  # optional: why the sizes and limits are what they are (in the report)

    [[claims]]                      # optional, repeatable
    text = "..."                    # required
    expect = "faster"               # required: faster | slower (variants[0] against variants[1],
                                    #   cycles per key at `size` on `distribution`), linear (every
                                    #   variant's cycles per key over `sizes` within tolerance:
                                    #   largest / smallest <= 1 + tolerance), distribution-independent
                                    #   (every variant's cycles per key over `distributions` at `size`
                                    #   within tolerance, the same way)
    variants = ["merge-sbb", "merge-branchy"]   # required: of run.variants (two for faster/slower)
    cpus = ["k6-2-300"]             # the machines it covers: presets and/or
    families = ["FAMILY"]           #   CPU families by name, see `retrosim cpus` (at least one machine of run.cpus)
    distribution = "uniform"        # faster/slower, linear (default the first sweep distribution)
    distributions = ["uniform"]     # distribution-independent (default every table distribution)
    size = 1024                     # faster/slower, distribution-independent (default table_size)
    sizes = [1024, 65536]           # linear: the range of sweep sizes it covers (default all)
    tolerance = 0.0                 # optional fraction (faster/slower: the margin; default 0)

A claim's runs must exist: its size and distribution are the table's (table_size, every
distribution) or the sweep's (a size of sizes, a sweep distribution), and each of its variants is
run there (max_size). A variant whose instruction set a covered CPU lacks (CMOV on the P5 and K6)
is not timed there; the claim says so for that CPU.

A scene builds only what it names: the variants' kernels, the distributions' keys (the Z-buffer
scene is loaded and rasterized only for "zbuffer"), its presets. Every problem is one SceneError
naming the file, line and field.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from sim.scenes.claims import Claim
from sim.scenes.schema import (CLAIM_CPUS, CLAIM_FAMILIES, CLAIM_TEXT, SCENE_DESCRIPTION, SCENE_KIND, SCENE_NAME,
                               SEED_RANGE, CpuChoice, Field, Validator, show)
from sim.scenes.sort import keys as K
from sim.scenes.sort.variants import VARIANTS

MAX_KEYS = 1 << 16  # the range (256 to 64 K); 16-bit keys, and the arena holds 3 x 128 KB
TIMED = ("faster", "slower")
SHAPES = ("linear", "distribution-independent")
SCENE = (SCENE_NAME, SCENE_KIND, SCENE_DESCRIPTION)
KEYS = (Field("distributions", "strlist", True, nonempty=True, unique=True, choices=tuple(K.DISTRIBUTIONS), noun="distribution"),
        Field("seed", "int", True, span=SEED_RANGE),
        Field("zbuffer_scene", "str", doc="a Z-buffer scene file next to this one, whose depth codes are the keys"),
        Field("table_size", "int", True, span=(1, MAX_KEYS + 1, f"between 1 and {MAX_KEYS:,} keys")),
        Field("sizes", "intlist", doc="the size sweep (default [table_size])"),
        Field("sweep_distributions", "strlist", nonempty=True, unique=True, choices=tuple(K.DISTRIBUTIONS), noun="distribution"))
CLAMP = (Field("lo", "int", default=16384), Field("hi", "int", default=49152))
RUN = (Field("variants", "strlist", True, nonempty=True, unique=True, choices=tuple(VARIANTS), noun="variant"),
       Field("cpus", "strlist", True, nonempty=True, unique=True, doc="CPU preset[:memory preset]"),
       Field("max_size", "table", doc="{ variant = keys }: the largest size a variant runs at"),
       Field("limits", "str", default="", doc="why the sizes and limits are what they are"))
CLAIM = (CLAIM_TEXT, Field("expect", "str", True, choices=TIMED + SHAPES, noun="expectation"),
         Field("variants", "strlist", True), CLAIM_CPUS, CLAIM_FAMILIES,
         # which runs it compares (read once expect says which of them it takes; defaults: the table's)
         Field("distribution", "str"), Field("distributions", "strlist"), Field("size", "int"), Field("sizes", "intlist"),
         Field("tolerance", "number", default=0.0, span=(0, 10, "between 0 and 10")))
CLAIM_RUNS = tuple(f for f in CLAIM if f.name in ("distribution", "distributions", "size", "sizes"))


@dataclass(frozen=True)
class SortClaim(Claim):
    distributions: tuple[str, ...] = ()   # one for faster/slower and linear
    sizes: tuple[int, ...] = ()           # one for faster/slower and distribution-independent

    def describe_coverage(self) -> str:
        parts = [f"the {f.upper()} family" for f in self.families] + list(self.cpus)
        return ", ".join(parts)


@dataclass(frozen=True)
class SortScene:
    path: Path
    name: str
    description: str
    distributions: tuple[str, ...]
    seed: int
    zbuffer_scene: str | None
    table_size: int
    sizes: tuple[int, ...]
    sweep_distributions: tuple[str, ...]
    clamp: tuple[int, int]
    variants: tuple[str, ...]
    machines: tuple[CpuChoice, ...]
    max_size: dict = field(default_factory=dict)
    limits: str = ""
    claims: tuple[SortClaim, ...] = ()
    kind = "sort"

    @property
    def cpus(self) -> list[str]:
        return [m.label for m in self.machines]

    @property
    def zbuffer_path(self) -> Path | None:
        return self.path.parent / f"{self.zbuffer_scene}.toml" if self.zbuffer_scene else None

    def runs(self, variant: str, size: int) -> bool:
        return size <= self.max_size.get(variant, MAX_KEYS)

    def cases(self) -> list[tuple[str, str, int]]:
        """Every (variant, distribution, size) the scene runs: the table, then the sweep, in order,
        each once."""
        out = [(v, d, self.table_size) for v in self.variants for d in self.distributions]
        out += [(v, d, n) for v in self.variants for d in self.sweep_distributions for n in self.sizes
                if self.runs(v, n)]
        return list(dict.fromkeys(out))

    @property
    def needs(self) -> dict:
        """What running it builds: the kernels, their entry points, the distributions (the
        Z-buffer scene only for "zbuffer"), the presets."""
        vs = [VARIANTS[v] for v in self.variants]
        return {"kernels": list(dict.fromkeys(v.file for v in vs)), "entries": [v.entry for v in vs],
                "distributions": list(dict.fromkeys(self.distributions + self.sweep_distributions)),
                "zbuffer_scene": self.zbuffer_scene if K.ZBUFFER in self.distributions + self.sweep_distributions else None,
                "cpus": list(dict.fromkeys(m.preset for m in self.machines))}


def _sizes_ok(v: Validator, sizes, field: str, table: str, key: str, index: int | None = None) -> None:
    for i, n in enumerate(sizes):
        if not 1 <= n <= MAX_KEYS:
            v.fail(f"{field}[{i}]", f"must be between 1 and {MAX_KEYS:,} keys, got {n}", table, key, index)
        if n in sizes[:i]:
            v.fail(f"{field}[{i}]", f"{n} is listed twice", table, key, index)


def load(path: Path, text: str, doc: dict) -> SortScene:
    """Validate a parsed kind = "sort" scene (sim.scenes.registry.load_scene reads the file and dispatches)."""
    v = Validator(path, text)
    sc = v.scene_header(doc, "sort", ("scene", "keys", "clamp", "run", "claims"), SCENE)
    name, description = sc["name"], sc["description"]

    kt = v.section(v.table(doc, "keys"), KEYS, "keys")
    dists, seed, zscene, table_size = kt["distributions"], kt["seed"], kt["zbuffer_scene"], kt["table_size"]
    sizes = kt["sizes"] or (table_size,)
    sweep = dists[:1] if kt["sweep_distributions"] is None else kt["sweep_distributions"]
    _sizes_ok(v, sizes, "keys.sizes", "keys", "sizes")
    if K.ZBUFFER in dists + sweep:
        if zscene is None:
            v.fail("keys.zbuffer_scene", "required with the 'zbuffer' distribution: the Z-buffer scene whose depth "
                   "codes are the keys", "keys", None)
        zpath = path.parent / f"{zscene}.toml"
        if not zpath.is_file():
            v.fail("keys.zbuffer_scene", f"no Z-buffer scene '{zscene}' next to this file ({zpath})", "keys",
                   "zbuffer_scene")
    elif zscene is not None:
        v.fail("keys.zbuffer_scene", "given, but no distribution is 'zbuffer'", "keys", "zbuffer_scene")

    ct = v.section(v.table(doc, "clamp", required=False), CLAMP, "clamp")
    lo, hi = ct["lo"], ct["hi"]
    if not 0 <= lo <= hi <= 0xFFFF:
        v.fail("clamp", f"need 0 <= lo <= hi <= 65535, got lo {lo}, hi {hi}", "clamp", None)

    ru = v.section(v.table(doc, "run"), RUN, "run")
    variants, cpus, limits = ru["variants"], ru["cpus"], ru["limits"]
    max_size = {} if ru["max_size"] is None else ru["max_size"]
    if not isinstance(max_size, dict):
        v.fail("run.max_size", f"expected a table {{ variant = keys }}, got {show(max_size)}", "run", "max_size")
    for x, n in max_size.items():
        if x not in variants:
            v.fail(f"run.max_size.{x}", f"not one of run.variants ({', '.join(variants)})", "run", "max_size")
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= MAX_KEYS:
            v.fail(f"run.max_size.{x}", f"expected a number of keys from 1 to {MAX_KEYS:,}, got {show(n)}", "run",
                   "max_size")
        if n < table_size:
            v.fail(f"run.max_size.{x}", f"{n} is below keys.table_size ({table_size}): the table runs every variant",
                   "run", "max_size")
    machines = v.machines(cpus)

    scene_cases = None
    claims = []
    for i, c in enumerate(v.claim_tables(doc)):
        f = f"claims[{i}]"
        cl = v.section(c, CLAIM, "claims", i, f, later=CLAIM_RUNS)
        expect, names, ccpus, families = cl["expect"], cl["variants"], cl["cpus"], cl["families"]
        need = 2 if expect in TIMED else None
        if not names or (need and len(names) != need) or any(x not in variants for x in names):
            v.fail(f"{f}.variants", f"expected {'two' if need else 'one or more'} of run.variants "
                   f"({', '.join(variants)}), got {show(list(names))}", "claims", "variants", i)
        v.claim_cpus(f, i, ccpus)
        v.families(f, families, i)
        if not ccpus and not families:
            v.fail(f, "names no CPU: give cpus = [...] and/or families = [...]", "claims", None, i)
        allowed = {"faster": ("distribution", "size"), "slower": ("distribution", "size"),
                   "linear": ("distribution", "sizes"), "distribution-independent": ("distributions", "size")}[expect]
        for key in ("distribution", "distributions", "size", "sizes"):
            if key in c and key not in allowed:
                v.fail(f"{f}.{key}", f"not used by expect = '{expect}' (it takes {' and '.join(allowed)})",
                       "claims", key, i)
        default_dist = sweep[0] if expect == "linear" else dists[0]
        runs = v.values(c, CLAIM_RUNS, "claims", i, f)
        dist = default_dist if runs["distribution"] is None else runs["distribution"]
        cdists = dists if runs["distributions"] is None else runs["distributions"]
        size = table_size if runs["size"] is None else runs["size"]
        csizes = runs["sizes"] or sizes
        for key, given in (("distribution", [dist]), ("distributions", cdists)):  # a typo: say so, by name
            for d in given:
                if d not in K.DISTRIBUTIONS:
                    v.fail(f"{f}.{key}", f"unknown distribution '{d}' (known: {', '.join(K.DISTRIBUTIONS)})",
                           "claims", key, i)
        if expect in SHAPES:
            what, n_of = ("sizes", len(csizes)) if expect == "linear" else ("distributions", len(cdists))
            if n_of < 2:
                v.fail(f"{f}.{what}", f"needs at least two {what} to compare", "claims", what, i)
        if scene_cases is None:
            scene_cases = set(SortScene(path, name, description, tuple(dists), seed, zscene, table_size, tuple(sizes),
                                        tuple(sweep), (lo, hi), tuple(variants), tuple(machines), max_size).cases())
        wanted = ([(x, dist, size) for x in names] if expect in TIMED else
                  [(x, dist, n) for x in names for n in csizes] if expect == "linear" else
                  [(x, d, size) for x in names for d in cdists])
        for case in wanted:
            if case not in scene_cases:
                v.fail(f, f"the scene does not run {case[0]} on {case[1]} keys at size {case[2]} (claims use the "
                       "table's or the sweep's runs: keys.table_size with keys.distributions, keys.sizes with "
                       "keys.sweep_distributions, within run.max_size)", "claims", None, i)
        claim = SortClaim(cl["text"], tuple(names), expect, cl["tolerance"], ccpus, families,
                          distributions=tuple(cdists) if expect == "distribution-independent" else (dist,),
                          sizes=tuple(csizes) if expect == "linear" else (size,))
        v.require_cover(f, i, machines, claim)
        claims.append(claim)
    return SortScene(path, name, description, tuple(dists), seed, zscene, table_size, tuple(sizes), tuple(sweep),
                     (lo, hi), tuple(variants), tuple(machines), max_size, limits, tuple(claims))
