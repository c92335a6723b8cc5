"""Instruction timing tables as data: load a family's TOML table and find the row for a decoded
instruction, saying exactly which row a prediction used.

Rows are keyed by (mnemonic, operand signature) in the vocabulary of :mod:`sim.guest.decode`. A lookup
tries the exact key first, then the documented generalisations below, cheapest first, and
reports the one it used: the reader of `retrosim explain` sees "add r8,i8 -> add r32,i32".

Generalisations (each is a statement about these families, not a guess per row):
- condition-code families share one row: j<cc> -> jcc, set<cc> -> setcc, cmov<cc> -> cmovcc;
- 8- and 16-bit register, memory and immediate operands take the 32-bit row (the uop count and
  ports of ALU operations do not depend on the operand size; the 16-bit length-changing-prefix
  penalty is a decoder effect the models add separately);
- an x87 register operand ST(i) takes the ST row, and an explicit leading ST(0) may be dropped
  (FCOM ST, m32fp is FCOM m32fp);
- the address-only operand of LEA is m32.
"""

from __future__ import annotations

import functools
import itertools
import re
import tomllib
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

from sim.errors import RetrosimError
from sim.cpus import record


_FAMILIES = {"j": "jcc", "set": "setcc", "cmov": "cmovcc"}
_NOT_FAMILY = {"jmp", "jecxz", "jcxz"}
_WIDER = {"r8": ("r32",), "r16": ("r32",), "m8": ("m32",), "m16": ("m32",), "i8": ("i32",), "i16": ("i32",),
          "sti": ("st",), "m": ("m32",), "rel8": ("rel32",), "rel16": ("rel32",)}


# Every field a row may have: a field the models do not read is removed from the tables, and the
# loader refuses one it does not know, so an ignored figure cannot come back unnoticed. A family's
# own fields are its record's (machine table [family] table_fields, sim/cpus/families.py).
ROW_FIELDS = {"mnemonic", "signature", "uops", "decoder", "latency", "throughput", "source", "note", "estimated"}
OVERRIDABLE = {"latency", "throughput", "precision_throughput"}  # what a K6 model_overrides entry may replace
# x87 precision control: a row field `precision_F = [24-bit, 53-bit, 64-bit]` gives field F at each
# precision (the control word in force, sim/guest/trace.py); F itself holds the 64-bit (FNINIT) figure
PRECISION_FIELDS = ("latency", "throughput", "cycles")
PRECISION_NAMES = ("24-bit", "53-bit", "64-bit")
TOP_LEVEL = {"insn", "unsupported"}


class MissingTiming(RetrosimError):
    """An executed instruction has no row in the family's table."""


@dataclass(frozen=True)
class TimingRow:
    mnemonic: str
    signature: str
    uops: int
    ports: tuple[str, ...]
    decoder: str
    latency: float | None
    throughput: float | None
    source: str
    note: str = ""
    estimated: bool = False
    extra: dict = field(default_factory=dict, compare=False, hash=False)

    @property
    def key(self) -> str:
        return f"{self.mnemonic} {self.signature}".strip()

    @property
    def precision_dependent(self) -> bool:
        return any(f"precision_{name}" in self.extra for name in PRECISION_FIELDS)

    def at_precision(self, precision: int) -> TimingRow:
        """The row with its figures at x87 precision index `precision` (0 = 24-bit, 1 = 53-bit,
        2 = 64-bit), model overrides included; the row itself when nothing depends on it."""
        if not self.precision_dependent:
            return self
        extra = dict(self.extra)
        fields = {}
        for name in PRECISION_FIELDS:
            values = self.extra.get(f"precision_{name}")
            if values is not None:
                if name in ("latency", "throughput"):
                    fields[name] = values[precision]
                else:
                    extra[name] = values[precision]
        if "model_overrides" in extra:
            extra["model_overrides"] = {
                model: {**over, **{name: over[f"precision_{name}"][precision] for name in PRECISION_FIELDS
                                   if f"precision_{name}" in over}}
                for model, over in extra["model_overrides"].items()}
        return replace(self, extra=extra, **fields)


@dataclass(frozen=True)
class Match:
    row: TimingRow
    asked: str  # "mnemonic signature" of the decoded instruction
    precision: int | None = None  # x87 precision index the row's figures were taken at, if they depend on it

    @property
    def generalised(self) -> bool:
        return self.asked != self.row.key

    def at_precision(self, precision: int) -> Match:
        if not self.row.precision_dependent:
            return self
        return Match(self.row.at_precision(precision), self.asked, precision)

    def describe(self) -> str:
        text = self.row.key if not self.generalised else f"{self.asked} -> {self.row.key}"
        return text if self.precision is None else f"{text} @{PRECISION_NAMES[self.precision]}"


def family_mnemonic(mnemonic: str) -> str:
    if mnemonic in _NOT_FAMILY:
        return mnemonic
    for prefix, family in _FAMILIES.items():
        if mnemonic.startswith(prefix) and mnemonic != prefix:
            return family
    return mnemonic


_STRING = re.compile(r"^(lods|stos|movs|scas|cmps|ins|outs)[bwdl]?$")


