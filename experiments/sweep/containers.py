"""Plain-container helpers of the sweep's composer: what two compositions must have equal to
differ only under some keys, the top-level keys an entry's interpolations reach, and Hydra's
``override_dirname`` rule."""

from __future__ import annotations

import copy
import re
from collections.abc import Sequence
from typing import Any

from hydra.core.override_parser.types import Override
from omegaconf import DictConfig

#: Keys of the Hydra node that a job's overrides change (besides ``runtime.choices``).
JOB_KEYS = ("overrides.task", "job.override_dirname", "job.id", "job.num")
#: Any top-level key (a relative interpolation that leaves its entry).
ANY_KEY = "*"
#: Resolvers that read the config by a key given as a plain string (not an interpolation).
CONFIG_READING_RESOLVERS = ("oc.select", "oc.dict.keys", "oc.dict.values")
#: ``${path}`` (a reference) or ``${name:`` (a resolver, whose arguments match on their own).
_INTERPOLATION = re.compile(r"\$\{\s*([^${}:\s]*)\s*([:}])")


def _drop(container: dict[str, Any], path: tuple[str, ...]) -> None:
    """Remove the key at ``path`` (keys from the top) from nested dicts, if present."""
    *parents, leaf = path
    for part in parents:
        container = container.get(part)
        if not isinstance(container, dict):
            return
    container.pop(leaf, None)


def _ignored(keys: Sequence[str]) -> list[tuple[str, ...]]:
    """The paths two compositions that differ only under ``keys`` (dotted) may differ at:
    those keys, their group choices (``hydra.runtime.choices``) and the job-specific Hydra
    keys."""
    paths = [tuple(key.split(".")) for key in keys]
    paths += [("hydra", "runtime", "choices", key) for key in keys]
    return paths + [("hydra", *job_key.split(".")) for job_key in JOB_KEYS]


def comparable(container: dict[str, Any], keys: Sequence[str]) -> dict[str, Any]:
    """A copy of a config's plain containers (interpolations unresolved) without the paths
    :func:`_ignored` names for ``keys``: what two compositions that differ only under
    ``keys`` have equal."""
    out = copy.deepcopy(container)
    for path in _ignored(keys):
        _drop(out, path)
    return out


def equal_except(a: dict[str, Any], b: dict[str, Any], keys: Sequence[str]) -> bool:
    """``comparable(a, keys) == comparable(b, keys)`` without copying either (only the
    dicts on the way to an ignored path are walked; the rest compared as they are): an
    earlier ``grand`` plan's 26 compositions checked in 0.7 instead of 5.5 ms."""
    skip = set(_ignored(keys))
    return _equal_except(a, b, (), skip, {p[:i] for p in skip for i in range(len(p))})


def _equal_except(
    a: Any, b: Any, at: tuple[str, ...], skip: set[tuple[str, ...]], above: set[tuple[str, ...]]
) -> bool:
    """:func:`equal_except` below path ``at`` (``above``: the proper prefixes of ``skip``)."""
    if at not in above or not (isinstance(a, dict) and isinstance(b, dict)):
        return a == b
    mine = {k for k in a if (*at, k) not in skip}
    if mine != {k for k in b if (*at, k) not in skip}:
        return False
    return all(_equal_except(a[k], b[k], (*at, k), skip, above) for k in mine)


def differing_paths(a: Any, b: Any, prefix: str = "") -> list[str] | None:
    """The dotted paths where two plain containers differ, as deep as both are dicts there
    (``{"x": {"y": 1, "z": 2}}`` and ``{"x": {"y": 1, "z": 3}}`` → ``["x.z"]``); None when a
    key is in one only (a part cannot be swapped in by setting values)."""
    if not (isinstance(a, dict) and isinstance(b, dict)):
        return [] if a == b else [prefix.rstrip(".")]
    if a.keys() != b.keys():
        return None
    found: list[str] = []
    for key in a:
        below = differing_paths(a[key], b[key], f"{prefix}{key}.")
        if below is None:
            return None
        found += below
    return found


def references(value: Any, depth: int = 0) -> set[str]:
    """The top-level keys that the interpolations inside ``value`` (an unresolved top-level
    entry, or a part of one ``depth`` levels down) refer to; :data:`ANY_KEY` for a relative
    one that leaves the entry."""
    if isinstance(value, dict):
        return set().union(*(references(v, depth + 1) for v in value.values()))
    if isinstance(value, list):
        return set().union(*(references(v, depth + 1) for v in value))
    found: set[str] = set()
    if isinstance(value, str) and "${" in value:
        for path, end in _INTERPOLATION.findall(value):
            dots = len(path) - len(path.lstrip("."))
            if end == ":":
                if path in CONFIG_READING_RESOLVERS:
                    found.add(ANY_KEY)
                continue
            if dots == 0:
                found.add(path.split(".")[0].split("[")[0])
            elif dots > depth:
                found.add(ANY_KEY)
    return found


def override_dirname(task: Sequence[Override], naming: DictConfig) -> str:
    """``hydra.job.override_dirname`` of a job's task overrides (Hydra's rule)."""
    excluded = set(naming.exclude_keys)
    lines = sorted(o.input_line for o in task if o.key_or_group not in excluded)
    return re.sub(pattern="[=]", repl=naming.kv_sep, string=naming.item_sep.join(lines))


def overlap(a: str, b: str) -> bool:
    """True when dotted keys ``a`` and ``b`` are one or one is under the other."""
    return a == b or a.startswith(b + ".") or b.startswith(a + ".")
