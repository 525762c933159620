"""Every third-party module the project imports is installed by what a user installs: a core
dependency (or one of theirs) for an import at module level or on the core path, and for an
optional feature's lazy import (inside a function) a package an extra or the ``--no-deps``
step of the README names itself. A module that comes only with a development tool's
dependencies (``threadpoolctl``, through mlflow's scikit-learn) is missing from a
newcomer's ``pip install .``: the served sweep's forked workers failed on it."""

from __future__ import annotations

import ast
import re
import sys
import tomllib
from importlib import metadata

from packaging.requirements import Requirement

from tests.conftest import PROJECT_ROOT

PACKAGES = ("ttc", "experiments", "hydra_plugins")


def _canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _closure(names: set[str]) -> set[str]:
    """``names`` (distributions) and everything they require, installed or not (extras off)."""
    seen: set[str] = set()
    todo = list(names)
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        try:
            requires = metadata.requires(name) or []
        except metadata.PackageNotFoundError:
            continue
        for text in requires:
            req = Requirement(text)
            if req.marker is None or req.marker.evaluate({"extra": ""}):
                todo.append(_canonical(req.name))
    return seen


def _third_party_imports() -> dict[str, set[tuple[str, bool]]]:
    """Top-level third-party module → {(file, imported at module level)}."""
    found: dict[str, set[tuple[str, bool]]] = {}
    for package in PACKAGES:
        for path in sorted((PROJECT_ROOT / package).rglob("*.py")):
            tree = ast.parse(path.read_text())
            top_level = {id(n) for n in tree.body}
            for node in ast.walk(tree):
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                    names = [node.module]
                else:
                    continue
                for name in names:
                    top = name.split(".")[0]
                    if top in sys.stdlib_module_names or top in (*PACKAGES, "__future__"):
                        continue
                    where = str(path.relative_to(PROJECT_ROOT))
                    found.setdefault(top, set()).add((where, id(node) in top_level))
    return found


def _declared() -> tuple[set[str], set[str]]:
    """(the core dependencies, the packages an extra or the README's ``--no-deps`` step names
    itself), canonical distribution names."""
    project = tomllib.loads((PROJECT_ROOT / "pyproject.toml").read_text())["project"]
    core = {_canonical(Requirement(d).name) for d in project["dependencies"]}
    extras = {_canonical(Requirement(d).name) for ds in project["optional-dependencies"].values()
              for d in ds}  # fmt: skip
    step = re.search(r"--no-deps ([^&]+)", (PROJECT_ROOT / ".ci" / "run").read_text())
    assert step, ".ci/run has no --no-deps step"
    no_deps = {_canonical(p.split("==")[0]) for p in step.group(1).split()}
    return core, extras | no_deps


def test_every_third_party_import_is_installed_by_what_a_user_installs() -> None:
    core, optional = _declared()
    installed = _closure(core)
    by_module = metadata.packages_distributions()
    found = _third_party_imports()
    assert {"numpy", "pandas", "cv2", "omegaconf", "yaml"} <= set(found)  # the scan works
    problems = []
    for module, places in sorted(found.items()):
        dists = {_canonical(d) for d in by_module.get(module, [])}
        if dists & installed:
            continue
        eager = sorted(f for f, top in places if top)
        if eager or not dists & optional:
            problems.append(f"{module} ({', '.join(sorted(dists)) or 'not installed here'}): "
                            f"{', '.join(sorted(f for f, _ in places))}")  # fmt: skip
    assert not problems, "imported, but no dependency installs it: " + "; ".join(problems)
