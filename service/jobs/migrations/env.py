"""Alembic environment of the job store: migrations run on the connection the store hands
over (``config.attributes["connection"]``), inside its transaction and lock."""

from __future__ import annotations

from alembic import context

from treesim.service.jobs.store import metadata

connection = context.config.attributes.get("connection")
if connection is None:  # pragma: no cover - the store always passes one
    raise RuntimeError("run migrations through treesim.service.jobs.store.Store.migrate()")
context.configure(
    connection=connection,
    target_metadata=metadata,
    render_as_batch=connection.dialect.name == "sqlite",
    compare_type=True,
)
with context.begin_transaction():
    context.run_migrations()
