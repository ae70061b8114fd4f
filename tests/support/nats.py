"""A nats-server for the backhaul's tests: on a free port, its JetStream store in a folder, open or with
the users and permissions ``tacit broker-config`` writes (``Secured``)."""

from __future__ import annotations

import contextlib
import shutil
import socket
import subprocess
import time
from pathlib import Path

from server.backhaul import access

NATS_SERVER = shutil.which("nats-server") or "/usr/sbin/nats-server"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class NatsServer:
    """Started and stopped on the same port and store (a restart, or a backhaul outage)."""

    def __init__(self, folder: Path) -> None:
        self.port = free_port()
        self.folder = folder
        self.url = f"nats://127.0.0.1:{self.port}"
        self.proc: subprocess.Popen[bytes] | None = None

    def arguments(self) -> list[str]:
        return ["-js", "-a", "127.0.0.1", "-p", str(self.port), "-sd", str(self.folder / "jetstream")]

    def start(self) -> None:
        self.proc = subprocess.Popen(
            [NATS_SERVER, *self.arguments()], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            with (
                contextlib.suppress(OSError),
                socket.create_connection(("127.0.0.1", self.port), timeout=0.2),
            ):
                return
            time.sleep(0.05)
        raise RuntimeError("nats-server did not start")

    def stop(self) -> None:
        if self.proc is not None:
            self.proc.terminate()
            self.proc.wait(timeout=10)
            self.proc = None


class Secured(NatsServer):
    """With the configuration ``tacit broker-config`` writes for ``gateways``; each role's credentials
    file is ``credentials(user)``."""

    def __init__(self, folder: Path, gateways: list[str]) -> None:
        super().__init__(folder)
        access.write(folder, gateways, f"127.0.0.1:{self.port}", str(folder / "jetstream"))

    def arguments(self) -> list[str]:
        return ["-c", str(self.folder / "nats-server.conf")]

    def credentials(self, user: str) -> access.BrokerAuth:
        return access.BrokerAuth.load(self.folder / f"{user}.toml")
