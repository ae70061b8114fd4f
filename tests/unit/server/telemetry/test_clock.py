"""The vehicle's report times on the shore's clock (``server.telemetry.clock``): the bound never comes
before the event's cause, whatever the stamp's rounding and the wait before the shore hears it."""

from __future__ import annotations

import random

from server.telemetry.clock import RESOLUTION_S, offset, on_shore_clock


def test_the_offset_is_a_lower_bound_and_the_least_delayed_check_point_sets_it() -> None:
    true_offset = 3.7  # the vehicle's clock is ahead
    made = [100.2, 130.9, 161.5]  # shore times the check-points were made
    waits = [4.0, 0.3, 9.0]  # their wait for a slot and their airtime
    stamps = [(float(int(m + true_offset)), m + w) for m, w in zip(made, waits, strict=True)]
    found = offset(stamps)
    assert found is not None and found <= true_offset
    assert found == max(t - h for t, h in stamps) and true_offset - found < 0.3 + RESOLUTION_S
    assert offset([]) is None


def test_an_event_is_never_shown_before_its_cause_nor_after_the_shore_heard_of_it() -> None:
    rng = random.Random(7)
    for _ in range(2000):
        true_offset = rng.uniform(-40.0, 40.0)
        sent = rng.uniform(0, 1000.0)  # the command left the shore (shore clock)
        acted = sent + rng.uniform(0.05, 5.0)  # the vehicle acted on it
        heard = acted + rng.uniform(0.5, 60.0)  # its check-point reached the shore
        stamp = float(int(acted + true_offset))  # whole seconds, vehicle clock
        others = [(float(int(t + true_offset)), t + rng.uniform(0.5, 60.0)) for t in (acted - 30, acted - 60)]
        shown = on_shore_clock(stamp, heard, offset([(stamp, heard), *others]))
        assert sent < shown <= heard
    assert on_shore_clock(50.0, 60.0, None) == 60.0  # no offset known: when the shore heard it
