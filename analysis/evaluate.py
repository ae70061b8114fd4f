"""``tacit eval-compression``: run the vehicle's compressor on a file, decode as the shore does, measure.

The run is event-ordered like the real link: a packet leaves when it is full, when a sample is
urgent, or when the oldest pending sample reaches ``--max-latency`` (at that exact time); the shore
decodes each delivered packet when it leaves. ``--loss`` drops packets (seeded) to show that the shore
marks what it lost and never shows it as certain. Link bits count whole 32-byte packets (256 bits),
header included. Baselines, side by side: send-all (every sample as 16 bits, 14 per packet) and
send-on-delta, framed on the same link:

- a channel's value is sent when it differs from the last value sent by more than eps; the shore holds
  the last value sent (so every sample is within eps, and nothing says a quiet value is still quiet);
- each value sent is a 4-byte message (a 2-byte time delta and channel word, a 2-byte value: 7 in a
  packet), or, where smaller, a row's values are one message (time word, a bit per channel, 2 bytes per
  value: 3 of 9 channels take 10 bytes, not 12);
- messages are packed as densely as they fit in the same frames as the codec's (32 bytes: the 2-byte
  priority header and a 30-byte payload); a packet leaves when full, or when its oldest message has
  waited ``--max-latency``.

The codec gives more than that: with ``--max-silence`` it also confirms predictable samples within that
bound, packets send-on-delta never sends; ``--max-silence none`` compares the two at the same guarantee.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import random
import re
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from analysis.series import Series, load
from tacit.codec import StreamDecoder, StreamEncoder, StreamSpec
from tacit.codec.versions import NEWEST, VERSIONS
from tacit.packets import PACKET_SIZE, PAYLOAD_SIZE, Stream
from tacit.predict import METHODS

PACKET_BITS = PACKET_SIZE * 8


@dataclass
class Result:
    samples: int  # present values (a blank cell is not a sample)
    packets: int
    link_bits: int
    bits_per_sample: float
    max_error_ratio: float
    rms_error_ratio: float
    max_latency_s: float  # unpredictable samples (q != 0): sent within --max-latency
    max_confirmation_s: float = 0.0  # any sample: confirmed within --max-silence
    unbounded_samples: int = 0
    us_per_tick: float | None = None
    samples_absent: int = 0  # blank / NaN / missing cells: stored as absent on the shore
    samples_not_represented: int = 0  # present values the shore does not hold (only lost packets)
    time_precision_s: float = 0.0  # the shore dates every sample to within this (half a tick)
    max_time_error_s: float = 0.0  # measured: largest |shore time - sample time|
    ideal_bits_per_sample: float = 0.0  # the Kalman + ideal entropy coder bound (values only)
    code_bits_per_sample: float = 0.0  # the arithmetic code alone (no header, no padding)


@dataclass
class Reconstruction:
    """Per input row: what the shore holds (NaN: absent or lost) and which values were sent (q != 0)."""

    times: np.ndarray
    truth: np.ndarray
    shore: np.ndarray
    sent: np.ndarray  # bool, rows x channels


def entropy_bits(symbols: list[int]) -> float:
    """Total bits of an ideal coder that knows the whole sequence's histogram."""
    if not symbols:
        return 0.0
    _, counts = np.unique(np.array(symbols), return_counts=True)
    p = counts / counts.sum()
    return float(-(counts * np.log2(p)).sum())


