"""What one override of a sweep's job changes in its config (:class:`Part`), and how a part is
swapped into a job's config (:func:`swap`) or sent to another process (:func:`detached`).

:class:`experiments.sweep.compose.Composer` finds a job's parts (each the subtree its
override's variant composition differs in from the template's) and makes the job's config by
swapping them into a copy of the template's.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from omegaconf import Container, DictConfig, OmegaConf, open_dict


@dataclass(frozen=True)
class Part:
    """What one local override changes: its config key, that key's node and group choice in
    the variant's composition, the variant's composition itself, and the nodes of the keys
    elsewhere it also sets (a ``@package _global_`` option: ``dataset=kitti_odometry`` sets
    its own lidar crop and camera pair distance)."""

    position: int
    item: str
    key: str
    node: Any
    choice: str | None
    config: DictConfig | None  # None: an earlier plan's variant (another template), or sent
    extras: tuple[tuple[str, Any], ...] = ()  # (dotted key, node) it also sets elsewhere

    @property
    def keys(self) -> tuple[str, ...]:
        """Every dotted key this part sets."""
        return (self.key, *(k for k, _ in self.extras))


def alone(node: Any) -> Any:
    """A copy of a config node without its parent (pickled alone, not with the composition
    it was taken from); a plain value as it is. Swapped into a job's config it takes that
    config as its parent, as the node itself would."""
    if not isinstance(node, Container):
        return node
    copied = copy.deepcopy(node)
    copied._set_parent(None)
    return copied


def detached(part: Part) -> Part:
    """``part`` without its variant's composition, its nodes :func:`alone`."""
    extras = tuple((key, alone(node)) for key, node in part.extras)
    return dataclasses.replace(part, node=alone(part.node), config=None, extras=extras)


def swap(cfg: DictConfig, parts: Sequence[Part]) -> None:
    """Set each part's node (a copy) and group choice on ``cfg``."""
    for part in parts:
        with open_dict(cfg):
            OmegaConf.update(cfg, part.key, copy.deepcopy(part.node), merge=False)
            for key, node in part.extras:
                OmegaConf.update(cfg, key, copy.deepcopy(node), merge=False)
        if part.choice is not None:
            with open_dict(cfg.hydra):
                cfg.hydra.runtime.choices[part.key] = part.choice
