"""The import graph of sim/ (every import, module-level or inside a function, read with ast, plus
the "module:Class" strings a module loads through importlib, and a submodule's imports from its
package's __init__ when that __init__ holds code): no cycles among sim modules, and no module
importing from a layer above its own. Also: a family is named only in its package and the
registry, and only sim/guest imports the emulator.

Layers, low to high (a module may import its own layer and the ones below):
base (sim.errors, sim.output, sim.reference, sim.inputfile, sim.tomlfile, sim.stats,
sim.portable_math) < sim.guest < sim.memory < sim.cpus
< sim.timing and sim.parallel < sim.reports < sim.studies < sim.scenes < sim.sweep < sim.cli.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SIM = Path(__file__).resolve().parents[1] / "sim"

# (prefix, layer): the longest matching prefix names a module's layer
LAYERS = [
    ("sim.errors", 0), ("sim.output", 0), ("sim.reference", 0), ("sim.inputfile", 0), ("sim.tomlfile", 0),
    ("sim.stats", 0), ("sim.portable_math", 0),
    ("sim.guest", 1), ("sim.memory", 2), ("sim.cpus", 3),
    ("sim.timing", 4), ("sim.parallel", 4),
    ("sim.reports", 5), ("sim.studies", 6), ("sim.scenes", 7), ("sim.sweep", 8), ("sim.cli", 9),
]
LAYER_NAMES = ["base", "guest", "memory", "cpus", "timing/parallel", "reports", "studies", "scenes", "sweep", "cli"]

# Known violations, each (importing module, imported module) -> the issue that will remove it. Both
# checks ignore these edges; test_allowed_list_holds_only_live_violations keeps the list from going
# stale. Empty since issue 21: add to it only with an open issue that removes the edge.
ALLOWED: dict[tuple[str, str], str] = {}


def module_name(path: Path) -> str:
    parts = path.relative_to(SIM.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules() -> dict[str, Path]:
    return {module_name(p): p for p in sorted(SIM.rglob("*.py"))}


def imports(path: Path, name: str, known: set[str]) -> list[tuple[str, int]]:
    """(imported sim module, line) for every import in the file, function-level ones included.
    `from sim.x import y` counts as importing sim.x.y when that is a module, else sim.x."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names if a.name.split(".")[0] == "sim"]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative import
                anchor = package.split(".")
                anchor = anchor[:len(anchor) - (node.level - 1)]
                base = ".".join(anchor + ([base] if base else []))
            if base.split(".")[0] != "sim":
                continue
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                out.append((sub if sub in known else base, node.lineno))
    # a module that imports by name (importlib.import_module) imports every sim module it names in
    # a string: a bare module name (a table of kinds -> modules) or a "module:Class" path (a registry
    # of classes loaded when first used: the import still runs, only later)
    if any(isinstance(node, ast.Attribute) and node.attr == "import_module" for node in ast.walk(tree)):
        out += [(named, node.lineno) for node in ast.walk(tree)
                if isinstance(node, ast.Constant) and isinstance(node.value, str)
                for named in [node.value.partition(":")[0]] if named in known]
    return out


def holds_code(path: Path) -> bool:
    """Whether a package's __init__ does more than describe and re-export its modules: any
    statement besides the docstring, imports and ``__all__`` (sim/cpus/__init__.py's make_model is
    code; sim/memory/__init__.py's re-exports are not)."""
    body = ast.parse(path.read_text(encoding="utf-8"), str(path)).body
    for i, node in enumerate(body):
        if i == 0 and isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant):
            continue  # the docstring
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            continue
        if isinstance(node, ast.Assign) and all(isinstance(t, ast.Name) and t.id in ("__all__", "__version__")
                                                for t in node.targets):
            continue
        return True
    return False


def layer_of(module: str) -> int:
    best = max((p for p, _ in LAYERS if module == p or module.startswith(p + ".")), key=len, default=None)
    if best is None:
        raise AssertionError(f"{module}: in no layer of tests/test_layers.py (add it to LAYERS)")
    return dict(LAYERS)[best]


@pytest.fixture(scope="module")
def graph() -> dict[str, list[tuple[str, int]]]:
    mods = modules()
    known = set(mods)
    return {name: [(t, line) for t, line in imports(path, name, known) if t != name]
            for name, path in mods.items()}


def test_every_module_has_a_layer(graph):
    for name in graph:
        if name != "sim":  # the package's own __init__ (a version string) belongs to no stage
            layer_of(name)


def test_no_module_imports_from_a_layer_above_its_own(graph):
    bad = []
    for name, edges in graph.items():
        if name == "sim":
            continue
        for target, line in edges:
            if target == "sim" or (name, target) in ALLOWED:
                continue
            if layer_of(target) > layer_of(name):
                bad.append(f"{modules()[name].relative_to(SIM.parent)}:{line}: {name} ({LAYER_NAMES[layer_of(name)]}) "
                           f"imports {target} ({LAYER_NAMES[layer_of(target)]})")
    assert not bad, "imports from a higher layer:\n" + "\n".join(bad)


def stale_allowances(allowed, graph) -> list[tuple[str, str]]:
    """The ALLOWED entries that are not live violations: the import no longer happens, or it does
    not go to a higher layer (so it needs no allowance)."""
    live = {(name, target) for name, edges in graph.items() for target, _ in edges}
    return sorted(e for e in allowed if e not in live or layer_of(e[1]) <= layer_of(e[0]))


