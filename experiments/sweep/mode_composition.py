"""One composition of a command's config where Hydra makes two.

Hydra 1.3 composes a command's primary config once to read ``hydra.mode``
(``Hydra.get_mode``, run mode MULTIRUN, sweep overrides not checked) and throws it away, then
composes it again with the same arguments to run a multirun (``Hydra.multirun``; upstream
issue https://github.com/hydra-ecosystem/hydra/issues/3440, open). With this config tree that
is ≈ 0.2 s of every sweep command.

:func:`compose_once` makes Hydra's config loader hand the first of two such compositions to
the second request instead of composing again: a MULTIRUN composition made without checking
the sweep overrides (``get_mode``'s request) is kept, and the next ``load_configuration`` with
the same config name, overrides, mode and source takes it (once; the sweep overrides are then
checked as Hydra would). Any other request (another mode, other overrides, a third request)
composes as before and drops what was kept. The kept object is handed out only once and its
first requester (``get_mode``) only reads ``hydra.mode`` from it, so no copy is needed.
Nothing changes for a single run (its second composition is in RUN mode).
"""

from __future__ import annotations

import functools
from typing import Any

from hydra._internal.config_loader_impl import ConfigLoaderImpl
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.types import RunMode

#: Marks the wrapped loader method (installed once per process).
INSTALLED = "_ttc_compose_once"


def _key(config_name: Any, overrides: list[str], run_mode: RunMode, from_shell: bool) -> Any:
    """What makes two requests the same composition."""
    return config_name, tuple(overrides), run_mode, from_shell


def compose_once() -> None:
    """Wrap ``ConfigLoaderImpl.load_configuration`` as the module docstring says (idempotent)."""
    original = ConfigLoaderImpl.load_configuration
    if getattr(original, INSTALLED, False):
        return
    kept: dict[Any, Any] = {}

    @functools.wraps(original)
    def load_configuration(
        self: ConfigLoaderImpl,
        config_name: str | None,
        overrides: list[str],
        run_mode: RunMode,
        from_shell: bool = True,
        validate_sweep_overrides: bool = True,
    ) -> Any:
        key = (id(self), _key(config_name, overrides, run_mode, from_shell))
        cfg = kept.pop(key, None)
        kept.clear()
        if cfg is not None:
            if validate_sweep_overrides:
                parsed = OverridesParser.create().parse_overrides(overrides=list(overrides))
                self.validate_sweep_overrides_legal(parsed, run_mode, from_shell)
            return cfg
        cfg = original(self, config_name, list(overrides), run_mode, from_shell,
                       validate_sweep_overrides)  # fmt: skip
        if run_mode == RunMode.MULTIRUN and not validate_sweep_overrides:  # get_mode's request
            kept[key] = cfg
        return cfg

    setattr(load_configuration, INSTALLED, True)
    ConfigLoaderImpl.load_configuration = load_configuration  # type: ignore[method-assign]
