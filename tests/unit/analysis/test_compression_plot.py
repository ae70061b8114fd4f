"""`tacit eval-compression --plot`: a title that names the file, the method, its cost and eps; each
channel's eps and unit; a legend in plain words."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from analysis.evaluate import Reconstruction, channel_unit, figure, plot_title
from tacit.codec import StreamSpec
from tacit.packets import Stream


def test_the_plot_says_what_it_shows() -> None:
    channels = ("RAW_IMU.xacc", "depth (m)", "oxygen")
    spec = StreamSpec("eval", Stream.KINEMATIC, channels, (12.0, 0.05, 0.2), 0.5, "kalman")
    times = np.arange(20) * 0.5
    truth = np.column_stack([np.sin(times), times / 10, np.ones(20)])
    rec = Reconstruction(times, truth, truth + 0.01, np.arange(60).reshape(20, 3) % 7 == 0)
    report = {"method": "kalman", "bits_per_sample": 1.8321, "max_error_ratio": 0.9994, "eps_relative": False}
    fig = figure(spec, rec, plot_title("data/small.tlog", report))
    try:
        assert fig.get_suptitle() == (
            "small.tlog: tacit (kalman), 1.832 bits per sample, largest error 0.999 x eps (eps in each "
            "channel's unit)"
        )
        axes = fig.axes[:3]
        assert [ax.get_title() for ax in axes] == [
            "RAW_IMU.xacc, eps 12 mG",
            "depth (m), eps 0.05 m",
            "oxygen, eps 0.2",
        ]
        assert [ax.get_ylabel() for ax in axes] == ["mG", "m", "channel units"]
        legend = [text.get_text() for text in axes[0].get_legend().get_texts()]
        assert legend == [
            "measured on the vehicle",
            "reconstructed on the shore",
            "error bound: reconstruction +- eps",
            "sent (the prediction missed by more than eps)",
        ]
        assert fig.get_supxlabel() == "time since the first sample (s)"
    finally:
        plt.close(fig)


def test_a_channels_unit_comes_from_its_header_or_its_mavlink_definition() -> None:
    assert channel_unit("temperature (degC)") == "degC"
    assert channel_unit("SCALED_PRESSURE2.press_abs") == "hPa"
    assert channel_unit("RAW_IMU.xgyro") == "mrad/s"
    assert channel_unit("NOT_A_MESSAGE.x") is None and channel_unit("salinity") is None
