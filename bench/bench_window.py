"""The window: what one poll carries at each rate, a version-3 vehicle (one packet in flight) beside a
version-4 one (as many as the last poll could carry, at most 14), on the recorded dive's IMU and water
at the agent's defaults (latency 10 s, silence 60 s; version 4's check-points say the silence), polled
every ``--interval`` s for ``--minutes`` minutes, every frame of the rate asked for, none lost.

Run: .venv/bin/python bench/bench_window.py [--interval 10] [--minutes 10]

Rates 0, 1, 3 and 5 (1, 6, 16 and 64 packets a poll). Per rate and version: packets per poll (mean and largest), the share of the dive's samples on the shore
at the end, and how long the delivered ones waited (mean and largest, s). Every packet is decoded as the
shore decodes it; the command fails (exit status 1) if a sample is off by more than its eps, is decoded
twice, or the run did not measure what it claims (a version-4 poll that could carry several packets
never brought more than one).
"""

from __future__ import annotations

import argparse
import itertools
import sys
from dataclasses import dataclass, field

import numpy as np
from bench_fleet import recorded_dive

from tacit.codec import EncodedPacket, PacketDecoder
from tacit.link import capacity
from tacit.packets import Stream
from tacit.streams import default_streams
from vehicle_agent.agent import AgentConfig
from vehicle_agent.compressor import Compressor

T0 = 1_800_000_000.0
RATES_SHOWN = (0, 1, 3, 5)  # one of each capacity: 1, 6, 16 and 64 packets a poll


@dataclass
class Run:
    per_poll: list[int] = field(default_factory=list)
    waits: list[float] = field(default_factory=list)
    samples: int = 0
    faults: list[str] = field(default_factory=list)


def run(rate: int, protocol: int, interval: float, minutes: float) -> Run:
    """One vehicle polled at ``rate`` every ``interval`` s: the packets each poll brought, and the
    samples' waits, each decoded and checked within eps."""
    config, streams = AgentConfig(), default_streams()
    compressor = Compressor(streams, config.max_latency, config.max_silence, protocol=protocol)
    compressor.silence_said(config.checkpoint_interval)
    decoder = PacketDecoder(list(streams.values()), protocol)
    specs = {s.name: s for s in streams.values()}
    imu, env = recorded_dive()
    period = {Stream.KINEMATIC: streams[Stream.KINEMATIC].period, Stream.ENVIRONMENTAL: 1.0}
    truth: dict[tuple[str, int], np.ndarray] = {}
    feeds = {
        Stream.KINEMATIC: itertools.cycle(imu),
        Stream.ENVIRONMENTAL: itertools.cycle(env),
    }
    out, seq, t, next_poll = Run(), 0, T0, T0 + interval
    in_flight: list[tuple[int, EncodedPacket]] = []
    held: set[tuple[str, int]] = set()
    step = min(period.values())
    while t < T0 + 60 * minutes:
        t += step
        for stream, every in period.items():
            k = round((t - T0) / every)
            if abs(k * every - (t - T0)) < 1e-9:
                values = next(feeds[stream])
                compressor.add(stream, t, values)
                truth[(streams[stream].name, k)] = np.array([np.nan if v is None else v for v in values])
                out.samples += 1
        for _, encoded in compressor.ready(t, seq):
            seq += 1
            in_flight.append((encoded.packet.seq, encoded))
        if t >= next_poll:
            next_poll += interval
            brought = in_flight[: capacity(rate)]
            in_flight = in_flight[len(brought) :]
            out.per_poll.append(len(brought))
            compressor.follow(capacity(rate))  # the vehicle learns what a poll carries from the poll
            for packet_seq, encoded in brought:
                compressor.resolve(packet_seq, True)
                for span in decoder.decode(encoded.packet.payload, t, packet_seq):
                    every = 1.0 if span.spec.name == streams[Stream.ENVIRONMENTAL].name else step
                    for at, values in zip(span.times, span.values, strict=True):
                        key = (span.spec.name, round((float(at) - T0) / every))
                        if key in held:
                            out.faults.append(f"{key} decoded twice")
                        held.add(key)
                        present = ~np.isnan(truth[key])
                        error = np.abs(values[present] - truth[key][present])
                        if np.any(error > np.asarray(specs[span.spec.name].eps)[present] + 1e-9):
                            out.faults.append(f"{key} off by more than eps")
                        out.waits.append(t - float(at))
    out.samples = len(truth)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--interval", type=float, default=10.0, help="s between two polls of the vehicle")
    parser.add_argument("--minutes", type=float, default=10.0, help="minutes of the dive polled")
    options = parser.parse_args()
    head = (
        f"{'rate':>4} {'packets/poll':>12} {'version':>7} {'per poll':>8} {'largest':>7} {'delivered':>9} "
        f"{'mean wait s':>11} {'largest wait s':>14}"
    )
    print(f"one vehicle, the recorded dive's IMU and water, polled every {options.interval:g} s")
    print(head)
    print("-" * len(head))
    faults = []
    for rate in RATES_SHOWN:
        for protocol in (3, 4):
            r = run(rate, protocol, options.interval, options.minutes)
            faults += [f"rate {rate}, version {protocol}: {f}" for f in r.faults[:3]]
            if protocol == 4 and capacity(rate) > 1 and max(r.per_poll) <= 1:
                faults.append(f"rate {rate}, version 4: no poll brought more than one packet")
            print(
                f"{rate:>4} {capacity(rate):>12} {protocol:>7} {np.mean(r.per_poll):>8.2f} {max(r.per_poll):>7} "
                f"{len(r.waits) / r.samples:>9.1%} {np.mean(r.waits):>11.1f} {max(r.waits):>14.1f}"
            )
    for fault in faults:
        print(f"NOT MEASURED AS CLAIMED: {fault}", file=sys.stderr)
    sys.exit(1 if faults else 0)


if __name__ == "__main__":
    main()
