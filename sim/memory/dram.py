"""Main-memory timing: the cost of a 32-byte line fill or writeback over the front-side bus.

Presets live in ``sim/memory/presets/NAME.toml`` (field names and sources are the research
colleague's). Timings there are in *bus* clocks as an x-y-y-y burst: x for the first 64-bit
transfer (the lead-off: row/column access plus chipset), y for each of the three more transfers of
a 32-byte line (EDO 5-2-2-2 = 11, PC66 SDRAM 5-1-1-1 = 8, PC100 SDRAM 4-1-1-1 = 7).

Core clocks. A P6 or K6 core runs at a fixed multiple of the bus clock, always a multiple of 1/2
(3.5 for a Pentium II 233 on a 66 MHz bus), so the ratio is an exact fraction: the MHz figures in
the CPU presets are rounded (233.33 / 66.67 = 3.49978...), so :func:`bus_ratio` snaps their
quotient to the nearest quarter. A cost in core clocks is ``ceil(bus_clocks * ratio)``: the core
can only use the data at a core-clock edge, so a fraction of a core clock rounds *up* (EDO at 3.5:
11 x 3.5 = 38.5 -> 39). Integer arithmetic on fractions only, so every machine gets the same number.

Lead-off. A line fill's critical chunk reaches the core ``overhead + first transfer`` bus clocks
after the request: the memory preset gives the first transfer (its own row/column access), the
*board* adds the rest (bus arbitration and request phases, the chipset's DRAM controller, a board
cache's tag check). That overhead is a property of a CPU on a given board and chipset, not of the
memory, so it is not in the memory presets: the caller (the CPU model, from the CPU preset's
``[memory] overhead_bus_clocks``, calibrated there on a measured memory latency) passes it in.
It may be fractional (a measured latency rarely falls on whole bus clocks); the sum times the
core/bus ratio is rounded up as every other cost.

Bus tenure. On a bus whose cycle runs from the request to its last data transfer, one line fill
at a time (the Socket 7 bus of the K6 presets: AMD-K6 data sheet sec. 6.3), a fill holds the bus
for ``overhead + the whole burst`` (``LineCosts.fill_tenure``), not the burst alone: the next
fill's request waits for it, and a pointer chase's time per load is that tenure, which is what the
K6 presets' overheads are calibrated on.

Page mode (issue 24). A preset's ``[pages]`` table (:class:`PageModel`) gives its chipset's page
policy, the open pages it tracks (one per bank) and their size, and what a page hit saves against
a page miss. The data side's cache walk (sim/memory/hierarchy.py) keeps the open row of each bank
as machine state and marks each line fill and writeback that finds its row open; the cores charge
those at the open-page lead-off and bus time (``LineCosts.*_hit``). The calibrated lead-off is the
page-miss cost (a pointer chase misses every time), so chase latencies do not move.

Writebacks. A line writeback is a 4-transfer burst write: the read burst less the preset's
``write_saving_bus_clocks`` (SDRAM: a WRITE takes its data with the command, no CAS latency;
EDO/FPM: 0, an estimate), and less the page-hit saving when its row is open. A transfer's bus time
never falls below the three trailing transfers and one clock for the first.

Open rows. :func:`row_access` is a simple open-page model: one open row per bank; a line fill costs
``row_hit`` / ``row_closed`` / ``row_conflict`` lead-off clocks instead of the burst's first figure,
plus the same three transfers. Only presets that give row timings support it (PC100: 2 / 4 / 6 at
CL2, from the datasheet tRCD/tRP/CL; its 4-1-1-1 lead-off equals the closed-row figure, so the
quoted burst is the closed-row case). EDO and PC66 rows were not found: asking for them is an error,
not a guess. Row geometry defaults to a 64-bit DIMM built from 64 Mbit x8 SDRAM chips: 4 banks, rows
of 512 columns x 8 bytes = 4 KB (Micron 64Mb SDRAM MT48LC8M8A2 data sheet: "each of the x8's
16,777,216-bit banks is organized as 4,096 rows by 512 columns by 8 bits"). The address map
(column bits lowest, then bank, then row) is an assumption; chipsets differ.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import numpy as np
from numba import njit

from sim.memory.cache import HOT
from sim.tomlfile import read_toml

MEMORY_PRESETS_DIR = Path(__file__).resolve().parent / "presets"
TRANSFERS_PER_LINE = 4  # 32-byte line over the 64-bit P6/Socket 7 data bus

DEFAULT_ROW_BYTES = 4096
DEFAULT_BANKS = 4
ROW_GEOMETRY_SOURCE = ("Micron 64Mb SDRAM (MT48LC8M8A2) data sheet: x8 part = 4 banks x 4,096 rows x 512 "
                       "columns x 8 bits; eight x8 chips on a 64-bit DIMM give 512 x 8 B = 4 KB rows")

# Row states for row_access().
ROW_HIT, ROW_CLOSED, ROW_CONFLICT = 0, 1, 2


@dataclass(frozen=True)
class DramTiming:
    """One memory preset, in bus clocks. ``row_*`` are None when the preset has no row timings."""

    name: str
    kind: str
    bus_mhz: float
    burst: tuple[int, ...]
    source: str
    row_hit: int | None = None
    row_closed: int | None = None
    row_conflict: int | None = None
    writeback_estimated: bool = True
    pages: "PageModel | None" = None

    @property
    def first_access_bus_clocks(self) -> int:
        return self.burst[0]

    @property
    def burst_bus_clocks(self) -> int:
        """Clocks of the three transfers after the first."""
        return sum(self.burst[1:])

    @property
    def line_fill_bus_clocks(self) -> int:
        return sum(self.burst)

    @property
    def line_writeback_bus_clocks(self) -> int:
        """A line writeback on a page miss: the read burst less the write's saving (SDRAM: a WRITE
        takes its data with the command, no CAS latency; see :class:`PageModel`)."""
        return self.bus_busy(self.pages.write_saving_bus_clocks if self.pages else 0)

    def bus_busy(self, saving: int) -> int:
        """Bus clocks of a line transfer whose lead-off is ``saving`` clocks shorter than the
        read burst's: never below the three trailing transfers and one clock for the first."""
        return max(sum(self.burst) - saving, self.burst_bus_clocks + 1)

    @property
    def has_rows(self) -> bool:
        return self.row_hit is not None

    def describe(self) -> str:
        return f"{self.name} ({self.kind}, {'-'.join(map(str, self.burst))} at {self.bus_mhz:g} MHz)"