def run_codec(
    series: Series,
    spec: StreamSpec,
    max_latency: float,
    loss: float = 0.0,
    seed: int = 1,
    urgent_threshold: float | None = None,
    max_silence: float | None = 60.0,
    progress: bool = False,
    protocol: int = NEWEST,
    checkpoints: float | None = None,
) -> tuple[Result, Reconstruction]:
    """``checkpoints``: a version-4 vehicle's check-point interval; each says up to when its streams were
    predictable (``PacketEncoder.predictable_until``), which confirms the samples before that
    (``max_confirmation_s``: by a packet or a check-point, whichever came first)."""
    encoder = StreamEncoder(spec, max_latency, urgent_threshold, max_silence, protocol)
    decoder = StreamDecoder(spec, protocol)
    rng = random.Random(seed)
    truth = series.values
    rows = len(truth)
    shore = np.full_like(truth, np.nan)
    shore_time = np.full(rows, np.nan)
    sent = np.zeros(truth.shape, dtype=bool)
    row_of: list[int] = []  # the encoder's sample number -> input row (all-absent rows are not samples)
    symbols: list[list[int]] = [[] for _ in spec.channels]
    packets, cpu = 0, 0.0
    latencies: list[float] = []
    confirmations: list[float] = []
    confirmed_at = np.full(len(series.times), np.inf)  # per row: when a packet or a check-point vouched
    marks: list[tuple[float, float]] = []  # (check-point time, predictable until)
    next_checkpoint = float(series.times[0]) + checkpoints if checkpoints and len(series.times) else np.inf
    code_bits: list[int] = []

    def send(now: float) -> None:
        nonlocal packets
        encoded = encoder.take()
        packets += 1
        code_bits.append(encoded.code_bits)
        delivered = rng.random() >= loss
        encoder.resolve(delivered)
        if not delivered:
            return
        span = decoder.decode(encoded.packet.payload, now, encoded.packet.seq)
        latencies.extend(now - t for t in encoded.surprise_times)
        confirmations.extend(now - t for t in encoded.sample_times)
        for serial in encoded.serials[0]:
            confirmed_at[row_of[serial]] = min(confirmed_at[row_of[serial]], now)
        for serial, r in zip(encoded.serials[0], encoded.rows[0], strict=True):
            at, row = span.times[r], span.values[r]
            held = shore[row_of[serial]]  # a sample too large for one packet arrives in parts (channels)
            shore[row_of[serial]] = np.where(np.isnan(row), held, row)
            shore_time[row_of[serial]] = at

    # on a terminal only (a log would keep every refresh), cleared before the caller prints
    bar = tqdm(
        total=rows, desc="encoding", unit=" rows", disable=None if progress else True, leave=False, delay=2.0
    )
    for i, (t, x) in enumerate(zip(series.times, truth, strict=True)):
        # packets due before this sample leave first; one due at its very time leaves after it is pushed
        # (as the agent pushes a tick's samples, then sends, and as send-on-delta's packet takes a message
        # that has waited exactly the bound)
        while (due := encoder.deadline()) is not None and due < t and encoder.ready(due):
            send(due)
        while next_checkpoint <= t:
            marks.append((next_checkpoint, encoder.predictable_until(next_checkpoint)))
            next_checkpoint += checkpoints or np.inf
        start = time.perf_counter()
        if encoder.push(t, x):
            row_of.append(i)
            q = encoder.last_q
            for c, v in enumerate(q):
                if v is not None:
                    symbols[c].append(v)
                    sent[i, c] = v != 0
        cpu += time.perf_counter() - start
        while encoder.ready(t):
            send(t)
        if i % 1000 == 999:
            bar.update(i + 1 - bar.n)
    bar.update(rows - bar.n)
    bar.close()
    end = float(series.times[-1]) if rows else 0.0
    while encoder.pending:  # the run's end: what is left leaves at its deadline, or now if it has none
        deadline = encoder.deadline()
        send(end if deadline is None else max(deadline, end))
    present = ~np.isnan(truth)
    held = present & ~np.isnan(shore)
    eps = np.broadcast_to(np.asarray(spec.eps), truth.shape)
    ratios = np.abs(shore - truth)[held] / eps[held]
    samples = int(present.sum())
    dated = ~np.isnan(shore_time)
    time_errors = np.abs(shore_time[dated] - series.times[dated])
    ideal = sum(entropy_bits(s) for s in symbols) / max(1, samples)
    result = Result(
        samples,
        packets,
        packets * PACKET_BITS,
        packets * PACKET_BITS / max(1, samples),
        float(ratios.max()) if ratios.size else 0.0,
        float(np.sqrt(np.mean(ratios**2))) if ratios.size else 0.0,
        float(max(latencies)) if latencies else 0.0,
        _confirmation(series.times[row_of], confirmed_at[row_of], marks)
        if checkpoints
        else float(max(confirmations))
        if confirmations
        else 0.0,
        int((present & ~held).sum()),
        us_per_tick=cpu / max(1, len(row_of)) * 1e6,
        samples_absent=int((~present).sum()),
        samples_not_represented=int((present & ~held).sum()),
        time_precision_s=spec.time_precision,
        max_time_error_s=float(time_errors.max()) if time_errors.size else 0.0,
        ideal_bits_per_sample=ideal,
        code_bits_per_sample=sum(code_bits) / max(1, samples),
    )
    return result, Reconstruction(series.times, truth, shore, sent)


