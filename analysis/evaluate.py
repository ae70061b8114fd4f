"""``tacit eval-compression``: run the vehicle's compressor on a file, decode as the shore does, measure.

The run is event-ordered like the real link: a packet leaves when it is full, when a sample is
urgent, or when the oldest pending sample reaches ``--max-latency`` (at that exact time); the shore
decodes each delivered packet when it leaves. ``--loss`` drops packets (seeded) to show that the shore
marks what it lost and never shows it as certain. Link bits count whole 32-byte packets (256 bits),
header included. Baselines, side by side: send-all (every sample as 16 bits, 14 per packet) and
send-on-delta (a sample when it moves more than eps from the last one sent, 4 bytes each: a 2-byte
time/channel word and a 2-byte value, 7 per packet).
"""

from __future__ import annotations

import argparse
import json
import math
import random
import sys
import time
from dataclasses import asdict, dataclass

import numpy as np

from analysis.series import Series, load
from tacit.codec import StreamDecoder, StreamEncoder, StreamSpec
from tacit.packets import PACKET_SIZE, Stream
from tacit.predict import METHODS

PACKET_BITS = PACKET_SIZE * 8


@dataclass
class Result:
    samples: int
    packets: int
    link_bits: int
    bits_per_sample: float
    max_error_ratio: float
    rms_error_ratio: float
    max_latency_s: float  # unpredictable samples (q != 0): sent within --max-latency
    max_confirmation_s: float = 0.0  # any sample: confirmed within --max-silence
    unbounded_samples: int = 0
    us_per_tick: float | None = None


@dataclass
class Reconstruction:
    """What the shore holds per tick (None: lost, unbounded), and which samples were sent (q != 0)."""

    ticks: list[int]
    truth: np.ndarray
    shore: np.ndarray  # NaN where unbounded
    sent: np.ndarray  # bool, ticks x channels


def first_per_tick(series: Series, spec: StreamSpec) -> tuple[list[int], np.ndarray, np.ndarray]:
    """The samples the encoder accepts: the first of each tick (later duplicates are dropped)."""
    ticks, times, rows, seen = [], [], [], set()
    for t, x in zip(series.times, series.values, strict=True):
        k = spec.tick(t)
        if k not in seen and (not ticks or k > ticks[-1]):
            seen.add(k)
            ticks.append(k)
            times.append(t)
            rows.append(x)
    return ticks, np.array(times), np.array(rows)


def run_codec(series: Series, spec: StreamSpec, max_latency: float, loss: float = 0.0, seed: int = 1,
              urgent_threshold: float | None = None, max_silence: float = 60.0) -> tuple[Result, Reconstruction]:  # fmt: skip
    encoder, decoder = StreamEncoder(spec, max_latency, urgent_threshold, max_silence), StreamDecoder(spec)
    rng = random.Random(seed)
    ticks, times, truth = first_per_tick(series, spec)
    index = {k: i for i, k in enumerate(ticks)}
    shore = np.full_like(truth, np.nan)
    packets, latencies, confirmations, cpu = 0, [], [], 0.0

    def send(now: float) -> None:
        nonlocal packets
        encoded = encoder.take()
        packets += 1
        delivered = rng.random() >= loss
        encoder.resolve(delivered)
        if not delivered:
            return
        span = decoder.decode(encoded.packet.payload, now)
        latencies.extend(now - t for t in encoded.surprise_times)
        confirmations.extend(now - t for t in encoded.sample_times)
        for i, row in enumerate(span.values):
            shore[index[span.first_tick + i]] = row

    for t, x in zip(series.times, series.values, strict=True):
        while (due := encoder.deadline()) is not None and due <= t and encoder.ready(due):
            send(due)
        start = time.perf_counter()
        encoder.push(t, x)
        cpu += time.perf_counter() - start
        while encoder.ready(t):
            send(t)
    while encoder.pending and encoder.ready(due := max(encoder.deadline(), series.times[-1])):  # type: ignore[type-var]
        send(due)
    sent = _sent_mask(series, spec, ticks, truth)
    eps = np.asarray(spec.eps)
    held = ~np.isnan(shore)
    ratios = np.abs(shore - truth)[held] / np.broadcast_to(eps, truth.shape)[held]
    samples = truth.size
    result = Result(samples, packets, packets * PACKET_BITS, packets * PACKET_BITS / samples,
                    float(ratios.max()) if ratios.size else 0.0,
                    float(np.sqrt(np.mean(ratios**2))) if ratios.size else 0.0,
                    float(max(latencies)) if latencies else 0.0,
                    float(max(confirmations)) if confirmations else 0.0, int((~held).sum()),
                    us_per_tick=cpu / max(1, len(ticks)) * 1e6)  # fmt: skip
    return result, Reconstruction(ticks, truth, shore, sent)


