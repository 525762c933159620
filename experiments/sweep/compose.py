"""The configs and settings of a sweep's jobs, from one Hydra composition per distinct option.

Hydra composes a job's config from scratch (~0.13 s with this config tree), and a sweep's
jobs differ from one another in a few ``key=value`` overrides. :class:`Composer` composes one
*template* job (the first) and, for every other value at a position, one *variant* (the
template with that one value), then derives every job from them:

* a job's **config** (what the launcher's workers run) is the template's with the subtree of
  each override that differs from the template replaced by its variant's, when that variant
  is *local*: a plain change (``key=value``: no ``@package``, no addition or deletion) whose
  composition differs from the template's only under ``key`` (and its choice in
  ``hydra.runtime.choices``), interpolations unresolved; and when no two differing overrides
  set overlapping keys (one under the other);
* a job's **setting** (:func:`experiments.configs.identity.setting_config`, what the planner reads) is
  made of its entries, each resolved once per distinct set of overrides it can depend on: the
  differing overrides that set the entry itself or any top-level key its interpolations reach
  (read from the template's and the variants' unresolved configs, transitively).

Anything else (another number of overrides, another key at a position, a variant that is not
local, overlapping keys) goes through Hydra's full composition. Resolvers are taken to depend
only on their arguments and the environment (``ttc_path``, ``kitti_raw_sequence``,
``oc.env``, ``oc.decode``), except those that read the config by a key
(:data:`CONFIG_READING_RESOLVERS`: an entry using one may depend on any other).
A test composes every option of every config group and every experiment both ways.

:func:`core_settings` makes the core's :class:`ttc.settings.Settings` of many settings (a
batch job's): each field is converted once per distinct value of the entries it is made of,
and its converter sees only those entries (:data:`experiments.configs.structured.SETTINGS_FIELDS`).
"""

from __future__ import annotations

import contextlib
import copy
import itertools
import operator
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import Override, OverrideType
from omegaconf import DictConfig, OmegaConf, open_dict

from experiments.configs.identity import SETTING_KEYS, finish_setting, setting_config, setting_entry
from experiments.configs.structured import SETTINGS_FIELDS, settings_field
from experiments.sweep.containers import (
    ANY_KEY,
    comparable,
    differing_paths,
    overlap,
    override_dirname,
    references,
)
from experiments.sweep.earlier import EarlierPlan
from experiments.sweep.parts import Part, detached, swap
from ttc.settings import Settings

#: The override naming the batch a job computes (:mod:`experiments.sweep.plan`).
BATCH_PREFIX = "batch="


