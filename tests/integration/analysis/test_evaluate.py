"""`tacit eval-compression` on the real ArduSub logs: the issue's bar, and the report's shape."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

KEYS = {
    "samples",
    "packets",
    "link_bits",
    "bits_per_sample",
    "max_error_ratio",
    "rms_error_ratio",
    "max_latency_s",
}


def evaluate(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "tacit.cli", "eval-compression", *args],
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.mark.parametrize("log", ["small.tlog", "2023-04-18_11-03-34.tlog"])
def test_raw_imu_fits_rate_zero_within_the_bound(real_data: Path, log: str) -> None:
    result = evaluate(
        str(real_data / "ardusub" / log), "--eps", "0.5", "--relative", "--max-latency", "10", "--json"
    )
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert KEYS <= set(report) and set(report["baselines"]) == {"send-all", "send-on-delta"}
    assert all(KEYS <= set(b) for b in report["baselines"].values())
    assert (
        report["samples"] == len(report["channels"]) * (report["samples"] // 9)
        and len(report["channels"]) == 9
    )
    assert report["link_bits"] == report["packets"] * 256
    assert report["bits_per_sample"] <= 2.86  # the rate-0 budget for the paper's IMU stream
    assert report["max_error_ratio"] <= 1.0
    assert report["max_latency_s"] <= 10.0 + 1e-9
    assert report["bits_per_sample"] < report["baselines"]["send-all"]["bits_per_sample"] / 5


def test_csv_with_loss_marks_samples_and_writes_a_plot(real_data: Path, tmp_path: Path) -> None:
    """Version 3 declares a lost packet's samples lost; version 4 codes them again: none is lost."""
    png = tmp_path / "plot.png"
    result = evaluate(
        str(real_data / "ardusub" / "small_raw_imu.csv"),
        "--columns",
        "xacc,ymag,zmag",
        "--eps",
        "0.5",
        "--relative",
        "--loss",
        "0.3",
        "--plot",
        str(png),
        "--json",
        "--protocol",
        "3",
    )
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["unbounded_samples"] > 0 and report["max_error_ratio"] <= 1.0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    args = [str(real_data / "ardusub" / "small_raw_imu.csv"), "--columns", "xacc", "--eps", "0.5"]
    four = json.loads(evaluate(*args, "--relative", "--loss", "0.3", "--json", "--protocol", "4").stdout)
    assert four["unbounded_samples"] == 0 and four["max_error_ratio"] <= 1.0


def test_human_table_and_clear_errors(real_data: Path, tmp_path: Path) -> None:
    result = evaluate(
        str(real_data / "ardusub" / "small_bar30.csv"), "--columns", "temperature_cdegC", "--eps", "5"
    )
    assert result.returncode == 0 and "send-on-delta" in result.stdout and "tacit (kalman)" in result.stdout
    bad = evaluate(str(real_data / "ardusub" / "small_bar30.csv"), "--columns", "nope", "--eps", "1")
    assert bad.returncode == 2 and "no column(s) ['nope']" in bad.stderr
    missing = evaluate(str(tmp_path / "none.csv"), "--eps", "1")
    assert missing.returncode == 2 and "none.csv" in missing.stderr


def test_files_as_owners_publish_them(tmp_path: Path) -> None:
    """ISO-8601 with a zone, blank / NaN / missing cells, a text column, per-channel eps by name."""
    lines = ["datetime,site,temp_c,cond"]
    for i in range(300):
        hour, minute = divmod(i * 5, 60)
        temp = "" if 100 <= i < 130 else ("missing" if i % 37 == 0 else f"{10 + 0.01 * i:.2f}")
        lines.append(
            f"2021-06-{1 + hour // 24:02d}T{hour % 24:02d}:{minute:02d}:00-06:00,A{i % 3},{temp},"
            f"{'NaN' if i % 50 == 0 else 300 + i % 7}"
        )
    path = tmp_path / "stream.csv"
    path.write_text("\n".join(lines) + "\n")
    result = evaluate(str(path), "--eps", "temp_c=0.1,cond=1", "--max-latency", "3600", "--json")
    assert result.returncode == 0, result.stderr
    assert "ISO-8601 with zone" in result.stderr and "skipped text column 'site', row 2" in result.stderr
    report = json.loads(result.stdout)
    assert report["channels"] == ["temp_c", "cond"] and report["eps"] == [0.1, 1.0]
    blank = sum(1 for i in range(300) if 100 <= i < 130 or i % 37 == 0) + sum(
        1 for i in range(300) if i % 50 == 0
    )
    assert report["samples_absent"] == blank and report["samples_not_represented"] == 0
    assert report["time_precision_s"] == 150.0 and report["max_error_ratio"] <= 1.0
    refused = evaluate(str(path), "--columns", "site,temp_c", "--eps", "0.1")
    assert refused.returncode == 2 and "column 'site', row 2" in refused.stderr


