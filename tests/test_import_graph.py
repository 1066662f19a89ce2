"""No import cycles in fixer4d/ or app/, and imports only run downward (docs/design.md §3).

* fixer4d/ and app/ (the viewer) have no import cycle, each alone and together.
* fixer4d's packages sit in layers (``LAYERS``, geometry at the bottom): a module imports only
  its own layer and the ones below it; the command line (``fixer4d.cli``) is the top, and the
  only place that parses arguments (``test_only_the_command_line_parses_arguments``).
* fixer4d never imports app: no import statement (``test_the_library_has_no_gui_import``) and
  no dynamic load either (importlib / ``__import__`` naming ``app``: ``dynamic_app_loads``); a
  package above the library registers itself through an entry point instead.

The graph is built statically from every module's AST, so it sees every import the code can
execute, not only those one test run happens to trigger:

* Module-level AND function-level (lazy) imports both count. A lazy import only postpones
  when an edge is followed; the dependency is the same, and "imports only run downward"
  (docs/design.md §3) is about the dependency. Lazy imports remain the way to keep optional backends
  (gsplat, diffusers, ...) and heavy libraries off ``import fixer4d``, never a way around a cycle.
* Imports under ``if TYPE_CHECKING:`` do not count: they never execute.
* Package ``__init__`` files count as the modules they are:
  - ``from fixer4d.a import b`` reads the namespace of ``fixer4d.a``: an edge to ``fixer4d.a``
    (its ``__init__``), and also to ``fixer4d.a.b`` when that is a module. This holds inside the
    package too: a module of ``a`` that wants a sibling writes ``import fixer4d.a.b as b`` or
    ``from fixer4d.a.b import name``, never reaching through the package its ``__init__`` is
    still building.
  - Importing ``fixer4d.a.b`` (in any form) first runs ``fixer4d/a/__init__.py``: an edge to
    ``fixer4d.a`` from every importer outside ``a`` (a module inside ``a`` runs after its
    package's ``__init__`` has started, so the package is not a new dependency of it).
"""
from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = "fixer4d"
ROOT = Path(__file__).resolve().parents[1] / PACKAGE
APP_ROOT = ROOT.parent / "app"


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


def _ancestors(module: str) -> list[str]:
    """'fixer4d.a.b.c' -> ['fixer4d', 'fixer4d.a', 'fixer4d.a.b']."""
    parts = module.split(".")
    return [".".join(parts[:k]) for k in range(1, len(parts))]


def import_graph(modules: dict[str, Path]) -> dict[str, set[str]]:
    """module -> the modules of ``modules`` it imports (see the module doc for what counts)."""
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for name, path in modules.items():
        is_pkg = path.name == "__init__.py"
        already_run = set(_ancestors(name))  # a module's own packages are initialised before it runs
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
                if mod in modules and modules[mod].name == "__init__.py":
                    targets.append(mod)  # `from P import x` reads P's namespace: P's __init__ is a dependency
            for t in targets:
                while t and t not in modules and "." in t:  # import fixer4d.a.b.Name -> fixer4d.a.b
                    t = t.rsplit(".", 1)[0]
                if t not in modules:
                    continue
                # importing P.m runs P's __init__ first (unless the importer is inside P)
                for dep in [t] + [a for a in _ancestors(t) if a in modules and a not in already_run]:
                    if dep != name:
                        graph[name].add(dep)
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
    # `from . import b` reads the package's namespace; the TYPE_CHECKING import is not an edge
    assert graph["fixer4d.sub.a"] == {"fixer4d.sub", "fixer4d.sub.b"}
    assert graph["fixer4d.sub"] == {"fixer4d.sub.a"}
    assert graph["fixer4d.c"] == {"fixer4d.sub", "fixer4d.sub.a"}  # importing sub.a runs sub's __init__
    assert cycles(graph) == [["fixer4d.c", "fixer4d.sub.a", "fixer4d.sub.b", "fixer4d.c"]]
    # a package whose __init__ imports a module that reaches back through the package's namespace
    (pkg / "c.py").write_text("")
    (pkg / "sub" / "b.py").write_text("")
    assert cycles(import_graph(module_names(pkg))) == [["fixer4d.sub", "fixer4d.sub.a", "fixer4d.sub"]]
    (pkg / "sub" / "a.py").write_text("def f():\n    import fixer4d.sub.b as b\n")  # the sibling, not the package
    graph = import_graph(module_names(pkg))
    assert graph["fixer4d.sub.a"] == {"fixer4d.sub.b"} and cycles(graph) == []
    (pkg / "c.py").write_text("def show():\n    import glfw.library\n    from app.viewer import Viewer\n")
    # app is not among the modules walked here: an import of it is no edge (but see external_imports)
    assert cycles(import_graph(module_names(pkg))) == []
    assert external_imports(module_names(pkg))["fixer4d.c"] == {"glfw", "app"}


