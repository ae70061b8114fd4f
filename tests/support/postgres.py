"""A PostgreSQL server for the tests: the one at TACIT_TEST_POSTGRES if it answers, else a throwaway cluster.

The throwaway cluster comes from the installed binaries (``/usr/lib/postgresql/*/bin/initdb`` and
``pg_ctl``, or on PATH): a temporary folder, a free port on 127.0.0.1, trust authentication, no fsync;
stopped and deleted afterwards. initdb refuses to run as root, so as root the cluster runs as the
``postgres`` user (or ``nobody``) through ``runuser``. ``scripts/install --test`` installs the binaries
with apt-get when it runs as root and there are none.

Run alone (``python -m tests.support.postgres``) it prints the URL and keeps the server until Ctrl-C.
"""

from __future__ import annotations

import glob
import os
import pwd
import shutil
import socket
import subprocess
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

DEFAULT = "postgresql+psycopg://postgres@127.0.0.1:5432/test"


def answers(url: str) -> bool:
    """Whether a PostgreSQL server accepts a connection at ``url`` (an SQLAlchemy or libpq URL)."""
    import psycopg

    try:
        with psycopg.connect(url.replace("postgresql+psycopg://", "postgresql://"), connect_timeout=3):
            return True
    except psycopg.OperationalError:
        return False


def binaries() -> Path | None:
    """The folder holding initdb and pg_ctl, newest installed version first."""
    found = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"), key=lambda p: int(Path(p).parts[-3]))
    if found:
        return Path(found[-1]).parent
    initdb = shutil.which("initdb")
    return Path(initdb).resolve().parent if initdb else None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _unprivileged_user() -> str | None:
    """The user to run the cluster as when we are root (initdb refuses root); None when we are not."""
    if os.geteuid() != 0:
        return None
    for name in ("postgres", "nobody"):
        try:
            pwd.getpwnam(name)
            return name
        except KeyError:
            continue
    raise RuntimeError("running as root and neither a postgres nor a nobody user exists to run initdb")


@contextmanager
def throwaway_cluster() -> Iterator[str]:
    """Start a temporary PostgreSQL cluster; yield its URL (database ``postgres``); stop and delete it."""
    bin_dir = binaries()
    if bin_dir is None:
        raise RuntimeError(
            "no PostgreSQL server answers and no initdb is installed: install PostgreSQL "
            "(`bash scripts/install --test` does as root, or: sudo apt-get install postgresql) "
            "or point TACIT_TEST_POSTGRES at a server"
        )
    user = _unprivileged_user()
    prefix = ["runuser", "-u", user, "--"] if user else []
    folder = Path(tempfile.mkdtemp(prefix="tacit-pg-"))
    if user:
        record = pwd.getpwnam(user)
        os.chown(folder, record.pw_uid, record.pw_gid)
    data, port = folder / "data", _free_port()

    def run(*args: str) -> None:
        subprocess.run([*prefix, *args], check=True, capture_output=True, text=True, timeout=120)

    try:
        run(
            str(bin_dir / "initdb"),
            "-D",
            str(data),
            "-U",
            "postgres",
            "--auth=trust",
            "-E",
            "UTF8",
            "--no-sync",
        )
        options = f"-p {port} -k {folder} -c listen_addresses=127.0.0.1 -c fsync=off -c full_page_writes=off"
        run(str(bin_dir / "pg_ctl"), "-D", str(data), "-o", options, "-l", str(folder / "log"), "-w", "start")
    except subprocess.CalledProcessError as e:
        log = folder / "log"
        detail = log.read_text() if log.exists() else ""
        shutil.rmtree(folder, ignore_errors=True)
        raise RuntimeError(f"could not start a throwaway PostgreSQL: {e.cmd}: {e.stderr}{detail}") from e
    try:
        yield f"postgresql+psycopg://postgres@127.0.0.1:{port}/postgres"
    finally:
        subprocess.run(
            [*prefix, str(bin_dir / "pg_ctl"), "-D", str(data), "-m", "immediate", "stop"],
            capture_output=True,
            timeout=60,
        )
        shutil.rmtree(folder, ignore_errors=True)


@contextmanager
def postgres_server(url: str | None = None) -> Iterator[str]:
    """The server at ``url`` (default TACIT_TEST_POSTGRES, else the local default) if it answers, else a
    throwaway cluster; yield the URL to use."""
    url = url or os.environ.get("TACIT_TEST_POSTGRES") or DEFAULT
    if answers(url):
        yield url
        return
    with throwaway_cluster() as throwaway:
        yield throwaway


if __name__ == "__main__":
    import signal
    import sys
    import time

    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))  # stop and delete the cluster on kill too
    with postgres_server() as server:
        print(server, flush=True)
        try:
            while True:
                time.sleep(3600)
        except KeyboardInterrupt:
            pass


@contextmanager
def copied_database(server: str, template: str) -> Iterator[str]:
    """A database of the caller's own on ``server``, a copy of the database ``template``; dropped
    afterwards. Its URL."""
    import uuid
    from urllib.parse import urlsplit

    import psycopg

    name = f"tacit_{uuid.uuid4().hex[:12]}"
    admin = server.replace("postgresql+psycopg://", "postgresql://")
    with psycopg.connect(admin, autocommit=True) as c:
        c.execute(f'CREATE DATABASE "{name}" TEMPLATE "{template}"')
    try:
        yield urlsplit(server)._replace(path=f"/{name}").geturl()
    finally:
        with psycopg.connect(admin, autocommit=True) as c:
            c.execute(f'DROP DATABASE "{name}" WITH (FORCE)')
