"""Variants of an earlier plan of the same sweep folder, reused by a new plan whose template
differs from the earlier one only under some keys.

Re-running a sweep after changing one axis (``+experiment=fp6_grid keypoint_filter=zscore``
after ``+experiment=fp6_grid``) gives every job a new override list, so none of the earlier
plan's Hydra compositions can be looked up as they are; yet the variants of the other axes
(``detector=sift``, ...) compose to the same subtrees. :class:`EarlierPlan` holds an earlier
plan's template and compositions; :meth:`EarlierPlan.view` checks that the new template's
composition equals the earlier template's outside the keys whose overrides differ (``delta``:
the same check the composer makes for a variant), and :meth:`EarlierView.variant` then gives,
for an override whose key is outside ``delta``, the earlier variant's composition when that
variant differs from the earlier template only under the override's key. The composer uses it
as it would its own variant: a job is the new template with the parts of its differing
overrides swapped in (the new template being, to the earlier one, such a job).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import OverrideType
from omegaconf import DictConfig, OmegaConf

from experiments.sweep.containers import equal_except, overlap


@dataclass
class EarlierPlan:
    """An earlier plan's template job and Hydra's compositions (template, variants)."""

    template: list[str]
    known: dict[tuple[str, ...], DictConfig] = field(default_factory=dict)

    def view(self, template: Sequence[str], base: dict[str, Any]) -> EarlierView | None:
        """The earlier variants usable with the new ``template`` (its composition ``base``,
        unresolved); None when its composition differs from the earlier template's outside
        the keys whose overrides differ, or an override is not a plain change."""
        earlier_base = self.known.get(tuple(self.template))
        parser = OverridesParser.create()
        old = {o.key_or_group: o for o in parser.parse_overrides(self.template)}
        new = {o.key_or_group: o for o in parser.parse_overrides(list(template))}
        if earlier_base is None or len(old) != len(self.template) or len(new) != len(template):
            return None  # a key given twice: positions cannot be matched by key
        delta = [k for k in {*old, *new} if _item(old.get(k)) != _item(new.get(k))]
        if any(o.type != OverrideType.CHANGE or o.package is not None
               for k in delta for o in (old.get(k), new.get(k)) if o is not None):  # fmt: skip
            return None
        dotted = [k.replace("/", ".") for k in delta]
        container = OmegaConf.to_container(earlier_base, resolve=False)
        if not equal_except(container, base, dotted):
            return None
        return EarlierView(self, container, list(old), dotted)


def _item(override: Any) -> str | None:
    """An override's text (None for none)."""
    return None if override is None else override.input_line


@dataclass
class EarlierView:
    """:class:`EarlierPlan` seen from a new template (:meth:`EarlierPlan.view`)."""

    plan: EarlierPlan
    base: dict[str, Any]  # the earlier template's composition, unresolved
    keys: list[str]  # the earlier template's override keys, by position
    delta: list[str]  # dotted keys whose overrides differ between the two templates

    def variant(self, key: str, item: str) -> tuple[DictConfig, dict[str, Any]] | None:
        """The earlier composition of the earlier template with ``item`` for override key
        ``key`` (and its unresolved container) when it differs from the earlier template
        only under ``key`` and ``key`` is outside :attr:`delta`; None otherwise."""
        dotted = key.replace("/", ".")
        if key not in self.keys or any(overlap(dotted, d) for d in self.delta):
            return None
        position = self.keys.index(key)
        template = self.plan.template
        cfg = self.plan.known.get((*template[:position], item, *template[position + 1 :]))
        if cfg is None:
            return None
        container = OmegaConf.to_container(cfg, resolve=False)
        if not equal_except(container, self.base, [dotted]):
            return None
        return cfg, container
