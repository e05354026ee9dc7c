"""treesim's HTTP service (FastAPI + jobs): a thin adapter over :mod:`pipeline`.

Not built yet: no issue covers it so far. The intended shape is in the project's
DESIGN notes (``create_app(settings)``, jobs in a SQL table claimed with a lease,
native work in child processes, RFC 9457 problem responses). Until then, use the
``treesim`` command line or the ``pipeline`` library.
"""
