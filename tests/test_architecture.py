"""The import graph of fishfmu/ and plant/ (every import, at module level or inside a function) has
no cycle, and the plant imports nothing from fishfmu (it is the physics, usable without the tool)."""

from __future__ import annotations

import ast
import re
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
    assert "fishfmu.cosim.runner" in graph["fishfmu.batch.engine"]  # imported inside a function only
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
    {"fishfmu.output"},
    {"fishfmu.batch", "fishfmu.analysis"},
    {"fishfmu.serve"},
    {"fishfmu.commands"},
    {"fishfmu.bench"},
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


# ---- one run lifecycle, one stop mechanism, modules a newcomer can read ------------------------------------------
LIFECYCLE = Path("fishfmu/output/run_folder.py")
"""The one writer of run_info.json and kpis.json (:class:`fishfmu.output.run_folder.RunFolder`)."""
WRITERS = ("write_run_info", "write_json_atomic", "write_text_atomic", "write_bytes_atomic", "write_file_atomic",
           "write_text", "write_bytes", "open")


def _tree(path: Path) -> ast.AST:
    return ast.parse(path.read_text(), str(path))


def run_info_writes() -> list[str]:
    """Outside the lifecycle module: a call of ``write_run_info``, or a write (:data:`WRITERS`) whose arguments or
    target name run_info.json or kpis.json (the strings, or the names MARKER and KPIS)."""
    found = []
    for path in sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")):
        rel = path.relative_to(ROOT)
        if rel == LIFECYCLE:
            continue
        for node in ast.walk(_tree(path)):
            if not isinstance(node, ast.Call):
                continue
            name = node.func.attr if isinstance(node.func, ast.Attribute) else getattr(node.func, "id", "")
            if name not in WRITERS:
                continue
            parts = [*node.args, *(k.value for k in node.keywords),
                     *([node.func.value] if isinstance(node.func, ast.Attribute) else [])]
            named = {n.value for p in parts for n in ast.walk(p) if isinstance(n, ast.Constant)} | \
                    {n.id for p in parts for n in ast.walk(p) if isinstance(n, ast.Name)}
            if name == "write_run_info" or named & {"run_info.json", "kpis.json", "MARKER", "KPIS"}:
                found.append(f"{rel}:{node.lineno}: {ast.unparse(node)[:80]}")
    return found


def test_run_info_and_kpis_are_written_only_by_the_run_folder():
    """Every command's folder goes through one lifecycle (RunFolder): nothing else writes its run_info.json or
    kpis.json, so 'running', 'partial' and 'failed' mean the same for every command."""
    found = run_info_writes()
    assert not found, "run_info.json or kpis.json written outside fishfmu/output/run_folder.py: " + "; ".join(found)
    assert "write_run_info" in {n.name for n in ast.walk(_tree(ROOT / LIFECYCLE)) if isinstance(n, ast.FunctionDef)}


def test_the_run_info_check_sees_one(tmp_path):
    (tmp_path / "fishfmu").mkdir()
    (tmp_path / "fishfmu" / "a.py").write_text(
        "from fishfmu.output.atomic import write_json_atomic\nMARKER = 'run_info.json'\n\n"
        "def f(out, doc):\n    write_json_atomic(out / 'kpis.json', doc)\n    (out / MARKER).write_text('{}')\n")
    globals()["ROOT"], saved = tmp_path, ROOT
    try:
        found = run_info_writes()
    finally:
        globals()["ROOT"] = saved
    assert [f.split(":")[1] for f in found] == ["5", "6"], found


def stop_mechanisms() -> list[str]:
    """Signal handlers set outside fishfmu/session.py (a worker process ignoring SIGINT aside), and stop requests
    made outside it."""
    found = []
    for path in sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")):
        rel = path.relative_to(ROOT)
        if rel == Path("fishfmu/session.py"):
            continue
        for node in ast.walk(_tree(path)):
            if not isinstance(node, ast.Call):
                continue
            call = ast.unparse(node.func)
            if call.endswith("signal.signal") and not (len(node.args) == 2 and ast.unparse(node.args[1]).endswith(
                    "SIG_IGN")):
                found.append(f"{rel}:{node.lineno}: {ast.unparse(node)}")
            elif call.rpartition(".")[2] in ("StopRequest", "stop_on_signals", "getsignal", "pthread_sigmask"):
                found.append(f"{rel}:{node.lineno}: {ast.unparse(node)}")
    return found


def test_one_stop_mechanism():
    """fishfmu's own process answers SIGINT and SIGTERM in one module, fishfmu/session.py (a stepping loop polls the
    request it gives, a loop over workers gets Interrupted); a worker process only ignores SIGINT."""
    found = stop_mechanisms()
    assert not found, "signals handled outside fishfmu/session.py: " + "; ".join(found)


