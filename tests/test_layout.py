"""The package's layers import one way only: no circle between its packages, deferred imports included."""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FIRST_PARTY = ("lerobot_taxdpd", "datasets_conv")


def _layer(module: str) -> str:
    """`lerobot_taxdpd.<package or module>`, or `datasets_conv`: the unit whose imports must not circle."""
    parts = module.split(".")
    return ".".join(parts[:2]) if parts[0] == "lerobot_taxdpd" else parts[0]


def _imported(tree: ast.AST) -> set[str]:
    names = set()
    for node in ast.walk(tree):  # imports inside functions count too: they still run
        if isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
        elif isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
    return {name for name in names if name.split(".")[0] in FIRST_PARTY}


def _layer_graph() -> dict[str, set[str]]:
    graph: dict[str, set[str]] = defaultdict(set)
    for package in FIRST_PARTY:
        for path in (ROOT / package).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            module = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            source = _layer(module)
            graph[source] |= {_layer(name) for name in _imported(ast.parse(path.read_text()))} - {source}
    return graph


def _circle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, str] = {}

    def visit(node: str, path: list[str]) -> list[str] | None:
        state[node] = "open"
        for target in sorted(graph.get(node, ())):
            if state.get(target) == "open":
                return [*path[path.index(target) :], target] if target in path else [node, target]
            if target not in state and (found := visit(target, [*path, target])):
                return found
        state[node] = "done"
        return None

    for start in sorted(graph):
        if start not in state and (found := visit(start, [start])):
            return found
    return None


def test_packages_import_each_other_without_a_circle():
    graph = _layer_graph()
    assert {"lerobot_taxdpd.policies", "lerobot_taxdpd.data", "lerobot_taxdpd.sim"} <= set(graph)
    assert _circle(graph) is None, " -> ".join(_circle(graph))
    # the foundations stay below the policies and the applications built on them
    assert graph["lerobot_taxdpd.data"] == set()
    assert graph["lerobot_taxdpd.maths"] <= {"lerobot_taxdpd.data"}
    assert graph["lerobot_taxdpd.policies"] <= {"lerobot_taxdpd.data", "lerobot_taxdpd.maths"}
