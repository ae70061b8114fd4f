"""Compression on every real log in tests/data/ardusub: bits per sample on the link, error, latency.

IMU (RAW_IMU's nine channels, or the dataflash IMU's six) at 0.25 and 0.5 standard deviation per
channel; water temperature (Bar30, SCALED_PRESSURE2) at 0.05 and 0.1 degC. Unpredictable samples leave within 10 s; predictable ones are confirmed within 60 s.
Also the vehicle side's CPU cost per tick.

Run: .venv/bin/python bench/bench_compression.py [--data DIR] [--method kalman] [--json]

``--sweep``: every series at latency bounds of 10 s, 60 s, 600 s, 1 h and 1 day, the codec beside
send-on-delta framed on the same link (``analysis.evaluate.send_on_delta``) at the same eps and latency
and the same guarantee (the codec with no silence bound: nothing confirms a quiet value), a check that the
codec costs at most one packet more, and what confirming predictable samples within max(60 s, latency)
adds. It fails (exit status 1) if it did not measure what it claims: a sample off by more than eps or not
held on the shore, a latency over its bound, or link bits that are not whole packets.

``--peers``: the goals' table on the public series (``bench/data``) and the ArduSub logs. Per series: the
codec's own bits (the arithmetic code alone, no latency bound, no framing; payload version 3, version 4,
and version 4 with a time tolerance of 0.75 period) beside SZ3 (``pysz``, the
error-bounded compressor of the scientific-data community; a benchmark dependency) at the same absolute
bound, each channel compressed separately with the sample times given free, over the whole series and
one latency window at a time, its decompressed error verified; and on the link at the agent's defaults
(latency 10 s, check-points every 60 s) the codec's packets beside send-on-delta's in the same frames:
version 4's, whose check-points say the silence (no packet leaves only to confirm a quiet stream), with
the longest any sample waited to be vouched for (by its packet or a check-point), and version 3's, whose
silence bound (60 s) sends packets for it. It fails if a decompressed value is off by more than eps, a
sample waited longer than the check-point interval plus the latency bound to be vouched for, or a run did
not measure what it claims.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from analysis.evaluate import (
    PACKET_BITS,
    Result,
    add_protocol_option,
    evaluate,
    make_spec,
    run_codec,
    send_on_delta,
)
from analysis.series import Series, load
from tacit.codec import StreamDecoder, StreamEncoder

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "ardusub"
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


PUBLIC = Path(__file__).resolve().parent / "data"
CREEK = "stream_h67014001_water_temp_f_15min.csv.gz"
PUBLIC_CASES = [
    # file, columns (None: every numeric one), time column (None: detected), eps, relative, max latency (in
    # the time column's unit), label: slow sensors get a latency that lets a packet fill
    ("glider_amadeus_ctd_temperature.csv", None, None, 0.05, False, 600.0, "glider CTD temp 0.05 degC (600 s)"),
    ("glider_sea035_oxygen.csv", None, None, 1.0, False, 600.0, "glider O2 30 s 1 umol/L (600 s)"),
    ("glider_sea035_oxygen.csv", None, None, 1.0, False, 3600.0, "glider O2 30 s 1 umol/L (3600 s)"),
    # the x-IMU's only clock is its packet counter: latency 10 s = 3900 packets
    ("handheld_ximu_256hz_imu.csv", None, "Packet number", 0.5, True, 3900.0, "x-IMU 256 Hz 0.5 sd (10 s)"),
    # 5 years at 15 min with months-long outages; 0.18 degF = 0.1 degC; a packet a day, or every 3 days
    (CREEK, ["Value"], None, 0.18, False, 86400.0, "creek water temp 15 min 0.1 degC (1 day)"),
    (CREEK, ["Value"], None, 0.18, False, 259200.0, "creek water temp 15 min 0.1 degC (3 days)"),
]  # fmt: skip


SWEEP_LATENCIES = [(10.0, "10 s"), (60.0, "60 s"), (600.0, "600 s"), (3600.0, "1 h"), (86400.0, "1 day")]
COUNTS_PER_SECOND = {"handheld_ximu_256hz_imu.csv": 390.0}  # a counter's clock: latencies in its unit


def sweep_cases(data: Path) -> list[tuple[str, Series, float, bool, float]]:
    """Every series of the tables once per eps: (label, series, eps, relative, time units per second)."""
    cases = []
    for name, columns, eps, relative, label in CASES:
        dataflash = name.endswith("BIN_imu0.csv")
        series = load(
            data / name,
            columns.split(","),
            "TimeUS" if dataflash else None,
            None,
            "us" if dataflash else None,
        )
        cases.append((f"{name} {label}", series, eps, relative, 1.0))
    seen = set()
    for name, listed, time_column, eps, relative, _, label in PUBLIC_CASES:
        if (name, eps) not in seen:  # a series at another latency is the same series
            seen.add((name, eps))
            series = load(PUBLIC / name, listed, time_column)
            cases.append((label.rsplit(" (", 1)[0], series, eps, relative, COUNTS_PER_SECOND.get(name, 1.0)))
    return cases


def measured(results: dict[str, Result], latency: float) -> list[str]:
    """What the sweep claims of each run but did not measure: each a sentence (none: all held)."""
    wrong = []
    samples = {r.samples for r in results.values()}
    for name, r in results.items():
        if r.max_error_ratio > 1 + 1e-9:
            wrong.append(f"{name}: a sample {r.max_error_ratio:.3f} eps off")
        if r.max_latency_s > latency * (1 + 1e-9):
            wrong.append(f"{name}: a sample waited {r.max_latency_s:.4g} > {latency:.4g}")
        if r.link_bits != r.packets * PACKET_BITS or len(samples) != 1 or r.samples_not_represented:
            wrong.append(f"{name}: packets, bits or samples not all counted")
    return wrong


def sweep_table(data: Path, method: str, protocol: int) -> bool:
    """The latency sweep; False if a measurement did not hold what it claims."""
    print("\ncodec vs send-on-delta framed on the same link, same eps, latency and guarantee:")
    head = (
        f"{'series':<46} {'latency':>7} {'samples':>8} {'codec pkt':>9} {'codec b/s':>9} {'SoD pkt':>8} "
        f"{'SoD b/s':>8} {'codec <= SoD + 1 pkt':>20} {'+ confirm b/s':>13}"
    )
    print(head)
    print("-" * len(head))
    faults = []
    for label, series, eps, relative, unit in tqdm(
        sweep_cases(data), desc="sweep", unit="series", leave=False
    ):
        spec = make_spec(series, eps, relative, method, None)
        for seconds, name in SWEEP_LATENCIES:
            latency = seconds * unit
            codec, _ = run_codec(series, spec, latency, max_silence=None, protocol=protocol)
            confirmed, _ = run_codec(
                series, spec, latency, max_silence=max(60.0 * unit, latency), protocol=protocol
            )
            sod = send_on_delta(series, spec, latency)
            runs = {"codec": codec, "codec confirming": confirmed, "send-on-delta": sod}
            faults += [f"{label} at {name}: {w}" for w in measured(runs, latency)]
            check = "ok" if codec.packets <= sod.packets + 1 else f"WORSE by {codec.packets - sod.packets}"
            print(
                f"{label:<46} {name:>7} {codec.samples:>8} {codec.packets:>9} {codec.bits_per_sample:>9.3f} "
                f"{sod.packets:>8} {sod.bits_per_sample:>8.3f} {check:>20} {confirmed.bits_per_sample:>13.3f}"
            )
    for fault in faults:
        print(f"NOT MEASURED AS CLAIMED: {fault}", file=sys.stderr)
    return not faults


# file (bench/data, or the ArduSub logs' folder for a .tlog), columns (None: every numeric one), time
# column (None: detected), eps (absolute, per channel as --eps takes it; "sd:x": x standard deviations),
# time units per second, label
PEER_CASES = [
    ("glider_amadeus_ctd.csv", None, None, "sci_water_temp=0.01,sci_water_cond=0.001,sci_water_pressure=0.01",
     1.0, "Slocum CTD T,C,P 2 s"),
    ("glider_amadeus_ctd_temperature.csv", None, None, "0.05", 1.0, "Slocum CTD temperature 2 s"),
    ("glider_amadeus_attitude.csv", None, None, "0.005,m_depth=0.1", 1.0, "Slocum attitude, depth 5 s"),
    ("glider_sea046_gpctd.csv.gz", ["GPCTD_CONDUCTIVITY", "GPCTD_TEMPERATURE", "GPCTD_PRESSURE"], None,
     "GPCTD_CONDUCTIVITY=0.001,GPCTD_TEMPERATURE=0.01,GPCTD_PRESSURE=0.1", 1.0, "SeaExplorer CTD C,T,P 1 s"),
    ("glider_sea046_nav.csv", ["Heading", "Pitch", "Roll", "Depth"], None, "0.2,Depth=0.1", 1.0,
     "SeaExplorer attitude, depth 10 s"),
    ("glider_sea035_oxygen.csv", None, None, "1.0", 1.0, "SeaExplorer oxygen 30 s"),
    ("glider_comet_density.csv.gz", None, None, "sci_water_pressure=0.01,density=0.01,pitch=0.005", 1.0,
     "Slocum density, pressure, pitch 1 s"),
    ("handheld_ximu_256hz_imu.csv", None, "Packet number", "sd:0.5", 390.0, "x-IMU 256 Hz"),
    ("small.tlog", IMU.split(","), None, "sd:0.5", 1.0, "ArduSub RAW_IMU 4 Hz"),
    ("small.tlog", ["SCALED_PRESSURE2.temperature"], None, "5.0", 1.0, "ArduSub water temperature"),
]  # fmt: skip
AGENT_LATENCY, AGENT_SILENCE = 10.0, 60.0  # vehicle_agent's defaults
TOLERANCE = 0.75  # the "v4 tol" column: payload version 4 with a time tolerance of 0.75 period


def sz3_bits(series: Series, eps: tuple[float, ...], window: float | None = None) -> tuple[int, float]:
    """SZ3's compressed bits for every channel of ``series`` (its present values, compressed separately,
    at absolute bound eps; times free), the whole series at once or ``window`` seconds at a time; and the
    largest decompressed error over eps (verified here, not taken from SZ3)."""
    import pysz  # a benchmark dependency only

    bits, worst = 0, 0.0
    starts = [0] if window is None else _window_starts(series.times, window)
    for c, bound in enumerate(eps):
        config = pysz.szConfig()
        config.errorBoundMode = pysz.szErrorBoundMode.ABS
        config.absErrorBound = bound
        for lo, hi in zip(starts, [*starts[1:], len(series.times)], strict=True):
            values = series.values[lo:hi, c]
            values = np.ascontiguousarray(values[~np.isnan(values)])
            if not len(values):
                continue
            compressed, _ = pysz.sz.compress(values, config)
            restored, _ = pysz.sz.decompress(compressed, np.float64, values.shape)
            bits += 8 * len(compressed)
            worst = max(worst, float(np.abs(restored - values).max()) / bound)
    return bits, worst


def _window_starts(times: np.ndarray, window: float) -> list[int]:
    """Where each latency window begins: a window holds the samples within ``window`` of its first."""
    starts, i = [], 0
    while i < len(times):
        starts.append(i)
        i = int(np.searchsorted(times, times[i] + window, side="right"))
    return starts


def peer_series(data: Path, name: str, columns: list[str] | None, time_column: str | None) -> Series:
    if name.endswith(".tlog") and columns is not None:
        return load(data / name, columns if "." in columns[0] else [f"RAW_IMU.{c}" for c in columns])
    return load(PUBLIC / name, columns, time_column)


def peers_table(data: Path, method: str) -> bool:
    """The goals' table; False if something was not measured as claimed."""
    head = (
        f"{'series':<34} {'samples':>7} {'v3 own':>7} {'v4 own':>7} {'v4 tol':>6} {'SZ3 whole':>9} "
        f"{'SZ3 window':>10} {'v4/SZ3':>6} {'codec pkt':>9} {'vouched s':>9} {'v3 pkt':>6} {'SoD pkt':>7} "
        f"{'codec b/s':>9} {'SoD b/s':>7}"
    )
    print(
        f"bits per sample; link at the agent's defaults (latency {AGENT_LATENCY:g} s, check-points every "
        f"{AGENT_SILENCE:g} s: version 4's say the silence, version 3's silence bound is {AGENT_SILENCE:g} s)"
    )
    print(head)
    print("-" * len(head))
    faults, ratios, packets = [], [], []
    for name, columns, time_column, eps, unit, label in tqdm(
        PEER_CASES, desc="peers", unit="series", leave=False
    ):
        series = peer_series(data, name, columns, time_column)
        relative = eps.startswith("sd:")
        spec = make_spec(series, eps.removeprefix("sd:"), relative, method, None)
        latency, silence = AGENT_LATENCY * unit, AGENT_SILENCE * unit
        unbound = float(series.times[-1] - series.times[0]) + 1.0  # no latency bound: packets leave full
        own_v3, _ = run_codec(series, spec, unbound, max_silence=None, protocol=3)
        own, _ = run_codec(series, spec, unbound, max_silence=None, protocol=4)
        tolerant = dataclasses.replace(spec, time_tolerance=TOLERANCE * spec.period)
        own_tol, _ = run_codec(series, tolerant, unbound, max_silence=None, protocol=4)
        link, _ = run_codec(series, spec, latency, max_silence=None, protocol=4, checkpoints=silence)
        v3, _ = run_codec(series, spec, latency, max_silence=silence, protocol=3)
        sod = send_on_delta(series, spec, latency)
        whole, whole_err = sz3_bits(series, spec.eps)
        windowed, window_err = sz3_bits(series, spec.eps, latency)
        faults += [f"{label}: {w}" for w in measured({"link": link, "v3": v3, "sod": sod}, silence)]
        faults += [
            f"{label}: {w}" for w in measured({"v3 own": own_v3, "v4 own": own, "tol": own_tol}, unbound)
        ]
        if link.max_confirmation_s > silence + latency:
            faults.append(f"{label}: a sample waited {link.max_confirmation_s:.4g} to be vouched for")
        faults += [f"{label}: SZ3 off by {e:.3f} eps" for e in (whole_err, window_err) if e > 1 + 1e-9]
        n = own.samples
        ratios.append(own.code_bits_per_sample / (whole / n))
        packets.append(link.packets - sod.packets)
        print(
            f"{label:<34} {n:>7} {own_v3.code_bits_per_sample:>7.3f} {own.code_bits_per_sample:>7.3f} "
            f"{own_tol.code_bits_per_sample:>6.3f} {whole / n:>9.3f} {windowed / n:>10.3f} {ratios[-1]:>6.2f} "
            f"{link.packets:>9} {link.max_confirmation_s / unit:>9.1f} {v3.packets:>6} {sod.packets:>7} "
            f"{link.bits_per_sample:>9.3f} {sod.bits_per_sample:>7.3f}"
        )
    print(
        f"v4 own at or below SZ3 whole on {sum(r <= 1 for r in ratios)} of {len(ratios)} series, within 1.1x on "
        f"{sum(r <= 1.1 for r in ratios)}; on the link no more packets than send-on-delta (within one) on "
        f"{sum(d <= 1 for d in packets)} of {len(packets)} series"
    )
    for fault in faults:
        print(f"NOT MEASURED AS CLAIMED: {fault}", file=sys.stderr)
    return not faults


