"""The top-level packages form layers, and no package's modules import each other in a cycle.

Layers, lowest first (:data:`RANK`): ``common`` < ``services`` < ``system`` < {``missions``,
``eval``} < ``products`` < ``launcher``; a module imports only lower layers and its own
package. ``missions`` and ``eval`` share a rank and never import each other. ``benchmarks``,
``tests`` and ``deploy`` sit above everything and may import anything. Every import counts:
module level, inside a function or under ``TYPE_CHECKING``, absolute or relative.

A top-level folder holding ``.py`` files that is not in :data:`RANK` fails the test until it is
given a rank. The module import graph (every ``.py`` file of the ranked folders, edges from
the imports above) has no cycle: each strongly connected component is a single module.
"""
from __future__ import annotations

import ast
import functools
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TOP = 100                        # the rank of code that may import anything
RANK: dict[str, int] = {
    "common": 0,
    "services": 1,
    "system": 2,
    "missions": 3,
    "eval": 3,
    "products": 4,
    "launcher": 5,
    "benchmarks": TOP,
    "tests": TOP,
    "deploy": TOP,
}
SKIP_DIRS = {".venv", "state", "runs", "build"}


@dataclass(frozen=True)
class Import:
    """One import statement's target, resolved to an absolute dotted name."""

    path: Path                   # the importing file
    line: int
    target: str                  # ``a.b.c`` (the module, or the module a name is taken from)
    names: tuple[str, ...] = ()  # for ``from a.b import x, y``: ("x", "y")


def module_name(path: Path, root: Path = REPO) -> str:
    """The dotted module name of ``path`` (``pkg/__init__.py`` is ``pkg``)."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


@functools.cache
def imports_of(path: Path, root: Path = REPO) -> tuple[Import, ...]:
    """Every import in ``path`` (any nesting), relative ones resolved against its package."""
    return tuple(_imports(path, root))


def _imports(path: Path, root: Path) -> Iterator[Import]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    package = module_name(path, root).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield Import(path, node.lineno, alias.name)
        elif isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            target = ".".join([*base, *([node.module] if node.module else [])])
            yield Import(path, node.lineno, target, tuple(a.name for a in node.names))


def top_folders(root: Path = REPO) -> list[str]:
    """The top-level folders of ``root`` that hold Python code (hidden and output folders aside)."""
    return sorted(d.name for d in root.iterdir()
                  if d.is_dir() and not d.name.startswith(".") and d.name not in SKIP_DIRS
                  and not d.name.endswith(".egg-info") and any(d.rglob("*.py")))


def sources(root: Path = REPO) -> Iterator[Path]:
    """The ``.py`` files of the ranked top-level folders."""
    for top in top_folders(root):
        if top in RANK:
            yield from sorted((root / top).rglob("*.py"))


def layer_violations(root: Path = REPO, rank: dict[str, int] = RANK) -> list[str]:
    """``file:line: target`` for each import of a same or higher layer's package."""
    found = []
    for path in sources(root):
        own = path.relative_to(root).parts[0]
        for imp in imports_of(path, root):
            other = imp.target.split(".")[0]
            if other in rank and other != own and rank[other] >= rank[own] and rank[own] < TOP:
                found.append(f"{path.relative_to(root)}:{imp.line}: imports {imp.target} "
                             f"({other}, rank {rank[other]} >= {own}, rank {rank[own]})")
    return found


def import_graph(root: Path = REPO) -> dict[str, set[str]]:
    """Module -> the project modules it imports (``from pkg import mod`` is an edge to ``pkg.mod``)."""
    paths = list(sources(root))
    modules = {module_name(p, root) for p in paths}
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for path in paths:
        me = module_name(path, root)
        for imp in imports_of(path, root):
            subs = [f"{imp.target}.{n}" for n in imp.names if f"{imp.target}.{n}" in modules]
            if subs:
                graph[me].update(subs)
            if imp.target in modules and len(subs) < max(len(imp.names), 1):
                graph[me].add(imp.target)
        graph[me].discard(me)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(start: str) -> None:   # iterative, so a deep graph does not hit the recursion limit
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            for child in children:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            else:
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

    for module in sorted(graph):
        if module not in index:
            visit(module)
    return sorted(found)


def describe_cycle(graph: dict[str, set[str]], component: list[str]) -> str:
    """One closed path through ``component``: ``a -> b -> a``."""
    members = set(component)
    path = [component[0]]
    seen = {component[0]: 0}
    while True:
        step = sorted(graph[path[-1]] & members)[0]
        if step in seen:
            return " -> ".join([*path[seen[step]:], step])
        seen[step] = len(path)
        path.append(step)


def test_every_top_level_package_has_a_rank() -> None:
    folders = top_folders()
    assert {"common", "services", "launcher", "tests"} <= set(folders)   # the walk sees the project
    unranked = [f for f in folders if f not in RANK]
    assert not unranked, f"top-level packages without a layer (give them one in tests/test_layering.py RANK): {unranked}"


def test_each_layer_imports_only_lower_layers() -> None:
    found = layer_violations()
    assert not found, "imports of a same or higher layer:\n" + "\n".join(found)


def test_missions_and_eval_do_not_import_each_other() -> None:
    assert RANK["missions"] == RANK["eval"]      # so the layer rule above forbids it
    found = [v for v in layer_violations() if v.startswith(("missions/", "eval/"))
             and (" imports eval" in v or " imports missions" in v)]
    assert not found, "\n".join(found)


def test_no_import_cycle_between_modules() -> None:
    graph = import_graph()
    assert "launcher.cli" in graph and "common.node" in graph["services.expmap.node"]
    found = [describe_cycle(graph, c) for c in cycles(graph)]
    assert not found, "import cycles:\n" + "\n".join(found)


def _write(root: Path, files: dict[str, str]) -> None:
    for rel, text in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)


def test_the_checker_flags_an_upward_import_with_its_line(tmp_path: Path) -> None:
    _write(tmp_path, {"common/a.py": "import os\n\ndef f():\n    from launcher import cli\n",
                      "launcher/cli.py": "from common import a\n",
                      "eval/e.py": "from missions.m import x\n", "missions/m.py": "x = 1\n",
                      "tests/t.py": "import launcher.cli\n"})
    found = layer_violations(tmp_path)
    assert [v.split(":")[:2] for v in found] == [["common/a.py", "4"], ["eval/e.py", "1"]]


def test_the_checker_flags_an_unranked_package(tmp_path: Path) -> None:
    _write(tmp_path, {"common/a.py": "", "docs/x.md": "", "newpkg/b.py": ""})
    assert [f for f in top_folders(tmp_path) if f not in RANK] == ["newpkg"]


def test_the_checker_finds_a_cycle_through_relative_and_local_imports(tmp_path: Path) -> None:
    _write(tmp_path, {"eval/__init__.py": "", "eval/a.py": "from . import b\n",
                      "eval/b.py": "def f():\n    from .c import g\n",
                      "eval/c.py": "import eval.a\n", "eval/d.py": "from eval.a import thing\n"})
    graph = import_graph(tmp_path)
    assert graph["eval.d"] == {"eval.a"}
    assert cycles(graph) == [["eval.a", "eval.b", "eval.c"]]
    assert describe_cycle(graph, cycles(graph)[0]) == "eval.a -> eval.b -> eval.c -> eval.a"