def _signature_candidates(signature: str):
    """The signature itself, then generalised variants with the fewest substitutions first."""
    tokens = signature.split(",") if signature else []
    variants = [((t,) + _WIDER.get(t, ())) for t in tokens]
    seen = set()
    for combo in sorted(itertools.product(*[range(len(v)) for v in variants]), key=sum):
        sig = ",".join(v[i] for v, i in zip(variants, combo))
        if sig not in seen:
            seen.add(sig)
            yield sig
    if tokens and tokens[0] == "st":  # an explicit ST(0) first operand may be implicit in the table
        yield from _signature_candidates(",".join(tokens[1:]))


class InstructionTable:
    """One family's table (e.g. sim/cpus/p6/p6.toml)."""

    def __init__(self, path: str | Path, family: str | None = None):
        self.path = Path(path)
        with open(self.path, "rb") as f:
            data = tomllib.load(f)
        family = family or self.path.stem
        self.rows: dict[tuple[str, str], TimingRow] = {}
        known = ROW_FIELDS | {"ports"}
        allowed = ROW_FIELDS | (record.read(family).table_fields if record.known(family) else set())
        for key in data:
            if key not in TOP_LEVEL:
                raise RetrosimError(f"{self.path}: unknown table [{key}] (known: {', '.join(sorted(TOP_LEVEL))})")
        # [unsupported] mnemonics: no row on purpose; executing one is refused with the reason
        unsupported = data.get("unsupported", {})
        self.unsupported = set(unsupported.get("mnemonics", []))
        for i, raw in enumerate(data.get("insn", [])):
            where = f"{self.path}: [[insn]] row {i + 1} ({raw.get('mnemonic', '?')} {raw.get('signature', '')})".rstrip()
            for name in raw:
                if name not in allowed:
                    raise RetrosimError(f"{where}: unknown field '{name}' (a {family} row has: "
                                        f"{', '.join(sorted(allowed))})")
            for model, fields in raw.get("model_overrides", {}).items():
                for name in fields:
                    if name not in OVERRIDABLE:
                        raise RetrosimError(f"{where}: model_overrides.{model}: unknown field '{name}' "
                                            f"(may replace: {', '.join(sorted(OVERRIDABLE))})")
            try:
                ports = raw.get("ports", [])
                row = TimingRow(
                    mnemonic=raw["mnemonic"], signature=raw.get("signature", ""), uops=int(raw["uops"]),
                    ports=tuple(ports) if isinstance(ports, list) else tuple(p for p in ports.split("+") if p),
                    decoder=raw.get("decoder", ""), latency=raw.get("latency"), throughput=raw.get("throughput"),
                    source=raw["source"], note=raw.get("note", ""), estimated=bool(raw.get("estimated", False)),
                    extra={k: v for k, v in raw.items() if k not in known})
            except KeyError as e:
                raise RetrosimError(f"{where}: missing field {e}") from None
            _check_precision_fields(where, raw)
            self.rows[(row.mnemonic, row.signature)] = row

    @cached_property
    def _cache(self) -> dict:
        return {}

    def lookup(self, mnemonic: str, signature: str) -> Match | None:
        key = (mnemonic, signature)
        if key not in self._cache:
            self._cache[key] = self._find(mnemonic, signature)
        return self._cache[key]

    def _find(self, mnemonic: str, signature: str) -> Match | None:
        asked = f"{mnemonic} {signature}".strip()
        for name in dict.fromkeys((mnemonic, family_mnemonic(mnemonic))):
            for sig in _signature_candidates(signature):
                row = self.rows.get((name, sig))
                if row is not None:
                    return Match(row, asked)
            # string instructions' operands are implicit (ESI, EDI, EAX): Capstone spells them out,
            # the tables key the plain form by mnemonic alone
            if _STRING.match(name) and (name, "") in self.rows:
                return Match(self.rows[(name, "")], asked)
        return None

    def require(self, mnemonic: str, signature: str, where: str) -> Match:
        match = self.lookup(mnemonic, signature)
        if match is None and (family_mnemonic(mnemonic) in self.unsupported or mnemonic in self.unsupported):
            raise MissingTiming(f"{where}: '{mnemonic}' does not exist on this family, the CPU raises #UD "
                                f"({self.path.name} [unsupported] gives the sources)")
        if match is None:
            raise MissingTiming(f"{where}: no timing row for '{mnemonic} {signature}'".rstrip() +
                                f" in {self.path.name} (add one, with its source)")
        return match


def _check_precision_fields(where: str, raw: dict) -> None:
    """precision_F lists three numbers (24/53/64-bit) whose last is F itself (the FNINIT figure),
    in the row and in each model override."""
    for scope, fields in [("", raw)] + [(f"model_overrides.{m}.", o) for m, o in raw.get("model_overrides", {}).items()]:
        for name in PRECISION_FIELDS:
            values = fields.get(f"precision_{name}")
            if values is None:
                continue
            if not (isinstance(values, list) and len(values) == 3 and all(isinstance(v, (int, float)) for v in values)):
                raise RetrosimError(f"{where}: {scope}precision_{name} must list three numbers (24, 53, 64-bit)")
            plain = fields.get(name, raw.get(name))
            if plain != values[2]:
                raise RetrosimError(f"{where}: {scope}precision_{name}[2] = {values[2]} differs from {scope}{name} = "
                                    f"{plain} (the 64-bit figure is the FNINIT default)")


@functools.cache
def load_table(family: str) -> InstructionTable:
    """The family's table, parsed once per process (tables are data files shipped with the package)."""
    path = record.table_path(family)
    if not path.is_file():
        raise RetrosimError(f"no instruction table for CPU family '{family}' ({path} is missing)")
    return InstructionTable(path)
