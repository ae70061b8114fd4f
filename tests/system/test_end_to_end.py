"""The whole chain, as separate processes (tacit sim, tacit serve, tacit agent), scripted through the REST
API as a scientist would: register the vehicle, start the square mission, send a move mid-mission,
abort. Commands arrive exactly once, the plume's priority packets reach the database, the shore's
reconstruction is within eps wherever it is marked certain, and the vehicle ends where it was told."""

from __future__ import annotations

import math
import time

from analysis.series import Measured, measured_samples
from launch.rig import Rig
from launch.stack import wait_for
from tacit.packets import Stream
from tacit.streams import default_streams
from tests.support.system import TruthWatcher

PLUME = {
    "surface_temp": 20.0,
    "thermocline_depth": 40.0,
    "front_step": 0.0,
    "plume_north": 22.0,
    "plume_east": 8.0,
    "plume_depth": 2.0,
    "plume_sigma": 6.0,
    "plume_sigma_z": 4.0,
    "plume_excess": 3.0,
    "patches": [],
}


def measured_temperatures(rig: Rig) -> Measured:
    """What the vehicle measured (its agent's tlog): every sample, with its time."""
    return measured_samples(rig.dir / "tlogs", "SCALED_PRESSURE2", ["temperature"], scale=0.01)


def test_scripted_mission_end_to_end() -> None:
    rig = Rig(200.0, scale=8.0, settle=0, mission=True, environment=PLUME)
    truth = TruthWatcher(rig.mavlink)
    try:
        api = rig.http
        mission = api.post(
            "/vehicles/1/missions",
            json={
                "name": "square",
                "number": 1,
                "waypoints": [{"north": 0, "east": 0, "depth": 2}, {"north": 20, "east": 0, "depth": 2}],
            },
        ).json()
        start = api.post(f"/missions/{mission['id']}/start").json()
        wait_for(
            lambda: api.get(f"/commands/{start['id']}").json()["status"] == "executed",
            60,
            what="mission start",
        )
        wait_for(
            lambda: any(
                p["priority"] == 3 and p["body"]["stream"] == "environmental"
                for p in api.get("/packets", params={"type": "priority", "limit": 1000}).json()["items"]
            ),
            90,
            what="the plume's time-sensitive packet in the database",
        )
        move = api.post(
            "/vehicles/1/commands", json={"command": "move", "distance": 6, "angle": 90, "depth": 0}
        ).json()
        wait_for(
            lambda: api.get(f"/commands/{move['id']}").json()["status"] == "executed",
            90,
            what="move executed",
        )
        abort = api.post(f"/missions/{mission['id']}/abort").json()
        wait_for(
            lambda: api.get(f"/commands/{abort['id']}").json()["status"] == "executed",
            60,
            what="abort executed",
        )
        time.sleep(20 / rig.scale)  # holding (20 s of vehicle time): it should stay where the abort found it
        link = api.get("/link").json()["vehicles"]["rov1"]
        assert link["checkpoint"]["state"] == "aborted"
        held = link["checkpoint"]
        end = truth.latest
        assert (
            math.hypot(end.north - held["north"], end.east - held["east"]) < 2.5
        )  # where the commands left it
        executed = rig.executed_per_seq()
        assert sorted(executed) == [start["seq"], move["seq"], abort["seq"]] and set(executed.values()) == {1}
        measured = measured_temperatures(rig)
        rows = api.get("/telemetry", params={"stream": "env", "limit": 5000}).json()["items"]
        spec = default_streams()[Stream.ENVIRONMENTAL]
        eps = spec.eps[0]
        checked = [  # each certain row is within eps of one of the samples taken within half a tick of it
            min(abs(r["values"][0] - m[0]) for m in near)
            for r in rows
            if r["certain"] and (near := measured.near(r["time"], spec.time_precision))
        ]
        assert len(checked) >= 5 and max(checked) <= eps + 1e-9
    finally:
        truth.close()
        rig.close()
