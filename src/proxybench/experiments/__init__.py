"""Studies: each a registered :class:`~proxybench.experiments.study.Study` in a folder of its own — a strict config →
jobs through the runner → measures (:mod:`proxybench.usefulness`) → a typed result → its report.

- ``study``: ``StudyConfig`` (the strict config base), ``Study`` (the registered interface) and the registry;
- ``config`` (the experiment file of predictivity, score-proxy, optimize, plan and plv-vs-prpv), ``agent_args``
  (agents as users name them), ``proxies`` (proxy instances, neutral sweep defaults), ``baselines``, ``reporting``;
- one folder per family, each with ``study`` (registration, terminal view), ``run``, measures' glue and ``report``:
  ``predictivity`` (thesis figures 3.3 / 3.4), ``score``, ``optimize`` (argmin PRPV, or argmax PLV), ``plan``
  (+ ``sequential``), ``heldout``, ``repeatability`` (thesis §5.4), ``plv`` (teaching), ``plv_prpv``, ``validate``.

Only :mod:`proxybench.runner` runs episodes; a study asks it for jobs and scores them with pure measures.
"""