def test_fixer4d_has_no_import_cycles():
    modules = module_names()
    assert len(modules) > 50 and "fixer4d.render.api" in modules
    found = cycles(import_graph(modules))
    assert not found, "import cycles in fixer4d/:\n" + "\n".join(" -> ".join(c) for c in found)


# docs/design.md §3: "the library has no GUI import" and "fixer4d never imports app".
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


# fixer4d's packages from the bottom layer up; a module may import its own layer and lower ones.
# The command line (``fixer4d.cli``, and any ``__main__``) is the top layer; the package
# root (``fixer4d/__init__.py``: process settings, no fixer4d imports) is the bottom.
LAYERS = (("errors", "atomic", "signals", "threads", "psnr", "cpus", "simd", "jsonfile", "numerics", "mkl_vendor", "stats"), ("geometry",), ("calib",), ("scene", "model", "restore"), ("render", "jit"),
          ("init", "eval"), ("train",), ("pipeline",), ("bench", "study"))


def layer_of(module: str) -> int:
    """The layer index of a fixer4d module (KeyError for a package missing from LAYERS)."""
    parts = module.split(".")
    if len(parts) == 1:
        return 0
    last = parts[-1]
    if parts[1] == "cli" or last == "__main__":
        return len(LAYERS)
    for k, names in enumerate(LAYERS):
        if parts[1] in names:
            return k
    raise KeyError(f"{module}: its package {parts[1]!r} has no layer; add it to LAYERS in tests/test_import_graph.py")


def upward_imports(graph: dict[str, set[str]]) -> list[str]:
    """'a -> b' for every fixer4d import of a higher layer than the importer's."""
    return sorted(f"{a} (layer {layer_of(a)}) -> {b} (layer {layer_of(b)})" for a, targets in graph.items()
                  if a.split(".")[0] == PACKAGE for b in targets
                  if b.split(".")[0] == PACKAGE and layer_of(b) > layer_of(a))


# Calls that load a module named by a value (importlib.import_module, __import__, runpy, ...).
DYNAMIC_LOADERS = ("import_module", "__import__", "find_spec", "spec_from_file_location", "load_module",
                   "run_module", "run_path", "SourceFileLoader")


def _names_app(text: str) -> bool:
    """A string naming the app package: "app", "app.bench", "app.bench:main", "app/bench.py"."""
    head = text.split(":")[0].replace("/", ".").removesuffix(".py")
    return head == "app" or head.startswith("app.")


def dynamic_app_loads(modules: dict[str, Path]) -> dict[str, list[str]]:
    """module -> the strings naming ``app`` in a module that loads modules dynamically (a
    constant passed to a loader, or any such constant elsewhere in the module, e.g. a table of
    module names the loader reads)."""
    out: dict[str, list[str]] = {}
    for name, path in modules.items():
        tree = ast.parse(path.read_text(), str(path))
        loads = any(isinstance(n, ast.Call) and ((isinstance(n.func, ast.Name) and n.func.id in DYNAMIC_LOADERS) or
                                                 (isinstance(n.func, ast.Attribute) and n.func.attr in DYNAMIC_LOADERS))
                    for n in ast.walk(tree))
        if not loads:
            continue
        found = [n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)
                 and _names_app(n.value)]
        if found:
            out[name] = found
    return out


def test_app_and_fixer4d_have_no_import_cycles():
    modules = {**module_names(ROOT), **module_names(APP_ROOT)}
    assert "app.viewer" in modules and "app.main" in modules
    found = cycles(import_graph(modules))
    assert not found, "import cycles:\n" + "\n".join(" -> ".join(c) for c in found)


def test_fixer4d_imports_only_run_downward():
    found = upward_imports(import_graph(module_names()))
    assert not found, "imports of a higher layer (see LAYERS):\n" + "\n".join(found)


def test_fixer4d_never_loads_app_dynamically():
    found = dynamic_app_loads(module_names())
    assert not found, f"fixer4d loads app by name (register an entry point instead): {found}"


