"""The import graph of the project's modules (every import statement, also inside functions and
``TYPE_CHECKING`` blocks): no circle, layers in one direction (``hydra_plugins`` →
``experiments`` → ``ttc``; in ``ttc``, evaluation and drawing below the engine), the core
free of Hydra, and no source file over the size where grab-bags grow."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from tests.conftest import PROJECT_ROOT

PACKAGES = ("ttc", "experiments", "hydra_plugins")
#: The engine: what runs settings over frames (evaluation and drawing work on its tables).
ENGINE = "ttc.engine"
MAX_LINES = 400


def _modules() -> dict[str, Path]:
    out = {}
    for package in PACKAGES:
        for path in sorted((PROJECT_ROOT / package).rglob("*.py")):
            name = ".".join(path.relative_to(PROJECT_ROOT).with_suffix("").parts)
            out[name.removesuffix(".__init__")] = path
    return out


def _imports(path: Path, modules: dict[str, Path]) -> set[str]:
    """The project modules ``path`` imports (``from pkg import mod`` counts as ``pkg.mod``)."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            subs = {f"{node.module}.{alias.name}" for alias in node.names}
            found |= {s for s in subs if s in modules} or {node.module}
    return {m for m in found if m in modules}


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: _imports(path, modules) - {name} for name, path in modules.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

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
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_graph_is_read() -> None:
    modules = _modules()
    assert "ttc.engine.runner" in modules and "experiments.run" in modules
    assert "ttc.settings" in _imports(modules["ttc.engine.runner"], modules)
    assert "ttc.steps.fusion" in _imports(modules["ttc.evaluation.fused_diagnosis"], modules)


def test_no_import_circle(graph: dict[str, set[str]]) -> None:
    assert _cycles(graph) == []


def test_a_circle_would_be_found() -> None:
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_layers_point_one_way(graph: dict[str, set[str]]) -> None:
    up = {
        m: sorted(d for d in deps if d.split(".")[0] != "ttc")
        for m, deps in graph.items()
        if m.startswith("ttc")
    }
    assert {m: d for m, d in up.items() if d} == {}
    from_experiments = {
        m: sorted(d for d in deps if d.startswith("hydra_plugins"))
        for m, deps in graph.items()
        if m.startswith("experiments")
    }
    assert {m: d for m, d in from_experiments.items() if d} == {}


def test_evaluation_and_drawing_import_nothing_from_the_engine(
    graph: dict[str, set[str]],
) -> None:
    judged = {
        m: sorted(d for d in deps if d.startswith(ENGINE))
        for m, deps in graph.items()
        if m.startswith(("ttc.evaluation", "ttc.draw"))
    }
    assert {m: d for m, d in judged.items() if d} == {}


def test_the_core_knows_no_hydra() -> None:
    for name, path in _modules().items():
        if name.startswith("ttc"):
            tree = ast.parse(path.read_text())
            roots = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import)
                     for a in n.names}  # fmt: skip
            roots |= {n.module.split(".")[0] for n in ast.walk(tree)
                      if isinstance(n, ast.ImportFrom) and n.module}  # fmt: skip
            assert not roots & {"hydra", "omegaconf", "experiments"}, name


def test_no_source_file_is_a_grab_bag() -> None:
    long = {
        name: n
        for name, path in _modules().items()
        if (n := len(path.read_text().splitlines())) > MAX_LINES
    }
    assert long == {}


def test_no_base_name_in_two_layers() -> None:
    """A module name means one thing: the core and the wiring do not share file names."""
    layers: dict[str, set[str]] = {}
    for name, path in _modules().items():
        if path.name != "__init__.py":
            layers.setdefault(path.stem, set()).add(name.split(".")[0])
    assert {stem: sorted(found) for stem, found in layers.items() if len(found) > 1} == {}
