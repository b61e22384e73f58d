"""Alembic environment of the results store: migrations run on the connection migrate.py
hands in (``config.attributes["connection"]``), inside the transaction it has open."""
from __future__ import annotations

from alembic import context

from accelcal_station.store.tables import metadata

connection = context.config.attributes["connection"]
context.configure(connection=connection, target_metadata=metadata,
                  render_as_batch=connection.dialect.name == "sqlite")  # SQLite alters by copying the table
with context.begin_transaction():
    context.run_migrations()
