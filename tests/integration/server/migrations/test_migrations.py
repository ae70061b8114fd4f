"""Schema migrations: upgrade, `alembic check` (models and migrations agree), downgrade, upgrade,
on a SQLite file and on PostgreSQL."""

from __future__ import annotations

from alembic import command
from sqlalchemy import inspect

from server.core.db import alembic_config, make_engine, migrate

TABLES = {
    "vehicle",
    "mission",
    "operator",
    "teammission",
    "teamproposal",
    "command",
    "commandevent",
    "frame",
    "packet",
    "relayedframe",
    "telemetry",
    "linkevent",
    "linkstate",
    "gateway",
    "assignment",
    "dispatch",
}


def tables(url: str) -> set[str]:
    engine = make_engine(url)
    try:
        return set(inspect(engine).get_table_names()) - {"alembic_version"}
    finally:
        engine.dispose()


def test_upgrade_check_downgrade_upgrade(database_url: str) -> None:
    config = alembic_config(database_url)
    migrate(database_url)
    assert tables(database_url) == TABLES
    command.check(config)  # raises if the models differ from what the migrations build
    command.downgrade(config, "base")
    assert tables(database_url) == set()
    migrate(database_url)
    assert tables(database_url) == TABLES
    command.check(config)
