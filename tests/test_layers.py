"""The package's import graph: no cycles, and imports point down the layers.

Every ``import`` and ``from ... import`` of a handeye module counts, at module level or inside a
function (a deferred import is still a dependency).
"""

from __future__ import annotations

import ast
from pathlib import Path

import handeye

PACKAGE = Path(handeye.__file__).resolve().parent
MAX_LINES = 600

#: lower layers never import higher ones (a name: every module in that package or that module)
LAYERS = (
    (
        "errors",
        "frames",
        "camera",
        "targets",
        "records",
        "mounting",
        "conventions",
        "special",
        "stats",
        "output",
        "config",
        "machine",
    ),
    ("configs", "apply", "kinematics", "factors", "contract"),
    ("session", "detect", "initial", "refine"),
    ("diagnose",),
    ("pipeline", "results", "options"),
    ("report",),
    ("collect",),
    ("recal",),
    ("export", "workflow"),
    ("cell",),
    ("batch",),
    ("sim", "cli"),
    ("__main__",),  # python -m handeye: the command
)


def _modules() -> dict[str, Path]:
    mods = {}
    for p in sorted(PACKAGE.rglob("*.py")):
        parts = list(p.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        mods[".".join(parts)] = p
    return mods


def _graph() -> dict[str, set[str]]:
    mods = _modules()
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for m, p in mods.items():
        pkg = m.split(".") if p.name == "__init__.py" else m.split(".")[:-1]
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                base = node.module or "" if node.level == 0 else ".".join(pkg[: len(pkg) - node.level + 1])
                if node.level and node.module:
                    base = f"{base}.{node.module}"
                names = [base] + [f"{base}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                continue
            for name in names:
                while name and name not in mods:
                    name = name.rpartition(".")[0]
                if name and name != m:
                    graph[m].add(name)
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def _layer(module: str) -> int:
    top = module.split(".")[1] if "." in module else ""
    for k, names in enumerate(LAYERS):
        if top in names:
            return k
    raise AssertionError(f"{module} is in no layer of tests/test_layers.py: add it")


def test_the_import_graph_has_no_cycle():
    assert _cycles(_graph()) == []


def test_imports_point_down_the_layers():
    graph = _graph()
    up = sorted(
        f"{m} -> {d}"
        for m, deps in graph.items()
        if m != "handeye"
        for d in deps
        if d != "handeye" and _layer(d) > _layer(m)
    )
    assert up == []


def test_no_module_is_longer_than_600_lines():
    long = {m: n for m, p in _modules().items() if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES}
    assert long == {}


def test_the_graph_sees_deferred_imports():
    """A function-level import is an edge: the check cannot be fooled by moving an import into a function."""
    graph = _graph()
    assert "handeye.workflow" in graph["handeye.cli.calibrate"]  # imported inside run()
    assert "handeye.refine.problem" in graph["handeye.refine.refitting"]