def _confirmation(times: np.ndarray, by_packet: np.ndarray, marks: list[tuple[float, float]]) -> float:
    """The longest a sample waited to be vouched for: by its packet, or by the first check-point that
    said its stream predictable past it (their marks never go back)."""
    if not len(times):
        return 0.0
    at = np.array([c for c, _ in marks] + [np.inf])
    until = np.maximum.accumulate(np.array([u for _, u in marks] + [np.inf]))
    by_checkpoint = at[np.searchsorted(until, times, side="left")]
    return float(np.max(np.minimum(by_packet, by_checkpoint) - times))


def pack(items: list[tuple[float, int]], capacity_bits: int, max_latency: float) -> tuple[int, float]:
    """Packets needed for (time, bits) messages sent in order, with the link's rule: a message waits at
    most ``max_latency`` (its packet leaves then), and a packet leaves when full (the next message, or any
    as small as the smallest, does not fit). Returns (packets, largest wait)."""
    smallest = min((bits for _, bits in items), default=0)
    packets, worst, used = 0, 0.0, 0
    batch: list[float] = []

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
        if used + smallest > capacity_bits:
            flush(t)
    if batch:
        flush(batch[0] + max_latency)
    return packets, worst


def send_all(series: Series, spec: StreamSpec, max_latency: float) -> Result:
    """Every present value as 16 bits, 14 per packet."""
    present = ~np.isnan(series.values)
    items = [(t, 16) for t, row in zip(series.times, present, strict=True) for _ in range(int(row.sum()))]
    samples = max(1, int(present.sum()))
    packets, latency = pack(items, (PACKET_SIZE - 4) * 8, max_latency)
    return Result(samples, packets, packets * PACKET_BITS, packets * PACKET_BITS / samples, 0.0, 0.0, latency)


SOD_WORD_BYTES = 2  # a send-on-delta message's time delta (and, per value, which channel)
SOD_VALUE_BYTES = 2  # each value it carries: the sensor's 16-bit reading


