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
    """With the configuration ``tacit broker-config`` writes for ``gateways`` (TLS with ``tls``, a
    certificate and its key); each role's credentials are ``credentials(user)``."""

    def __init__(self, folder: Path, gateways: list[str], tls: tuple[str, str] | None = None) -> None:
        super().__init__(folder)
        access.write(folder, gateways, f"127.0.0.1:{self.port}", str(folder / "jetstream"), tls)
        if tls is not None:
            self.url = f"tls://127.0.0.1:{self.port}"

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