@dataclass(frozen=True)
class PageModel:
    """A chipset's page-mode behaviour (a memory preset's ``[pages]`` table): ``open_pages`` banks
    with one open row of ``page_bytes`` each (policy "open": a row stays open after an access until
    another row of its bank is needed); a line transfer whose row is open saves
    ``hit_saving_bus_clocks`` of the lead-off against a page miss (SDRAM: tRP + tRCD, the precharge
    and activate a hit skips; EDO/FPM: RAS precharge and RAS access against the CAS-only page-mode
    access). A write saves ``write_saving_bus_clocks`` more (SDRAM: the CAS latency).

    Calibration. The CPU presets' ``overhead_bus_clocks`` were calibrated on a pointer chase, which
    on an open-page chipset is a page miss every time, so the burst's lead-off (with that overhead)
    stays the page-miss cost and a page hit is cheaper by the saving: the chase latency is
    unchanged by construction."""

    chipset: str
    policy: str
    open_pages: int
    page_bytes: int
    hit_saving_bus_clocks: int
    write_saving_bus_clocks: int
    source: str
    estimated: tuple[str, ...] = ()
    # field -> (low, high, reason): the plausible range of each estimated figure ([pages.ranges]),
    # which the claims' robustness pass (sim/scenes/claims.py) times at both ends
    ranges: dict = field(default_factory=dict, compare=False)


# The [pages] figures an override may replace (``pages.FIELD``, sim/cpus/__init__.py): the savings
# only re-time; the geometry (open pages, page size) changes which accesses are page hits.
PAGE_FIELDS = ("hit_saving_bus_clocks", "write_saving_bus_clocks", "open_pages", "page_bytes")
PAGE_GEOMETRY = ("open_pages", "page_bytes")


