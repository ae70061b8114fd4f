"""The README's first command and each install extra, on a fresh checkout, as a user runs them.

The rest of the suite runs in the test environment, which has every extra and every test tool: it
cannot see a command that needs a package its own extra does not install. These tests copy the
checkout (what ``git clone`` would give, plus files not yet committed), create fresh virtual
environments with only what each command installs, and run the entry points there.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from launch.pi_install import fresh_root, install_agent
from vehicle_agent.check import EXIT_CONFIG, EXIT_UNREADY

ROOT = Path(__file__).resolve().parents[2]
INSTALL_TIMEOUT = 900  # s: a first install downloads numpy, scipy, viser...


def fresh_checkout(where: Path) -> Path:
    """The files git tracks (and new ones it does not ignore), copied: no .venv, no data, no caches."""
    listed = (
        subprocess.run(
            ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
            cwd=ROOT,
            capture_output=True,
            check=True,
        )
        .stdout.decode()
        .split("\0")
    )
    clone = where / "tacit"
    for name in filter(None, listed):
        source = ROOT / name
        if source.is_symlink():  # as git clone makes them (server/web, server/migrations)
            (clone / name).parent.mkdir(parents=True, exist_ok=True)
            (clone / name).symlink_to(source.readlink())
        elif source.is_file():
            (clone / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, clone / name)
    return clone


def user_env(**extra: str) -> dict[str, str]:
    """The environment of a user's shell: none of the test environment's Python settings."""
    env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PYTHONPATH", "PYTHONHOME")}
    env["PATH"] = os.pathsep.join(p for p in env.get("PATH", "").split(os.pathsep) if ".venv" not in p)
    return {**env, **extra}


def fresh_venv(where: Path, requirement: str) -> Path:
    """A new virtual environment with ``pip install REQUIREMENT`` (not editable: as on a Pi)."""
    base = getattr(sys, "_base_executable", sys.executable)
    subprocess.run([base, "-m", "venv", str(where)], check=True, env=user_env())
    subprocess.run(
        [str(where / "bin" / "python"), "-m", "pip", "install", "-q", "--no-compile", requirement],
        check=True,
        env=user_env(),
        timeout=INSTALL_TIMEOUT,
    )
    return where / "bin"


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_http(url: str, timeout: float) -> bytes:
    deadline = time.monotonic() + timeout
    while True:
        try:
            with urllib.request.urlopen(url, timeout=5) as response:
                return response.read()
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)


def tacit(bin_dir: Path, *args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(bin_dir / "tacit"), *args], capture_output=True, text=True, timeout=120, env=user_env(), cwd=cwd
    )


def test_start_command_from_a_fresh_checkout(tmp_path: Path) -> None:
    """``./scripts/start``: installs what it needs, starts everything, the dashboard loads, Ctrl-C stops it."""
    from playwright.sync_api import sync_playwright

    clone = fresh_checkout(tmp_path)
    port, map_port = free_port(), free_port()
    proc = subprocess.Popen(
        [
            "bash",
            "scripts/start",
            "--headless",
            "--json",
            "--port",
            str(port),
            "--map-port",
            str(map_port),
            "--data-dir",
            str(tmp_path / "demo"),
        ],
        cwd=clone,
        env=user_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        line = proc.stdout.readline() if proc.stdout else ""
        assert line, f"tacit demo printed nothing: {proc.stderr.read() if proc.stderr else ''}"[-3000:]
        info = json.loads(line)
        health = json.loads(wait_http(info["api_url"] + "/health", 60))
        assert health["status"] == "ok"
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path="/usr/bin/chromium", args=["--no-sandbox"])
            page = browser.new_page()
            page.goto(info["dashboard_url"])
            assert "Tacit" in page.title()
            browser.close()
        proc.send_signal(signal.SIGINT)  # Ctrl-C
        assert proc.wait(timeout=60) == 0, (proc.stderr.read() if proc.stderr else "")[-3000:]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert (clone / ".venv" / "bin" / "tacit").exists()


@pytest.fixture(scope="module")
def checkout(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The fresh checkout's wheel, built once: what ``pip install ./tacit[EXTRA]`` builds, then installs."""
    where = tmp_path_factory.mktemp("checkout")
    clone = fresh_checkout(where)
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(where / "dist"), str(clone)],
        check=True,
        env=user_env(),
        timeout=INSTALL_TIMEOUT,
    )
    (wheel,) = (where / "dist").glob("tacit-*.whl")
    return wheel


