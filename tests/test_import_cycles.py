"""No import circles among flightrecon's modules, counting the lazy imports inside functions too.

A circle hidden in a function-level import still ties the modules on it into one piece: none of
them can be read, tested or moved alone, and the layers of docs/architecture.md stop meaning
anything. The walk reads the source with `ast` (nothing is imported), so it sees every import a
module can run, whichever branch or function it sits in. An edge goes to the module named, not to
the packages above it: `flightrecon/render/__init__.py` re-exporting its submodules is a facade,
not a circle.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "flightrecon"


def _module_name(path: Path, root: Path) -> str:
    parts = path.relative_to(root.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules(root: Path) -> dict[str, Path]:
    return {_module_name(p, root): p for p in sorted(root.rglob("*.py"))}


def _imported(node: ast.AST, here: str, is_package: bool, modules: dict[str, Path]) -> set[str]:
    """The package's modules an import statement loads: for `from X import a`, the submodule X.a when
    there is one, else X itself."""
    if isinstance(node, ast.Import):
        return {alias.name for alias in node.names} & modules.keys()
    if not isinstance(node, ast.ImportFrom):
        return set()
    base = node.module or ""
    if node.level:  # relative: from the package holding this module
        package = here.split(".") if is_package else here.split(".")[:-1]
        anchor = ".".join(package[:len(package) - node.level + 1])
        base = f"{anchor}.{base}" if base else anchor
    names = {f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base for alias in node.names}
    return names & modules.keys()


def import_graph(root: Path = PACKAGE) -> dict[str, set[str]]:
    """module -> the package's modules it imports anywhere in its source (top level or in a function)."""
    modules = _modules(root)
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        edges = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            edges |= _imported(node, name, path.name == "__init__.py", modules)
        edges.discard(name)
        graph[name] = edges
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted: every
    import circle lies inside one of them."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_import_circle_in_the_package():
    graph = import_graph()
    assert len(graph) > 100 and graph["flightrecon.mission.loop"]  # the walk found the package and its imports
    assert cycles(graph) == []


@pytest.mark.parametrize("lazy", [False, True])
def test_the_walk_finds_a_circle_top_level_or_in_a_function(tmp_path, lazy):
    pkg = tmp_path / "flightrecon"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("from flightrecon.sub.b import B\n")  # a facade: no circle
    (pkg / "a.py").write_text("from flightrecon.sub import b\n")
    back = "def f():\n    from .. import a\n" if lazy else "import flightrecon.a\n"
    (pkg / "sub" / "b.py").write_text(back + "B = 1\n")
    (pkg / "c.py").write_text("from flightrecon.a import x\n")
    assert cycles(import_graph(pkg)) == [["flightrecon.a", "flightrecon.sub.b"]]
    (pkg / "sub" / "b.py").write_text("B = 1\n")
    assert cycles(import_graph(pkg)) == []