def _page_ranges(t: dict, where: str, est: list[str], values: dict) -> dict:
    """[pages.ranges]: ``FIELD = { low = L, high = H, reason = "..." }`` for every estimated field
    (and only those), the model's figure inside."""
    r = t.get("ranges", {})
    if not isinstance(r, dict):
        raise ValueError(f"{where}: [pages.ranges] must be a table")
    for f in est:
        if f not in PAGE_FIELDS:
            raise ValueError(f"{where}: [pages] estimated names {f!r}, not one of {', '.join(PAGE_FIELDS)}")
    if set(r) != set(est):
        raise ValueError(f"{where}: [pages.ranges] must give a range for exactly the estimated fields "
                         f"({', '.join(est) or 'none'}), got {', '.join(r) or 'none'}")
    out = {}
    for f, spec in r.items():
        ok = (isinstance(spec, dict) and set(spec) == {"low", "high", "reason"}
              and all(type(spec[k]) is int for k in ("low", "high")) and isinstance(spec["reason"], str)
              and spec["reason"].strip())
        if not ok:
            raise ValueError(f"{where}: [pages.ranges] {f} must be {{ low = INT, high = INT, reason = \"...\" }}")
        if not 0 <= spec["low"] <= values[f] <= spec["high"]:
            raise ValueError(f"{where}: [pages.ranges] {f} = {spec['low']}..{spec['high']} does not hold "
                             f"the model's {values[f]}")
        if f in PAGE_GEOMETRY and any(v <= 0 or v & (v - 1) for v in (spec["low"], spec["high"])):
            raise ValueError(f"{where}: [pages.ranges] {f} ends must be powers of two, got {spec['low']}..{spec['high']}")
        out[f] = (spec["low"], spec["high"], spec["reason"].strip())
    return out


def _page_model(d: dict, where: str, first_transfer: int) -> PageModel | None:
    t = d.get("pages")
    if t is None:
        return None
    if not isinstance(t, dict):
        raise ValueError(f"{where}: [pages] must be a table")

    def need(field, kind):
        if field not in t:
            raise ValueError(f"{where}: [pages] is missing {field!r}")
        v = t[field]
        if not isinstance(v, kind) or isinstance(v, bool):
            raise ValueError(f"{where}: [pages] {field} = {v!r} is not a {kind.__name__}")
        return v

    policy = need("policy", str)
    if policy not in ("open", "closed"):
        raise ValueError(f"{where}: [pages] policy must be 'open' or 'closed', got {policy!r}")
    n, size = need("open_pages", int), need("page_bytes", int)
    for what, v in (("open_pages", n), ("page_bytes", size)):
        if v <= 0 or v & (v - 1):
            raise ValueError(f"{where}: [pages] {what} must be a power of two, got {v}")
    hit, wr = need("hit_saving_bus_clocks", int), need("write_saving_bus_clocks", int)
    if hit < 0 or wr < 0:
        raise ValueError(f"{where}: [pages] savings must be >= 0, got {hit} on a hit, {wr} on a write")
    est = t.get("estimated", [])
    if not isinstance(est, list) or not all(isinstance(x, str) for x in est):
        raise ValueError(f"{where}: [pages] estimated must be a list of field names")
    ranges = _page_ranges(t, where, est, {"open_pages": n, "page_bytes": size, "hit_saving_bus_clocks": hit,
                                           "write_saving_bus_clocks": wr})
    if policy == "closed":
        hit = 0  # every access opens its row and closes it again
        ranges.pop("hit_saving_bus_clocks", None)
    return PageModel(need("chipset", str), policy, n, size, hit, wr, need("source", str), tuple(est), ranges)


def available_memory_presets() -> list[str]:
    return sorted(p.stem for p in MEMORY_PRESETS_DIR.glob("*.toml"))


