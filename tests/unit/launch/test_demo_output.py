"""What `tacit demo` prints: each vehicle's ground-station address in the banner, and at exit the
channel's frames, whose counts add up and say what they count."""

from __future__ import annotations

import argparse
import re

import pytest

from launch.demo import _announce, _channel
from simulators.acoustics import ChannelParameters
from simulators.channel import Channel, Kind, Transmission
from simulators.clock import VirtualScheduler
from tacit import rates


def test_the_banner_gives_each_vehicles_ground_station_address(capsys: pytest.CaptureFixture[str]) -> None:
    vehicles = [
        {
            "name": f"rov{i}",
            "address": i + 1,
            "home": [0.0, 30.0 * i],
            "mavlink": [f"tcp:127.0.0.1:{4000 + i}", f"udpout:127.0.0.1:{5000 + i}"],
        }
        for i in (1, 2)
    ]
    info = {
        key: "x"
        for key in (
            "data_dir",
            "sign_in_url",
            "observer_url",
            "map_url",
            "api_url",
            "dashboard_url",
            "token",
            "read_token",
        )
    }
    _announce(
        {**info, "vehicles": vehicles},
        argparse.Namespace(json=False, headless=True, time_scale=1.0, gateways=0),
    )
    out = capsys.readouterr().out
    for i in (1, 2):
        assert (
            f"Vehicle rov{i}: modem address {i + 1}" in out
            and f"MAVLink tcp:127.0.0.1:{4000 + i} (its agent's)" in out
        )
        assert (
            f"ground station: UDP 127.0.0.1:{5000 + i} (mavproxy.py --master=udpout:127.0.0.1:{5000 + i};"
            in out
        )


def test_the_exit_summary_counts_frames_that_add_up(capsys: pytest.CaptureFixture[str]) -> None:
    sched = VirtualScheduler()
    channel = Channel(sched, ChannelParameters(seed=1))
    for name, address, east in (("shore", 1, 0.0), ("rov2", 2, 2500.0), ("rov3", 3, 4000.0)):
        channel.add_node(name, lambda e=east: (0.0, e, 0.0), lambda rec: None, address=address)
    for i in range(40):  # the shore and rov2 (2.5 km) in turn, rov3 (4 km) overhearing
        name, src, dest = ("shore", 1, 2) if i % 2 else ("rov2", 2, 1)
        tx = Transmission(Kind.DATA, src, dest, 0, rates.data_airtime_s(0, 2), [b"x" * 32] * 2)
        sched.call_later(15.0 * i, lambda n=name, t=tx: channel.transmit(n, t))
    sched.call_later(
        700.0, lambda: channel.transmit("rov3", Transmission(Kind.DATA, 3, 1, 0, 3.6, [b"x" * 32]))
    )
    sched.call_later(
        700.5, lambda: channel.transmit("rov2", Transmission(Kind.DATA, 2, 1, 0, 3.6, [b"x" * 32]))
    )
    sched.run()
    _channel({"channel": channel.stats, "collided": []})
    line = capsys.readouterr().out
    found = re.search(
        r"channel: (\d+) transmissions .* At the modem each was for, (\d+) of (\d+) frames arrived and (\d+) were "
        r"lost: (\d+) in collisions, (\d+) while that modem was transmitting, (\d+) to range and noise .* The "
        r"other modems overheard (\d+) of (\d+)\.",
        line,
    )
    assert found, line
    sent, arrived, frames, lost, collided, deaf, noise, heard, overheard = map(int, found.groups())
    assert sent == 42 and frames == 82 and overheard == 82
    assert arrived + lost == frames and collided + deaf + noise == lost
    assert collided == 2 and noise > 0 and heard < overheard  # the 4 km modem misses some