def test_the_stop_check_sees_one(tmp_path):
    (tmp_path / "plant").mkdir()
    (tmp_path / "plant" / "a.py").write_text(
        "import signal\nfrom fishfmu.cosim.stop import StopRequest\n\ndef f(h):\n"
        "    signal.signal(signal.SIGINT, signal.SIG_IGN)\n    signal.signal(signal.SIGTERM, h)\n    return StopRequest()\n")
    globals()["ROOT"], saved = tmp_path, ROOT
    try:
        found = stop_mechanisms()
    finally:
        globals()["ROOT"] = saved
    assert [f.split(":")[1] for f in found] == ["6", "7"], found


MAX_LINES = 450


def long_modules() -> dict[str, bool]:
    """Each module of more than MAX_LINES lines, and whether its docstring states why ('Over 450 lines: ...')."""
    out = {}
    for path in sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")):
        if len(path.read_text().splitlines()) > MAX_LINES:
            doc = ast.get_docstring(_tree(path)) or ""
            out[str(path.relative_to(ROOT))] = f"over {MAX_LINES} lines:" in doc.lower()
    return out


def test_no_module_over_450_lines_without_a_reason_at_its_top():
    unexplained = sorted(m for m, reason in long_modules().items() if not reason)
    assert not unexplained, (
        f"over {MAX_LINES} lines with no reason in the module docstring ('Over {MAX_LINES} lines: why'): "
        + ", ".join(unexplained))


MAX_FUNCTION_LINES = 100


def long_functions() -> list[str]:
    """Every function (or method) of the packages longer than MAX_FUNCTION_LINES lines, with its place."""
    out = []
    for path in sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")):
        for node in ast.walk(_tree(path)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                if node.end_lineno - node.lineno + 1 > MAX_FUNCTION_LINES:
                    out.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name}")
    return out


def test_no_function_over_100_lines():
    # issue 43: build_model was 128 lines and resolve_wiring 109, each doing several things one after another
    assert long_functions() == []


def imports_without_a_reason(path: Path) -> list[int]:
    """Lines of imports inside a function with no comment saying why: neither on the import itself nor on the
    line just above the run of imports it belongs to."""
    lines = path.read_text().splitlines()
    found = []
    for fn in ast.walk(_tree(path)):
        if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        for block in ast.walk(fn):
            for stmts in (getattr(block, f, None) for f in ("body", "orelse", "finalbody")):
                first = None
                for st in stmts if isinstance(stmts, list) else []:
                    if not isinstance(st, (ast.Import, ast.ImportFrom)):
                        first = None
                        continue
                    first = first or st
                    above = first.lineno - 2
                    while above >= 0 and not lines[above].strip():
                        above -= 1
                    if not any("#" in lines[k] for k in range(st.lineno - 1, st.end_lineno)) and not (
                            above >= 0 and "#" in lines[above]):
                        found.append(st.lineno)
    return sorted(set(found))


def test_an_import_inside_a_function_says_why():
    """Imports are at module level, where a reader sees what a module depends on; one inside a function carries a
    comment saying why (slow and needed only there, say which: asyncua for serve, matplotlib for a report)."""
    found = {str(p.relative_to(ROOT)): lines for pkg in PACKAGES for p in sorted((ROOT / pkg).rglob("*.py"))
             if (lines := imports_without_a_reason(p))}
    assert not found, "imports inside a function without a comment saying why: " + "; ".join(
        f"{m}: lines {', '.join(map(str, v))}" for m, v in sorted(found.items()))


def test_the_lazy_import_check_sees_one(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("def f():\n    # slow: asyncua\n    import asyncua\n    import json\n\n\ndef g():\n    x = 1\n"
                 "    import json\n    import csv  # a reason\n    return x\n")
    assert imports_without_a_reason(f) == [9]


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


# ---- the plant as a component: one output, ports declared once ---------------------------------------------
PLANT_OUTPUT = {"state", "step", "build_ahead"}
"""All that code outside the plant uses of a Plant: its step (which returns the sensor readings), the state it
publishes after it, and build_ahead, which changes nothing the plant computes, only when it does a rebuild's work
(plant/sim/plant.py)."""


def plant_public_attributes() -> set[str]:
    """Public methods, properties and ``self.x`` fields of :class:`plant.sim.plant.Plant`."""
    tree = ast.parse((ROOT / "plant" / "sim" / "plant.py").read_text())
    cls = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "Plant")
    names = {n.name for n in cls.body if isinstance(n, ast.FunctionDef)}
    names |= {n.attr for n in ast.walk(cls) if isinstance(n, ast.Attribute) and isinstance(n.ctx, ast.Store)
              and isinstance(n.value, ast.Name) and n.value.id == "self"}
    return {n for n in names if not n.startswith("_")}