def sod_messages(moved: int, channels: int) -> list[int]:
    """The sizes in bytes of the send-on-delta messages for one row whose ``moved`` values are sent: a
    message per value (a 2-byte time/channel word, the 2-byte value: 4 bytes), or, when smaller, one for
    the row (a 2-byte time word, a channel mask of a bit per channel, 2 bytes per value)."""
    single = SOD_WORD_BYTES + SOD_VALUE_BYTES
    row = SOD_WORD_BYTES + -(-channels // 8) + SOD_VALUE_BYTES * moved
    return [row] if row < single * moved and row <= PAYLOAD_SIZE else [single] * moved


def send_on_delta(series: Series, spec: StreamSpec, max_latency: float) -> Result:
    """The baseline on the same link: a channel's value is sent when it differs from the last value sent
    by more than eps (the shore holds the last value sent), as ``sod_messages`` (one channel: 4 bytes),
    packed as densely as they fit in the codec's 30-byte payloads, each packet leaving when full or when
    its oldest message has waited ``max_latency``. Absent values are neither sent nor scored."""
    truth = series.values
    eps = np.asarray(spec.eps)
    last = np.full(truth.shape[1], np.nan)
    items: list[tuple[float, int]] = []
    errors = np.zeros_like(truth)
    for i, (t, row) in enumerate(zip(series.times, truth, strict=True)):
        present = ~np.isnan(row)
        moved = present & (np.isnan(last) | (np.abs(row - last) > eps))
        last[moved] = row[moved]
        items.extend((t, 8 * size) for size in sod_messages(int(moved.sum()), len(row)))
        errors[i] = np.where(present, np.abs(row - last) / eps, 0.0)
    samples = max(1, int((~np.isnan(truth)).sum()))
    packets, latency = pack(items, PAYLOAD_SIZE * 8, max_latency)
    return Result(
        samples,
        packets,
        packets * PACKET_BITS,
        packets * PACKET_BITS / samples,
        float(errors.max()),
        float(np.sqrt(np.mean(errors**2))),
        latency,
    )


def parse_eps(text: str, names: tuple[str, ...]) -> list[float]:
    """``--eps``: one number for every channel, one per channel (``0.1,0.5,...``), or ``name=value``
    pairs (with an optional bare default: ``0.1,temp=0.05``)."""
    parts = [p.strip() for p in str(text).split(",") if p.strip()]
    try:
        if all("=" not in p for p in parts):
            numbers = [float(p) for p in parts]
            if len(numbers) == 1:
                return numbers * len(names)
            if len(numbers) != len(names):
                raise ValueError(f"--eps has {len(numbers)} values for {len(names)} channels {list(names)}")
            return numbers
        default = [float(p) for p in parts if "=" not in p]
        named = dict((k.strip(), float(v)) for k, v in (p.split("=", 1) for p in parts if "=" in p))
    except ValueError as exc:
        if "--eps" in str(exc):
            raise
        raise ValueError(f"--eps {text!r}: not numbers ({exc})") from None
    unknown = [k for k in named if k not in names]
    if unknown:
        raise ValueError(f"--eps names {unknown} that are not channels; channels: {list(names)}")
    lacking = [n for n in names if n not in named]
    if lacking and not default:
        raise ValueError(
            f"--eps gives no bound for {lacking} (add a bare default, e.g. --eps 0.1,{names[0]}=...)"
        )
    return [named.get(n, default[0] if default else 0.0) for n in names]


DEPTH_NAMES = ("depth", "pressure", "pres")  # a channel named with one of these is the vehicle's depth


def depth_channel(names: tuple[str, ...]) -> str | None:
    """The channel that is the vehicle's depth (or pressure), by its name (None: none is)."""
    found = [n for n in names if set(re.split(r"[^a-z0-9]+", n.lower())) & set(DEPTH_NAMES)]
    return found[0] if found else None


def make_spec(
    series: Series,
    eps: float | str,
    relative: bool,
    method: str,
    period: float | None,
    depth: str | None = "",
) -> StreamSpec:
    """The stream's definition; ``depth``: its depth channel's name ("": found by name, ``depth_channel``;
    None: none), which version 4 predicts profiles by."""
    bounds = parse_eps(str(eps), series.names)
    std = np.nanstd(series.values, axis=0) if len(series.values) else np.zeros(len(series.names))
    per_channel = tuple(float(e * s) if relative else float(e) for e, s in zip(bounds, std, strict=True))
    if any(not e > 0 for e in per_channel):
        flat = [n for n, e in zip(series.names, per_channel, strict=True) if not e > 0]
        raise ValueError(f"eps must be positive; channels with zero spread or no value: {flat}")
    if depth == "":
        depth = depth_channel(series.names)
    return StreamSpec(
        "eval", Stream.KINEMATIC, series.names, per_channel, period or series.period, method, depth=depth
    )


def plot(path: str, spec: StreamSpec, rec: Reconstruction, title: str) -> None:
    import matplotlib.pyplot as plt

    fig = figure(spec, rec, title)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def figure(spec: StreamSpec, rec: Reconstruction, title: str) -> Any:
    """Per channel: what was measured, what the shore reconstructed with its error bound eps around it,
    and the samples the vehicle sent (those the shared prediction missed by more than eps)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(spec.channels)
    cols = 3 if n > 4 else 1
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5 * cols, 2.4 * rows + 0.8), squeeze=False, sharex=True)
    t = rec.times - rec.times[0]
    for c, ax in enumerate(axes.flat):
        if c >= n:
            ax.axis("off")
            continue
        unit = channel_unit(spec.channels[c])
        eps = spec.eps[c]
        ax.plot(t, rec.truth[:, c], color="0.6", lw=1, label="measured on the vehicle")
        ax.plot(t, rec.shore[:, c], color="tab:blue", lw=1, label="reconstructed on the shore")
        ax.fill_between(
            t,
            rec.shore[:, c] - eps,
            rec.shore[:, c] + eps,
            color="tab:blue",
            alpha=0.15,
            label="error bound: reconstruction +- eps",
        )
        ax.scatter(
            t[rec.sent[:, c]],
            rec.truth[rec.sent[:, c], c],
            s=6,
            color="tab:red",
            label="sent (the prediction missed by more than eps)",
        )
        ax.set_title(f"{spec.channels[c]}, eps {eps:.3g}{f' {unit}' if unit else ''}", fontsize=9)
        ax.set_ylabel(unit or "channel units", fontsize=8)
    axes.flat[0].legend(fontsize=7, loc="best")
    fig.suptitle(title, fontsize=10)
    fig.supxlabel("time since the first sample (s)")
    fig.tight_layout()
    return fig


def channel_unit(channel: str) -> str | None:
    """A channel's unit: a CSV header's "name (unit)", or a tlog's MESSAGE.field's in the MAVLink
    definitions; None when neither says."""
    if found := re.fullmatch(r".*\(([^()]+)\)\s*", channel):
        return found.group(1)
    kind, _, field = channel.partition(".")
    if not field:
        return None
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    message = getattr(mavlink, f"MAVLink_{kind.lower()}_message", None)
    units: dict[str, str] = getattr(message, "fieldunits_by_name", None) or {}
    return units.get(field) or None


def plot_title(file: str, report: dict[str, Any]) -> str:
    """The plot's title: the file, the method, the error bound and what it cost."""
    eps = "eps: --eps x each channel's std" if report["eps_relative"] else "eps in each channel's unit"
    return (
        f"{Path(file).name}: tacit ({report['method']}), {report['bits_per_sample']:.3f} bits per sample, "
        f"largest error {report['max_error_ratio']:.3f} x eps ({eps})"
    )


def _silence(text: str) -> float | None:
    return None if text.strip().lower() == "none" else float(text)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="a CSV file (one row per sample) or a MAVLink .tlog")
    parser.add_argument(
        "--columns",
        help="comma-separated channels (CSV columns, or MESSAGE.field for a tlog; "
        "default: every column, or RAW_IMU's nine for a tlog)",
    )
    parser.add_argument(
        "--time-column",
        help="CSV time column: ISO-8601, or UNIX s/ms/us/ns (detected) "
        "(default: a column named t_unix_s, time, timestamp, datetime or date)",
    )
    parser.add_argument("--period", type=float, help="sample period in s (default: median interval)")
    parser.add_argument(
        "--eps",
        required=True,
        help="error bound, in channel units (or x std): one number, "
        "one per channel (0.1,0.5,...), or name=value pairs with an optional default",
    )
    parser.add_argument("--relative", action="store_true", help="eps is a multiple of each channel's std")
    parser.add_argument(
        "--max-latency", type=float, default=10.0, help="seconds an unpredictable sample may wait (10)"
    )
    parser.add_argument(
        "--max-silence",
        type=_silence,
        default=60.0,
        help="seconds a predictable sample may wait to be confirmed (60); 'none': no packet leaves only to "
        "confirm (send-on-delta's guarantee)",
    )
    parser.add_argument(
        "--time-unit",
        choices=("s", "ms", "us", "ns"),
        help="unit of a numeric time column (default: detected from its magnitude)",
    )
    parser.add_argument("--method", choices=METHODS, default="kalman", help="predictor (default kalman)")
    parser.add_argument("--loss", type=float, default=0.0, help="fraction of packets lost (seeded)")
    parser.add_argument(
        "--urgent-threshold", type=float, help="|q| at or above which a sample goes out at once"
    )
    parser.add_argument(
        "--time-tolerance",
        type=float,
        help="seconds within which the shore may date a sample (default: half the period); a payload "
        "protocol 4 vehicle then keeps a wandering clock's samples a tick apart",
    )
    parser.add_argument(
        "--depth-channel",
        default="",
        help="the channel that is the vehicle's depth or pressure, which protocol 4 predicts the other "
        "channels' profiles by (default: one named depth or pressure; 'none': no profile prediction)",
    )
    add_protocol_option(parser)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--plot", metavar="PNG", help="write truth, reconstruction and sent points")
    parser.add_argument("--json", action="store_true", help="one JSON object")