class Composer:
    """The configs and settings of a sweep's jobs (module docstring), from Hydra's
    compositions of a template job and of one variant per distinct ``key=value``."""

    def __init__(
        self,
        loader: Any,
        master: DictConfig,
        known: Mapping[tuple[str, ...], DictConfig] | None = None,
        template: Sequence[str] | None = None,
        earlier: EarlierPlan | None = None,
        parts: Mapping[tuple[int, str], Part | None] | None = None,
    ) -> None:
        """``loader``: Hydra's config loader; ``master``: the multirun's master config;
        ``known``: Hydra's compositions of some jobs made from the same ``master`` (the
        sweeper's, handed to the workers); ``template``: the template job (default: the
        first job asked for); ``earlier``: an earlier plan of the sweep folder, whose
        variants serve where they can (:mod:`experiments.sweep.earlier`); ``parts``: the
        parts another composer of the same template found (:meth:`shared`)."""
        self.loader, self.master = loader, master
        self.known: dict[tuple[str, ...], DictConfig] = dict(known or {})
        self.parser = OverridesParser.create()
        self.template: list[str] | None = None
        self.full_compositions = 0  # Hydra compositions made by this composer
        self.earlier, self._view = earlier, None
        self.inherited = 0  # parts taken from the earlier plan's variants
        self._parts: dict[tuple[int, str], Part | None] = {}
        self._entries: dict[tuple[str, tuple[int, ...], Any], Any] = {}
        self._refs: dict[str, set[str]] = {}
        self._closures: dict[str, set[str]] = {}
        self._positions: dict[str, tuple[tuple[int, ...], Any]] = {}
        self._touched: dict[int, set[str]] = {}  # position → top-level keys of its extras
        self._scratch: DictConfig | None = None  # the template's config, parts swapped in
        if template is not None:
            self._set_template(list(template))
        self._parts.update(parts or {})

    # -- Hydra's compositions ---------------------------------------------------------------
    def hydra(self, overrides: Sequence[str]) -> DictConfig:
        """Hydra's composition of a job, kept (shared: not to be modified)."""
        key = tuple(overrides)
        if key not in self.known:
            self.full_compositions += 1
            self.known[key] = self.loader.load_sweep_config(self.master, list(overrides))
        return self.known[key]

    def full(self, overrides: Sequence[str]) -> DictConfig:
        """Hydra's own composition of a job, a new object (a copy of a kept one, or composed
        and not kept)."""
        key = tuple(overrides)
        if key in self.known:
            return copy.deepcopy(self.known[key])
        self.full_compositions += 1
        return self.loader.load_sweep_config(self.master, list(overrides))

    def shared(self) -> tuple[Any, ...]:
        """What another process's composer starts from (``Composer(loader, master,
        *shared)``): the compositions no part stands for (the template's among them), the
        template and the parts found so far, each without its variant's composition and its
        nodes copies of their own (:func:`experiments.sweep.parts.detached`). A worker swaps
        parts' nodes in and reads nothing else of a variant: unpickling the variants' and an
        earlier plan's 14 compositions cost each worker ≈ 0.15 s before its first job."""
        assert self.template is not None
        stand_in = {
            tuple([*self.template[:position], item, *self.template[position + 1 :]])
            for (position, item), part in self._parts.items()
            if part is not None and part.config is not None
        }
        known = {key: cfg for key, cfg in self.known.items() if key not in stand_in}
        parts = {memo: None if p is None else detached(p) for memo, p in self._parts.items()}
        return known, self.template, None, parts

    # -- jobs from parts --------------------------------------------------------------------
    def _set_template(self, overrides: list[str]) -> None:
        """Compose the template job; note its keys, overlapping positions and references. A
        composition that fails sets no template (the next request fails with Hydra's error)."""
        self.base = self.hydra(overrides)
        self.template = overrides
        self.keys = [o.key_or_group for o in self.parser.parse_overrides(overrides)]
        dotted = [key.replace("/", ".") for key in self.keys]
        self._overlaps = [
            (i, j)
            for i, j in itertools.combinations(range(len(dotted)), 2)
            if overlap(dotted[i], dotted[j])
        ]
        self.base_container = OmegaConf.to_container(self.base, resolve=False)
        self._add_references(self.base_container)
        if self.earlier is not None:
            self._view = self.earlier.view(overrides, self.base_container)

    def _add_references(self, container: dict[str, Any]) -> None:
        """Add the references between top-level keys of an unresolved config."""
        for key, value in container.items():
            if key != "hydra":
                self._refs.setdefault(key, set()).update(references(value))
        self._closures.clear()
        self._positions.clear()

    def _reach(self, key: str) -> set[str]:
        """``key`` and every top-level key its interpolations reach, transitively."""
        if key not in self._closures:
            reach, todo = {key}, [key]
            while todo:
                for ref in self._refs.get(todo.pop(), ()):
                    if ref not in reach:
                        reach.add(ref)
                        todo.append(ref)
            self._closures[key] = reach
        return self._closures[key]

    def _part(self, position: int, item: str) -> Part | None:
        """The :class:`Part` of ``item`` at ``position`` when its variant is local."""
        memo = (position, item)
        if memo not in self._parts:
            self._parts[memo] = None
            (override,) = self.parser.parse_overrides([item])
            if (
                override.type == OverrideType.CHANGE
                and override.package is None
                and override.key_or_group == self.keys[position]
            ):
                earlier = self._earlier_part(position, item)
                self._parts[memo] = earlier or self._local_part(position, item, override)
        return self._parts[memo]

    def _earlier_part(self, position: int, item: str) -> Part | None:
        """The :class:`Part` of ``item`` at ``position`` from the earlier plan's variant,
        when it has a local one and the templates differ only elsewhere."""
        found = self._view.variant(self.keys[position], item) if self._view else None
        if found is None:
            return None
        cfg, container = found
        key = self.keys[position].replace("/", ".")
        self._add_references(container)
        self.inherited += 1
        choice = cfg.hydra.runtime.choices.get(key)
        return Part(position, item, key, OmegaConf.select(cfg, key), choice, None)

    def _local_part(self, position: int, item: str, override: Override) -> Part | None:
        """Compose the variant with ``item`` at ``position``; its :class:`Part` when it
        differs from the template only under the override's key, else None."""
        assert self.template is not None
        variant = [*self.template[:position], item, *self.template[position + 1 :]]
        cfg = self.hydra(variant)
        key = override.key_or_group.replace("/", ".")
        container = OmegaConf.to_container(cfg, resolve=False)
        mine, base = comparable(container, [key]), comparable(self.base_container, [key])
        if mine["hydra"] != base["hydra"]:
            return None
        paths = differing_paths({**mine, "hydra": {}}, {**base, "hydra": {}})
        if paths is None or any(overlap(key, path) for path in paths):
            return None
        self._add_references(container)
        choice = cfg.hydra.runtime.choices.get(key)
        extras = tuple((path, OmegaConf.select(cfg, path)) for path in paths)
        if extras:  # it changes entries beyond its key: what reaches them changes
            tops = self._touched.setdefault(position, set())
            tops.update(path.split(".")[0] for path in paths)
            self._positions.clear()
        return Part(position, item, key, OmegaConf.select(cfg, key), choice, cfg, extras)

    def parts(self, overrides: Sequence[str]) -> list[Part] | None:
        """The parts of the overrides that differ from the template; None when the job
        cannot be derived from them (module docstring)."""
        overrides = list(overrides)
        if self.template is None:
            self._set_template(overrides)
        assert self.template is not None
        if len(overrides) != len(self.template):
            return None
        parts, differing = [], set()
        for position, item in enumerate(overrides):
            if item != self.template[position]:
                part = self._part(position, item)
                if part is None:
                    return None
                parts.append(part)
                differing.add(position)
        if any(i in differing and j in differing for i, j in self._overlaps):
            return None
        if any(p.extras for p in parts) and any(
            overlap(a, b)
            for p, q in itertools.combinations(parts, 2)
            for a in p.keys
            for b in q.keys
        ):
            return None
        return parts

    @contextlib.contextmanager
    def _swapped(self, parts: Sequence[Part]) -> Iterator[DictConfig]:
        """The template's config with ``parts`` swapped in, to read inside the ``with`` block
        only (shared: not to be modified). With at most one part, the template's or the
        variant's composition; else one scratch copy of the template (made once: a deep copy
        costs ≈ 15 ms) with the parts swapped in, and the template's top-level nodes they
        touched and its group choices put back after the block."""
        if not parts:
            yield self.base
            return
        if len(parts) == 1 and parts[0].config is not None:
            yield parts[0].config
            return
        tops = {key.split(".")[0] for part in parts for key in part.keys}
        if not tops <= set(self.base.keys()):  # a part adds a top-level key: a copy of its own
            cfg = copy.deepcopy(self.base)
            swap(cfg, parts)
            yield cfg
            return
        if self._scratch is None:
            self._scratch = copy.deepcopy(self.base)
        scratch = self._scratch
        swap(scratch, parts)
        try:
            yield scratch
        finally:
            with open_dict(scratch):
                for top in tops:  # a copy of the template's own node, interpolations kept
                    scratch[top] = self.base._get_node(top)
            with open_dict(scratch.hydra):
                scratch.hydra.runtime.choices = self.base.hydra.runtime._get_node("choices")

    def config(self, overrides: Sequence[str]) -> DictConfig:
        """The config of the job with these overrides, a new object (a batch's
        ``batch=<id>``, a plain string each batch has its own of, is set on the config)."""
        overrides = list(overrides)
        batch = [o for o in overrides if o.startswith(BATCH_PREFIX)]
        if batch:
            cfg = self.config([o for o in overrides if not o.startswith(BATCH_PREFIX)])
            with open_dict(cfg):
                cfg.batch = batch[-1][len(BATCH_PREFIX) :]
                cfg.hydra.overrides.task.extend(batch)
            return cfg
        parts = self.parts(overrides)
        if parts is None:
            return self.full(overrides)
        cfg = copy.deepcopy(self.base)
        swap(cfg, parts)
        task = [o for o in self.parser.parse_overrides(overrides) if not o.is_hydra_override()]
        with open_dict(cfg.hydra):
            cfg.hydra.overrides.task = [o.input_line for o in task]
            naming = cfg.hydra.job.config.override_dirname
            cfg.hydra.job.override_dirname = override_dirname(task, naming)
        return cfg

    @contextlib.contextmanager
    def shared_config(self, overrides: Sequence[str]) -> Iterator[DictConfig]:
        """The config of the job with these overrides, to read inside the ``with`` block only
        (its Hydra keys may be those of the template): :meth:`_swapped`'s when the job is
        derived from parts, else Hydra's composition."""
        parts = self.parts(overrides)
        if parts is None:
            yield self.full(overrides)
            return
        with self._swapped(parts) as cfg:
            yield cfg

    def setting(self, overrides: Sequence[str]) -> dict[str, Any]:
        """The :func:`experiments.configs.identity.setting_config` of the job with these overrides;
        entries equal between jobs are the same objects."""
        overrides = list(overrides)
        parts = self.parts(overrides)
        if parts is None:
            return setting_config(self.full(overrides))
        entries = {}
        for key in SETTING_KEYS:
            positions, values = self._reaching(key)
            memo = (key, positions, values(overrides))
            if memo not in self._entries:  # once per distinct value of what reaches it
                touching = [p for p in parts if p.position in positions]
                with self._swapped(touching) as cfg:
                    self._entries[memo] = setting_entry(cfg, key)
            entries[key] = self._entries[memo]
        return finish_setting(entries)

    def _reaching(self, key: str) -> tuple[tuple[int, ...], Any]:
        """The positions of the overrides that can change setting entry ``key`` (those that
        set a top-level key in its :meth:`_reach`), and a function of a job's overrides giving
        their values there."""
        if key not in self._positions:
            reach = self._reach(key)
            positions = tuple(
                i for i, k in enumerate(self.keys)
                if ANY_KEY in reach or k.replace("/", ".").split(".")[0] in reach
                or reach & self._touched.get(i, set())
            )  # fmt: skip
            values = operator.itemgetter(*positions) if positions else (lambda _: ())
            self._positions[key] = (positions, values)
        return self._positions[key]