def _sent_mask(series: Series, spec: StreamSpec, ticks: list[int], truth: np.ndarray) -> np.ndarray:
    """Which samples were 'unpredictable' (q != 0): replay the vehicle's predictor without loss."""
    predictor = spec.predictor()
    mask = np.zeros(truth.shape, dtype=bool)
    last = None
    for i, (k, x) in enumerate(zip(ticks, truth, strict=True)):
        for _ in range(0 if last is None else k - last - 1):
            predictor.skip()
        last = k
        prediction = predictor.predict()
        q = np.round((x - prediction) / spec.step)
        mask[i] = q != 0
        predictor.update(prediction + q * spec.step)
    return mask


def pack(items: list[tuple[float, int]], capacity_bits: int, max_latency: float) -> tuple[int, float]:
    """Packets needed for (time, bits) items sent in order, each packet leaving when the next item does
    not fit or when its oldest item is ``max_latency`` old; returns (packets, largest latency)."""
    packets, worst, batch, used = 0, 0.0, [], 0

    def flush(at: float) -> None:
        nonlocal packets, worst, batch, used
        packets += 1
        worst = max(worst, at - batch[0])
        batch, used = [], 0

    for t, bits in items:
        if batch and t - batch[0] > max_latency:
            flush(batch[0] + max_latency)
        if batch and used + bits > capacity_bits:
            flush(t)
        batch.append(t)
        used += bits
    if batch:
        flush(batch[0] + max_latency)
    return packets, worst


def send_all(series: Series, spec: StreamSpec, max_latency: float) -> Result:
    ticks, times, truth = first_per_tick(series, spec)
    items = [(t, 16) for t in times for _ in range(truth.shape[1])]
    packets, latency = pack(items, (PACKET_SIZE - 4) * 8, max_latency)
    return Result(
        truth.size, packets, packets * PACKET_BITS, packets * PACKET_BITS / truth.size, 0.0, 0.0, latency
    )


def send_on_delta(series: Series, spec: StreamSpec, max_latency: float) -> Result:
    ticks, times, truth = first_per_tick(series, spec)
    eps = np.asarray(spec.eps)
    last = truth[0].copy()
    items = [(times[0], 32) for _ in range(truth.shape[1])]
    errors = np.zeros_like(truth)
    for i in range(1, len(truth)):
        moved = np.abs(truth[i] - last) > eps
        last[moved] = truth[i][moved]
        items.extend((times[i], 32) for _ in range(int(moved.sum())))
        errors[i] = np.abs(truth[i] - last) / eps
    packets, latency = pack(items, 7 * 32, max_latency)
    return Result(truth.size, packets, packets * PACKET_BITS, packets * PACKET_BITS / truth.size,
                  float(errors.max()), float(np.sqrt(np.mean(errors**2))), latency)  # fmt: skip


def make_spec(series: Series, eps: float, relative: bool, method: str, period: float | None) -> StreamSpec:
    std = series.values.std(axis=0)
    per_channel = tuple(float(eps * s) if relative else float(eps) for s in std)
    if any(not e > 0 for e in per_channel):
        flat = [n for n, e in zip(series.names, per_channel, strict=True) if not e > 0]
        raise ValueError(f"eps must be positive; channels with zero spread: {flat}")
    return StreamSpec("eval", Stream.KINEMATIC, series.names, per_channel, period or series.period, method)


