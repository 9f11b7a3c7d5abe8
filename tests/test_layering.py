"""The zoo's modules import one another one way (its packages are the layers, data -> protocol
-> store -> hub -> evaluation -> stats -> report -> leaderboard -> cli): no module reaches,
directly or through others, back to itself. Imports inside functions count: they hide a circle,
they do not remove it. docs/architecture.md's package graph is the code's."""

import ast
import runpy
from pathlib import Path

ZOO = Path(__file__).resolve().parents[1] / "zoo"


def import_graph() -> dict[str, set[str]]:
    modules = {}
    for path in ZOO.rglob("*.py"):
        parts = path.relative_to(ZOO.parent).with_suffix("").parts
        modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    graph = {}
    for name, path in modules.items():
        targets = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                candidates = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                candidates = [a.name for a in node.names]
            else:
                continue
            targets |= {c for c in candidates if c in modules}
        # the package itself (``from zoo import __version__``) is not a layer
        graph[name] = targets - {name, "zoo"}
    return graph


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
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


def test_no_import_circles():
    graph = import_graph()
    assert (
        "zoo.protocol.plan" in graph["zoo.evaluation.evaluator"]
        and "zoo.paths" in graph["zoo.models.registry"]
    )
    assert circles(graph) == []


def test_the_circle_finder_finds_circles():
    assert circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_the_architecture_doc_draws_the_code_s_package_graph(capsys):
    graph = runpy.run_path(str(ZOO.parent / "docs" / "package_graph.py"))
    assert graph["main"](["--check"]) == 0, capsys.readouterr().out
    edges = graph["package_imports"]()
    assert "store" in edges["hub"] and "hub" not in edges["store"]
    # the reduction keeps an edge only where no longer path implies it
    assert graph["reduced"]({"a": {"b", "c"}, "b": {"c"}, "c": set()}) == {
        "a": {"b"},
        "b": {"c"},
        "c": set(),
    }
