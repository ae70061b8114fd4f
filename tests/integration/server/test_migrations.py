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


def test_a_tick_of_today_is_stored(database_url: str) -> None:
    """A 4 Hz stream's tick today is time / 0.25 s, past 2**31: PostgreSQL's INTEGER refused it."""
    from sqlmodel import Session, select

    from server.telemetry.models import Telemetry
    from server.vehicles.models import Vehicle

    migrate(database_url)
    engine = make_engine(database_url)
    tick = int(1_795_514_068 / 0.25)
    try:
        with Session(engine) as s:
            s.add(Vehicle(id=1, name="rov1", address=2, key_hex="00" * 32))
            s.flush()
            s.add(Telemetry(vehicle_id=1, stream="imu", tick=tick, time=1_795_514_068.0, values=[0.0]))
            s.commit()
            assert s.exec(select(Telemetry.tick)).one() == tick
    finally:
        engine.dispose()
