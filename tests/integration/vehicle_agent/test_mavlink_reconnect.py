"""The agent's MAVLink link notices the vehicle going away and reconnects when it comes back on the same endpoint."""

from __future__ import annotations

from launch.stack import wait_for


def test_mavlink_link_drops_and_the_agent_reconnects(tmp_path, capfd) -> None:
    import socket

    from tests.conftest import tacit_process
    from vehicle_agent.mavlink_io import MavlinkLink

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    link = MavlinkLink(f"tcp:127.0.0.1:{port}", tlog=tmp_path / "agent.tlog", reconnect_max=1.0)
    link.start()
    try:
        with tacit_process("sim", "--mavlink-port", str(port)):
            assert link.wait_connected(20)
            wait_for(lambda: link.telemetry.heartbeats >= 1, 10, what="heartbeats")
        wait_for(lambda: not link.connected, 20, what="the drop noticed")  # the vehicle went away
        with tacit_process("sim", "--mavlink-port", str(port)):  # and came back on the same endpoint
            assert link.wait_connected(30)
            before = link.telemetry.heartbeats
            wait_for(lambda: link.telemetry.heartbeats > before, 10, what="telemetry again")
    finally:
        link.stop()
    assert (tmp_path / "agent.tlog").stat().st_size > 0
    # the drop is an error the reader handles once, not pymavlink's print in a loop (54,279 lines in a log)
    assert "EOF on TCP socket" not in capfd.readouterr().out
