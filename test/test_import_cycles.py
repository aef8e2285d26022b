"""No import cycles in canopy_stereo, between modules or between its folders.

Data flows one way through the package, and imports follow it downwards::

    ros   cli   batch   pipeline          on top: commands, nodes, end-to-end runs
      \\     |     |     /
    sim  viz  fusion  measure             points -> measurements, models, pictures
               |        |
    segmentation  disparity  elas  features    images -> rectified -> disparity, masks
                   \\     |     /
                   io -> geometry         at the bottom: files, cameras, rigs, transforms

(images -> rectified -> disparity -> points -> measurements). A module may import
what lies below it, never what lies above, so no module and no folder ever
reaches itself through its imports. The graph is read from the source with
:mod:`ast`, counting every import: module level, inside functions, under
``TYPE_CHECKING``, absolute and relative. ``from canopy_stereo.x import y`` is an
edge to ``canopy_stereo.x.y`` when that is a module, else to ``canopy_stereo.x``
(its ``__init__``); importing a submodule does not count as importing its parent
package's ``__init__`` (Python allows that while the package initialises).
Top-level modules (``canopy_stereo.errors``, the package ``__init__``) are nodes of
their own in the folder graph.
"""
from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

PACKAGE = "canopy_stereo"
ROOT = Path(__file__).resolve().parents[1] / PACKAGE

#: Folders at the bottom and what each may import (besides itself and top-level modules).
BOTTOM = {"geometry": set(), "io": {"geometry"}}
#: Folders on top: nothing below them may import them.
TOP = {"ros", "cli", "batch", "pipeline"}


def _modules() -> dict[str, tuple[Path, bool]]:
    """Dotted module name -> (file, is package ``__init__``)."""
    mods = {}
    for path in sorted(ROOT.rglob("*.py")):
        parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
        is_pkg = parts[-1] == "__init__"
        if is_pkg:
            parts = parts[:-1]
        mods[".".join(parts)] = (path, is_pkg)
    return mods


def _resolve(name: str, mods) -> str | None:
    """The longest prefix of ``name`` that is a module of the package."""
    while name and name not in mods:
        name = name.rpartition(".")[0]
    return name or None


def import_graph() -> dict[str, dict[str, list[str]]]:
    """``{module: {imported module: ["file:line", ...]}}`` over all of canopy_stereo."""
    mods = _modules()
    graph: dict[str, dict[str, list[str]]] = {}
    for name, (path, is_pkg) in mods.items():
        edges: dict[str, list[str]] = defaultdict(list)
        package = name if is_pkg else name.rpartition(".")[0]
        where = str(path.relative_to(ROOT.parent))
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            targets = []
            if isinstance(node, ast.Import):
                targets = [_resolve(a.name, mods) for a in node.names if a.name.split(".")[0] == PACKAGE]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")
                    base = base[:len(base) - (node.level - 1)]
                    module = ".".join(base + ([node.module] if node.module else []))
                else:
                    module = node.module or ""
                if module.split(".")[0] != PACKAGE:
                    continue
                for alias in node.names:
                    full = f"{module}.{alias.name}"
                    targets.append(full if full in mods else _resolve(module, mods))
            for target in targets:
                place = f"{where}:{node.lineno}"
                if target is not None and target != name and place not in edges[target]:
                    edges[target].append(place)
        graph[name] = dict(edges)
    return graph


def folder_of(module: str) -> str:
    """``canopy_stereo.measure.leaf`` -> ``measure``; top-level modules stand for themselves."""
    parts = module.split(".")
    if len(parts) >= 2 and (ROOT / parts[1]).is_dir():
        return parts[1]
    return module


def folder_graph(graph) -> dict[str, dict[str, list[str]]]:
    """``{folder: {imported folder: ["file:line -> module", ...]}}``."""
    out: dict[str, dict[str, list[str]]] = defaultdict(lambda: defaultdict(list))
    for module, edges in graph.items():
        for target, places in edges.items():
            a, b = folder_of(module), folder_of(target)
            if a != b:
                out[a][b] += [f"{p} -> {target}" for p in places if f"{p} -> {target}" not in out[a][b]]
    return {k: dict(v) for k, v in out.items()}


def find_cycles(graph) -> list[list[str]]:
    """One cycle (``[a, b, ..., a]``) per strongly connected component with more than one node."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []

    def visit(v: str) -> None:  # Tarjan; the package is far too shallow for the recursion limit
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, {}):
            if w not in index:
                visit(w)
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
            visit(v)
    cycles = []
    for comp in components:  # shortest way back to the first node, inside the component
        members, start = set(comp), comp[0]
        came_from = {start: None}
        frontier = [start]
        found = None
        while frontier and found is None:
            nxt = []
            for v in frontier:
                for w in sorted(graph.get(v, {})):
                    if w == start:
                        found = v
                        break
                    if w in members and w not in came_from:
                        came_from[w] = v
                        nxt.append(w)
                if found is not None:
                    break
            frontier = nxt
        path = [start]
        v = found
        while v is not None and v != start:
            path.append(v)
            v = came_from[v]
        cycles.append([start] + path[1:][::-1] + [start])
    return cycles


def _describe(cycle, graph) -> str:
    steps = []
    for a, b in zip(cycle, cycle[1:]):
        steps.append(f"  {a} -> {b}   ({'; '.join(graph[a][b][:3])})")
    return " -> ".join(cycle) + "\n" + "\n".join(steps)


def test_the_graph_sees_function_level_and_relative_imports(tmp_path):
    """The reader itself: a known import inside a function is an edge."""
    graph = import_graph()
    # batch.run_batch imports the engine inside a function (Dask is optional)
    assert "canopy_stereo.batch.engine" in graph["canopy_stereo.batch"]
    assert "canopy_stereo.errors" in graph["canopy_stereo.io.rig"]
    assert find_cycles({"a": {"b": []}, "b": {"c": []}, "c": {"a": []}, "d": {"a": []}}) == [
        ["a", "b", "c", "a"]]
    tree = ast.parse("def f():\n    from .leaf import measure_leaf\n")
    node = tree.body[0].body[0]
    assert isinstance(node, ast.ImportFrom) and node.level == 1


def test_no_module_imports_itself_through_others():
    graph = import_graph()
    cycles = find_cycles(graph)
    assert not cycles, "import cycles between modules:\n" + "\n".join(_describe(c, graph) for c in cycles)


def test_no_folder_imports_itself_through_others():
    graph = folder_graph(import_graph())
    cycles = find_cycles(graph)
    assert not cycles, "import cycles between folders:\n" + "\n".join(_describe(c, graph) for c in cycles)


def test_imports_follow_the_data_flow():
    """io and geometry sit at the bottom; ros, cli, batch and pipeline on top."""
    graph = folder_graph(import_graph())
    wrong = []
    for folder, edges in sorted(graph.items()):
        for target, places in sorted(edges.items()):
            if not (ROOT / target).is_dir():
                continue  # top-level modules (errors) are below everything
            if folder in BOTTOM and target not in BOTTOM[folder]:
                wrong.append(f"{folder} (bottom) imports {target}: {places[0]}")
            if target in TOP and folder not in TOP:
                wrong.append(f"{folder} imports {target} (top): {places[0]}")
    assert not wrong, "imports against the data flow:\n" + "\n".join(wrong)
