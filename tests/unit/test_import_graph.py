"""The first-party modules import one another without cycles, and only the command line imports the command
line's package.

Every import counts, wherever it stands: at the top of a module, inside a function (a "lazy" import is
still a dependency) and under ``if TYPE_CHECKING:`` (a type is a dependency too). A cycle means two
modules cannot be understood, tested or loaded one without the other; the fix is to move what both need
into a module below them (as :mod:`service.views` holds the job views that :mod:`service.context` and
:mod:`service.jobs` both use).
"""

from __future__ import annotations

import ast
import itertools
from collections.abc import Iterable, Mapping
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: The first-party packages whose modules make up the graph.
PACKAGES = ("api_schemas", "backend", "workers", "service", "eigenscope")
#: The command line's package: it sits on top of the others, none of them imports it.
CLI = "eigenscope"

#: module -> {imported module -> line of the first such import}.
Graph = dict[str, dict[str, int]]


def module_files(root: Path, packages: Iterable[str]) -> dict[str, Path]:
    """Every ``.py`` file of ``packages`` under ``root``, by dotted module name (a package by its own
    name, from its ``__init__.py``)."""
    found: dict[str, Path] = {}
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            found[".".join(parts)] = path
    return found


def _existing(name: str, modules: Mapping[str, Path]) -> str | None:
    """``name`` or its longest prefix that is a module of the graph (``import a.b.c`` of a missing
    ``c`` still loads ``a.b``); None for a third-party module."""
    parts = name.split(".")
    while parts:
        candidate = ".".join(parts)
        if candidate in modules:
            return candidate
        parts.pop()
    return None


def imports_of(module: str, path: Path, modules: Mapping[str, Path]) -> dict[str, int]:
    """The modules of the graph that ``module`` (in ``path``) imports, each with its first line.

    ``import a.b`` depends on ``a.b``; ``from a import b`` on the module ``a.b`` when there is one, else
    on ``a`` (where ``b`` is a name); relative imports are resolved against the module's package.
    """
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    edges: dict[str, int] = {}

    def add(name: str, line: int) -> None:
        target = _existing(name, modules)
        if target is not None and target != module:
            edges.setdefault(target, line)

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                add(alias.name, node.lineno)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".") if package else []
                if node.level > 1:
                    base = base[: len(base) - (node.level - 1)]
                source = ".".join([*base, *([node.module] if node.module else [])])
            else:
                source = node.module or ""
            for alias in node.names:
                submodule = f"{source}.{alias.name}" if source else alias.name
                if alias.name != "*" and submodule in modules:
                    add(submodule, node.lineno)
                elif source:
                    add(source, node.lineno)
    return dict(sorted(edges.items()))


def import_graph(root: Path, packages: Iterable[str]) -> tuple[Graph, dict[str, Path]]:
    modules = module_files(root, packages)
    return {name: imports_of(name, path, modules) for name, path in modules.items()}, modules


def find_cycles(graph: Graph) -> list[list[str]]:
    """One cycle in each group of modules that import one another (the strongly connected components of
    two or more modules, by Tarjan's algorithm, without recursion): ``[a, b, ..., a]``, each importing the
    next."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []
    counter = 0
    for start in sorted(graph):
        if start in index:
            continue
        work: list[tuple[str, Iterable[str]]] = [(start, iter(graph[start]))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            node, targets = work[-1]
            advanced = False
            for target in targets:
                if target not in graph:
                    continue
                if target not in index:
                    index[target] = low[target] = counter
                    counter += 1
                    stack.append(target)
                    on_stack.add(target)
                    work.append((target, iter(graph[target])))
                    advanced = True
                    break
                if target in on_stack:
                    low[node] = min(low[node], index[target])
            if advanced:
                continue
            work.pop()
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    components.append(sorted(component))
    return [_cycle_in(graph, set(component)) for component in components]


def _cycle_in(graph: Graph, component: set[str]) -> list[str]:
    """A shortest cycle through the component's first module (breadth first, within the component)."""
    first = min(component)
    previous: dict[str, str] = {}
    frontier = [first]
    while frontier:
        following = []
        for node in frontier:
            for target in graph[node]:
                if target not in component:
                    continue
                if target == first:
                    path = [node]
                    while path[-1] != first:
                        path.append(previous[path[-1]])
                    return [*reversed(path), first]
                if target not in previous:
                    previous[target] = node
                    following.append(target)
        frontier = following
    raise AssertionError(f"no cycle through {first} in {sorted(component)}")  # pragma: no cover


