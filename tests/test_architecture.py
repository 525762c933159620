"""The import graph of the project's modules (every import statement, also inside functions and
``TYPE_CHECKING`` blocks): no circle, layers in one direction (``hydra_plugins`` →
``experiments`` → ``ttc``, and inside ``experiments`` the layers of ``docs/architecture.md``;
in ``ttc``, evaluation and drawing below the engine), the core
free of Hydra, and no source file over the size where grab-bags grow."""

from __future__ import annotations

import ast
import re
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


def layers() -> list[list[str]]:
    """The layers of ``docs/architecture.md``'s "Layers" list, lowest first: each a list of
    module prefixes (a package or a module)."""
    text = (PROJECT_ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    section = text.split("\n## Layers\n", 1)[1].split("\n## ", 1)[0]
    found = [re.match(r"^\d+\. ((?:`[\w.]+` ?)+):", line) for line in section.splitlines()]
    return [re.findall(r"`([\w.]+)`", m.group(1)) for m in found if m]


def _layer_of(module: str, table: list[list[str]]) -> tuple[int, str] | None:
    """(layer index, the prefix that holds ``module``) in ``table``, None when none does."""
    for index, prefixes in enumerate(table):
        for prefix in prefixes:
            if module == prefix or module.startswith(prefix + "."):
                return index, prefix
    return None


def upward_imports(graph: dict[str, set[str]], table: list[list[str]]) -> list[str]:
    """Every import of ``graph`` that goes up ``table``'s layers, or sideways between two
    packages of one layer below the top (the top layer's entry points may call each other),
    as ``"importer -> imported"``; a module in no layer is listed as ``"module -> ?"``."""
    out = []
    for module, deps in sorted(graph.items()):
        if module in {p.split(".")[0] for layer in table for p in layer}:
            continue  # a bare package folder (its __init__)
        mine = _layer_of(module, table)
        if mine is None:
            out.append(f"{module} -> ?")
            continue
        for dep in sorted(deps):
            theirs = _layer_of(dep, table)
            up = theirs is None or theirs[0] > mine[0]
            sideways = theirs is not None and theirs[0] == mine[0] < len(table) - 2
            if up or (sideways and theirs[1] != mine[1]):
                out.append(f"{module} -> {dep}")
    return out


def test_the_layers_are_read_from_the_docs() -> None:
    table = layers()
    assert table[0] == ["ttc"] and table[-1] == ["hydra_plugins"]
    assert ["experiments.sweep", "experiments.report"] in table and len(table) >= 8


def test_layers_point_one_way(graph: dict[str, set[str]]) -> None:
    assert upward_imports(graph, layers()) == []


def test_an_upward_import_would_be_found() -> None:
    table = [["a"], ["b", "c"], ["d", "e"], ["f"]]
    graph = {"a.x": {"b.y"}, "b.y": {"c.z"}, "c.z": {"a.x"}, "d.t": {"e.u"}, "g": set()}
    assert upward_imports(graph, table) == ["a.x -> b.y", "b.y -> c.z", "g -> ?"]


def test_experiments_top_holds_only_entry_points() -> None:
    """The top of ``experiments/`` is folders by concern and its entry points."""
    top = sorted(p.name for p in (PROJECT_ROOT / "experiments").glob("*.py"))
    assert top == ["__init__.py", "cli.py", "run.py"]


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


def test_no_base_name_in_two_places() -> None:
    """A module name means one thing: no two modules of the project share a file name
    (``__init__`` and ``__main__`` aside)."""
    places: dict[str, set[str]] = {}
    for name, path in _modules().items():
        if path.name not in ("__init__.py", "__main__.py"):
            places.setdefault(path.stem, set()).add(name)
    assert {stem: sorted(found) for stem, found in places.items() if len(found) > 1} == {}
