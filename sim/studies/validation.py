"""Compare the models with published loop and block timings (`retrosim validate`), a study: it
times the cases and hands its results to the report (sim/reports/validation.py, which only renders).

Cases live in `validation/FAMILY.toml`: a loop body or block (as `retrosim loop` takes it), the
published cycles per iteration and the publication. Each case is timed with the loop harness on the
file's CPU preset (or the case's own `cpu`); the report gives per-case error, MAPE and the share
within one cycle per family, and for the ten worst cases the counters that say where the model's
cycles go. Nothing here feeds back into the models: a miss is reported, never tuned away.

Independence: a case agrees "by construction" when the model took the figure it tests from the same
publication. Each source in a file names `row_keys`, the citation keys under which the instruction
tables and machine parameters cite that publication for the same figures (InstLatX64 sources get
"InstLat" and "IL-" by default: the tables cite sibling chips' dumps of the same tests). A case is
independent when neither a table row it uses nor the family's machine parameters cite one of its
source's keys (or the case's own extra `row_keys`, for a rule such as an AGI penalty that the
published figure includes).
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass, field
from pathlib import Path

from sim import stats
from sim.cpus import presets
from sim.cpus.families import FAMILIES
from sim.guest import loop_program
from sim.timing import loop
from sim.reports.views import explain_rows
from sim.errors import RetrosimError
from sim.tomlfile import read_toml

VALIDATION_DIR = Path(__file__).resolve().parents[2] / "validation"
INSTLAT_KEYS = ("InstLat", "IL-")  # how the tables cite InstLatX64 dumps
ITERATIONS = 40  # per pass; cycles are taken over iterations 20..40 of the second pass


@dataclass(frozen=True)
class Case:
    name: str
    body: str
    published: float
    source: str
    regs: tuple[str, ...] = ()
    note: str = ""
    cpu: str | None = None               # a preset other than the file's (e.g. the Pentium MMX)
    row_keys: tuple[str, ...] = ()       # extra citation keys of the same figures (see module doc)


@dataclass(frozen=True)
class Source:
    text: str
    row_keys: tuple[str, ...] = ()       # citation keys under which the tables cite the same figures


@dataclass
class Family:
    family: str
    cpu: str
    cpu_note: str
    sources: dict[str, Source]
    cases: list[Case]
    path: Path

    def source_of(self, case: Case) -> Source | None:
        return self.sources.get(case.source.split()[0]) if case.source.split() else None

    def keys_of(self, case: Case) -> tuple[str, ...]:
        src = self.source_of(case)
        return (src.row_keys if src else ()) + case.row_keys


@dataclass
class CaseResult:
    case: Case
    model: float | None = None
    error: str | None = None                              # a case the harness could not run
    per_iteration: dict[str, float] = field(default_factory=dict)
    rows: list[dict] = field(default_factory=list)        # explain rows (table row, its source)
    dependence: list[str] = field(default_factory=list)   # "row X: key" / "machine: key" citing the same figures

    @property
    def abs_error(self) -> float:
        return abs(self.model - self.case.published)

    @property
    def rel_error(self) -> float:
        return self.abs_error / self.case.published

    @property
    def independent(self) -> bool:
        return self.model is not None and not self.dependence


def cites(text: str, key: str) -> bool:
    """Whether a citation string names `key` as a key of its own ("AF9" is not "AF99" nor "AF9x";
    a key ending in a separator, such as "IL-", is a prefix: "IL-K6")."""
    tail = r"(?![A-Za-z0-9])" if key[-1:].isalnum() else ""
    return re.search(r"(?<![A-Za-z0-9])" + re.escape(key) + tail, text, re.IGNORECASE) is not None


def machine_sources(family: str) -> list[str]:
    """Every source string of the family's machine parameters (its machine table, through the
    family registry; none for a family not registered)."""
    if family not in FAMILIES:
        return []
    out: list[str] = []

    def walk(node):
        if isinstance(node, dict):
            for k, v in node.items():
                if isinstance(v, str) and "source" in k:
                    out.append(v)
                else:
                    walk(v)
        elif isinstance(node, list):
            for v in node:
                walk(v)
    walk(FAMILIES[family].machine)
    return out


def dependence(rows: list[dict], machine: list[str], keys: tuple[str, ...]) -> list[str]:
    """Which table rows (by instruction) and machine parameters cite one of `keys`."""
    found = []
    for r in rows:
        hit = [k for k in keys if cites(r.get("source") or "", k)]
        if hit:
            found.append(f"row {r['row']}: {hit[0]}")
    for k in keys:
        if any(cites(m, k) for m in machine):
            found.append(f"machine: {k}")
    return list(dict.fromkeys(found))


def _str_list(value, where: str) -> tuple[str, ...]:
    if not isinstance(value, list) or not all(isinstance(x, str) and x.strip() for x in value):  # "AF9" is not a list
        raise RetrosimError(f"{where}: must be a list of non-empty strings")
    return tuple(value)


def _source(key: str, value, path: Path) -> Source:
    where = f"{path}: [sources] {key}"
    if isinstance(value, str):
        text, keys = value, None
    elif isinstance(value, dict):
        unknown = set(value) - {"text", "row_keys"}
        if unknown or not isinstance(value.get("text"), str):
            raise RetrosimError(f"{where}: expected a string or {{text = \"...\", row_keys = [...]}}"
                                + (f" (unknown field {', '.join(sorted(unknown))})" if unknown else ""))
        text, keys = value["text"], value.get("row_keys")
    else:
        raise RetrosimError(f"{where}: expected a string or a table, got {type(value).__name__}")
    if keys is None:
        keys = list(INSTLAT_KEYS) if "instlat" in text.lower() else []
    return Source(text, _str_list(keys, f"{where}.row_keys"))


_CASE_FIELDS = {"name": str, "body": str, "published": (int, float), "source": str, "regs": list, "note": str,
                "cpu": str, "row_keys": list}


def load_family(path: Path) -> Family:
    _, data = read_toml(path, "validation case file")
    for key in ("family", "cpu", "case"):
        if key not in data:
            raise RetrosimError(f"{path}: missing '{key}'")
    if not isinstance(data["case"], list):
        raise RetrosimError(f"{path}: 'case' must be an array of tables ([[case]])")
    known = set(presets.available())
    for where, cpu in [("cpu", data["cpu"])]:
        if cpu not in known:
            raise RetrosimError(f"{path}: {where} '{cpu}' is not a CPU preset (have: {', '.join(sorted(known))})")
    sources = {k: _source(k, v, path) for k, v in dict(data.get("sources", {})).items()}
    cases = []
    for i, c in enumerate(data["case"], 1):
        missing = [k for k in ("name", "body", "published", "source") if k not in c]
        if missing:
            raise RetrosimError(f"{path}: case {i}: missing {', '.join(missing)}")
        label = f"{path}: case {i} '{c['name']}'"
        for k, v in c.items():
            if k not in _CASE_FIELDS:
                raise RetrosimError(f"{label}: unknown field '{k}' (fields: {', '.join(_CASE_FIELDS)})")
            if not isinstance(v, _CASE_FIELDS[k]) or isinstance(v, bool):
                raise RetrosimError(f"{label}: field '{k}' has the wrong type ({type(v).__name__})")
        if c["published"] <= 0:
            raise RetrosimError(f"{label}: published must be a positive number")
        if sources and c["source"].split()[:1] and c["source"].split()[0] not in sources:
            raise RetrosimError(f"{label}: source key '{c['source'].split()[0]}' is not in [sources]")
        if "cpu" in c and c["cpu"] not in known:
            raise RetrosimError(f"{label}: cpu '{c['cpu']}' is not a CPU preset")
        cases.append(Case(c["name"], c["body"], float(c["published"]), c["source"],
                          _str_list(c.get("regs", []), f"{label}: regs") if c.get("regs") else (),
                          c.get("note", ""), c.get("cpu"),
                          _str_list(c.get("row_keys", []), f"{label}: row_keys") if c.get("row_keys") else ()))
    return Family(data["family"], data["cpu"], data.get("cpu_note", ""), sources, cases, path)


def families(directory: Path = VALIDATION_DIR, only: list[str] | None = None) -> list[Family]:
    paths = sorted(directory.glob("*.toml"))
    fams = [load_family(p) for p in paths]
    if only:
        unknown = set(only) - {f.family for f in fams}
        if unknown:
            raise RetrosimError(f"no validation cases for {', '.join(sorted(unknown))} "
                                f"(have: {', '.join(f.family for f in fams)})")
        fams = [f for f in fams if f.family in only]
    return fams


def run_case(case: Case, cpu: str, keys: tuple[str, ...] = (), machine: list[str] | None = None) -> CaseResult:
    try:
        t, = loop.time_body(case.body, [case.cpu or cpu], name=case.name, iterations=ITERATIONS,
                            regs=loop_program.parse_regs(case.regs), timeline_iterations=0)
    except RetrosimError as e:
        return CaseResult(case, error=str(e))
    rows = explain_rows(t.result)
    return CaseResult(case, t.cycles_per_iteration, None, t.per_iteration, rows,
                      dependence(rows, machine or [], keys))


@dataclass
class FamilyResult:
    family: Family
    results: list[CaseResult]
    seconds: float

    @property
    def timed(self) -> list[CaseResult]:
        return [r for r in self.results if r.model is not None]

    def mape(self, subset=None) -> float:
        rs = self.timed if subset is None else subset
        return 100 * stats.mean([r.rel_error for r in rs], float("nan"))  # exact, as every report statistic

    def within_one(self, subset=None) -> float:
        rs = self.timed if subset is None else subset
        return sum(r.abs_error <= 1.0 for r in rs) / len(rs) if rs else float("nan")

    @property
    def independent(self) -> list[CaseResult]:
        return [r for r in self.timed if r.independent]

    @property
    def dependent(self) -> list[CaseResult]:
        return [r for r in self.timed if not r.independent]

    def sibling_dump_cases(self) -> int:
        """Timed cases that are not independent because a row cites InstLatX64 dumps (of a sibling core)."""
        return sum(any(cites(d, k) for d in r.dependence for k in INSTLAT_KEYS) for r in self.dependent)


def run_family(fam: Family) -> FamilyResult:
    start = time.perf_counter()
    machine = machine_sources(fam.family)
    results = [run_case(c, fam.cpu, fam.keys_of(c), machine) for c in fam.cases]
    return FamilyResult(fam, results, time.perf_counter() - start)
