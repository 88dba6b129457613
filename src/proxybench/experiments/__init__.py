"""Studies: each one a strict config → jobs through the runner → measures (:mod:`proxybench.usefulness`) → a report.

- ``config``: the experiment file shared by ``predictivity``, ``optimize`` and ``plan`` (``--config FILE``);
  ``agent_args``: agents as users name them; ``proxies``: proxy instances and the neutral sweep defaults;
- ``predictivity`` (thesis figures 3.3 / 3.4), ``optimize`` (argmin PRPV), ``sequential`` (target episodes where
  the order is open), ``heldout`` + ``heldout_analysis`` (how often each metric picks the best available θ),
  ``repeatability`` (thesis §5.4), ``plv`` + ``dagger`` + ``plv_objective`` + ``optimize_plv`` (teaching);
- ``reports``: tables, figures and self-contained HTML pages of every study.

Only :mod:`proxybench.runner` runs episodes; a study asks it for jobs and scores them with pure measures.
"""
