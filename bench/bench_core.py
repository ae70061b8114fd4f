"""Throughput of the link core: packets encoded/decoded, priority payloads decoded into samples (the
codec, on the chain as the shore decodes them) and NMEA sentences parsed per second of CPU time.

Run: .venv/bin/python bench/bench_core.py [--seconds 1.0] [--profile]
"""

from __future__ import annotations

import argparse
import cProfile
import time
from collections.abc import Callable

import numpy as np
from profiling import summary

from tacit import auth, nmea, packets
from tacit.codec import PacketDecoder, PacketEncoder, StreamSpec
from tacit.packets import (
    PAYLOAD_SIZE,
    CheckpointPacket,
    Command,
    ControlPacket,
    MissionState,
    Priority,
    PriorityPacket,
    Stream,
)
from tacit.streams import default_streams

KEY = bytes(range(32))


def rate(fn: Callable[[], object], seconds: float, batch: int = 200) -> float:
    """Calls per second of ``fn``, measured over about ``seconds`` (in runs of ``batch`` calls). Seconds of
    this process's CPU time: on a machine shared with other work they are what the figure is of."""
    n = 0
    start = time.process_time()
    while (elapsed := time.process_time() - start) < seconds:
        for _ in range(batch):
            fn()
        n += batch
    return n / elapsed


def codec_payloads(count: int) -> tuple[list[StreamSpec], list[tuple[bytes, float]]]:
    """``count`` priority payloads of the default streams and their reception times, in chain order: the
    IMU a noisy sensor at 4 Hz (a standard deviation of 10 units, about one eps: a surprise every few
    samples), as bench_server's vehicle sends, each packet delivered."""
    specs = list(default_streams().values())
    imu = specs[0]
    encoder = PacketEncoder(specs, max_latency=1.0)
    rng = np.random.default_rng(1)
    out: list[tuple[bytes, float]] = []
    tick, t0 = 0, 1_800_000_000.0
    while len(out) < count:
        while not encoder.ready(t0 + tick * imu.period):
            encoder.push(0, t0 + tick * imu.period, rng.normal(0, 10, len(imu.channels)))
            tick += 1
        out.append((encoder.take().packet.payload, t0 + tick * imu.period))
        encoder.resolve(True)
    return specs, out


def decode_all(specs: list[StreamSpec], payloads: list[tuple[bytes, float]]) -> int:
    """Every payload decoded in order by a fresh shore decoder; the samples they held."""
    decoder = PacketDecoder(specs)
    return sum(len(span.ticks) for payload, at in payloads for span in decoder.decode(payload, at))


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seconds", type=float, default=1.0, help="time per measurement")
    parser.add_argument(
        "--profile", action="store_true", help="then where the codec's decoding time goes (cProfile)"
    )
    options = parser.parse_args()
    seconds = options.seconds
    control = ControlPacket(Command.MOVE, seq=42, time=1_800_000_000, distance=25.5, angle=-30, depth=2)
    control_frame = auth.sign(control, KEY, 2)
    checkpoint = CheckpointPacket(seq=1, time=1_800_000_000, state=MissionState.PREPROGRAMMED, depth=3.5)
    checkpoint_frame = checkpoint.encode()
    priority_frame = PriorityPacket(1, Priority.IMPORTANT, Stream.KINEMATIC, bytes(PAYLOAD_SIZE)).encode()
    rxd = nmea.RxData(2, 1, False, 1, checkpoint_frame).line()
    cst = (
        "$CACST,0,223413.0000,0,1440,25,0175,0166,75,01,01,01,03,1,007,006,0,3,3,0,146,03,04,"
        "-100,-1,000,-1.2,45,10000,2000"
    )
    cst += "*" + nmea.checksum(cst[1:])
    rows = [
        ("control sign (encode + HMAC)", lambda: auth.sign(control, KEY, 2), "packets/s"),
        ("control verify (HMAC + decode)", lambda: auth.verify(control_frame, KEY, 2), "packets/s"),
        ("check-point encode", checkpoint.encode, "packets/s"),
        ("check-point decode", lambda: packets.decode(checkpoint_frame), "packets/s"),
        ("priority decode", lambda: packets.decode(priority_frame), "packets/s"),
        ("NMEA parse $CARXD (32-byte frame)", lambda: nmea.parse(rxd), "sentences/s"),
        ("NMEA parse $CACST (29 fields)", lambda: nmea.parse(cst), "sentences/s"),
        ("NMEA build $CCTXD", lambda: nmea.TxData(1, 2, True, control_frame).line(), "sentences/s"),
    ]
    print(f"{'operation':<36} {'rate':>12}  unit")
    for name, fn, unit in rows:
        print(f"{name:<36} {rate(fn, seconds):>12,.0f}  {unit}")
    specs, payloads = codec_payloads(200)
    decoded = rate(lambda: decode_all(specs, payloads), seconds, batch=1) * len(payloads)
    per = decode_all(specs, payloads) / len(payloads)
    print(f"{'priority payload decode (codec)':<36} {decoded:>12,.0f}  packets/s ({per:.1f} samples each)")
    if options.profile:
        profile = cProfile.Profile()
        profile.runcall(decode_all, specs, payloads)
        print(f"\n{len(payloads)} payloads of the codec decoded once, under cProfile:")
        print(summary(profile, len(payloads)))


if __name__ == "__main__":
    main()
