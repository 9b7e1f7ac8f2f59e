"""The import graph of fishfmu/ and plant/ (every import, at module level or inside a function) has
no cycle, and the plant imports nothing from fishfmu (it is the physics, usable without the tool)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("fishfmu", "plant")


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for f in sorted((ROOT / pkg).rglob("*.py")):
            parts = list(f.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = f
    return out


def _imports(module: str, path: Path, known: dict[str, Path]) -> set[str]:
    """The modules of ``known`` that ``module`` imports anywhere in its source (``from a import b``
    counts as importing ``a.b`` when that is a module, else ``a``)."""

    def resolve(name: str) -> str | None:
        while name and name not in known:
            name = name.rpartition(".")[0]
        return name or None

    deps: set[str | None] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            deps.update(resolve(a.name) for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
                base = base[:len(base) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            deps.update(resolve(f"{mod}.{a.name}") or resolve(mod) for a in node.names)
    return {d for d in deps if d is not None and d != module}


def import_graph() -> dict[str, set[str]]:
    known = _modules()
    return {m: _imports(m, p, known) for m, p in known.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as ``[a, b, ..., a]``, or None."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(v: str) -> list[str] | None:
        state[v] = 1
        path.append(v)
        for w in sorted(graph.get(v, ())):
            if state.get(w) == 1:
                return path[path.index(w):] + [w]
            if w not in state and (found := visit(w)) is not None:
                return found
        path.pop()
        state[v] = 2
        return None

    for v in sorted(graph):
        if v not in state and (found := visit(v)) is not None:
            return found
    return None


def test_find_cycle_finds_a_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def test_the_graph_sees_function_level_imports():
    graph = import_graph()
    assert "fishfmu.fmu.build" in graph["fishfmu.cosim.build"]  # imported inside fmu_path()
    assert "plant.sim.simulate" in graph["fishfmu.cosim.runner"]


def test_no_import_cycle():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_plant_imports_nothing_from_fishfmu():
    bad = sorted(f"{m} -> {d}" for m, deps in import_graph().items() if m.split(".")[0] == "plant"
                 for d in deps if d.split(".")[0] == "fishfmu")
    assert not bad, "plant imports fishfmu: " + ", ".join(bad)


PLANT_PARTS = [
    {"plant", "plant.errors", "plant.validation"},  # shared: may import one another
    {"plant.fish"},
    {"plant.contract"},
    {"plant.sim"},
]
"""The plant's three parts (plant/__init__.py), each a sub-package, after what all three share: the fish,
then the measured-data and KPI contract (which knows the fish), then the line in Exudyn."""


def _plant_part(module: str) -> str:
    return ".".join(module.split(".")[:2])


def test_the_plant_is_its_three_parts_in_order():
    layer_of = {p: i for i, layer in enumerate(PLANT_PARTS) for p in layer}
    bad = []
    for m, deps in import_graph().items():
        if m.split(".")[0] != "plant":
            continue
        a = _plant_part(m)
        assert a in layer_of, f"{m}: not in one of the plant's parts (PLANT_PARTS)"
        bad += [f"{m} -> {d}" for d in deps if d.split(".")[0] == "plant" and _plant_part(d) != a
                and layer_of[_plant_part(d)] > layer_of[a]]
    assert not bad, "plant imports against its parts' order: " + ", ".join(sorted(bad))
    assert "plant.fish.population" in import_graph()["plant.contract.measured"]  # the check sees real imports


LAYERS = [
    {"plant"},
    {"fishfmu.terminal", "fishfmu.fmu"},
    {"fishfmu.scenario"},
    {"fishfmu.cosim"},
    {"fishfmu.session"},
    {"fishfmu.batch", "fishfmu.analysis"},
    {"fishfmu.output"},
    {"fishfmu.serve"},
    {"fishfmu.bench"},
    {"fishfmu.commands"},
    {"fishfmu.cli"},
]
"""Each part may import only parts of lower layers (and itself): physics, FMUs, scenario, one run, the command's
process (its signals), what a command writes (its folder's lifecycle), many runs and measured data, serving over
OPC UA, commands, benchmarks (which measure what the commands do), CLI."""


def _part(module: str) -> str:
    parts = module.split(".")
    return parts[0] if parts[0] == "plant" or len(parts) == 1 else ".".join(parts[:2])


def test_each_part_imports_only_lower_layers():
    layer_of = {p: i for i, layer in enumerate(LAYERS) for p in layer}
    bad = []
    for m, deps in import_graph().items():
        if m == "fishfmu":
            continue
        a = _part(m)
        assert a in layer_of, f"{m}: part {a} has no layer in LAYERS"
        for d in deps:
            b = _part(d)
            if b != a and b != "fishfmu" and layer_of[b] >= layer_of[a]:
                bad.append(f"{m} -> {d}")
    assert not bad, "imports against the layers: " + ", ".join(sorted(bad))


def test_the_layer_check_sees_an_upward_import():
    """The check above is not vacuous: the CLI does import the commands, never the other way."""
    graph = import_graph()
    assert "fishfmu.commands" in graph["fishfmu.cli"]
    assert "fishfmu.cosim.runner" in graph["fishfmu.commands"]


def test_benchmarks_are_imported_by_nothing_but_the_cli_and_not_by_tests():
    users = sorted(m for m, deps in import_graph().items() if any(_part(d) == "fishfmu.bench" for d in deps)
                   and _part(m) not in ("fishfmu.bench", "fishfmu.cli"))
    assert not users, users
    known = _modules()
    for f in sorted((ROOT / "tests").glob("*.py")):
        deps = _imports(f"tests.{f.stem}", f, known)
        assert not any(_part(d) == "fishfmu.bench" for d in deps), f"{f.name} imports a benchmark"


def _own_private_attributes(tree: ast.AST) -> set[str]:
    """Names ``_x`` assigned as ``self._x`` (or defined as methods) in this module's classes."""
    own = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"):
            own.add(node.attr)
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            own.add(node.name)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            own.add(node.target.id)
    return own


def private_reads_across_modules() -> list[str]:
    """``obj._x`` where ``_x`` is not an attribute of this module's own classes, and
    ``from module import _x``, anywhere in fishfmu/ and plant/."""
    found = []
    for m, path in _modules().items():
        tree = ast.parse(path.read_text(), str(path))
        own = _own_private_attributes(tree)
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__")
                    and node.attr not in own):
                found.append(f"{path.relative_to(ROOT)}:{node.lineno}: {ast.unparse(node)}")
            elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] in PACKAGES:
                found += [f"{path.relative_to(ROOT)}:{node.lineno}: from {node.module} import {a.name}"
                          for a in node.names if a.name.startswith("_") and not a.name.startswith("__")]
    return found


