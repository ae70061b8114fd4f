"""What the processes write is owner-only whatever the umask: the demo's folder and its logs, the modem
log, the agent's tlog."""

from __future__ import annotations

import os
import stat
from pathlib import Path

from launch.stack import Stack, StackConfig
from tacit.modemlog import ModemLog
from vehicle_agent.mavlink_io import MavlinkLink


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_the_demo_folder_its_logs_and_tlogs_are_owner_only(tmp_path: Path) -> None:
    old = os.umask(0o022)  # the usual umask: what is not created narrow is readable by everyone
    try:
        data = tmp_path / "demo"
        data.mkdir(mode=0o755)  # left by an older run
        stack = Stack(StackConfig(data))
        assert mode(data) == 0o700
        stack.spawn(["--help"], "serve.log").wait(timeout=60)
        assert mode(data / "serve.log") == 0o600 and "usage" in stack.log("serve.log")
        modem_log = ModemLog(tmp_path / "logs" / "shore-modem.log")
        modem_log.write(">", "$CCCFG,SRC,1")
        modem_log.close()
        assert mode(tmp_path / "logs") == 0o700 and mode(tmp_path / "logs" / "shore-modem.log") == 0o600
        tlog = MavlinkLink("udpin:127.0.0.1:0", tmp_path / "agent.tlog")
        tlog.stop()
        assert mode(tmp_path / "agent.tlog") == 0o600
    finally:
        os.umask(old)