def test_core_alone_runs_the_core_and_names_the_missing_extras(checkout: Path, tmp_path: Path) -> None:
    """``pip install tacit``: the wire format, codec and modem tools; other commands say what to install."""
    bin_dir = fresh_venv(tmp_path / "venv", str(checkout))
    imports = subprocess.run(
        [
            str(bin_dir / "python"),
            "-c",
            "import tacit.codec, tacit.modem, tacit.auth, tacit.limits, tacit.link; print('ok')",
        ],
        capture_output=True,
        text=True,
    )
    assert imports.stdout.strip() == "ok", imports.stderr
    assert tacit(bin_dir, "--help").returncode == 0
    assert tacit(bin_dir, "modem-log", "--help").returncode == 0
    for command, extra in (
        ("agent", "agent"),
        ("serve", "server"),
        ("demo", "demo"),
        ("sim", "sim"),
        ("eval-compression", "analysis"),
    ):
        result = tacit(bin_dir, command, "--help")
        assert result.returncode == 2, result.stderr
        assert f"pip install 'tacit[{extra}]'" in result.stderr and "Traceback" not in result.stderr


def test_the_pi_install_runs_the_agent_without_the_web_stack_or_plotting(tmp_path: Path) -> None:
    """docs/agent.md's install (``deploy/install-agent``, its Python environment included) into a temporary
    root: the agent's packages only (deploy/agent-requirements.txt), and the agent checks its configuration."""
    clone = fresh_checkout(tmp_path)
    root = fresh_root(tmp_path / "root")
    done = install_agent(root, clone=clone, env=user_env(), timeout=INSTALL_TIMEOUT)
    assert done.returncode == 0, done.stderr
    bin_dir = root / "opt/tacit/.venv/bin"
    assert tacit(bin_dir, "agent", "--help").returncode == 0
    for absent in (
        "fastapi",
        "matplotlib",
        "lxml",
    ):  # the shore's packages; filterpy's and pymavlink's extras
        found = subprocess.run([str(bin_dir / "python"), "-c", f"import {absent}"], capture_output=True)
        assert found.returncode != 0, f"{absent} is installed on the Pi"
    config = root / "etc/tacit/agent.toml"
    checked = tacit(bin_dir, "agent", "--check", "--config", str(config))
    assert checked.returncode == EXIT_UNREADY and "Traceback" not in checked.stderr, checked.stderr
    assert [x.removeprefix(f"{config}: ").split(":")[0] for x in checked.stdout.splitlines()][:3] == [
        "key",
        "modem_url",
        "mavlink_url",
    ]
    assert tacit(bin_dir, "agent", "--config", str(config)).returncode == EXIT_CONFIG
    assert "tacit[server]" in tacit(bin_dir, "serve", "--help").stderr


def test_server_extra_alone_serves_the_api_and_the_dashboard(checkout: Path, tmp_path: Path) -> None:
    """``pip install tacit[server]``: the API, its migrations and the dashboard ship in the package, and
    ``/metrics`` is served beside them."""
    bin_dir = fresh_venv(tmp_path / "venv", f"{checkout}[server]")
    port, metrics = free_port(), free_port()
    env = user_env(TACIT_DATABASE_URL=f"sqlite:///{tmp_path}/tacit.db", TACIT_WRITE_TOKENS="op")
    proc = subprocess.Popen(
        [str(bin_dir / "tacit"), "serve", "--port", str(port), "--no-map", "--metrics-port", str(metrics)],
        cwd=tmp_path,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        health = json.loads(wait_http(f"http://127.0.0.1:{port}/api/v1/health", 60))
        assert health["status"] == "ok"
        assert b"Tacit" in wait_http(f"http://127.0.0.1:{port}/", 10)
        assert b"\ntacit_modem_ready " in wait_http(f"http://127.0.0.1:{metrics}/metrics", 10)
    finally:
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 0, (proc.stderr.read() if proc.stderr else "")[-3000:]
