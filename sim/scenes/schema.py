"""What every scene file shares, whatever its kind: reading it (bounded, see sim.tomlfile), the
one error type, the validator every kind's loader checks its tables with, and the machines a
scene runs on.

Every problem raises one :class:`SceneError` whose message names the file (with a line when one can
be found) and the dotted field: ``scenes/a.toml:12: run.variants[1]: unknown variant 'z24' ...``.
The formats themselves are documented in each kind's module (sim.scenes.zbuffer.scene,
sim.scenes.texture.scene, sim.scenes.snap.scene).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

from sim.cpus.families import FAMILIES as REGISTERED
from sim.cpus.machine import MachineKey
from sim.errors import RetrosimError
from sim.tomlfile import read_toml

MAX_SCENE_BYTES = 64 << 20  # 65535 explicit triangles take about 6 MB
FAMILIES = tuple(REGISTERED)  # CPU families a claim may name (the registry, sim/cpus/families.py)
_KIND_NAMES = {"int": "an integer", "number": "a number", "str": "a string", "strlist": "an array of strings",
               "range": "an array of two numbers [lo, hi]", "tables": "an array of tables", "any": "a value"}


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

    def scene_header(self, doc: dict, kind: str, tables: tuple[str, ...], scene_keys: dict) -> tuple[dict, str, str]:
        """What every kind's file shares: only the kind's top-level tables, a [scene] table with
        `scene_keys`, and scene.name equal to the file's name. Returns ([scene], name, description)."""
        for key in doc:
            if key not in tables:
                here = isinstance(doc[key], dict)
                self.fail(key, f"unknown table (allowed for kind '{kind}': {', '.join(tables)})",
                          key if here else None, None if here else key)
        sc = self.table(doc, "scene")
        self.keys(sc, scene_keys, "scene", note=f" for kind '{kind}'")
        name = self.typed(sc, "name", "str", "scene")
        if name != self.path.stem:
            self.fail("scene.name", f"'{name}' must equal the file name '{self.path.stem}'", "scene", "name")
        return sc, name, self.typed(sc, "description", "str", "scene", default="")

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

    def require_cover(self, field: str, index: int, machines: list, covers, cpus=(), families=(),
                      memories=()) -> None:
        """A claim must cover at least one of the scene's machines (covers(preset, memory, family)),
        and the scene must run every machine it names (its `cpus`, `families`, within `memories`):
        otherwise part of the claim would go unchecked without a word (sim.scenes.claims.unrun)."""
        from sim.cpus.machine import family_of
        from sim.scenes.claims import unrun

        if not any(covers(m.preset, m.memory, family_of(m.preset)) for m in machines):
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

    def keys(self, data: dict, allowed: dict, table: str, index: int | None = None, field: str | None = None,
             note: str = "") -> None:
        field = field or table
        for key in data:
            if key not in allowed:
                self.fail(f"{field}.{key}", f"unknown key{note} (allowed: {', '.join(allowed)})", table, key, index)
        for key, (_, required) in allowed.items():
            if required and key not in data:
                self.fail(f"{field}.{key}", f"missing required field{note}", table, None, index)

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
        if kind == "tables":
            if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
                wrong()
            return value
        return value

    def at_least(self, value, minimum, field: str, table: str, key: str, what: str = "") -> None:
        if value is not None and value < minimum:
            self.fail(field, f"must be >= {minimum}{what}, got {value}", table, key)

    def at_most(self, value, maximum, field: str, table: str, key: str, what: str = "") -> None:
        if value is not None and value > maximum:
            self.fail(field, f"must be <= {maximum}{what}, got {value}", table, key)

