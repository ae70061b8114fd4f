"""Slot timings: longer with range, shorter with the time scale."""

from __future__ import annotations

import pytest

from server.core.config import Settings
from server.link.state import VehicleState
from server.link.timing import Timing
from tacit import rates


def test_slot_timings_grow_with_range_and_shrink_with_time_scale() -> None:
    near, far = VehicleState(1, "a", 2, {}), VehicleState(2, "b", 3, {})
    near.range_m, far.range_m = 100.0, 3000.0
    timing = Timing(Settings(time_scale=1.0))
    assert timing.ack_timeout(far) - timing.ack_timeout(near) == pytest.approx(1.5 * 2 * 2900 / 1500)
    assert timing.poll_window(far, 1) > timing.poll_window(far, 0) > timing.poll_window(near, 0)
    assert Timing(Settings(time_scale=10.0)).ack_timeout(far) == pytest.approx(timing.ack_timeout(far) / 10)
    unknown = VehicleState(3, "c", 4, {})
    assert timing.range_m(unknown) == Settings().default_range  # until a ping measures it


def test_a_poll_window_covers_the_longest_answer_at_its_rate_and_no_more() -> None:
    """The window is in frames of the rate, not in packets: at rate 5 (eight 256-byte frames) an unanswered
    poll once cost 19 s, as if 32 frames could come back."""
    vehicle = VehicleState(1, "a", 2, {})
    vehicle.range_m = 300.0
    timing = Timing(Settings(time_scale=1.0))
    for number, rate in rates.RATES.items():
        heard_by = (
            rates.airtime_s(rates.CYCLE_INIT_BITS, 0) + 2 * 300.0 / Settings().sound_speed
            + rates.TURNAROUND_S + rates.data_airtime_s(number, rate.frames)
        )  # fmt: skip
        assert heard_by < timing.poll_window(vehicle, number) < 1.5 * heard_by + 1.5, number