def load_memory_preset(name: str) -> DramTiming:
    """The memory preset ``sim/memory/presets/NAME.toml``, checked for consistency."""
    path = MEMORY_PRESETS_DIR / f"{name}.toml"
    # a name, never a path: `../../x` would read any .toml (a web request names presets too)
    if not path.is_file() or name != Path(name).name or name.startswith("."):
        raise ValueError(f"unknown memory preset {name!r} (available: {', '.join(available_memory_presets())})")
    _, d = read_toml(path, "memory preset", ValueError, shared=True)
    where = f"{path.name}"

    def need(field):
        if field not in d:
            raise ValueError(f"{where}: missing field {field!r}")
        return d[field]

    burst = tuple(need("burst"))
    if len(burst) != TRANSFERS_PER_LINE or not all(isinstance(x, int) and x > 0 for x in burst):
        raise ValueError(f"{where}: burst must be {TRANSFERS_PER_LINE} positive integers, got {list(burst)}")
    # The preset repeats the burst as separate fields; they must agree.
    for field, value in (("first_transfer_bus_clocks", burst[0]), ("line_fill_bus_clocks", sum(burst))):
        if field in d and d[field] != value:
            raise ValueError(f"{where}: {field} = {d[field]} disagrees with burst {list(burst)} ({value})")
    if "next_transfer_bus_clocks" in d and any(x != d["next_transfer_bus_clocks"] for x in burst[1:]):
        raise ValueError(f"{where}: next_transfer_bus_clocks = {d['next_transfer_bus_clocks']} "
                         f"disagrees with burst {list(burst)}")
    rows = [d.get(f"row_{k}_bus_clocks") for k in ("open_hit", "closed", "conflict")]
    if any(r is not None for r in rows) and not all(isinstance(r, int) for r in rows):
        raise ValueError(f"{where}: row_open_hit/closed/conflict_bus_clocks must be given together")
    return DramTiming(name=need("name"), kind=need("type"), bus_mhz=float(need("bus_mhz")), burst=burst,
                      source=need("source"), row_hit=rows[0], row_closed=rows[1], row_conflict=rows[2],
                      pages=_page_model(d, where, burst[0]))


def bus_ratio(core_mhz: float, fsb_mhz: float) -> Fraction:
    """Core clocks per bus clock as an exact fraction: the quotient snapped to the nearest 1/4
    (real multipliers are multiples of 1/2; the preset MHz figures are rounded)."""
    if core_mhz <= 0 or fsb_mhz <= 0:
        raise ValueError(f"clock frequencies must be positive, got core {core_mhz} MHz, bus {fsb_mhz} MHz")
    exact = Fraction(core_mhz) / Fraction(fsb_mhz)
    ratio = Fraction(round(exact * 4), 4)
    if ratio < 1 or abs(exact - ratio) > Fraction(1, 100) * ratio:
        raise ValueError(f"core {core_mhz} MHz / bus {fsb_mhz} MHz = {float(exact):.4f} is not a "
                         "multiple of 1/4 (within 1%)")
    return ratio


