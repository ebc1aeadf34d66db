"""The package's import floors: no import cycle, and no module imports one from a floor above its own.

The imports are read from the source (``ast``), at any depth: an ``import`` inside a function is an
edge as much as one at the top of a module (it runs as soon as the function does). Relative imports are
resolved to module names; ``from package import name`` is an edge to the submodule ``package.name`` when
there is one, else to the package (its ``__init__``). The parent packages Python imports first are not
counted: every module would depend on ``meshdenoise/__init__.py`` otherwise. :data:`FLOORS` is the table
docs/design.md draws ("How the code is organised"); a module in no floor, or in two, fails too.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = "meshdenoise"

# floor -> the modules on it, bottom up: a module imports only modules of its own floor or of floors below.
# "x" is meshdenoise/x.py (or the package x/__init__.py alone); "x.*" is the package x and every module under it.
FLOORS: dict[int, tuple[str, ...]] = {
    0: ("_launch", "arrays", "adapters", "cache", "constraints", "data", "geometry", "io.*", "kernels.*", "meshinfo",
        "metrics", "multishift", "progress", "shapes"),
    1: ("operators", "solvers.*", "locality", "normal_filter", "folds", "gpu", "ot.*"),
    2: ("registry", "noise", "scanner", "tuning.*"),
    3: ("plugins.*",),
    4: ("policy.*", "default"),
    5: ("pipeline.*", "commands.*", "cli", "demo", "warmup", "render.*", "report.*", "reproduce.*", ""),
}
FLOOR_NAMES = {
    0: "arrays, files and kernels",
    1: "operators and solvers",
    2: "registry, noise and tuning",
    3: "filters",
    4: "the default",
    5: "pipelines, commands, reports and the package's API",
}


def modules(root: Path = ROOT, package: str = PACKAGE) -> dict[str, tuple[Path, bool]]:
    """Every module of the package: ``{dotted name: (path, is a package's __init__)}``."""
    out = {}
    for path in sorted((root / package).rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        package = parts[-1] == "__init__"
        if package:
            parts = parts[:-1]
        out[".".join(parts)] = (path, package)
    return out


def imports(mods: dict[str, tuple[Path, bool]]) -> dict[str, dict[str, int]]:
    """``{module: {imported module of the package: line of its first import}}``, imports at any depth."""
    graph: dict[str, dict[str, int]] = {}
    for name, (path, package) in mods.items():
        base = name if package else name.rpartition(".")[0]
        edges = graph.setdefault(name, {})
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    parts = base.split(".")
                    parts = parts[: len(parts) - (node.level - 1)]
                    module = ".".join(parts + ([node.module] if node.module else []))
                else:
                    module = node.module or ""
                targets = [f"{module}.{a.name}" if f"{module}.{a.name}" in mods else module for a in node.names]
            else:
                continue
            for target in targets:
                while target and target not in mods:  # import a.b.c of a name inside a.b: the module a.b
                    target = target.rpartition(".")[0]
                if target and target != name:
                    edges.setdefault(target, node.lineno)
    return graph


def cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm, without recursion)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, {})))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def floor_of(module: str) -> list[int]:
    """The floors whose patterns match ``module`` (a dotted name of the package)."""
    short = module[len(PACKAGE) + 1:] if module != PACKAGE else ""
    out = []
    for floor, patterns in FLOORS.items():
        for pattern in patterns:
            if pattern.endswith(".*"):
                stem = pattern[:-2]
                hit = short == stem or short.startswith(stem + ".")
            else:
                hit = short == pattern
            if hit:
                out.append(floor)
                break
    return out


def test_the_reader_sees_imports_inside_functions_relative_ones_and_cycles(tmp_path):
    files = {
        "pkg/__init__.py": "from .a import f\n",
        "pkg/a.py": "import numpy\nfrom . import b\n\ndef f():\n    from .sub.c import g  # inside a function\n",
        "pkg/b.py": "from pkg.sub import c\n",
        "pkg/sub/__init__.py": "",
        "pkg/sub/c.py": "from .. import a\nfrom ..b import name_in_b\n\nclass K:\n    def m(self):\n        import pkg.a.f\n",
    }
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    graph = imports(modules(tmp_path, "pkg"))
    assert {k: sorted(v) for k, v in graph.items()} == {
        "pkg": ["pkg.a"], "pkg.a": ["pkg.b", "pkg.sub.c"], "pkg.b": ["pkg.sub.c"], "pkg.sub": [],
        "pkg.sub.c": ["pkg.a", "pkg.b"]}
    assert graph["pkg.a"]["pkg.sub.c"] == 5
    assert cycles(graph) == [["pkg.a", "pkg.b", "pkg.sub.c"]]
    assert cycles({"a": {"b": 1}, "b": {}}) == []


def test_no_import_cycle():
    graph = imports(modules())
    found = cycles(graph)
    lines = []
    for component in found:
        members = set(component)
        lines.append("cycle: " + ", ".join(component))
        for module in component:
            for target, line in sorted(graph[module].items()):
                if target in members:
                    lines.append(f"    {module} imports {target} (line {line})")
    assert not found, "\n".join(lines)


def test_every_module_is_on_one_floor():
    bad = {module: floor_of(module) for module in modules() if len(floor_of(module)) != 1}
    assert not bad, f"modules on no floor or on several (add them to FLOORS and docs/design.md): {bad}"


def test_no_module_imports_from_a_floor_above_its_own():
    graph = imports(modules())
    climbs = []
    for module, targets in sorted(graph.items()):
        here = floor_of(module)
        for target, line in sorted(targets.items()):
            there = floor_of(target)
            if here and there and there[0] > here[0]:
                climbs.append(f"{module} (floor {here[0]}) imports {target} (floor {there[0]}) at line {line}")
    assert not climbs, "imports from a higher floor:\n" + "\n".join(climbs)


def test_design_md_draws_these_floors():
    """docs/design.md's table of floors names each floor's modules as FLOORS does, bottom up."""
    text = (ROOT / "docs" / "design.md").read_text(encoding="utf-8")
    section = text.split("\n## How the code is organised\n", 1)[1].split("\n## ", 1)[0]
    rows = [line for line in section.splitlines() if re.match(r"\|\s*\d+\s*\|", line)]
    assert [int(row.split("|")[1]) for row in rows] == sorted(FLOORS)
    for row in rows:
        floor = int(row.split("|")[1])
        cells = row.split("|")
        assert cells[2].strip() == FLOOR_NAMES[floor], row
        drawn = set(re.findall(r"`([^`]+)`", cells[3]))
        want = {_drawn(pattern) for pattern in FLOORS[floor]}
        assert drawn == want, (floor, sorted(drawn ^ want))


def _drawn(pattern: str) -> str:
    """How docs/design.md writes a FLOORS pattern: ``operators.py``, ``tuning/``, ``__init__.py``."""
    if pattern == "":
        return "__init__.py"
    if pattern.endswith(".*"):
        return pattern[:-2].replace(".", "/") + "/"
    return pattern.replace(".", "/") + ".py"
