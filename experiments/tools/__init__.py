"""Commands around the sweeps: two sweeps side by side (:mod:`.compare`), pictures of one frame
pair under a setting (:mod:`.show`), the documented rows schema (:mod:`.schema`), the sweep
benchmark (:mod:`.benchmark`) and its compute floor (:mod:`.floor`), and the learned features'
per-stage times (:mod:`.learned_timing`)."""
