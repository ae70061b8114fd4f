"""`tacit sim`: several vehicles from a config file, TCP modem ports, clean shutdown with a report."""

from __future__ import annotations

import asyncio
import json
import signal
import subprocess
import sys
from pathlib import Path

from pymavlink import mavutil

from simulators.parameters import MODEM_LOSS
from tacit.modem import DriverSettings, LinkState, ModemDriver
from tests.conftest import tacit_process

CONFIG = """
seed = 4
time_scale = 2.0
[channel]
noise_level_db = 95
[[modems]]
address = 1
name = "shore"
position = [0, 0, 1]
tcp_port = 0
[[modems]]
address = 2
attach = "alpha"
[[modems]]
address = 3
attach = "beta"
[[vehicles]]
name = "alpha"
[[vehicles]]
name = "beta"
start = [40, 10, 0]
"""


def test_two_vehicles_three_modems_and_a_report(tmp_path: Path) -> None:
    path = tmp_path / "sim.toml"
    path.write_text(CONFIG)
    with tacit_process("sim", "--config", str(path)) as (proc, info):
        assert [m["address"] for m in info["modems"]] == [1, 2, 3]
        assert {v["name"] for v in info["vehicles"]} == {"alpha", "beta"}
        urls = {v["mavlink"][0] for v in info["vehicles"]}
        assert len(urls) == 2
        for url in urls:
            assert mavutil.mavlink_connection(url, source_system=255).wait_heartbeat(timeout=10)

        async def use_tcp_modem() -> tuple[LinkState, float | None]:
            driver = ModemDriver(DriverSettings(url=info["modems"][0]["tcp"], address=1, echo_timeout=2))
            await driver.start()
            travel = await driver.ping(3, timeout=10)
            state = driver.state
            await driver.stop()
            return state, travel

        state, travel = asyncio.run(use_tcp_modem())
        assert state is LinkState.READY
        assert travel is not None and abs(travel - (40**2 + 10**2 + 1) ** 0.5 / 1500) < 0.002
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=10)
    assert proc.returncode == 0
    report = json.loads(out.strip().splitlines()[-1])["report"]
    assert report["channel"]["transmissions"] >= 2
    assert set(report["vehicles"]) == {"alpha", "beta"}


def test_bad_config_is_a_clear_error(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text("[[modems]]\naddress = 1\nattach = 'nobody'\n")
    result = subprocess.run(
        [sys.executable, "-m", "tacit.cli", "sim", "--config", str(path)],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert result.returncode == 2 and "unknown vehicle 'nobody'" in result.stderr
    path.write_text("[channel]\nnoise = 3\n")
    result = subprocess.run(
        [sys.executable, "-m", "tacit.cli", "sim", "--config", str(path)],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert result.returncode == 2 and "unknown channel parameters ['noise']" in result.stderr


def test_a_vehicle_modem_taken_out_of_range_over_mavlink_and_back(tmp_path: Path) -> None:
    """``SIM_MODEM_LOSS`` set on a vehicle (PARAM_SET over its MAVLink) silences the modem riding it, and
    only that one, until it is set back to 0."""
    path = tmp_path / "sim.toml"
    path.write_text(CONFIG)
    with tacit_process("sim", "--config", str(path)) as (_proc, info):
        beta = mavutil.mavlink_connection(info["vehicles"][1]["mavlink"][0], source_system=250)

        def set_loss(loss: float) -> None:
            beta.mav.param_set_send(1, 1, MODEM_LOSS.encode(), loss, mavutil.mavlink.MAV_PARAM_TYPE_REAL32)
            echo = beta.recv_match(type="PARAM_VALUE", blocking=True, timeout=10)
            assert echo is not None and echo.param_id == MODEM_LOSS and echo.param_value == loss

        async def pings() -> tuple[float | None, float | None]:
            driver = ModemDriver(DriverSettings(url=info["modems"][0]["tcp"], address=1, echo_timeout=2))
            await driver.start()
            travel = await driver.ping(3, timeout=5), await driver.ping(2, timeout=10)
            await driver.stop()
            return travel

        set_loss(1.0)
        to_beta, to_alpha = asyncio.run(pings())
        assert to_beta is None and to_alpha is not None
        set_loss(0.0)
        to_beta, _ = asyncio.run(pings())
        assert to_beta is not None
        beta.close()
