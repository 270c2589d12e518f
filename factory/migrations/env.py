"""Alembic environment of the process record: runs on the connection :func:`factory.record.upgrade` gives."""

from alembic import context

from factory.record import metadata

connection = context.config.attributes.get("connection")
if connection is None:
    raise RuntimeError("the record's migrations run through factory.record.upgrade (factory simulate --db)")
# render_as_batch: SQLite alters tables by copying them
context.configure(connection=connection, target_metadata=metadata, render_as_batch=True)
with context.begin_transaction():
    context.run_migrations()
