"""``ttc-bench judge``: another implementation's TTC numbers judged like the harness's own
settings (docs/judge.md). ``readers`` and ``layouts``: files to one long table; ``harness``:
the settings and reference they are ranked with; ``judging``: the joint ranking;
``report``: the files written; ``cli``: the command. The core of it is pure:
:mod:`ttc.evaluation.external`."""