def degraded(series: Series, seed: int = 2) -> Series:
    """5 % of samples removed at random and +-30 % of a period of timing jitter."""
    rng = np.random.default_rng(seed)
    keep = rng.random(len(series.times)) > 0.05
    times = series.times + rng.uniform(-0.3, 0.3, len(series.times)) * series.period
    order = np.argsort(times[keep], kind="stable")
    return Series(series.names, times[keep][order], series.values[keep][order])


def decode_rate(series: Series, spec, max_latency: float, protocol: int) -> float:
    """Packets per second the pure-Python shore decoder handles."""
    encoder, payloads = StreamEncoder(spec, max_latency, protocol=protocol), []
    for t, x in zip(series.times, series.values, strict=True):
        encoder.push(t, x)
        while encoder.ready(t):
            packet = encoder.take().packet
            payloads.append((packet.payload, t, packet.seq))
            encoder.resolve(True)
    decoder = StreamDecoder(spec, protocol)
    start = time.perf_counter()
    for payload, at, seq in payloads:
        decoder.decode(payload, at, seq)
    return len(payloads) / max(1e-9, time.perf_counter() - start)


def robustness_table(data: Path, protocol: int) -> None:
    print("\nclean vs 5 % removed and +-30 % jitter (RAW_IMU 0.5 sd, latency 10 s), and public data:")
    head = (
        f"{'case':<46} {'bits/sample':>11} {'code only':>9} {'send-on-delta':>13} {'ideal':>6} {'x ideal':>7} "
        f"{'max err/eps':>11} {'absent':>6} {'not repr':>8} {'time prec s':>11} {'pkt/s decoded':>13}"
    )
    print(head)
    print("-" * len(head))
    cases = []
    for name in ("small.tlog", "2023-04-18_11-03-34.tlog"):
        series = load(data / name)
        cases += [
            (f"{name} clean", series, 0.5, True, 10.0),
            (f"{name} 5% gone +-30% jitter", degraded(series), 0.5, True, 10.0),
        ]
    for name, columns, time_column, eps, relative, latency, label in PUBLIC_CASES:
        cases.append((label, load(PUBLIC / name, columns, time_column), eps, relative, latency))
    clean_spec = None
    for label, series, eps, relative, latency in cases:
        spec = make_spec(series, eps, relative, "kalman", None)
        if "jitter" in label and clean_spec is not None:
            spec = clean_spec  # the same stream definition as the clean run
        clean_spec = spec
        result, _ = run_codec(series, spec, latency, max_silence=max(60.0, latency), protocol=protocol)
        sod = send_on_delta(series, spec, latency).bits_per_sample
        ideal = result.ideal_bits_per_sample
        print(
            f"{label:<46} {result.bits_per_sample:>11.3f} {result.code_bits_per_sample:>9.3f} {sod:>13.3f} {ideal:>6.3f} "
            f"{result.bits_per_sample / max(ideal, 1e-9):>7.2f} {result.max_error_ratio:>11.3f} "
            f"{result.samples_absent:>6} {result.samples_not_represented:>8} {result.time_precision_s:>11.3f} "
            f"{decode_rate(series, spec, latency, protocol):>13.0f}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", type=Path, default=DATA, help="folder of the logs")
    parser.add_argument("--method", default="kalman", help="predictor (kalman, kalman-cv, mean, hold)")
    parser.add_argument("--json", action="store_true", help="one JSON object per case")
    add_protocol_option(parser)
    parser.add_argument("--only-robustness", action="store_true", help="only the clean/degraded/public table")
    parser.add_argument("--sweep", action="store_true", help="only the latency sweep against send-on-delta")
    parser.add_argument(
        "--peers", action="store_true", help="only the goals' table: the codec, SZ3, send-on-delta"
    )
    options = parser.parse_args()
    if options.peers:
        sys.exit(0 if peers_table(options.data, options.method) else 1)
    if options.sweep:
        sys.exit(0 if sweep_table(options.data, options.method, options.protocol) else 1)
    if options.only_robustness:
        robustness_table(options.data, options.protocol)
        return
    rows = []
    for name, columns, eps, relative, label in tqdm(CASES, desc="logs", unit="case"):
        dataflash = name.endswith("BIN_imu0.csv")
        args = argparse.Namespace(
            file=str(options.data / name),
            columns=columns,
            period=None,
            eps=eps,
            time_column="TimeUS" if dataflash else None,
            time_unit="us" if dataflash else "s",
            relative=relative,
            max_latency=10.0,
            max_silence=60.0,
            method=options.method,
            protocol=options.protocol,
            loss=0.0,
            seed=1,
            urgent_threshold=None,
            progress=False,
        )
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
        print(
            f"{name:<32} {label:<22} {r['samples']:>8} {r['packets']:>8} {r['bits_per_sample']:>12.3f} "
            f"{sod:>14.3f} {r['max_error_ratio']:>12.3f} {r['max_latency_s']:>10.1f} {r['max_confirmation_s']:>10.1f} {r['us_per_tick']:>8.0f}"
        )
    robustness_table(options.data, options.protocol)


if __name__ == "__main__":
    main()