def test_no_private_field_or_function_is_read_across_modules():
    found = private_reads_across_modules()
    assert not found, "private names read across modules: " + "; ".join(found)


def test_the_private_read_check_sees_one(tmp_path):
    pkg = tmp_path / "plant"
    pkg.mkdir()
    (pkg / "a.py").write_text("class A:\n    def __init__(self):\n        self._x = 1\n")
    (pkg / "b.py").write_text("from plant.a import A, _hidden\n\ndef f(a):\n    return a._x\n")
    globals()["ROOT"], saved = tmp_path, ROOT
    try:
        found = private_reads_across_modules()
    finally:
        globals()["ROOT"] = saved
    assert any("a._x" in f for f in found) and any("_hidden" in f for f in found), found
    assert not any(f.startswith("plant/a.py") for f in found), found


def _exits_and_exit_codes(path: Path) -> list[str]:
    """``EXIT_*`` names defined, and ``sys.exit``/``typer.Exit``/``SystemExit`` called, outside an
    ``if __name__ == "__main__":`` block."""
    tree = ast.parse(path.read_text(), str(path))
    main_blocks = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If) and "__main__" in ast.unparse(node.test)
                   for n in ast.walk(node)}
    found = []
    for node in ast.walk(tree):
        if isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            found += [f"{path.relative_to(ROOT)}:{node.lineno}: {t.id} =" for t in targets
                      if isinstance(t, ast.Name) and t.id.startswith("EXIT_")]
        elif isinstance(node, ast.Call) and id(node) not in main_blocks and ast.unparse(node.func) in (
                "sys.exit", "typer.Exit", "SystemExit"):
            found.append(f"{path.relative_to(ROOT)}:{node.lineno}: {ast.unparse(node.func)}(...)")
    return found


def test_exit_codes_are_the_command_lines():
    """Exit codes are defined in one module (fishfmu/cli/exit_codes.py) and only the command line ends the
    process with one; below it, failures are exceptions (plant.errors) and outcomes are results."""
    home = ROOT / "fishfmu" / "cli" / "exit_codes.py"
    defined = [f for f in _exits_and_exit_codes(home) if "EXIT_" in f]
    assert defined, "fishfmu/cli/exit_codes.py defines no exit code"
    bad = [f for m, path in _modules().items() if path != home
           for f in _exits_and_exit_codes(path)
           if "EXIT_" in f or not m.startswith("fishfmu.cli")]
    assert not bad, "exit codes outside the command line: " + "; ".join(bad)


def test_the_exit_code_check_sees_one(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("import sys\nEXIT_X = 5\n\ndef f():\n    sys.exit(EXIT_X)\n\nif __name__ == '__main__':\n"
                 "    raise SystemExit(f())\n")
    globals()["ROOT"], saved = tmp_path, ROOT
    try:
        found = _exits_and_exit_codes(f)
    finally:
        globals()["ROOT"] = saved
    assert [x.split(": ", 1)[1] for x in found] == ["EXIT_X =", "sys.exit(...)"], found
