"""How a sweep runs: its jobs' configs and settings (:mod:`.compose`), the workers and the
launcher that runs them (:mod:`.workers`, :mod:`.launcher`), the sweeper that expands the
jobs, validates and plans (:mod:`.jobs`, :mod:`.sweeper`; its compositions kept for a re-plan,
:mod:`.kept`, and reused by a sweep with another axis, :mod:`.earlier`; the plain-container
helpers, :mod:`.containers`) and what Ctrl-C says (:mod:`.interrupt`). The Hydra plugins in
``hydra_plugins/`` are thin shims over these modules."""
