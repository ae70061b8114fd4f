"""Alembic environment: Tacit's models are the target; SQLite gets batch mode (ALTER via copy). Run by
hand (`alembic upgrade head`, reading alembic.ini), TACIT_DATABASE_URL names the database as it does for
the server; the server passes its own URL."""

from __future__ import annotations

import os

from alembic import context
from sqlalchemy import engine_from_config, pool
from sqlmodel import SQLModel

import server.tables  # noqa: F401  (registers every domain's tables)

config = context.config
target_metadata = SQLModel.metadata
if config.config_file_name is not None and os.environ.get("TACIT_DATABASE_URL"):
    config.set_main_option("sqlalchemy.url", os.environ["TACIT_DATABASE_URL"])


def run_migrations_offline() -> None:
    context.configure(url=config.get_main_option("sqlalchemy.url"), target_metadata=target_metadata,
                      literal_binds=True, render_as_batch=True)  # fmt: skip
    with context.begin_transaction():
        context.run_migrations()


def run_migrations_online() -> None:
    connectable = config.attributes.get("connection")
    if connectable is None:
        connectable = engine_from_config(config.get_section(config.config_ini_section, {}), prefix="sqlalchemy.",
                                         poolclass=pool.NullPool)  # fmt: skip
    with connectable.connect() as connection:
        context.configure(connection=connection, target_metadata=target_metadata, render_as_batch=True,
                          compare_type=True)  # fmt: skip
        with context.begin_transaction():
            context.run_migrations()
        connection.commit()


if context.is_offline_mode():
    run_migrations_offline()
else:
    run_migrations_online()
