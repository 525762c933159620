"""Configs to core objects: the typed schemas Hydra checks a config against and the
conversion of a config to :mod:`ttc`'s settings (:mod:`.structured`), and a run's setting and
its run id (:mod:`.identity`, the one run-id function). Above :mod:`experiments.host` and
:mod:`experiments.data`; below the store."""
