"""What every scene file shares, whatever its kind: reading it (bounded, see sim.tomlfile), the
one error type, the declared schema every kind's tables are validated from (:class:`Field`,
:meth:`Validator.section`), and the machines a scene runs on.

A kind declares each table as a tuple of :class:`Field` (name, type, required or default, range or
choices, a line of doc) and reads it with one call, ``v.section(doc_table, FIELDS, "run")``: the
unknown and missing keys, each value's type, its range, its choices, emptiness and repeats are
checked there, each with the same one-line message in every kind. What a declaration cannot say
(one field against another: a claim's variants among run.variants, a range within the z range) the
kind's loader checks after it.

Every problem raises one :class:`SceneError` whose message names the file (with a line when one can
be found) and the dotted field: ``scenes/a.toml:12: run.variants[1]: unknown variant 'z24' ...``.
The formats themselves are documented in each kind's module (sim.scenes.zbuffer.scene,
sim.scenes.texture.scene, sim.scenes.snap.scene, sim.scenes.sort.scene).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sim.cpus.families import FAMILIES as REGISTERED
from sim.cpus.machine import MachineKey
from sim.errors import RetrosimError
from sim.tomlfile import read_toml

MAX_SCENE_BYTES = 64 << 20  # 65535 explicit triangles take about 6 MB
FAMILIES = tuple(REGISTERED)  # CPU families a claim may name (the registry, sim/cpus/families.py)
_KIND_NAMES = {"int": "an integer", "number": "a number", "str": "a string", "strlist": "an array of strings",
               "range": "an array of two numbers [lo, hi]", "tables": "an array of tables", "any": "a value"}
SEED_RANGE = (0, 1 << 63, "between 0 and 2^63 - 1")  # every generator's seed (numpy's default_rng takes it)


@dataclass(frozen=True)
class Field:
    """One key of a scene table, declared. ``type``: int, number, str, strlist, intlist, range (two
    numbers in [0, 1]), tables (an array of tables), table or any (checked by the kind's loader). A field is
    ``required`` or has a ``default`` (None: absent). Checks, in this order, each failing with one
    message naming the field: ``nonempty`` (a list); ``unique`` (a list: the repeat's index, or no
    index when ``unique == "bare"``); ``choices`` (a str, or each item of a strlist: "unknown
    NOUN 'x' (known: ...)" with ``noun``); ``span`` = (lo, hi, words): lo <= value < hi, else "must
    be WORDS"; ``min`` / ``max``: "must be >= / <= N" (``max_note`` follows N)."""

    name: str
    type: str
    required: bool = False
    default: Any = None
    min: int | float | None = None
    max: int | float | None = None
    max_note: str = ""
    span: tuple | None = None
    choices: tuple = ()
    noun: str = ""
    nonempty: bool = False
    unique: bool | str = False
    doc: str = ""


# [scene]: every kind's header (each kind lists them, in the order its messages name them, with its own fields)
SCENE_KIND = Field("kind", "str", True, doc="the kind of scene (sim.scenes.registry.KINDS)")
SCENE_NAME = Field("name", "str", True, doc="must equal the file's stem")
SCENE_DESCRIPTION = Field("description", "str", default="", doc="one line for the report")


# A claim's coverage: the presets and the families its words cover (sim.scenes.claims.Claim).
CLAIM_TEXT = Field("text", "str", True, doc="the claim's words, as published")
CLAIM_CPUS = Field("cpus", "strlist", default=(), doc="presets the words cover (any memory)")
CLAIM_FAMILIES = Field("families", "strlist", default=(), doc="CPU families the words cover (see `retrosim cpus`)")


class SceneError(RetrosimError):
    """A scene file is malformed; the message is `file[:line]: field: problem`."""


def read_scene(path: Path) -> tuple[str, dict]:
    """(text, document) of a scene file: a regular file of at most MAX_SCENE_BYTES of UTF-8 TOML."""
    return read_toml(path, "scene file", SceneError, MAX_SCENE_BYTES)


def toml_type(value) -> str:
    if isinstance(value, bool):
        return "boolean"
    if isinstance(value, int):
        return "integer"
    if isinstance(value, float):
        return "float"
    if isinstance(value, str):
        return "string"
    if isinstance(value, list):
        return "array"
    if isinstance(value, dict):
        return "table"
    return type(value).__name__


def show(value) -> str:
    text = ("true" if value else "false") if isinstance(value, bool) else repr(value)
    return text if len(text) <= 40 else text[:37] + "..."



@dataclass(frozen=True)
class CpuChoice:
    """One `preset[:memory]` entry of run.cpus, with the memory preset resolved (the CPU preset's
    default memory when none is given)."""

    preset: str
    memory: str
    memory_given: bool

    @property
    def label(self) -> str:
        return f"{self.preset}:{self.memory}"



def line_of(text: str, table: str | None, key: str | None = None, index: int | None = None) -> int | None:
    """Best-effort line number of `key` in [table] (the index-th [[table]] for arrays of tables),
    or of the table's header when key is None; None when not found."""
    header = re.compile(r"^\s*(\[\[?)\s*([^\]]+?)\s*\]\]?\s*(#.*)?$")
    keyline = re.compile(r"""^\s*(?:"([^"]*)"|'([^']*)'|([A-Za-z0-9_-]+))\s*=""")
    current, seen, in_target = "", {}, table in (None, "")
    for number, line in enumerate(text.splitlines(), 1):
        m = header.match(line)
        if m:
            current = m.group(2).replace(" ", "")
            count = seen.get(current, -1) + 1 if m.group(1) == "[[" else 0
            seen[current] = count
            in_target = current == table and (index is None or count == index)
            if in_target and key is None:
                return number
            continue
        if in_target and key is not None:
            k = keyline.match(line)
            if k and next(g for g in k.groups() if g is not None) == key:
                return number
    return None


class Validator:
    """Checks of a parsed scene document, each failing with one SceneError that names the file,
    the line (found in the text) and the dotted field."""

    def __init__(self, path: Path, text: str):
        self.path, self.text = path, text

    def fail(self, field: str, message: str, table: str | None = None, key: str | None = None,
             index: int | None = None):
        line = line_of(self.text, table, key, index) if (table or key) else None
        where = f"{self.path}:{line}" if line else f"{self.path}"
        raise SceneError(f"{where}: {field}: {message}" if field else f"{where}: {message}")

    def table(self, doc: dict, name: str, required: bool = True) -> dict:
        if name not in doc:
            if required:
                self.fail(name, f"missing required table [{name}]")
            return {}
        value = doc[name]
        if not isinstance(value, dict):
            self.fail(name, f"expected a table [{name}], got {toml_type(value)}", None, name)
        return value

    def scene_header(self, doc: dict, kind: str, tables: tuple[str, ...], fields: tuple[Field, ...]) -> dict:
        """What every kind's file shares: only the kind's top-level tables, a [scene] table declared
        by `fields`, and scene.name equal to the file's name. The [scene] values (Validator.section)."""
        for key in doc:
            if key not in tables:
                here = isinstance(doc[key], dict)
                self.fail(key, f"unknown table (allowed for kind '{kind}': {', '.join(tables)})",
                          key if here else None, None if here else key)
        values = self.section(self.table(doc, "scene"), fields, "scene", note=f" for kind '{kind}'")
        if values["name"] != self.path.stem:
            self.fail("scene.name", f"'{values['name']}' must equal the file name '{self.path.stem}'", "scene", "name")
        return values

    def machine(self, machines: list, label: str, memory: str | None, field: str, table: str, key: str,
                index: int | None = None) -> None:
        """Append the CpuChoice of a machine label (preset{overrides}) and memory to `machines`, with
        one error naming `field` for an unknown preset or memory, an unusable override, or a repeat."""
        from sim.cpus import presets
        from sim.cpus.build import make_model
        from sim.cpus.overrides import machine_label, memory_presets, split_label

        try:
            preset, overrides = split_label(label)
        except RetrosimError as e:
            self.fail(field, str(e), table, key, index)
        known_cpus, known_mem = presets.available(), memory_presets()
        if preset not in known_cpus:
            self.fail(field, f"unknown CPU preset '{preset}' (known: {', '.join(known_cpus)})", table, key, index)
        if memory is not None and memory not in known_mem:
            self.fail(field, f"unknown memory preset '{memory}' (known: {', '.join(known_mem)})", table, key, index)
        try:
            label = machine_label(preset, overrides)
            model = make_model(label, memory)  # validates every override (and the geometry it makes)
        except RetrosimError as e:
            self.fail(field, f"CPU preset '{preset}' is unusable: {e}", table, key, index)
        choice = CpuChoice(label, model.dram.name, memory is not None)
        # the same machine spelled twice ('pentium2-233' and its default 'pentium2-233:edo')
        same = next((m for m in machines if (m.preset, m.memory) == (choice.preset, choice.memory)), None)
        if same is not None:
            self.fail(field, f"repeats '{same.label}' (both are {choice.preset} with {choice.memory} memory)",
                      table, key, index)
        machines.append(choice)

    def machines(self, cpus) -> list[CpuChoice]:
        """run.cpus entries (preset{overrides}[:memory]) as CpuChoices, each checked by :meth:`machine`."""
        machines: list[CpuChoice] = []
        for i, entry in enumerate(cpus):
            key = MachineKey.parse(entry)
            self.machine(machines, key.label, key.memory, f"run.cpus[{i}]", "run", "cpus")
        return machines

    def families(self, field: str, families, index: int) -> None:
        """A claim's families = [...] name known families."""
        for fam in families:
            if fam not in FAMILIES:
                self.fail(f"{field}.families", f"unknown family '{fam}' (known: {', '.join(FAMILIES)})",
                          "claims", "families", index)

    def claim_cpus(self, field: str, index: int, cpus) -> None:
        """A claim's cpus = [...] name known presets (plain presets: only Z-buffer claims take preset:memory)."""
        from sim.cpus import presets

        for p in cpus:
            if p not in presets.available():
                self.fail(f"{field}.cpus", f"unknown CPU preset '{p}' (known: {', '.join(presets.available())})",
                          "claims", "cpus", index)

    def require_cover(self, field: str, index: int, machines: list, claim) -> None:
        """A claim (sim.scenes.claims.Claim) must cover at least one of the scene's machines, and the
        scene must run every machine it names (its `cpus`, `families`, within `memories`): otherwise
        part of the claim would go unchecked without a word (sim.scenes.claims.unrun)."""
        from sim.cpus.machine import family_of
        from sim.scenes.claims import unrun

        cpus, families, memories = claim.cpus, claim.families, claim.memories
        if not any(claim.covers(m.preset, m.memory, family_of(m.preset)) for m in machines):
            self.fail(field, f"covers none of run.cpus ({', '.join(m.label for m in machines)})", "claims", None,
                      index)
        missing = unrun(cpus, families, memories, machines)
        if missing:
            within = f" with memory {', '.join(memories)}" if memories else ""
            self.fail(field, f"names {', '.join(missing)}{within}, which the scene does not run (run: "
                      f"{', '.join(f'{m.preset}:{m.memory}' for m in machines)}); run it or drop it from the claim",
                      "claims", None, index)

    def claim_tables(self, doc: dict) -> list[dict]:
        """The [[claims]] tables of a scene (none: an empty list)."""
        raw = doc.get("claims", [])
        if not isinstance(raw, list) or not all(isinstance(c, dict) for c in raw):
            self.fail("claims", "expected an array of tables [[claims]]", None, "claims")
        return raw

    def keys(self, data: dict, fields: tuple[Field, ...], table: str, index: int | None = None,
             field: str | None = None, note: str = "") -> None:
        """`data` holds no key but the fields' and every required one."""
        field = field or table
        for key in data:
            if not any(f.name == key for f in fields):
                self.fail(f"{field}.{key}", f"unknown key{note} (allowed: {', '.join(f.name for f in fields)})",
                          table, key, index)
        for f in fields:
            if f.required and f.name not in data:
                self.fail(f"{field}.{f.name}", f"missing required field{note}", table, None, index)

    def typed(self, data: dict, key: str, kind: str, table: str, index: int | None = None,
              field: str | None = None, default=None):
        field = f"{field or table}.{key}"
        if key not in data:
            return default
        value = data[key]

        def wrong(what=None):
            self.fail(field, f"expected {_KIND_NAMES[kind]}, got {what or toml_type(value)} {show(value)}",
                      table, key, index)

        if kind == "int":
            if isinstance(value, bool) or not isinstance(value, int):
                wrong()
            return value
        if kind == "number":
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                wrong()
            if not math.isfinite(value):
                self.fail(field, f"must be finite, got {value}", table, key, index)
            return float(value)
        if kind == "str":
            if not isinstance(value, str):
                wrong()
            return value
        if kind == "strlist":
            if not isinstance(value, list):
                wrong()
            for i, item in enumerate(value):
                if not isinstance(item, str):
                    self.fail(f"{field}[{i}]", f"expected a string, got {toml_type(item)} {show(item)}",
                              table, key, index)
            return tuple(value)
        if kind == "range":
            if (not isinstance(value, list) or len(value) != 2
                    or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value)):
                wrong()
            lo, hi = float(value[0]), float(value[1])
            if not (0.0 <= lo < hi <= 1.0):
                self.fail(field, f"need 0 <= lo < hi <= 1, got {show(value)}", table, key, index)
            return lo, hi
        if kind == "intlist":
            if not isinstance(value, list) or any(isinstance(x, bool) or not isinstance(x, int) for x in value):
                self.fail(field, f"expected an array of integers, got {show(value)}", table, key, index)
            return tuple(value)
        if kind == "tables":
            if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
                wrong()
            return value
        return value

    def section(self, data: dict, fields: tuple[Field, ...], table: str, index: int | None = None,
                field: str | None = None, note: str = "", later: tuple[Field, ...] = ()) -> dict:
        """The values of a table declared by `fields` (name -> value, or the field's default when
        absent): its keys, then every value's type, then each field's checks in declaration order.
        `table` and `index` find the line ([[table]] number `index`); `field` is the dotted name the
        messages use (default `table`); `note` follows "unknown key" and "missing required field".
        `later`: fields of `fields` the kind reads later (:meth:`values`), once the others say
        whether they apply."""
        self.keys(data, fields, table, index, field, note)
        return self.values(data, tuple(f for f in fields if f not in later), table, index, field)

    def values(self, data: dict, fields: tuple[Field, ...], table: str, index: int | None = None,
               field: str | None = None) -> dict:
        """The typed and checked values of `fields` in `data` (its keys already checked: :meth:`section`)."""
        values = {f.name: self.typed(data, f.name, f.type, table, index, field, default=f.default) for f in fields}
        for f in fields:
            if f.name in data:
                self.check(f, values[f.name], table, index, field)
        return values

    def check(self, f: Field, value, table: str, index: int | None = None, field: str | None = None) -> None:
        """`f`'s declared checks of its (typed) `value`."""
        name = f"{field or table}.{f.name}"

        def fail(message, where=name):
            self.fail(where, message, table, f.name, index)

        if f.nonempty and not value:
            fail("must not be empty")
        items = value if isinstance(value, tuple) and f.type == "strlist" else None
        if items is not None:
            for i, x in enumerate(items):
                if f.unique and x in items[:i]:
                    fail(f"'{x}' is listed twice", name if f.unique == "bare" else f"{name}[{i}]")
                if f.choices and x not in f.choices:
                    fail(f"unknown {f.noun} '{x}' (known: {', '.join(f.choices)})", f"{name}[{i}]")
        elif f.choices and value not in f.choices:
            fail(f"unknown {f.noun} '{value}' (known: {', '.join(f.choices)})")
        if f.span is not None and not f.span[0] <= value < f.span[1]:
            fail(f"must be {f.span[2]}, got {value}")
        if f.min is not None and value < f.min:
            fail(f"must be >= {f.min}, got {value}")
        if f.max is not None and value > f.max:
            fail(f"must be <= {f.max}{f.max_note}, got {value}")