def test_allowed_list_holds_only_live_violations(graph):
    """An ALLOWED entry that no longer happens, or never was a violation, is taken out (so the list
    only shrinks). ALLOWED is empty, so the check is also run on entries of each kind."""
    stale = stale_allowances(ALLOWED, graph)
    assert not stale, f"remove from ALLOWED in tests/test_layers.py (not a live violation): {stale}"
    upward = ("sim.errors", "sim.cli.app")  # the base layer importing the CLI
    with_upward = {**graph, "sim.errors": graph["sim.errors"] + [(upward[1], 1)]}
    assert stale_allowances({upward: "issue"}, with_upward) == []            # live and upward: kept
    assert stale_allowances({upward: "issue"}, graph) == [upward]             # not imported: stale
    downward = next((n, t) for n, edges in graph.items() for t, _ in edges   # imported, not upward
                    if n != "sim" and t != "sim" and layer_of(t) < layer_of(n))
    assert stale_allowances({downward: "issue"}, graph) == [downward]


def cycles(graph) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index, low, on, stack, out = {}, {}, set(), [], []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w, _ in graph.get(v, ()):
            if w not in graph:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def cycle_edges(graph) -> dict[str, list[tuple[str, int]]]:
    """The edges the cycle check follows. A package's __init__ that only re-exports its modules is
    not a cycle through them, so an edge from a submodule to such an __init__ is dropped (`from
    sim.memory import cache` in a sim.memory module names the module, which imports() resolves).
    An __init__ that holds code (:func:`holds_code`) is a module like any other: a submodule that
    imports a function from it, while the __init__ imports the submodule, is a cycle."""
    mods = modules()
    plain = {name for name, path in mods.items() if path.name == "__init__.py" and not holds_code(path)}
    return {name: [(t, line) for t, line in targets
                   if not (t in plain and name.startswith(t + ".")) and (name, t) not in ALLOWED]
            for name, targets in graph.items()}


def test_import_graph_sees_registry_strings_and_packages_with_code(tmp_path):
    """The two ways a cycle hid from this test: a "module:Class" string loaded through importlib,
    and a submodule importing from its package's __init__ when that __init__ holds code."""
    reg = tmp_path / "registry.py"
    reg.write_text('import importlib\nMODELS = {"x": "sim.pkg.model:Model"}\n'
                   'def load(k):\n    m, c = MODELS[k].split(":")\n    return getattr(importlib.import_module(m), c)\n')
    assert ("sim.pkg.model", 2) in imports(reg, "sim.pkg.registry", {"sim.pkg.model", "sim.pkg.registry"})
    init = tmp_path / "__init__.py"
    init.write_text('"""doc"""\nfrom sim.pkg import model\n__all__ = ["model"]\n')
    assert not holds_code(init)
    init.write_text('"""doc"""\nfrom sim.pkg import model\ndef make():\n    return model.Model()\n')
    assert holds_code(init)
    assert not holds_code(SIM / "memory" / "__init__.py")  # re-exports only


def test_no_import_cycles(graph):
    edges = cycle_edges(graph)
    bad = []
    for comp in cycles(edges):
        members = set(comp)
        where = list(dict.fromkeys(f"{modules()[n].relative_to(SIM.parent)}:{line}: {n} imports {t}"
                                   for n in comp for t, line in edges[n] if t in members))
        bad.append(" <-> ".join(comp) + "\n  " + "\n  ".join(where))
    assert not bad, "import cycles:\n" + "\n".join(bad)


def test_no_module_imports_another_modules_private_names():
    """A name with a leading underscore is its module's own: what another module needs is made
    public (or the code moves), so a module's private helpers can change without a search."""
    bad = []
    for name, path in modules().items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "sim":
                bad += [f"{path.relative_to(SIM.parent)}:{node.lineno}: {node.module}.{a.name}"
                        for a in node.names if a.name.startswith("_") and not a.name.startswith("__")]
    assert not bad, "private names imported from another module:\n" + "\n".join(bad)


# -- where a family may be named, and where the emulator may be imported ---------------------------
FAMILY_PLACES = ("sim/cpus/families.py",)  # the registry; and each family's own package

# Modules that still name a family, each -> the change of issue 35 that makes it family data.
# test_family_names_only_in_family_packages_and_the_registry keeps this list from going stale.
FAMILY_NAMES_PENDING: dict[str, str] = {}  # empty since issue 35: add only with an open issue that removes it


def family_literals(path: Path, names: set[str]) -> list[tuple[int, str]]:
    """(line, text) of every string constant in the file that is a family's name."""
    return [(node.lineno, node.value) for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path)))
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value.lower() in names]


def test_family_names_only_in_family_packages_and_the_registry(tmp_path):
    """A new family is its package plus one registry line: no other module branches on a family's
    name ("p5", "k6", ...) as a string constant."""
    from sim.cpus.families import FAMILIES

    names = set(FAMILIES)
    bad, live = [], set()
    for path in sorted(SIM.rglob("*.py")):
        rel = path.relative_to(SIM.parent).as_posix()
        if rel in FAMILY_PLACES or any(rel.startswith(f"sim/cpus/{n}/") for n in names):
            continue
        found = family_literals(path, names)
        if found and rel in FAMILY_NAMES_PENDING:
            live.add(rel)
        elif found:
            bad += [f"{rel}:{line}: {text!r}" for line, text in found]
    assert not bad, "a family named outside its package and the registry:\n" + "\n".join(bad)
    stale = sorted(set(FAMILY_NAMES_PENDING) - live)
    assert not stale, f"remove from FAMILY_NAMES_PENDING in tests/test_layers.py (names no family now): {stale}"
    probe = tmp_path / "probe.py"  # the check sees a comparison and a dict key, not a longer word
    probe.write_text('if family == "p5":\n    x = {"K6": 1, "p5_machine.toml": 2}\n')
    assert family_literals(probe, names) == [(1, "p5"), (2, "K6")]
