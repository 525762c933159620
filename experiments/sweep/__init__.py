"""How a sweep runs: a finished command recognised before Hydra starts (:mod:`.finished`), the
plan made before any worker starts (:mod:`.plan`), a batch of settings in one job
(:mod:`.batch`), the shared work done while planning (:mod:`.warm_up`), its jobs' configs and
settings (:mod:`.compose`), the workers and the launcher that runs them (:mod:`.workers`,
:mod:`.launcher`), the sweeper that expands the jobs, validates and plans (:mod:`.jobs`,
:mod:`.sweeper`; its compositions kept for a re-plan, :mod:`.kept`, and reused by a sweep with
another axis, :mod:`.earlier`; the plain-container helpers, :mod:`.containers`) and what Ctrl-C
says (:mod:`.interrupt`). The Hydra plugins in ``hydra_plugins/`` are thin shims over these
modules."""