def core_clocks(bus_clocks: int | Fraction, ratio: Fraction) -> int:
    """``ceil(bus_clocks * ratio)``, exactly."""
    return -(-(bus_clocks * ratio.numerator) // ratio.denominator)


@dataclass(frozen=True)
class LineCosts:
    """What one 32-byte line costs on a given CPU and memory, in core clocks."""

    memory: str
    ratio: Fraction
    fill_bus_clocks: int
    writeback_bus_clocks: int
    fill: int
    writeback: int
    overhead_bus_clocks: Fraction = Fraction(0)
    lead_off: int = 0  # core clocks from the request to the critical chunk: ceil((overhead + first) x ratio)
    # the same on an open DRAM page (equal to the above without a page model)
    fill_hit: int = 0
    writeback_hit: int = 0
    lead_off_hit: int = 0
    # the bus tenure of a line fill on a bus whose cycle runs from the request (ADS#) to the last
    # data transfer, the board's overhead included: ceil((overhead + fill burst) x ratio); on an open page
    fill_tenure: int = 0
    fill_tenure_hit: int = 0


def exact(value: float | int | Fraction, what: str = "overhead_bus_clocks") -> Fraction:
    """A preset figure as an exact fraction (15.5 -> 31/2, not the binary float), checked >= 0."""
    if isinstance(value, bool) or not isinstance(value, (int, float, Fraction)):
        raise ValueError(f"{what} must be a number, got {value!r}")
    f = value if isinstance(value, Fraction) else Fraction(str(value))
    if f < 0:
        raise ValueError(f"{what} must be >= 0, got {value}")
    return f


def line_costs(timing: DramTiming, core_mhz: float, fsb_mhz: float,
               overhead_bus_clocks: float | Fraction = 0) -> LineCosts:
    """Line fill, line writeback and the fill's lead-off in core clocks (rounded up) for a core at
    ``core_mhz`` on a ``fsb_mhz`` bus whose board adds ``overhead_bus_clocks`` before the memory's
    first transfer (see the module docstring). The memory must be rated for at least the bus clock."""
    if fsb_mhz > timing.bus_mhz + 0.5:
        raise ValueError(f"memory preset {timing.name} is rated for {timing.bus_mhz:g} MHz, "
                         f"below the {fsb_mhz:g} MHz bus")
    ratio = bus_ratio(core_mhz, fsb_mhz)
    over = exact(overhead_bus_clocks)
    fill, wb = timing.line_fill_bus_clocks, timing.line_writeback_bus_clocks
    lead = core_clocks(over + timing.first_access_bus_clocks, ratio)
    pages = timing.pages
    save = pages.hit_saving_bus_clocks if pages else 0
    write_save = pages.write_saving_bus_clocks if pages else 0
    lead_hit = over + timing.first_access_bus_clocks - save
    if lead_hit < 1:
        raise ValueError(f"memory preset {timing.name}: a page hit's lead-off ({over} + "
                         f"{timing.first_access_bus_clocks} - {save} bus clocks) must be at least 1")
    return LineCosts(timing.name, ratio, fill, wb, core_clocks(fill, ratio), core_clocks(wb, ratio), over, lead,
                     core_clocks(timing.bus_busy(save), ratio), core_clocks(timing.bus_busy(save + write_save), ratio),
                     core_clocks(lead_hit, ratio), core_clocks(over + fill, ratio),
                     core_clocks(over + timing.bus_busy(save), ratio))


class OpenRowModel:
    """Builder for :func:`row_access`: the per-bank open-row array and the preset's row timings."""

    def __init__(self, timing: DramTiming, row_bytes: int = DEFAULT_ROW_BYTES, banks: int = DEFAULT_BANKS):
        if not timing.has_rows:
            raise ValueError(f"memory preset {timing.name} gives no row-hit/row-miss timings; "
                             "the open-row model needs row_open_hit/closed/conflict_bus_clocks")
        for what, n in (("row_bytes", row_bytes), ("banks", banks)):
            if n <= 0 or n & (n - 1):
                raise ValueError(f"{what} must be a power of two, got {n}")
        self.timing = timing
        self.row_shift = row_bytes.bit_length() - 1
        self.bank_mask = banks - 1
        self.open_rows = np.full(banks, -1, np.int64)
        self.leadoff = np.array([timing.row_hit, timing.row_closed, timing.row_conflict], np.int64)

    def params(self):
        """``(open_rows, row_shift, bank_mask, leadoff, burst_rest)``: the arguments of
        :func:`row_access` after the address."""
        return self.open_rows, self.row_shift, self.bank_mask, self.leadoff, self.timing.burst_bus_clocks

    def reset(self) -> None:
        self.open_rows.fill(-1)


@njit(**HOT)
def row_state(open_rows, row_shift, bank_mask, addr):
    """ROW_HIT, ROW_CLOSED or ROW_CONFLICT for a line at ``addr`` (state not changed).
    Address map: the low ``row_shift`` bits address within a row, the next bits pick the bank."""
    bank = (addr >> row_shift) & bank_mask
    row = addr >> row_shift  # the bank bits included: a unique row number
    state = ROW_CONFLICT
    if open_rows[bank] == row:
        state = ROW_HIT
    elif open_rows[bank] < 0:
        state = ROW_CLOSED
    return state


@njit(**HOT)
def row_access(addr, open_rows, row_shift, bank_mask, leadoff, burst_rest):
    """Bus clocks of one line transfer (fill or writeback) at ``addr`` under the open-row model,
    leaving the row open: ``leadoff[state] + burst_rest``."""
    state = row_state(open_rows, row_shift, bank_mask, addr)
    open_rows[(addr >> row_shift) & bank_mask] = addr >> row_shift
    return leadoff[state] + burst_rest
