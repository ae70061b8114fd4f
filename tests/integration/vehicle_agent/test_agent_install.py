"""docs/agent.md's install into a temporary root (``deploy/install-agent --root``; its Python environment
is this one): the service user, each file with its owner and mode, a unit systemd accepts; then the
installed configuration through ``tacit agent --check``, as installed and once given a key, a modem and
an autopilot (``tacit sim``), and an agent that refuses its configuration exits as the unit expects."""

from __future__ import annotations

import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav

from launch import pi_install as install
from tacit.cli import main
from tests.conftest import tacit_process
from vehicle_agent.check import EXIT_CONFIG, EXIT_UNREADY

ROOT = Path(__file__).resolve().parents[3]
KEY = "5a" * 32


def fresh_root(where: Path) -> Path:
    """A fresh root with the Python environment the install would make: a link to this one's ``tacit``."""
    root = install.fresh_root(where)
    (root / "opt/tacit/.venv/bin").mkdir(parents=True)
    (root / "opt/tacit/.venv/bin/tacit").symlink_to(Path(sys.executable).parent / "tacit")
    return root


def install_here(root: Path) -> subprocess.CompletedProcess[str]:
    return install.install_agent(root, "--skip-python")


def entry(root: Path, table: str, name: str) -> list[str]:
    (line,) = [x for x in (root / "etc" / table).read_text().splitlines() if x.startswith(f"{name}:")]
    return line.split(":")


def agent(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    """``tacit agent ARGS`` (in this process: the exit status, what it printed and its errors)."""
    status = main(["agent", *args])
    out, err = capsys.readouterr()
    return status, out, err


def test_the_install_makes_the_service_user_its_files_and_a_unit_systemd_accepts(tmp_path: Path) -> None:
    root = fresh_root(tmp_path / "root")
    done = install_here(root)
    assert done.returncode == 0, done.stderr
    user = entry(root, "passwd", "tacit")
    uid, gid = int(user[2]), int(user[3])
    assert user[5:] == ["/var/lib/tacit", "/usr/sbin/nologin"]
    assert "tacit" in entry(root, "group", "dialout")[3].split(",")
    config = (root / "etc/tacit/agent.toml").stat()
    assert (stat.S_IMODE(config.st_mode), config.st_uid, config.st_gid) == (0o640, 0, gid)
    assert (root / "etc/tacit/missions/transect.json").read_text() == (
        ROOT / "deploy/missions/transect.json"
    ).read_text()
    for folder in ("var/lib/tacit", "var/log/tacit"):
        made = (root / folder).stat()
        assert (stat.S_IMODE(made.st_mode), made.st_uid, made.st_gid) == (0o750, uid, gid)
    unit = root / "etc/systemd/system/tacit-agent.service"
    assert unit.read_text() == (ROOT / "deploy/tacit-agent.service").read_text()

    with (root / "etc/tacit/agent.toml").open("a") as edited:
        edited.write("# the vehicle's own settings\n")
    (root / "etc/tacit/agent.toml").chmod(0o644)
    assert install_here(root).returncode == 0  # again, after an update
    assert (root / "etc/tacit/agent.toml").read_text().endswith("# the vehicle's own settings\n")
    assert stat.S_IMODE((root / "etc/tacit/agent.toml").stat().st_mode) == 0o640
    assert [x.split(":")[0] for x in (root / "etc/passwd").read_text().splitlines()] == ["root", "tacit"]

    here = tmp_path / "tacit-agent.service"  # systemd checks ExecStart's program: this environment's
    here.write_text(
        unit.read_text().replace("/opt/tacit/.venv/bin/tacit", str(Path(sys.executable).parent / "tacit"))
    )
    verify = subprocess.run(
        ["systemd-analyze", "verify", str(here)], capture_output=True, text=True, timeout=60
    )
    assert (verify.returncode, verify.stdout + verify.stderr) == (0, "")


def test_the_installed_configuration_is_checked_before_a_dive(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = fresh_root(tmp_path / "root")
    assert install_here(root).returncode == 0
    config = root / "etc/tacit/agent.toml"
    status, out, err = agent(capsys, "--check", "--config", str(config))
    lines = out.splitlines()
    assert status == EXIT_UNREADY, err
    assert [x.removeprefix(f"{config}: ").split(":")[0] for x in lines] == [
        "key",
        "modem_url",
        "mavlink_url",
        "3 problem(s)",
    ]
    assert "/dev/ttyUSB0: no such device" in lines[1]

    with tacit_process("sim") as (_, info):
        tcp = next(url for url in info["vehicle"]["mavlink"] if url.startswith("tcp:"))
        pty = next(m["pty"] for m in info["modems"] if m["address"] == 2)
        text = config.read_text().replace("PUT-THE-VEHICLE-KEY-HERE", KEY)
        config.write_text(text.replace("/dev/ttyUSB0", pty).replace("tcp:127.0.0.1:5777", tcp))
        assert agent(capsys, "--check", "--config", str(config)) == (
            0,
            f"{config}: ready: vehicle 2, modem {pty}, autopilot on {tcp} (SYSID_MYGCS 255), "
            "missions 1 square, 2 lawnmower, 3 transect\n",
            "",
        )
        gcs = mavutil.mavlink_connection(tcp, source_system=250)
        gcs.mav.param_set_send(1, 1, b"SYSID_MYGCS", 1, mav.MAV_PARAM_TYPE_INT16)
        assert gcs.recv_match(type="PARAM_VALUE", blocking=True, timeout=10) is not None
        gcs.close()
        status, out, _ = agent(capsys, "--check", "--config", str(config))
        assert status == EXIT_UNREADY
        assert f"mavlink_url: {tcp}: the autopilot's SYSID_MYGCS is 1" in out


def test_an_agent_that_refuses_its_configuration_says_each_problem_and_exits_for_good(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    shutil.copy(ROOT / "deploy/agent.example.toml", tmp_path / "agent.toml")  # no missions folder beside it
    config = tmp_path / "agent.toml"
    config.chmod(0o600)
    config.write_text(config.read_text().replace("PUT-THE-VEHICLE-KEY-HERE", KEY))
    status, _, err = agent(capsys, "--config", str(config))
    assert status == EXIT_CONFIG
    assert err.splitlines() == [
        f"tacit agent: {config}: missions[2]: cannot read {tmp_path}/missions/transect.json: No such file or directory",
        f"tacit agent: not started: 1 problem(s) in {config} (tacit agent --check --config {config} tries the "
        "modem and the autopilot too)",
    ]
