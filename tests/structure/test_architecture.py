"""The structure rules, checked on the source with ``ast``: imports point one way, functions fit on a screen.

Every module of ``vastcal/``, ``drivers/`` and ``simulators/`` (installed as ``vastcal.drivers`` and
``vastcal.simulators``) is parsed. An import of a vastcal module anywhere in a module counts — at the top,
inside a function (a lazy import) or under ``if TYPE_CHECKING`` — because each says that one module
needs the other. Importing a submodule runs its package's ``__init__`` too, but a package that gathers
its submodules' names is not a cycle with them, so the package itself counts only where a name is
imported from it that is not a submodule (``from vastcal.session import Session``).
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
ROOTS = ("vastcal", "drivers", "simulators")
LINKED = ("drivers", "simulators", "rig_configs")  # symbolic links inside vastcal/ to the folders above
MAX_STATEMENTS = 60
MAX_PARAMETERS = 10


def module_files(repo: Path = REPO) -> dict[str, Path]:
    """Dotted module name → source file, for every module of the three trees."""
    out: dict[str, Path] = {}
    for root in ROOTS:
        for p in sorted((repo / root).rglob("*.py")):
            rel = p.relative_to(repo)
            if root == "vastcal" and len(rel.parts) > 1 and rel.parts[1] in LINKED:
                continue
            parts = list(rel.with_suffix("").parts)
            if root != "vastcal":
                parts.insert(0, "vastcal")
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = p
    return out


@dataclass(frozen=True)
class Import:
    """One import of a vastcal module: who, where, what."""

    source: str
    line: int
    target: str


def _absolute(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    """The dotted name a (possibly relative) ``from … import`` refers to."""
    if not node.level:
        return node.module or ""
    base = module.split(".") if is_package else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def imports_of(module: str, path: Path, modules: dict[str, Path]) -> Iterator[Import]:
    """Every import of another vastcal module in ``path``, wherever it stands."""
    tree = ast.parse(path.read_text(), filename=str(path))
    for node in ast.walk(tree):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = _absolute(module, path.name == "__init__.py", node)
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
        for t in dict.fromkeys(targets):
            if t in modules and t != module:
                yield Import(module, node.lineno, t)


def import_graph(repo: Path = REPO) -> dict[str, dict[str, int]]:
    """module → {imported module: line of the first such import}."""
    modules = module_files(repo)
    graph: dict[str, dict[str, int]] = {m: {} for m in modules}
    for m, p in modules.items():
        for imp in imports_of(m, p, modules):
            graph[m].setdefault(imp.target, imp.line)
    return graph


def cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """One cycle (a → b → … → a) through each strongly connected group of modules (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    groups: list[set[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                group.add(w)
                if w == v:
                    break
            if len(group) > 1:
                groups.append(group)

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return [_cycle_in(graph, g) for g in groups]


def _cycle_in(graph: dict[str, dict[str, int]], group: set[str]) -> list[str]:
    """A shortest cycle through the first module (by name) of a strongly connected group."""
    start = min(group)
    paths = {start: [start]}
    frontier = [start]
    while frontier:
        nxt = []
        for v in frontier:
            for w in sorted(graph[v]):
                if w == start:
                    return paths[v] + [start]
                if w in group and w not in paths:
                    paths[w] = paths[v] + [w]
                    nxt.append(w)
        frontier = nxt
    raise AssertionError(f"no cycle through {start}")  # unreachable for a strongly connected group


def describe(cycle: list[str], graph: dict[str, dict[str, int]]) -> str:
    """``a (line 12) -> b (line 40) -> a``: each step with the line of the import that makes it."""
    steps = [f"{a} (line {graph[a][b]})" for a, b in zip(cycle, cycle[1:])]
    return " -> ".join(steps + [cycle[-1]])


def oversized_functions(repo: Path = REPO) -> list[str]:
    """``file:line name: N statements, M parameters`` for each function over either limit.

    Statements: every statement node inside the function, nested blocks and functions included.
    Parameters: all of them (positional, keyword-only, ``*args``, ``**kwargs``), less ``self``/``cls``.
    """
    out = []
    for p in module_files(repo).values():
        for node in ast.walk(ast.parse(p.read_text(), filename=str(p))):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            a = node.args
            n_params = len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs) + bool(a.vararg) + bool(a.kwarg)
            if (a.posonlyargs + a.args)[:1] and (a.posonlyargs + a.args)[0].arg in ("self", "cls"):
                n_params -= 1
            n_statements = sum(isinstance(s, ast.stmt) for s in ast.walk(node)) - 1
            if n_statements > MAX_STATEMENTS or n_params > MAX_PARAMETERS:
                rel = p.relative_to(repo)
                out.append(f"{rel}:{node.lineno} {node.name}: {n_statements} statements, {n_params} parameters")
    return sorted(out)


def test_no_import_cycle_among_vastcal_modules() -> None:
    graph = import_graph()
    found = [describe(c, graph) for c in cycles(graph)]
    assert not found, "import cycles (lazy and type-only imports included):\n" + "\n".join(found)


def test_no_function_over_the_size_limits() -> None:
    found = oversized_functions()
    assert not found, (
        f"functions with more than {MAX_STATEMENTS} statements or {MAX_PARAMETERS} parameters:\n" + "\n".join(found)
    )


# -- the checks themselves, on small trees made here --------------------------------------------


def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        p = tmp_path / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    for root in ROOTS:
        (tmp_path / root).mkdir(exist_ok=True)
    return tmp_path


def test_a_lazy_import_that_closes_a_cycle_is_found_and_named(tmp_path: Path) -> None:
    repo = _tree(
        tmp_path,
        {
            "vastcal/__init__.py": "",
            "vastcal/a.py": "from vastcal.b import f\n",
            "vastcal/b.py": "def f():\n    from vastcal import c\n",
            "vastcal/c.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from vastcal.a import g\n",
            "vastcal/d.py": "import vastcal.a\n",
        },
    )
    graph = import_graph(repo)
    found = cycles(graph)
    assert found == [["vastcal.a", "vastcal.b", "vastcal.c", "vastcal.a"]]
    assert describe(found[0], graph) == "vastcal.a (line 1) -> vastcal.b (line 2) -> vastcal.c (line 3) -> vastcal.a"


def test_a_package_gathering_its_submodules_is_no_cycle_but_a_name_from_it_counts(tmp_path: Path) -> None:
    repo = _tree(
        tmp_path,
        {
            "vastcal/__init__.py": "",
            "vastcal/p/__init__.py": "from vastcal.p.x import X\nfrom .y import Y\n",
            "vastcal/p/x.py": "from vastcal.p import y\n",
            "vastcal/p/y.py": "Y = 1\n",
        },
    )
    assert cycles(import_graph(repo)) == []
    (repo / "vastcal/p/y.py").write_text("from vastcal.p import X\n")  # a name the package gathers: a real cycle
    assert cycles(import_graph(repo)) == [["vastcal.p", "vastcal.p.y", "vastcal.p"]]


def test_drivers_and_simulators_count_as_vastcal_modules(tmp_path: Path) -> None:
    repo = _tree(
        tmp_path,
        {
            "vastcal/__init__.py": "",
            "vastcal/rig.py": "def connect():\n    from vastcal.drivers.stage import Stage\n",
            "drivers/__init__.py": "",
            "drivers/stage.py": "from vastcal.rig import connect\n",
        },
    )
    assert cycles(import_graph(repo)) == [["vastcal.drivers.stage", "vastcal.rig", "vastcal.drivers.stage"]]


@pytest.mark.parametrize(
    ("source", "expected"),
    [
        ("def f(a, b):\n" + "    x = 1\n" * 60, []),
        ("def f(a, b):\n" + "    x = 1\n" * 61, ["f: 61 statements, 2 parameters"]),
        ("class C:\n    def m(self, a, b, c, d, e, f, g, h, i, j):\n        pass\n", []),
        ("def f(a, b, c, d, e, f, g, h, i, *j, k):\n    pass\n", ["f: 1 statements, 11 parameters"]),
        ("def f():\n    def g():\n" + "        x = 1\n" * 60, ["f: 61 statements, 0 parameters"]),
    ],
    ids=["60 statements", "61 statements", "self and 10 parameters", "11 parameters", "a nested function counts"],
)
def test_function_size_counts_statements_and_parameters(tmp_path: Path, source: str, expected: list[str]) -> None:
    repo = _tree(tmp_path, {"vastcal/__init__.py": "", "vastcal/m.py": source})
    found = [line.split(" ", 1)[1] for line in oversized_functions(repo)]
    assert found == expected