def add_protocol_option(parser: argparse.ArgumentParser) -> None:
    """``--protocol``: the version the vehicle speaks, which says what the codec codes."""
    parser.add_argument(
        "--protocol",
        type=int,
        choices=VERSIONS,
        default=NEWEST,
        help=f"the protocol version the vehicle speaks (default {NEWEST}, a new agent's; 3: today's vehicles)",
    )


def evaluate(args: argparse.Namespace) -> tuple[dict[str, Any], Series, StreamSpec, Reconstruction]:
    columns = [c.strip() for c in args.columns.split(",")] if args.columns else None
    progress = getattr(args, "progress", True)
    series = load(
        args.file, columns, args.time_column, args.period, getattr(args, "time_unit", None), progress
    )
    for note in series.notes:
        print(f"tacit eval-compression: {note}", file=sys.stderr)
    rows, channels = series.values.shape
    print(
        f"tacit eval-compression: read {rows} rows of {channels} channels: "
        f"{rows * channels - series.absent} samples, {series.absent} absent",
        file=sys.stderr,
    )
    depth = getattr(args, "depth_channel", "")
    spec = make_spec(
        series, args.eps, args.relative, args.method, args.period, None if depth == "none" else depth
    )
    spec = dataclasses.replace(spec, time_tolerance=getattr(args, "time_tolerance", None))
    result, rec = run_codec(
        series,
        spec,
        args.max_latency,
        args.loss,
        args.seed,
        args.urgent_threshold,
        args.max_silence,
        progress,
        getattr(args, "protocol", NEWEST),
    )
    baselines = {"send-all": send_all, "send-on-delta": send_on_delta}
    report: dict[str, object] = {
        **asdict(result),
        "method": args.method,
        "protocol": getattr(args, "protocol", NEWEST),
        "channels": list(spec.channels),
        "rows": len(series.times),
        "eps": list(spec.eps),  # per channel, in channel units (with --relative: --eps x the channel's std)
        "eps_relative": bool(args.relative),
        "period_s": spec.period,
        "depth_channel": spec.depth,
        "notes": list(series.notes),
        "baselines": {
            name: _baseline(baseline(series, spec, args.max_latency)) for name, baseline in baselines.items()
        },
    }
    return report, series, spec, rec


