"""treesim's HTTP service: a thin adapter over :mod:`treesim` (FastAPI, a SQL job store,
workers that run each job in its own process), an OGC API - Processes - Part 1: Core
server. Installed with the ``service`` extra (``pip install "treesim[service]"``); the
folder is ``service/`` in the repository.

* :func:`treesim.service.app.create_app` builds the app from
  :class:`treesim.service.settings.Settings` (``TREESIM_*`` environment variables);
  ``treesim serve`` runs it with an embedded worker, ``treesim worker`` runs workers alone
  (:mod:`treesim.service.cli`).
* :mod:`treesim.service.api`: the routes: the OGC landing page and conformance
  (:mod:`~treesim.service.api.ogc`), processes and execution
  (:mod:`~treesim.service.api.processes`), jobs and results, uploads, health, the pages;
  users and their tokens (:mod:`~treesim.service.api.deps`).
* :mod:`treesim.service.processes`: one module per process (``run``, ``reconstruct``,
  ``scan``, ``compare``, ``plan``, ``plot-scan``, ``plot-from-cloud``, ``validate``), their
  inputs and the JSON Schemas of their parameters, from the parameter models;
  :mod:`treesim.service.openapi30` writes them (and the API's definition) in OpenAPI 3.0.
* :mod:`treesim.service.jobs`: the job store (:mod:`~treesim.service.jobs.store`, Alembic
  migrations), the worker (:mod:`~treesim.service.jobs.worker`) and what runs in a job's process
  (:mod:`~treesim.service.jobs.runner`).
* :mod:`treesim.service.problems`: one table from treesim's errors to problem objects and HTTP
  statuses.
"""
