"""The fleet on the screens (``server.screens.fleet``): one palette, and when a silent vehicle is overdue
for its place in the schedule (or, never heard, awaited until its first report is due)."""

from __future__ import annotations

import pytest

from server.screens import fleet


def test_each_vehicle_has_its_own_colour_from_the_one_palette() -> None:
    colours = [fleet.colour(i) for i in range(len(fleet.PALETTE))]
    assert len(set(colours)) == len(colours)
    assert fleet.colour(len(fleet.PALETTE)) == colours[0]
    assert fleet.rgb("#0072b2") == (0, 114, 178)


def test_a_vehicle_is_overdue_after_its_report_gap_and_three_of_its_slot_intervals() -> None:
    gap = fleet.report_gap([100.0, 120.0, 141.0, 160.0])
    assert gap == 20.0
    two_equal = [(1.0, 4.0), (1.0, 6.0)]  # shares and slot lengths
    assert fleet.slot_interval(1.0, two_equal) == pytest.approx(10.0)  # every other slot, 5 s each
    assert fleet.slot_interval(2.0, [(2.0, 5.0), (1.0, 5.0)]) == pytest.approx(7.5)  # a double share
    assert fleet.overdue_after(gap, 10.0) == pytest.approx(20.0 + fleet.OVERDUE_SLOTS * 10.0)
    assert fleet.overdue_after(20.0, None) == 20.0  # no slot planned yet
    assert fleet.slot_interval(1.0, []) is None
    assert fleet.report_gap([100.0]) is None  # fewer than two check-points: the report interval stands in


def test_a_silence_counts_from_the_last_frame_or_from_when_the_shore_could_first_hear() -> None:
    assert fleet.silence(990.0, listening=900.0, registered=800.0, now=1000.0) == 10.0
    assert fleet.silence(None, listening=900.0, registered=800.0, now=1000.0) == 100.0  # since it listens
    assert fleet.silence(None, listening=900.0, registered=950.0, now=1000.0) == 50.0  # since registered


def test_each_gateway_its_own_colour_for_any_number_of_gateways_grey_once_silent() -> None:
    colours = [fleet.gateway_colour(i, alive=True) for i in range(len(fleet.GATEWAYS))]
    assert len(set(colours)) == len(colours) and not set(colours) & set(fleet.PALETTE)  # not a vehicle's
    assert fleet.gateway_colour(len(fleet.GATEWAYS) + 1, alive=True) == colours[1]  # more gateways: again
    assert (
        fleet.gateway_colour(0, alive=False) == fleet.gateway_colour(3, alive=False) == fleet.GATEWAY_SILENT
    )
