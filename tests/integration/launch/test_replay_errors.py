"""`tacit replay`, `sim`, `eval-compression`, `demo` and `serve` fail in one line: a missing log, a busy port."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path


def tacit(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "tacit.cli", *args], capture_output=True, text=True, timeout=timeout
    )


def test_a_missing_log_is_named_as_such(tmp_path: Path) -> None:
    missing = str(tmp_path / "dive.tlog")
    for args in (
        ("replay", missing),
        ("sim", "--replay", missing),
        ("eval-compression", missing, "--eps", "1"),
    ):
        result = tacit(*args)
        assert result.returncode == 2 and result.stderr.strip().endswith(
            "no such file" if args[0] != "sim" else "no such file (the .tlog to replay)"
        ), result.stderr
        assert "port" not in result.stderr and "Traceback" not in result.stderr


def test_a_busy_port_is_one_line(tmp_path: Path, real_data: Path) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = str(busy.getsockname()[1])
        runs = {
            "replay": tacit(
                "replay",
                str(real_data / "ardusub" / "small.tlog"),
                "--port",
                port,
                "--data-dir",
                str(tmp_path / "r"),
            ),  # fmt: skip
            "demo": tacit("demo", "--headless", "--port", port, "--data-dir", str(tmp_path / "d")),
            "serve": tacit(
                "serve", "--port", port, "--no-map", "--database-url", f"sqlite:///{tmp_path}/s.db"
            ),
        }
    for name, result in runs.items():
        assert result.returncode == 1, (name, result.stderr)
        assert result.stderr.strip() == (
            f"tacit {name}: cannot listen on 127.0.0.1:{port} (Address already in use); choose another with --port"
        ), result.stderr
    assert not (tmp_path / "d").exists()  # nothing was started