def plant_attribute_reads() -> list[str]:
    """Reads of a Plant's attributes other than :data:`PLANT_OUTPUT` in fishfmu/: on a name ``plant``, on any
    ``x.plant``, on a name bound to ``Plant(...)`` or annotated ``Plant``."""
    attrs = plant_public_attributes() - PLANT_OUTPUT
    found = []
    for m, path in _modules().items():
        if m.split(".")[0] != "fishfmu":
            continue
        tree = ast.parse(path.read_text(), str(path))
        plants = {"plant"}
        for node in ast.walk(tree):
            if (isinstance(node, ast.Assign) and isinstance(node.value, ast.Call)
                    and ast.unparse(node.value.func) == "Plant"):
                plants |= {t.id for t in node.targets if isinstance(t, ast.Name)}
            elif (isinstance(node, ast.arg) and node.annotation is not None
                  and "Plant" in ast.unparse(node.annotation).split(" ")):
                plants.add(node.arg)
        for node in ast.walk(tree):
            if not isinstance(node, ast.Attribute) or node.attr not in attrs:
                continue
            v = node.value
            if (isinstance(v, ast.Name) and v.id in plants) or (isinstance(v, ast.Attribute) and v.attr == "plant"):
                found.append(f"{path.relative_to(ROOT)}:{node.lineno}: {ast.unparse(node)}")
    return found


def test_nothing_outside_the_plant_reads_a_plant_but_its_step_and_state():
    assert {"status", "t_s", "model"} <= plant_public_attributes()  # what the check looks for, for tests only
    found = plant_attribute_reads()
    assert not found, "read a Plant's fields, not its published state: " + "; ".join(found)


def test_the_plant_read_check_sees_one(tmp_path):
    pkg = tmp_path / "fishfmu"
    pkg.mkdir()
    (tmp_path / "plant" / "sim").mkdir(parents=True)
    (tmp_path / "plant" / "sim" / "plant.py").write_text((ROOT / "plant" / "sim" / "plant.py").read_text())
    (pkg / "a.py").write_text("def f(cosim, sc, plant: Plant):\n    p = Plant(sc.line, [])\n    return (cosim.plant.status, "
                              "plant.t_s, p.model, cosim.plant.state, sc.plant.numerics)\n")
    globals()["ROOT"], saved = tmp_path, ROOT
    try:
        found = plant_attribute_reads()
    finally:
        globals()["ROOT"] = saved
    assert [f.split(": ", 1)[1] for f in found] == ["cosim.plant.status", "plant.t_s", "p.model"], found


PLANT_SIGNALS = ("speed", "load_force", "load_mass", "blocked")


def _names_a_signal(node: ast.AST) -> bool:
    """A string that is a plant signal or a port name ``<id>.<signal>`` (also as an f-string such as
    ``f"{c}.speed"``; not a connection ``"a.x -> plant.c1.speed"``)."""
    if isinstance(node, ast.JoinedStr) and node.values:
        parts = [v.value for v in node.values if isinstance(v, ast.Constant)]
        if not all(re.fullmatch(r"[\w.]*", str(s)) for s in parts):
            return False
        node = node.values[-1]
    return (isinstance(node, ast.Constant) and isinstance(node.value, str)
            and any(node.value == s or node.value.endswith(f".{s}") for s in PLANT_SIGNALS))


def port_lists() -> list[str]:
    """Tuples, lists, sets and dicts that enumerate two or more of the plant's signals or ports, outside the
    declaration (plant/sim/ports.py)."""
    found = []
    for m, path in _modules().items():
        if m == "plant.sim.ports":
            continue
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            items = (node.keys if isinstance(node, ast.Dict) else node.elts
                     if isinstance(node, (ast.Tuple, ast.List, ast.Set)) else [])
            if sum(_names_a_signal(x) for x in items if x is not None) >= 2:
                found.append(f"{path.relative_to(ROOT)}:{node.lineno}: {ast.unparse(node)[:80]}")
    return found


def test_the_plants_ports_are_declared_once():
    """Wiring, the master, the plant FMU, serve and the plant's outputs take the ports from plant.sim.ports; none
    lists them again (checked: no enumeration of two or more of its signals elsewhere)."""
    declared = ast.parse((ROOT / "plant" / "sim" / "ports.py").read_text())
    assert any(_names_a_signal(n) for n in ast.walk(declared))
    found = port_lists()
    assert not found, "the plant's ports listed outside plant/sim/ports.py: " + "; ".join(found)


def test_the_port_list_check_sees_one(tmp_path):
    (tmp_path / "fishfmu").mkdir()
    (tmp_path / "fishfmu" / "a.py").write_text(
        'UNITS = {"speed": "m/s", "load_force": "N"}\nX = [f"{c}.blocked" for c in "ab"]\n'
        'def f(c):\n    return [f"{c}.load_mass", f"{c}.speed"], ("load_force_n", "load_mass_kg"), {"blocked": 1}\n'
        'C = [f"a.y -> plant.{c}.speed", f"plant.{c}.load_force -> b.u"]\n')
    globals()["ROOT"], saved = tmp_path, ROOT
    try:
        found = port_lists()
    finally:
        globals()["ROOT"] = saved
    assert [f.split(":")[1] for f in found] == ["1", "4"], found