def test_the_checks_catch_a_broken_tree(tmp_path):
    """A deliberately broken pair of packages: each rule above reports its violation."""
    lib, app = tmp_path / PACKAGE, tmp_path / "app"
    for d in (lib / "geometry", lib / "train", lib / "bench", app / "panels"):
        d.mkdir(parents=True)
        (d / "__init__.py").write_text("")
    (lib / "__init__.py").write_text("")
    (app / "__init__.py").write_text("")
    (lib / "geometry" / "camera.py").write_text("def fit():\n    from fixer4d.train import loop\n")  # upward
    (lib / "train" / "loop.py").write_text("from fixer4d.geometry import camera\n")
    (lib / "bench" / "cli.py").write_text("import importlib\nBENCHES = {'viewer': 'app.bench'}\n"
                                           "def run(n):\n    return importlib.import_module(BENCHES[n])\n")
    (lib / "bench" / "raw.py").write_text("def run():\n    return __import__('app.bench')\n")
    (lib / "bench" / "fine.py").write_text("import importlib\ndef run():\n    return importlib.import_module('fixer4d.train')\n")
    (app / "main.py").write_text("from app.viewer import Viewer\n")
    (app / "viewer.py").write_text("def open_():\n    from app.panels.files import ask\n")
    (app / "panels" / "files.py").write_text("def ask():\n    from app.main import open_source\n")  # lazy, still a cycle
    lib_modules = module_names(lib)
    graph = import_graph({**lib_modules, **module_names(app)})
    assert cycles(graph) == [["app.main", "app.viewer", "app.panels.files", "app.main"],
                             ["fixer4d.geometry.camera", "fixer4d.train.loop", "fixer4d.geometry.camera"]]
    # the geometry <-> train cycle is caught as a cycle; its upward edge by the layer rule too
    assert upward_imports(graph) == [f"fixer4d.geometry.camera (layer 1) -> fixer4d.train{m} (layer {layer_of('fixer4d.train')})"
                                     for m in ("", ".loop")]
    assert dynamic_app_loads(lib_modules) == {"fixer4d.bench.cli": ["app.bench"], "fixer4d.bench.raw": ["app.bench"]}
    (lib / "geometry" / "camera.py").write_text("")
    (app / "panels" / "files.py").write_text("def ask(services):\n    return services.open_source\n")
    fixed = import_graph({**module_names(lib), **module_names(app)})
    assert cycles(fixed) == [] and upward_imports(fixed) == []


# The library below the pipeline: what a run is made of, usable without a run folder or a command line.
BELOW_THE_PIPELINE = ("geometry", "model", "render", "scene", "init", "restore", "train", "eval")


def reaches_up(graph: dict[str, set[str]]) -> list[str]:
    """'a -> b' for every import of the pipeline or the command line by a module of BELOW_THE_PIPELINE."""
    top = (f"{PACKAGE}.pipeline", f"{PACKAGE}.cli")
    return sorted(f"{a} -> {b}" for a, targets in graph.items() if a.split(".")[1:2] and a.split(".")[1] in BELOW_THE_PIPELINE
                  for b in targets if any(b == t or b.startswith(t + ".") for t in top))


def test_the_library_never_imports_the_pipeline_or_a_verb():
    found = reaches_up(import_graph(module_names()))
    assert not found, "imports of fixer4d.pipeline or fixer4d.cli below the pipeline:\n" + "\n".join(found)


def test_only_the_command_line_parses_arguments():
    """Verbs are modules of fixer4d.cli; no other module is a command line of its own (named
    like one, or importing argparse), except the benchmarks, whose options `fixer4d bench NAME`
    passes through."""
    def parses(name: str) -> bool:
        return "argparse" in external_imports({name: modules[name]})[name]

    modules = module_names()
    found = sorted(m for m in modules if m.split(".")[1:2] not in (["cli"], ["bench"])
                   and ("cli" in m.split(".")[-1] or parses(m)))
    assert not found, f"argument parsing outside fixer4d/cli: {found}"


def test_the_floors_checks_catch_a_verb_below(tmp_path):
    lib = tmp_path / PACKAGE
    for d in (lib / "render", lib / "pipeline", lib / "cli"):
        d.mkdir(parents=True)
        (d / "__init__.py").write_text("")
    (lib / "__init__.py").write_text("")
    (lib / "pipeline" / "stages.py").write_text("")
    (lib / "cli" / "common.py").write_text("")
    (lib / "render" / "cli.py").write_text("import argparse\ndef run():\n    from fixer4d.pipeline import stages\n")
    (lib / "render" / "video.py").write_text("from fixer4d.cli.common import x\n")
    graph = import_graph(module_names(lib))
    assert reaches_up(graph) == ["fixer4d.render.cli -> fixer4d.pipeline", "fixer4d.render.cli -> fixer4d.pipeline.stages",
                                 "fixer4d.render.video -> fixer4d.cli", "fixer4d.render.video -> fixer4d.cli.common"]
