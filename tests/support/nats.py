"""A nats-server for the backhaul's tests (``launch.broker``'s), and certificates for its TLS."""

from __future__ import annotations

import subprocess
from pathlib import Path

from launch.broker import NatsServer, Secured, binary, free_port

__all__ = ["NATS_SERVER", "NatsServer", "Secured", "certificates", "free_port"]

NATS_SERVER = binary()


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
