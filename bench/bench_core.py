"""Throughput of the link core: packets encoded/decoded and NMEA sentences parsed per second.

Run: .venv/bin/python bench/bench_core.py [--seconds 1.0]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

from tacit import auth, nmea, packets
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

KEY = bytes(range(32))


def rate(fn: Callable[[], object], seconds: float) -> float:
    """Calls per second of ``fn``, measured over about ``seconds``."""
    n, batch = 0, 200
    start = time.perf_counter()
    while (elapsed := time.perf_counter() - start) < seconds:
        for _ in range(batch):
            fn()
        n += batch
    return n / elapsed


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seconds", type=float, default=1.0, help="time per measurement")
    seconds = parser.parse_args().seconds
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


if __name__ == "__main__":
    main()
