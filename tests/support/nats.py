"""A nats-server for the backhaul's tests: on a free port, its JetStream store in a folder, open or with
the users and permissions ``tacit broker-config`` writes (``Secured``)."""

from __future__ import annotations

import contextlib
import json
import shutil
import socket
import subprocess
import time
import uuid
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
        self.started = False  # it ran once: a restart keeps its port
        self.name = f"tacit-test-{uuid.uuid4().hex[:12]}"  # told apart from another server on its port

    def arguments(self) -> list[str]:
        return ["-js", "-a", "127.0.0.1", "-p", str(self.port), "-sd", str(self.folder / "jetstream")]

    def start(self) -> None:
        """Start it and wait until it listens. The first start moves to another free port if this one
        was taken meanwhile (another test process's server: ``free_port`` only reserves it while asked);
        a restart keeps its port (the clients reconnect to it)."""
        for _ in range(5):
            if self._started():
                self.started = True
                return
            if self.started:
                break
            self._rebind()
        raise RuntimeError(f"nats-server did not start on port {self.port}")

    def _started(self) -> bool:
        """Whether this server (not another on its port) listens within 20 s."""
        proc = subprocess.Popen(
            [NATS_SERVER, *self.arguments(), "-n", self.name],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        self.proc = proc
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and proc.poll() is None:
            name = self._listening()
            if name == self.name:
                return True
            if name is not None:  # another server holds the port; ours cannot bind it
                break
            time.sleep(0.05)
        self.stop()
        return False

    def _listening(self) -> str | None:
        """The name the server on this port gives in its INFO line; None if none answers."""
        with contextlib.suppress(OSError, ValueError):
            with socket.create_connection(("127.0.0.1", self.port), timeout=0.5) as conn:
                line = conn.makefile("rb").readline()
            if line.startswith(b"INFO "):
                return str(json.loads(line[5:]).get("server_name", ""))
        return None

    def _rebind(self) -> None:
        self.port = free_port()
        self.url = f"nats://127.0.0.1:{self.port}"

    def stop(self) -> None:
        if self.proc is not None:
            self.proc.terminate()
            self.proc.wait(timeout=10)
            self.proc = None


class Secured(NatsServer):
    """With the configuration ``tacit broker-config`` writes for ``gateways`` (TLS with ``tls``, a
    certificate and its key); each role's credentials are ``credentials(user)``."""

    def __init__(self, folder: Path, gateways: list[str], tls: tuple[str, str] | None = None) -> None:
        super().__init__(folder)
        self.gateways, self.tls = gateways, tls
        self._configure()

    def _configure(self) -> None:
        access.write(
            self.folder, self.gateways, f"127.0.0.1:{self.port}", str(self.folder / "jetstream"), self.tls
        )
        if self.tls is not None:
            self.url = f"tls://127.0.0.1:{self.port}"

    def _rebind(self) -> None:
        super()._rebind()
        self._configure()

    def arguments(self) -> list[str]:
        return ["-c", str(self.folder / "nats-server.conf")]

    def credentials(self, user: str, ca_file: str | None = None) -> access.BrokerAuth:
        return access.BrokerAuth.load(self.folder / f"{user}.toml", ca_file)


def certificates(folder: Path) -> tuple[str, str, str]:
    """A CA and a certificate it signs for 127.0.0.1 (openssl): (CA, certificate, key), PEM files."""
    folder.mkdir(parents=True, exist_ok=True)
    ca, ca_key, cert, key, csr, ext = (
        str(folder / n) for n in ("ca.pem", "ca.key", "server.pem", "server.key", "server.csr", "ext")
    )
    Path(ext).write_text("subjectAltName=IP:127.0.0.1\n")
    ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]
    for args in (
        ["req", "-x509", *ec, "-keyout", ca_key, "-out", ca, "-days", "1", "-subj", "/CN=tacit test CA"],
        ["req", *ec, "-keyout", key, "-out", csr, "-subj", "/CN=127.0.0.1"],
        ["x509", "-req", "-in", csr, "-CA", ca, "-CAkey", ca_key, "-CAcreateserial", "-out", cert,
         "-days", "1", "-extfile", ext],
    ):  # fmt: skip
        subprocess.run(["openssl", *args], check=True, capture_output=True)
    return ca, cert, key
