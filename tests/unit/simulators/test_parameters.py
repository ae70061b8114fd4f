"""The simulated BlueROV2's parameters are a real ArduSub's, exactly as its recorded dive reported them,
and take a value as ArduPilot does."""

from __future__ import annotations

import struct

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from analysis.tlog import messages
from simulators.parameters import MODEM_LOSS, Parameters
from tests.conftest import DATA


def test_the_table_is_what_the_recorded_ardusub_reported() -> None:
    params = Parameters.ardusub()
    reported = {}
    for msg in messages(DATA / "ardusub" / "small.tlog", "PARAM_VALUE"):
        assert msg.param_count == 887
        known = reported.get(msg.param_id)
        reported[msg.param_id] = (msg.param_value, msg.param_type, known[2] if known else msg.param_index)
    assert params.names[:887] == sorted(reported, key=lambda name: reported[name][2])
    assert {name: (params[name], params.kinds[name], params.index(name)) for name in reported} == reported
    assert params.names[887:] == [MODEM_LOSS] and len(params) == 888
    assert (params["SYSID_MYGCS"], params["FS_PILOT_TIMEOUT"]) == (255.0, 3.0)


def test_a_value_is_set_as_ardupilot_sets_it() -> None:
    params = Parameters.ardusub()
    assert params.kinds["FRAME_CONFIG"] == mavlink.MAV_PARAM_TYPE_INT8
    for value, kept in (
        (2.999, 3.0),
        (2.5, 2.0),
        (-1.995, -2.0),
        (-1.5, -1.0),
        (300.0, 127.0),
        (-300.0, -128.0),
    ):
        assert params.set("FRAME_CONFIG", value) and params["FRAME_CONFIG"] == kept
    assert params.kinds["SURFACE_DEPTH"] == mavlink.MAV_PARAM_TYPE_REAL32
    assert (
        params.set("SURFACE_DEPTH", -12.3)
        and params["SURFACE_DEPTH"] == struct.unpack("<f", struct.pack("<f", -12.3))[0]
    )
    for name, value in (
        ("SURFACE_DEPTH", float("nan")),
        ("SURFACE_DEPTH", float("inf")),
        ("NO_SUCH_PARAM", 1.0),
    ):
        assert not params.set(name, value)
    assert params["SURFACE_DEPTH"] == struct.unpack("<f", struct.pack("<f", -12.3))[0]
    assert "NO_SUCH_PARAM" not in params
    assert Parameters.ardusub()["FRAME_CONFIG"] == 2.0  # each vehicle its own copy