def plot(path: str, series: Series, spec: StreamSpec, rec: Reconstruction) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(spec.channels)
    cols = 3 if n > 4 else 1
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5 * cols, 2.2 * rows), squeeze=False, sharex=True)
    t = np.array(rec.ticks) * spec.period
    t = t - t[0]
    for c, ax in enumerate(axes.flat):
        if c >= n:
            ax.axis("off")
            continue
        ax.plot(t, rec.truth[:, c], color="0.6", lw=1, label="truth")
        ax.plot(t, rec.shore[:, c], color="tab:blue", lw=1, label="shore reconstruction")
        ax.fill_between(
            t, rec.shore[:, c] - spec.eps[c], rec.shore[:, c] + spec.eps[c], color="tab:blue", alpha=0.15
        )
        ax.scatter(
            t[rec.sent[:, c]], rec.truth[rec.sent[:, c], c], s=6, color="tab:red", label="sent (q != 0)"
        )
        ax.set_title(spec.channels[c], fontsize=9)
    axes.flat[0].legend(fontsize=7, loc="best")
    fig.supxlabel("time (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="a CSV file (one row per sample) or a MAVLink .tlog")
    parser.add_argument("--columns", help="comma-separated channels (CSV columns, or MESSAGE.field for a tlog; "
                        "default: every column, or RAW_IMU's nine for a tlog)")  # fmt: skip
    parser.add_argument("--time-column", help="CSV column of UNIX seconds (default t_unix_s if present)")
    parser.add_argument("--period", type=float, help="sample period in s (default: median interval)")
    parser.add_argument("--eps", type=float, required=True, help="error bound, in channel units (or x std)")
    parser.add_argument("--relative", action="store_true", help="eps is a multiple of each channel's std")
    parser.add_argument(
        "--max-latency", type=float, default=10.0, help="seconds an unpredictable sample may wait (10)"
    )
    parser.add_argument(
        "--max-silence",
        type=float,
        default=60.0,
        help="seconds a predictable sample may wait to be confirmed (60)",
    )
    parser.add_argument("--time-unit", choices=("s", "ms", "us"), default="s", help="unit of the time column")
    parser.add_argument("--method", choices=METHODS, default="kalman", help="predictor (default kalman)")
    parser.add_argument("--loss", type=float, default=0.0, help="fraction of packets lost (seeded)")
    parser.add_argument(
        "--urgent-threshold", type=float, help="|q| at or above which a sample goes out at once"
    )
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--plot", metavar="PNG", help="write truth, reconstruction and sent points")
    parser.add_argument("--json", action="store_true", help="one JSON object")


def evaluate(args: argparse.Namespace) -> tuple[dict[str, object], Series, StreamSpec, Reconstruction]:
    columns = [c.strip() for c in args.columns.split(",")] if args.columns else None
    series = load(args.file, columns, args.time_column, args.period)
    scale = {"s": 1.0, "ms": 1e-3, "us": 1e-6}[args.time_unit]
    series = Series(series.names, series.times * scale, series.values)
    spec = make_spec(series, args.eps, args.relative, args.method, args.period)
    result, rec = run_codec(series, spec, args.max_latency, args.loss, args.seed, args.urgent_threshold,
                            args.max_silence)  # fmt: skip
    baselines = {"send-all": send_all, "send-on-delta": send_on_delta}
    report: dict[str, object] = {
        **asdict(result),
        "method": args.method,
        "channels": list(spec.channels),
        "eps": list(spec.eps),
        "period_s": spec.period,
        "baselines": {
            name: _baseline(baseline(series, spec, args.max_latency)) for name, baseline in baselines.items()
        },
    }
    return report, series, spec, rec


def _baseline(result: Result) -> dict[str, object]:
    """A baseline's figures: the codec-only ones (losses marked, CPU) do not apply to it."""
    return {k: v for k, v in asdict(result).items() if k not in ("unbounded_samples", "us_per_tick")}


def _table(report: dict[str, object]) -> str:
    keys = (
        "samples",
        "packets",
        "link_bits",
        "bits_per_sample",
        "max_error_ratio",
        "rms_error_ratio",
        "max_latency_s",
    )
    rows = [(f"tacit ({report['method']})", report)] + list(report["baselines"].items())  # type: ignore[union-attr]
    lines = [f"{'method':<18}" + "".join(f"{k:>17}" for k in keys)]
    for name, row in rows:
        cells = "".join(f"{row[k]:>17.3f}" if isinstance(row[k], float) else f"{row[k]:>17}" for k in keys)
        lines.append(f"{name:<18}{cells}")
    if report.get("unbounded_samples"):
        lines.append(f"lost (marked unbounded on shore): {report['unbounded_samples']} samples")
    lines.append(
        f"predictable samples confirmed within {report['max_confirmation_s']:.1f} s "
        "(baselines: silence is never confirmed)"
    )
    lines.append(f"vehicle CPU: {report['us_per_tick']:.0f} us per {len(report['channels'])}-channel tick")  # type: ignore[arg-type]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    if not 0 <= args.loss < 1:
        print("tacit eval-compression: --loss is a fraction 0..1", file=sys.stderr)
        return 2
    try:
        report, series, spec, rec = evaluate(args)
    except (OSError, ValueError) as exc:
        print(f"tacit eval-compression: {exc}", file=sys.stderr)
        return 2
    if args.plot:
        plot(args.plot, series, spec, rec)
    print(json.dumps(report) if args.json else _table(report))
    return 0
