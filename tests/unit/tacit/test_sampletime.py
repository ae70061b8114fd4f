"""A sample is dated by its autopilot stamp, not its arrival: messages that arrive together keep the times
they were measured at, and a reboot of the autopilot starts its stamps over."""

from __future__ import annotations

import pytest

from tacit.sampletime import SampleClock


def test_messages_that_waited_keep_their_measured_times() -> None:
    clock = SampleClock()
    prompt = [clock.date(boot, arrival) for boot, arrival in [(10.0, 100.01), (10.25, 100.26)]]
    late = [clock.date(boot, 101.3) for boot in (10.5, 10.75, 11.0)]  # the reader stalled: all at once
    assert prompt + late == pytest.approx([100.01, 100.26, 100.51, 100.76, 101.01])


def test_a_date_is_never_after_the_arrival_and_a_reboot_starts_over() -> None:
    clock = SampleClock()
    for boot, arrival in [(50.0, 1000.2), (50.25, 1000.3), (50.5, 1000.9)]:  # the last one late
        assert clock.date(boot, arrival) <= arrival
    assert clock.date(50.75, 1001.0) == pytest.approx(1000.8)  # by the least delay: 50.25 at 1000.3
    assert clock.date(0.5, 1010.0) == pytest.approx(1010.0)  # rebooted: its stamps count from 0 again
    assert clock.date(None, 1011.0) == 1011.0  # a message without a stamp: its arrival