def test_epoch_milliseconds_are_detected(tmp_path: Path) -> None:
    path = tmp_path / "ms.csv"
    path.write_text("timestamp,x\n" + "".join(f"{1_600_000_000_000 + 500 * i},{i % 5}\n" for i in range(100)))
    result = evaluate(str(path), "--eps", "0.5", "--json")
    assert result.returncode == 0, result.stderr
    assert "UNIX time in ms" in result.stderr and json.loads(result.stdout)["period_s"] == 0.5


def test_a_logs_other_clocks_are_not_compressed_as_data(real_data: Path) -> None:
    """The extracts carry t_unix_s and the autopilot's own clock (time_usec): only the IMU is data."""
    result = evaluate(
        str(real_data / "ardusub" / "small_raw_imu.csv"), "--eps", "0.5", "--relative", "--json"
    )
    assert result.returncode == 0, result.stderr
    assert "skipped column 'time_usec': another clock" in result.stderr
    assert "time_usec" not in json.loads(result.stdout)["channels"]
    named = evaluate(
        str(real_data / "ardusub" / "small_raw_imu.csv"),
        "--columns",
        "time_usec,xacc",
        "--eps",
        "0.5",
        "--relative",
        "--json",
    )
    assert named.returncode == 0 and json.loads(named.stdout)["channels"] == ["time_usec", "xacc"]


def test_clock_columns_are_told_by_their_words(tmp_path: Path) -> None:
    from analysis.series import load

    path = tmp_path / "log.csv"
    path.write_text(
        "SampleTime,time_boot_ms,runtime_h,update_count,x\n"
        + "".join(f"{1_600_000_000 + i},{1000 * i},{i / 3600},{i},{i % 5}\n" for i in range(20))
    )
    series = load(path)
    assert series.names == (
        "runtime_h",
        "update_count",
        "x",
    )  # measurements, though "time" and "date" are in them
    assert any("time_boot_ms" in note for note in series.notes) and series.times[1] - series.times[0] == 1.0


def test_a_glider_log_as_it_writes_it(tmp_path: Path) -> None:
    """A SeaExplorer's log: semicolons (a trailing one too), day-first slashed times, blank cells; with a
    time tolerance every sample is dated within it."""
    lines = ["Timestamp;NavState;Depth;Pitch;"]
    for i in range(200):
        second = i * 10 + (3 if i % 3 == 0 else 0)  # a clock that wanders about its 10 s
        minute, second = divmod(second, 60)
        pitch = "" if i % 40 == 7 else f"{-20 + (i % 9) * 0.5:.2f}"
        lines.append(
            f"13/09/2020 {17 + minute // 60:02d}:{minute % 60:02d}:{second:02d};117;{i * 0.4:.1f};{pitch};"
        )
    path = tmp_path / "sea046.gli.sub.csv"
    path.write_text("\n".join(lines) + "\n")
    result = evaluate(str(path), "--eps", "0.2", "--time-tolerance", "7.5", "--max-latency", "600", "--json")
    assert result.returncode == 0, result.stderr
    assert "dd/mm/yyyy HH:MM:SS, no zone given: read as UTC" in result.stderr
    report = json.loads(result.stdout)
    assert report["channels"] == ["NavState", "Depth", "Pitch"] and report["protocol"] == 4
    assert report["samples_absent"] == 5 and report["samples_not_represented"] == 0
    assert report["time_precision_s"] == 7.5 and report["max_time_error_s"] <= 7.5
    assert report["max_error_ratio"] <= 1.0


def test_a_ship_logger_splits_date_and_time_of_day(tmp_path: Path) -> None:
    """A thermosalinograph's file: the date in one column (year first, with slashes), the time of day in
    another, a reading every 5 s."""
    lines = ["Date,Time,TSG_temp,TSG_sal"]
    for i in range(120):
        minute, second = divmod(i * 5, 60)
        lines.append(f"2019/07/21,12:{minute:02d}:{second:02d},{14 + 0.003 * i:.3f},{32 + 0.001 * i:.3f}")
    path = tmp_path / "tsg.csv"
    path.write_text("\n".join(lines) + "\n")
    result = evaluate(str(path), "--eps", "0.01", "--json")
    assert result.returncode == 0, result.stderr
    assert "the date in column 'Date', the time of day in column 'Time'" in result.stderr
    report = json.loads(result.stdout)
    assert report["channels"] == ["TSG_temp", "TSG_sal"] and report["period_s"] == 5.0
    assert report["max_time_error_s"] <= 2.5 and report["max_error_ratio"] <= 1.0
