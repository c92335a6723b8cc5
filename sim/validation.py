"""Compare the models with published loop and block timings (`retrosim validate`).

Cases live in `validation/FAMILY.toml`: a loop body or block (as `retrosim loop` takes it), the
published cycles per iteration and the publication. Each case is timed with the loop harness on the
file's CPU preset; the report gives per-case error, MAPE and the share within one cycle per family,
and for the ten worst cases the counters that say where the model's cycles go. Nothing here feeds
back into the models: a miss is reported, never tuned away.
"""

from __future__ import annotations

import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from . import loop, views
from .errors import RetrosimError

VALIDATION_DIR = Path(__file__).resolve().parent.parent / "validation"
ITERATIONS = 40  # per pass; cycles are taken over iterations 20..40 of the second pass


@dataclass(frozen=True)
class Case:
    name: str
    body: str
    published: float
    source: str
    regs: tuple[str, ...] = ()
    note: str = ""


@dataclass
class Family:
    family: str
    cpu: str
    cpu_note: str
    sources: dict[str, str]
    cases: list[Case]
    path: Path


@dataclass
class CaseResult:
    case: Case
    model: float | None = None
    error: str | None = None                              # a case the harness could not run
    per_iteration: dict[str, float] = field(default_factory=dict)
    rows: list[dict] = field(default_factory=list)        # explain rows (table row, its source)

    @property
    def abs_error(self) -> float:
        return abs(self.model - self.case.published)

    @property
    def rel_error(self) -> float:
        return self.abs_error / self.case.published

    @property
    def row_cites_instlat(self) -> bool:
        """Whether a table row used by the case names InstLatX64 as its source (not independent)."""
        return any("instlat" in (r.get("source") or "").lower() or "il-" in (r.get("source") or "").lower()
                   for r in self.rows)


def load_family(path: Path) -> Family:
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise RetrosimError(f"{path}: {e}") from None
    for key in ("family", "cpu", "case"):
        if key not in data:
            raise RetrosimError(f"{path}: missing '{key}'")
    cases = []
    for i, c in enumerate(data["case"], 1):
        missing = [k for k in ("name", "body", "published", "source") if k not in c]
        if missing:
            raise RetrosimError(f"{path}: case {i}: missing {', '.join(missing)}")
        if not isinstance(c["published"], (int, float)) or c["published"] <= 0:
            raise RetrosimError(f"{path}: case {i} '{c['name']}': published must be a positive number")
        cases.append(Case(c["name"], c["body"], float(c["published"]), c["source"], tuple(c.get("regs", ())),
                          c.get("note", "")))
    return Family(data["family"], data["cpu"], data.get("cpu_note", ""), dict(data.get("sources", {})), cases, path)


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


def run_case(case: Case, cpu: str) -> CaseResult:
    try:
        t, = loop.time_body(case.body, [cpu], name=case.name, iterations=ITERATIONS,
                            regs=loop.parse_regs(case.regs), timeline_iterations=0)
    except RetrosimError as e:
        return CaseResult(case, error=str(e))
    return CaseResult(case, t.cycles_per_iteration, None, t.per_iteration, views.explain_rows(t.result))


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
        return 100 * sum(r.rel_error for r in rs) / len(rs) if rs else float("nan")

    def within_one(self, subset=None) -> float:
        rs = self.timed if subset is None else subset
        return sum(r.abs_error <= 1.0 for r in rs) / len(rs) if rs else float("nan")

    @property
    def independent(self) -> list[CaseResult]:
        return [r for r in self.timed if not r.row_cites_instlat]


def run_family(fam: Family) -> FamilyResult:
    start = time.perf_counter()
    results = [run_case(c, fam.cpu) for c in fam.cases]
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
           "absolute percentage error. *Row cites InstLat* marks cases whose instruction-table row names "
           "InstLatX64 measurements (of a sibling core) as its source: those agree by construction more than "
           "by prediction, so the independent subset is summarised on its own line.", "",
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
        dep = len(fr.timed) - len(fr.independent)
        out += ["", f"{fr.family.family.upper()}: {dep} of {len(fr.timed)} timed cases use a table row that cites "
                    "InstLatX64 dumps of a sibling core. The measurements here come from a chip whose dump no row "
                    "cites, so no figure was fitted to them, but where a row took the same instruction's figure from "
                    "a sibling, agreement confirms the harness more than the model; the misses, and the cases with "
                    "more than one instruction (store-load round trips, PUSH+POP, the string and flag pairs), are "
                    "the informative part."]
    for fr in results:
        fam = fr.family
        out += ["", f"## {fam.family.upper()} on {fam.cpu}", "", fam.cpu_note, "", "Sources:", ""]
        out += [f"- **{k}**: {v}" for k, v in fam.sources.items()]
        out += ["", "| case | body | published | model | error | error % | row cites InstLat | source |",
                "|---|---|---:|---:|---:|---:|:-:|---|"]
        for r in fr.results:
            c = r.case
            if r.model is None:
                out.append(f"| {_cell(c.name)} | `{_cell(c.body)}` | {c.published:g} | - | - | - | - | "
                           f"{_cell(c.source)} (harness error: {_cell(r.error or '')}) |")
                continue
            out.append(f"| {_cell(c.name)} | `{_cell(c.body)}` | {c.published:g} | {r.model:.2f} | "
                       f"{r.model - c.published:+.2f} | {100 * (r.model - c.published) / c.published:+.0f} % | "
                       f"{'yes' if r.row_cites_instlat else 'no'} | {_cell(c.source)} |")
        worst = sorted(fr.timed, key=lambda r: r.rel_error, reverse=True)[:10]
        out += ["", f"### The ten worst {fam.family.upper()} cases: where the model's cycles go", "",
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