def _baseline(result: Result) -> dict[str, object]:
    """A baseline's figures: the codec-only ones (losses marked, CPU) do not apply to it."""
    return {k: v for k, v in asdict(result).items() if k not in ("unbounded_samples", "us_per_tick")}


def _table(report: dict[str, Any]) -> str:
    keys = (
        "samples",
        "packets",
        "link_bits",
        "bits_per_sample",
        "max_error_ratio",
        "rms_error_ratio",
        "max_latency_s",
    )
    rows = [(f"tacit ({report['method']})", report)] + list(report["baselines"].items())
    lines = [f"{'method':<18}" + "".join(f"{k:>17}" for k in keys)]
    for name, row in rows:
        cells = "".join(f"{row[k]:>17.3f}" if isinstance(row[k], float) else f"{row[k]:>17}" for k in keys)
        lines.append(f"{name:<18}{cells}")
    bounds = ", ".join(
        f"{name}={eps:.4g}" for name, eps in zip(report["channels"], report["eps"], strict=True)
    )
    lines.append(
        f"eps (error bound): {bounds}" + (" (--eps x each channel's std)" if report["eps_relative"] else "")
    )
    if report.get("unbounded_samples"):
        lines.append(f"lost (marked unbounded on shore): {report['unbounded_samples']} samples")
    lines.append(
        f"absent in the file (stored as absent): {report['samples_absent']} values; present but not "
        f"represented on shore: {report['samples_not_represented']}"
    )
    lines.append(
        f"time: every sample dated within {report['time_precision_s']:.4g} s (largest seen "
        f"{report['max_time_error_s']:.4g} s); ideal bound {report['ideal_bits_per_sample']:.3f} bits/sample"
    )
    lines.append(
        f"predictable samples confirmed within {report['max_confirmation_s']:.1f} s "
        "(baselines: silence is never confirmed)"
    )
    lines.append(f"vehicle CPU: {report['us_per_tick']:.0f} us per {len(report['channels'])}-channel tick")
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
        plot(args.plot, spec, rec, plot_title(args.file, report))
    print(json.dumps(report) if args.json else _table(report))
    return 0