def variant_jobs(jobs: Sequence[Sequence[str]]) -> list[list[str]]:
    """The first job and, for every other ``key=value`` at a position, the first job with that
    value there (what :class:`Composer` composes); jobs of another length as they are."""
    if not jobs:
        return []
    first = list(jobs[0])
    out, seen = [first], set()
    for job in jobs:
        if len(job) != len(first):
            out.append(list(job))
            continue
        for position, item in enumerate(job):
            if item != first[position] and (position, item) not in seen:
                seen.add((position, item))
                out.append([*first[:position], item, *first[position + 1 :]])
    return out


def core_settings(settings: Sequence[dict[str, Any]]) -> list[Settings | Exception]:
    """The core's :class:`Settings` of each setting (the exception instead where a value is
    bad: it costs only its setting), each field converted once per distinct value of its
    entries (told apart by their ``repr``: twice as fast as sorted JSON, 7.4 → 3.7 ms a batch
    of 160; equal entries written in another key order are only converted twice)."""
    fields: dict[tuple[str, str], Any] = {}
    out: list[Settings | Exception] = []
    for setting in settings:
        values: dict[str, Any] = {}
        for name, (sources, _) in SETTINGS_FIELDS.items():
            memo = (name, repr([setting.get(s) for s in sources]))
            if memo not in fields:
                try:
                    fields[memo] = settings_field(name, setting)
                except Exception as exc:  # kept: every setting with this value fails alike
                    fields[memo] = exc
            if isinstance(fields[memo], Exception):
                out.append(fields[memo])
                break
            values[name] = fields[memo]
        else:
            out.append(Settings(**values))
    return out
