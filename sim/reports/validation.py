"""Compare the models with published loop and block timings (`retrosim validate`).

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
from sim.guest import loop_program
from sim.timing import loop
from sim.reports import views
from sim.errors import RetrosimError
from sim.tomlfile import read_toml

VALIDATION_DIR = Path(__file__).resolve().parents[2] / "validation"
TABLES_DIR = Path(__file__).resolve().parents[1] / "cpus"  # each family's package: NAME/NAME_machine.toml
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


def machine_sources(family: str, tables_dir: Path = TABLES_DIR) -> list[str]:
    """Every source string of the family's machine parameters (`FAMILY_machine.toml`)."""
    path = tables_dir / family / f"{family}_machine.toml"
    if not path.is_file():
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
    walk(read_toml(path)[1])
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
    from sim.cpus import presets

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
    rows = views.explain_rows(t.result)
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


def run_family(fam: Family) -> FamilyResult:
    start = time.perf_counter()
    machine = machine_sources(fam.family)
    results = [run_case(c, fam.cpu, fam.keys_of(c), machine) for c in fam.cases]
    return FamilyResult(fam, results, time.perf_counter() - start)


# -- report ---------------------------------------------------------------------------------
_COUNTERS = ("uops", "decode_groups", "port0", "port1", "port2", "port3", "port4", "msrom_uops", "vector_cycles")


def _where(r: CaseResult) -> str:
    """The counters that say where the model's cycles go (per iteration), largest stalls first."""
    p = r.per_iteration
    stalls = sorted(((p.get(k, 0), k[6:].replace("_", " ")) for k in views.STALLS if p.get(k)), reverse=True)
    parts = [f"{k.replace('_', ' ')} {p[k]:g}" for k in _COUNTERS if p.get(k)]
    text = ", ".join(parts)
    if stalls:
        text += "; stall cycles: " + ", ".join(f"{what} {v:g}" for v, what in stalls[:4])
    return text


def _rows_used(r: CaseResult) -> str:
    return "; ".join(dict.fromkeys(f"{row['instruction'].split()[0]}: {row['row']}" for row in r.rows))


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " / ")


def markdown(results: list[FamilyResult], command: str = "retrosim validate") -> str:
    out = ["# Validation against published loop timings", "",
           f"Generated by `{command}`. Each case is a loop body or block timed with `retrosim loop` on the "
           "family's preset (steady state: cycles between iterations 20 and 40 of a warm second pass) and "
           "compared with a published measurement of the same code. No table row, machine parameter or test "
           "was fitted to these figures; where the model misses, the miss is shown, not tuned away. The cases, "
           "their sources and their loop bodies are in `validation/*.toml`.", "",
           "Error is model minus published, in core clocks per iteration of the body; MAPE is the mean "
           "absolute percentage error. *Same source* names the table rows (by the row used) or machine "
           "parameters that cite the case's publication for the same figures (each source's `row_keys` in the "
           "case file: for InstLatX64 dumps, the tables' InstLat citations of sibling cores; for a worked "
           "example, the section whose per-instruction figures or rule the example restates). Those cases agree "
           "by construction more than by prediction, so the independent subset (\"-\" in that column) is "
           "summarised on its own.", "",
           "## Summary", "",
           "| family | preset | cases | MAPE | within 1 cycle | independent cases | MAPE (independent) | within 1 (independent) | harness errors |",
           "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for fr in results:
        ind = fr.independent
        pct = lambda x: "-" if x != x else f"{x:.1f} %"  # noqa: E731  (nan: no case in the subset)
        share = lambda x: "-" if x != x else f"{x:.0%}"  # noqa: E731
        out.append(f"| {fr.family.family} | {fr.family.cpu} | {len(fr.timed)} | {pct(fr.mape())} | "
                   f"{share(fr.within_one())} | {len(ind)} | {pct(fr.mape(ind))} | {share(fr.within_one(ind))} | "
                   f"{len(fr.results) - len(fr.timed)} |")
    for fr in results:
        dep = [r for r in fr.timed if not r.independent]
        il = sum(any(cites(d, k) for d in r.dependence for k in INSTLAT_KEYS) for r in dep)
        out += ["", f"{fr.family.family.upper()}: {len(dep)} of {len(fr.timed)} timed cases are not independent"
                    + (f" ({il} of them because a table row cites InstLatX64 dumps of a sibling core: the "
                       "measurements come from a chip whose dump no row cites, so no figure was fitted to them, "
                       "but agreement there confirms the harness more than the model)" if il else "")
                    + f"; {len(fr.independent)} {'is' if len(fr.independent) == 1 else 'are'} independent."]
    for fr in results:
        fam = fr.family
        out += ["", f"## {fam.family.upper()} on {fam.cpu}", "", fam.cpu_note, "", "Sources:", ""]
        out += [f"- **{k}**: {v.text}" + (f" (same figures cited in the tables as: {', '.join(v.row_keys)})"
                                          if v.row_keys else "") for k, v in fam.sources.items()]
        out += ["", "| case | body | published | model | error | error % | same source | source |",
                "|---|---|---:|---:|---:|---:|:-:|---|"]
        for r in fr.results:
            c = r.case
            if r.model is None:
                out.append(f"| {_cell(c.name)} | `{_cell(c.body)}` | {c.published:g} | - | - | - | - | "
                           f"{_cell(c.source)} (harness error: {_cell(r.error or '')}) |")
                continue
            cpu = f" (on {c.cpu})" if c.cpu and c.cpu != fam.cpu else ""
            out.append(f"| {_cell(c.name)}{cpu} | `{_cell(c.body)}` | {c.published:g} | {r.model:.2f} | "
                       f"{r.model - c.published:+.2f} | {100 * (r.model - c.published) / c.published:+.0f} % | "
                       f"{_cell('; '.join(r.dependence)) or '-'} | {_cell(c.source)} |")
        worst = sorted(fr.timed, key=lambda r: r.rel_error, reverse=True)[:10]
        worst_ind = sorted(fr.independent, key=lambda r: r.rel_error, reverse=True)[:5]
        worst += [r for r in worst_ind if r not in worst]
        out += ["", f"### The ten worst {fam.family.upper()} cases (and the five worst independent ones): "
                    "where the model's cycles go", "",
                "| case | published | model | counters per iteration | table rows used |", "|---|---:|---:|---|---|"]
        for r in worst:
            out.append(f"| {_cell(r.case.name)} | {r.case.published:g} | {r.model:.2f} | {_cell(_where(r))} | "
                       f"{_cell(_rows_used(r))} |")
        notes = [r for r in fr.results if r.case.note]
        if notes:
            out += ["", "Notes on misses:", ""] + [f"- **{r.case.name}**: {r.case.note}" for r in notes]
    out += ["", f"Run time: {sum(fr.seconds for fr in results):.1f} s for "
                f"{sum(len(fr.results) for fr in results)} cases.", ""]
    return "\n".join(out)
