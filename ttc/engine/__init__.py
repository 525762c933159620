"""Running settings over frames: the stage cache (:mod:`~ttc.engine.cache`), the cached stages
and their streaming (:mod:`~ttc.engine.stages`), FP.1–FP.4 of a frame pair shared by the
settings of a group (:mod:`~ttc.engine.pair_steps`) and the one runner
(:mod:`~ttc.engine.runner`)."""
