"""The codec is never worse than send-on-delta on the same link (issue 22, item 9), and that baseline is
framed as the codec is: the same 32-byte frames, the same latency bound."""

from pathlib import Path

import numpy as np

from analysis.evaluate import PACKET_BITS, make_spec, run_codec, send_on_delta, sod_messages
from analysis.series import Series, load

GLIDER = Path(__file__).resolve().parents[3] / "bench" / "data" / "glider_amadeus_ctd_temperature.csv"


def one_channel(values: list[float], times: list[float] | None = None) -> Series:
    at = np.arange(len(values), dtype=np.float64) if times is None else np.array(times)
    return Series(("x",), at, np.array(values, dtype=np.float64)[:, None])


def test_send_on_delta_sends_what_moved_past_eps_and_flushes_at_the_latency_bound() -> None:
    series = one_channel([0.0, 0.5, 2.0, 2.5, 4.0, 10.0, 10.2])  # sent: 0, 2, 4, 10 (at t 0, 2, 4, 5)
    spec = make_spec(series, 1.0, False, "hold", 1.0)
    result = send_on_delta(series, spec, max_latency=3.0)
    # t 0 and 2 leave together at t 3 (the first waited 3 s); t 4 and 5 at t 7
    assert (result.packets, result.link_bits, result.max_latency_s) == (2, 2 * PACKET_BITS, 3.0)
    assert result.max_error_ratio <= 1.0  # the shore holds the last value sent


def test_send_on_delta_packs_seven_one_channel_messages_per_frame() -> None:
    series = one_channel([2.0 * i for i in range(20)])  # every sample moves: 20 messages of 4 bytes
    result = send_on_delta(series, make_spec(series, 1.0, False, "hold", 1.0), max_latency=100.0)
    assert result.packets == 3  # 7 + 7 + 6: a full packet leaves at once
    assert result.max_latency_s == 100.0  # the last, part-full, waits for its bound


def test_send_on_delta_messages_are_per_value_or_per_row_whichever_is_smaller() -> None:
    assert sod_messages(1, 1) == [4]  # a 2-byte time/channel word, a 2-byte value
    assert sod_messages(0, 9) == []
    assert sod_messages(2, 9) == [4, 4]
    assert sod_messages(3, 9) == [10]  # time word, a 2-byte mask of 9 channels, three values
    assert sod_messages(9, 9) == [22]


def test_codec_is_never_worse_than_send_on_delta_on_a_slow_jittered_profiling_sensor() -> None:
    # a glider's CTD temperature, ~0.5 Hz with jitter, down and up through the thermocline: 20 minutes
    full = load(GLIDER)
    series = Series(full.names, full.times[:600], full.values[:600])
    spec = make_spec(series, 0.05, False, "kalman", None)
    sod = send_on_delta(series, spec, max_latency=10.0)
    # the same guarantee as send-on-delta's: no packet leaves only to confirm a predictable sample
    codec, rec = run_codec(series, spec, max_latency=10.0, max_silence=None)
    assert codec.packets <= sod.packets + 1
    assert codec.link_bits <= sod.link_bits + PACKET_BITS
    assert codec.max_error_ratio <= 1.0 and codec.samples_not_represented == 0
    assert codec.max_latency_s <= 10.0
    # the predictor follows the drift (hold) rather than lagging it: no more surprises than send-on-delta
    # sends values (the Kalman filter alone sent 134 against 116)
    sent, last = 0, np.nan
    for x in series.values[:, 0]:
        if not abs(x - last) <= 0.05:
            sent, last = sent + 1, x
    assert int(rec.sent.sum()) <= sent


SMALL_TLOG = Path(__file__).resolve().parents[2] / "data" / "ardusub" / "small.tlog"


def test_a_whole_unit_sensor_that_barely_moves_costs_no_more_than_send_on_delta() -> None:
    # water temperature in whole centidegrees, 1245-1260 in 635 samples: send-on-delta sends 2-3 values
    series = load(SMALL_TLOG, ["SCALED_PRESSURE2.temperature"])
    for eps in (10.0, 5.0):
        spec = make_spec(series, eps, False, "kalman", None)
        for latency in (10.0, 60.0):
            codec, _ = run_codec(series, spec, latency, max_silence=None)
            assert codec.packets <= send_on_delta(series, spec, latency).packets + 1, (eps, latency)
            assert codec.max_error_ratio <= 1.0 and codec.max_latency_s <= latency


def test_a_channels_first_value_is_coded_within_a_sixteenth_of_eps() -> None:
    series = one_channel([1245.0, 1245.0, 1250.0, 1245.0])
    _, rec = run_codec(series, make_spec(series, 10.0, False, "kalman", 1.0), 10.0, max_silence=None)
    assert abs(rec.shore[0, 0] - 1245.0) <= 10.0 / 16
    assert not rec.sent[1:].any()  # 1250 is within eps of the first value: no surprise


def test_a_sample_taken_at_the_deadline_rides_in_the_packet_that_leaves_then() -> None:
    # a sample every 15 min, latency 1 h: send-on-delta's packet holds the values of t 0 and 3600 (its
    # oldest has waited exactly the bound); the codec's, sent at the same instant, holds the same samples
    series = one_channel([10.0, 10.0, 10.0, 10.0, 20.0], [0.0, 900.0, 1800.0, 2700.0, 3600.0])
    spec = make_spec(series, 1.0, False, "kalman", 900.0)
    assert send_on_delta(series, spec, 3600.0).packets == 1
    codec, _ = run_codec(series, spec, 3600.0, max_silence=None)
    assert codec.packets == 1 and codec.max_latency_s <= 3600.0
