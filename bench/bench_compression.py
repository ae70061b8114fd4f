"""Compression on every real log in ../shared/data/ardusub: bits per sample on the link, error, latency.

IMU (RAW_IMU's nine channels, or the dataflash IMU's six) at 0.25 and 0.5 standard deviation per
channel; water temperature (Bar30, SCALED_PRESSURE2) at 0.05 and 0.1 degC. Unpredictable samples leave within 10 s; predictable ones are confirmed within 60 s.
Also the vehicle side's CPU cost per tick.

Run: .venv/bin/python bench/bench_compression.py [--data DIR] [--method kalman] [--json]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from tqdm import tqdm

from analysis.evaluate import evaluate

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "ardusub"
IMU = "xacc,yacc,zacc,xgyro,ygyro,zgyro,xmag,ymag,zmag"
TLOG_IMU = ",".join(f"RAW_IMU.{c}" for c in IMU.split(","))
CASES = [
    # file, columns, eps, relative, label
    ("small.tlog", TLOG_IMU, 0.25, True, "RAW_IMU 0.25 sd"),
    ("small.tlog", TLOG_IMU, 0.5, True, "RAW_IMU 0.5 sd"),
    ("2023-04-18_11-03-34.tlog", TLOG_IMU, 0.25, True, "RAW_IMU 0.25 sd"),
    ("2023-04-18_11-03-34.tlog", TLOG_IMU, 0.5, True, "RAW_IMU 0.5 sd"),
    ("small_raw_imu.csv", IMU, 0.5, True, "RAW_IMU 0.5 sd"),
    ("2023-04-18_11-03-34_raw_imu.csv", IMU, 0.5, True, "RAW_IMU 0.5 sd"),
    ("small_BIN_imu0.csv", "GyrX,GyrY,GyrZ,AccX,AccY,AccZ", 0.25, True, "IMU0 25 Hz 0.25 sd"),
    ("small_BIN_imu0.csv", "GyrX,GyrY,GyrZ,AccX,AccY,AccZ", 0.5, True, "IMU0 25 Hz 0.5 sd"),
    ("small.tlog", "SCALED_PRESSURE2.temperature", 5.0, False, "water temp 0.05 degC"),
    ("small.tlog", "SCALED_PRESSURE2.temperature", 10.0, False, "water temp 0.1 degC"),
    ("2023-04-18_11-03-34.tlog", "SCALED_PRESSURE2.temperature", 5.0, False, "water temp 0.05 degC"),
    ("2023-04-18_11-03-34.tlog", "SCALED_PRESSURE2.temperature", 10.0, False, "water temp 0.1 degC"),
]


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", type=Path, default=DATA, help="folder of the logs")
    parser.add_argument("--method", default="kalman", help="predictor (kalman, kalman-cv, mean, hold)")
    parser.add_argument("--json", action="store_true", help="one JSON object per case")
    options = parser.parse_args()
    rows = []
    for name, columns, eps, relative, label in tqdm(CASES, desc="logs", unit="case"):
        dataflash = name.endswith("BIN_imu0.csv")
        args = argparse.Namespace(file=str(options.data / name), columns=columns, period=None, eps=eps,
                                  time_column="TimeUS" if dataflash else None, time_unit="us" if dataflash else "s",
                                  relative=relative, max_latency=10.0, max_silence=60.0, method=options.method,
                                  loss=0.0, seed=1, urgent_threshold=None)  # fmt: skip
        report, *_ = evaluate(args)
        rows.append((name, label, report))
    if options.json:
        for name, label, report in rows:
            print(json.dumps({"file": name, "case": label, **report}))
        return
    head = f"{'file':<32} {'case':<22} {'samples':>8} {'packets':>8} {'bits/sample':>12} {'send-on-delta':>14} {'max err/eps':>12} {'max lat s':>10} {'confirm s':>10} {'us/tick':>8}"
    print(head)
    print("-" * len(head))
    for name, label, r in rows:
        sod = r["baselines"]["send-on-delta"]["bits_per_sample"]
        print(f"{name:<32} {label:<22} {r['samples']:>8} {r['packets']:>8} {r['bits_per_sample']:>12.3f} "
              f"{sod:>14.3f} {r['max_error_ratio']:>12.3f} {r['max_latency_s']:>10.1f} {r['max_confirmation_s']:>10.1f} {r['us_per_tick']:>8.0f}")  # fmt: skip


if __name__ == "__main__":
    main()
