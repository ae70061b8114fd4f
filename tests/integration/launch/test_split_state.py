"""The split demo's state is its data folder and that folder's own database, kept together: a new folder
gets an empty database, the same folder its own again, and a folder of the other layout is refused."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import psycopg
import pytest

from launch import split

SERVER = "postgresql+psycopg://postgres@127.0.0.1:5432/test"


@pytest.fixture
def folder(tmp_path: Path) -> Iterator[Path]:
    data = tmp_path / "demo-gateways"
    data.mkdir()
    yield data
    url = (data / split.MARKER).read_text().strip() if (data / split.MARKER).exists() else None
    if url:
        with psycopg.connect(split._libpq(SERVER), autocommit=True) as c:
            c.execute(f'DROP DATABASE IF EXISTS "{url.rsplit("/", 1)[1]}" WITH (FORCE)')


def rows(url: str) -> int:
    with psycopg.connect(split._libpq(url)) as c:
        c.execute("CREATE TABLE IF NOT EXISTS probe (n int)")
        count = c.execute("SELECT count(*) FROM probe").fetchone()
        c.execute("INSERT INTO probe VALUES (1)")
        return int(count[0]) if count else 0


def test_a_folder_keeps_its_own_database_and_a_new_one_starts_empty(folder: Path, tmp_path: Path) -> None:
    url = split.database(SERVER, folder)
    assert rows(url) == 0 and split.database(SERVER, folder) == url and rows(url) == 1  # resumed
    (folder / split.MARKER).unlink()  # the folder deleted and made again under the same name
    assert split.database(SERVER, folder) == url and rows(url) == 0  # what it found was not its own
    other = tmp_path / "elsewhere"
    other.mkdir()
    try:
        assert split.database(SERVER, other) != url
    finally:
        with psycopg.connect(split._libpq(SERVER), autocommit=True) as c:
            c.execute(f'DROP DATABASE "{split.database(SERVER, other).rsplit("/", 1)[1]}" WITH (FORCE)')


def test_a_folder_of_the_other_layout_or_of_an_unknown_shore_is_refused(folder: Path) -> None:
    assert split.other_layout(folder, split=True) is None
    (folder / "agent-state-rov2.json").write_text("{}")  # agents' counters, their shore's database unknown
    assert "database is not known" in (split.other_layout(folder, split=True) or "")
    split.database(SERVER, folder)
    assert split.other_layout(folder, split=True) is None
    assert "split-shore demo" in (split.other_layout(folder, split=False) or "")
    (folder / "tacit.db").write_text("")
    assert "one-shore demo" in (split.other_layout(folder, split=True) or "")