def _describe(cycle: list[str], graph: Graph, modules: Mapping[str, Path], root: Path) -> str:
    steps = [
        f"{a} ({modules[a].relative_to(root)}:{graph[a][b]}) imports {b}"
        for a, b in itertools.pairwise(cycle)
    ]
    return " -> ".join(cycle) + "\n    " + "\n    ".join(steps)


def _write(root: Path, files: Mapping[str, str]) -> None:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")


def test_the_scan_sees_every_kind_of_import(tmp_path: Path) -> None:
    """Relative imports, ``from package import module``, function bodies and ``TYPE_CHECKING`` blocks
    all make edges, to modules of the graph only; a name imported from a package is the package."""
    _write(
        tmp_path,
        {
            "pkg/__init__.py": "from pkg.sub import helper\n",
            "pkg/a.py": (
                "from typing import TYPE_CHECKING\nimport numpy\n"
                "if TYPE_CHECKING:\n    from pkg.b import Thing\n"
                "def f():\n    from . import c\n"
            ),
            "pkg/b.py": "from .sub import d\nfrom .. import other\n",
            "pkg/c.py": "import pkg.sub.d\nfrom pkg.sub.d import value\nimport pkg.missing\n",
            "pkg/sub/__init__.py": "from ..c import *\nfrom . import helper\n",
            "pkg/sub/d.py": "from pkg import sub\n",
            "pkg/sub/helper.py": "",
        },
    )
    graph, _ = import_graph(tmp_path, ["pkg"])
    assert graph == {
        "pkg": {"pkg.sub.helper": 1},
        "pkg.a": {"pkg.b": 4, "pkg.c": 6},
        "pkg.b": {"pkg.sub.d": 1},
        "pkg.c": {"pkg": 3, "pkg.sub.d": 1},
        "pkg.sub": {"pkg.c": 1, "pkg.sub.helper": 2},
        "pkg.sub.d": {"pkg.sub": 1},
        "pkg.sub.helper": {},
    }
    # pkg.sub -> pkg.c -> pkg.sub.d -> pkg.sub; pkg.a -> pkg.b -> ... is not a cycle.
    assert find_cycles(graph) == [["pkg.c", "pkg.sub.d", "pkg.sub", "pkg.c"]]


def test_a_cycle_is_found_however_long_and_wherever_it_starts() -> None:
    chain = {f"m{i}": {f"m{i + 1}": 1} for i in range(5000)}
    chain["m5000"] = {}
    assert find_cycles(chain) == []
    chain["m5000"] = {"m17": 3}
    (cycle,) = find_cycles(chain)
    assert cycle[0] == cycle[-1]
    assert set(cycle) == {f"m{i}" for i in range(17, 5001)}
    assert len(cycle) == 5000 - 17 + 2
    assert all(b in chain[a] for a, b in itertools.pairwise(cycle))
    two = {"a": {"b": 1}, "b": {"a": 1}, "c": {"d": 1}, "d": {"c": 1, "a": 2}}
    assert find_cycles(two) == [["a", "b", "a"], ["c", "d", "c"]]


def test_first_party_modules_import_one_another_without_cycles() -> None:
    graph, modules = import_graph(ROOT, PACKAGES)
    assert len(graph) > 100, sorted(graph)
    assert sum(len(edges) for edges in graph.values()) > 300
    # The scan sees the imports that matter (TYPE_CHECKING and function bodies among them).
    assert "workers.pipeline.fft" in graph["workers.pipeline.spectra"]
    assert "backend.urls" in graph["workers.streams"]
    cycles = find_cycles(graph)
    for cycle in cycles:
        print("import cycle:", _describe(cycle, graph, modules, ROOT))
    assert not cycles, "import cycles among first-party modules:\n" + "\n".join(
        _describe(cycle, graph, modules, ROOT) for cycle in cycles
    )


def test_only_the_command_line_imports_its_package() -> None:
    graph, modules = import_graph(ROOT, PACKAGES)
    offenders = [
        f"{modules[module].relative_to(ROOT)}:{line} imports {target}"
        for module, edges in graph.items()
        if module.split(".")[0] != CLI
        for target, line in edges.items()
        if target.split(".")[0] == CLI
    ]
    assert not offenders, "only the command line imports eigenscope: " + "; ".join(offenders)
