"""treesim's HTTP service: a thin adapter over :mod:`pipeline` (FastAPI, a SQL job store,
workers that run each job in its own process).

* :func:`service.app.create_app` builds the app from :class:`service.settings.Settings`
  (``TREESIM_*`` environment variables); ``treesim serve`` runs it with an embedded
  worker, ``treesim worker`` runs workers alone (:mod:`service.cli`).
* :mod:`service.processes`: the processes ``run``, ``reconstruct``, ``scan``, ``compare``,
  their inputs and the JSON Schemas of their parameters, from the parameter model.
* :mod:`service.jobs`: the job store (:mod:`~service.jobs.store`, Alembic migrations),
  the worker (:mod:`~service.jobs.worker`) and what runs in a job's process
  (:mod:`~service.jobs.runner`).
* :mod:`service.problems`: one table from treesim's errors to problem objects and HTTP
  statuses.
"""
