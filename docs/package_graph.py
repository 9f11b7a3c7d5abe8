"""The package graph of docs/architecture.md, drawn from the code: which of zoo's packages
import which (import-linter's own graph, ``grimp``), as a Mermaid picture between the
doc's markers. ``python docs/package_graph.py`` rewrites the picture; ``--check`` exits 1
where the doc no longer shows the code (tests/test_layering.py runs it)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import grimp

DOC = Path(__file__).with_name("architecture.md")
BEGIN, END = "<!-- package graph: begin -->", "<!-- package graph: end -->"


def package_imports() -> dict[str, set[str]]:
    """Each package (or top-level module) of zoo -> the packages it imports directly."""
    graph = grimp.build_graph("zoo")

    def package(module: str) -> str | None:
        parts = module.split(".")
        return parts[1] if len(parts) > 1 else None

    edges: dict[str, set[str]] = {}
    for module in graph.modules:
        source = package(module)
        if source is None:
            continue
        edges.setdefault(source, set())
        for imported in graph.find_modules_directly_imported_by(module):
            target = package(imported)
            if target is not None and target != source:
                edges[source].add(target)
    return edges


def reduced(edges: dict[str, set[str]]) -> dict[str, set[str]]:
    """The edges no longer path implies (the transitive reduction of an acyclic graph)."""

    def reach(node: str, seen: set[str]) -> set[str]:
        for nxt in edges.get(node, ()):
            if nxt not in seen:
                seen.add(nxt)
                reach(nxt, seen)
        return seen

    out = {}
    for source, targets in edges.items():
        implied = set().union(*(reach(t, set()) for t in targets)) if targets else set()
        out[source] = {t for t in targets if t not in implied}
    return out


def picture() -> str:
    edges = package_imports()
    lines = ["```mermaid", "flowchart TD"]
    for source in sorted(edges):
        for target in sorted(reduced(edges)[source]):
            lines.append(f"    {source} --> {target}")
    lines.append("```")
    lines.append("")
    lines.append("| package | imports directly |")
    lines.append("|---|---|")
    for source in sorted(edges, key=lambda s: (-len(_below(edges, s)), s)):
        imported = ", ".join(f"`{t}`" for t in sorted(edges[source])) or "-"
        lines.append(f"| `{source}` | {imported} |")
    return "\n".join(lines)


def _below(edges: dict[str, set[str]], node: str) -> set[str]:
    seen: set[str] = set()
    todo = list(edges.get(node, ()))
    while todo:
        n = todo.pop()
        if n not in seen:
            seen.add(n)
            todo += edges.get(n, ())
    return seen


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if the doc is stale")
    args = parser.parse_args(argv)
    text = DOC.read_text()
    if BEGIN not in text or END not in text:
        print(f"{DOC}: the markers {BEGIN} and {END} are missing", file=sys.stderr)
        return 1
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    new = f"{head}{BEGIN}\n{picture()}\n{END}{tail}"
    if args.check:
        if new != text:
            print(f"{DOC}: the package graph is not the code's; run python {__file__}")
            return 1
        print(f"{DOC}: the package graph is the code's")
        return 0
    if new == text:
        print(f"{DOC}: unchanged")
        return 0
    tmp = DOC.with_suffix(".md.tmp")
    tmp.write_text(new)
    tmp.replace(DOC)
    print(f"{DOC}: package graph rewritten")
    return 0


if __name__ == "__main__":
    sys.exit(main())
