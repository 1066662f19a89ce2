"""No import cycles in fixer4d/ (DESIGN.md §2: imports only run downward).

The graph is built statically from every module's AST, so it sees every import the code can
execute, not only those one test run happens to trigger:

* Module-level AND function-level (lazy) imports both count. A lazy import only postpones
  when an edge is followed; the dependency is the same, and DESIGN's "imports only run
  downward" is about the dependency. Lazy imports remain the way to keep optional backends
  (gsplat, diffusers, ...) and heavy libraries off ``import fixer4d``, never a way around a cycle.
* Imports under ``if TYPE_CHECKING:`` do not count: they never execute.
* ``from fixer4d.a import b`` is an edge to the module ``fixer4d.a.b`` when that is a module,
  else to ``fixer4d.a`` (b is a name defined there). Importing ``fixer4d.a.b`` also runs
  ``fixer4d/a/__init__.py``; that implicit edge to the parent package is not counted, so a
  package ``__init__`` that re-exports its modules does not put every sibling import in a cycle.
"""
from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = "fixer4d"
ROOT = Path(__file__).resolve().parents[1] / PACKAGE


def module_names(root: Path = ROOT) -> dict[str, Path]:
    """Dotted module name -> file, for every .py under ``root``."""
    out = {}
    for path in sorted(root.rglob("*.py")):
        parts = list(path.relative_to(root.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(tree: ast.AST):
    """Import nodes of ``tree`` at any depth, skipping ``if TYPE_CHECKING:`` bodies."""
    stack = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            stack.extend(node.orelse)
            continue
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        stack.extend(ast.iter_child_nodes(node))


def import_graph(modules: dict[str, Path]) -> dict[str, set[str]]:
    """module -> the fixer4d modules it imports (see the module doc for what counts)."""
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for name, path in modules.items():
        is_pkg = path.name == "__init__.py"
        for node in _imports(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                if node.level:
                    base = name.split(".") if is_pkg else name.split(".")[:-1]
                    base = base[: len(base) - (node.level - 1)]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in modules else mod for a in node.names]
            for t in targets:
                while t and t not in modules and "." in t:  # import fixer4d.a.b.Name -> fixer4d.a.b
                    t = t.rsplit(".", 1)[0]
                if t in modules and t != name and t.split(".")[0] == PACKAGE:
                    graph[name].add(t)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One concrete cycle (a -> b -> ... -> a) per strongly connected component of size > 1."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    components: list[list[str]] = []

    def strongconnect(v: str) -> None:  # Tarjan; the graph has ~100 nodes, recursion is fine
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                strongconnect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                components.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            strongconnect(v)
    out = []
    for comp in components:  # shortest path from the first member back to itself inside the component
        members, start = set(comp), comp[0]
        prev: dict[str, str] = {}
        frontier, seen, end = [start], {start}, None
        while frontier and end is None:
            nxt = []
            for u in frontier:
                for w in sorted(graph[u] & members):
                    if w == start:
                        end = u
                        break
                    if w not in seen:
                        seen.add(w)
                        prev[w] = u
                        nxt.append(w)
                if end is not None:
                    break
            frontier = nxt
        path = [end]
        while path[-1] != start:
            path.append(prev[path[-1]])
        out.append(path[::-1] + [start])
    return out


def test_the_walker_sees_lazy_imports_and_finds_a_known_cycle(tmp_path):
    pkg = tmp_path / PACKAGE
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("from fixer4d.sub.a import f\n")
    (pkg / "sub" / "a.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from fixer4d import c\n"
                                      "def f():\n    from . import b\n")
    (pkg / "sub" / "b.py").write_text("import fixer4d.c\n")
    (pkg / "c.py").write_text("def g():\n    from fixer4d.sub.a import f\n")
    graph = import_graph(module_names(pkg))
    assert graph["fixer4d.sub.a"] == {"fixer4d.sub.b"}  # the TYPE_CHECKING import is not an edge
    assert graph["fixer4d.sub"] == {"fixer4d.sub.a"}
    assert cycles(graph) == [["fixer4d.c", "fixer4d.sub.a", "fixer4d.sub.b", "fixer4d.c"]]
    (pkg / "c.py").write_text("def show():\n    import glfw.library\n    from app.viewer import Viewer\n")
    assert cycles(import_graph(module_names(pkg))) == []
    assert external_imports(module_names(pkg))["fixer4d.c"] == {"glfw", "app"}


def test_fixer4d_has_no_import_cycles():
    modules = module_names()
    assert len(modules) > 50 and "fixer4d.render.api" in modules
    found = cycles(import_graph(modules))
    assert not found, "import cycles in fixer4d/:\n" + "\n".join(" -> ".join(c) for c in found)


# DESIGN.md §2: "the library has no GUI import" and "fixer4d never imports app".
GUI_MODULES = ("app", "glfw", "moderngl", "imgui", "imgui_bundle", "OpenGL")


def external_imports(modules: dict[str, Path]) -> dict[str, set[str]]:
    """module -> top-level names of every non-fixer4d module it imports (lazy ones included)."""
    out: dict[str, set[str]] = {}
    for name, path in modules.items():
        found = set()
        for node in _imports(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                found |= {a.name.split(".")[0] for a in node.names}
            elif not node.level and node.module:
                found.add(node.module.split(".")[0])
        out[name] = found - {PACKAGE}
    return out


def test_the_library_has_no_gui_import():
    bad = {m: sorted(e & set(GUI_MODULES)) for m, e in external_imports(module_names()).items() if e & set(GUI_MODULES)}
    assert not bad, f"GUI imports in the library: {bad}"
