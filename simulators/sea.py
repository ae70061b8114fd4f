"""A scripted sea for the shore's MAC on virtual time: shore modems (driver-shaped: ``send``, ``poll``,
``ping``, listeners of received frames) and vehicles at fixed ranges, on one band.

No NMEA and no ptys: each exchange takes the time the channel gives it (airtime at the rate from
``tacit.rates``, propagation at the range, the modems' turnaround, the vehicle's host answering a data
request) on the running event loop's clock (``simulators.virtual_loop`` makes it virtual), and each frame
is lost with the frame error rate of the rate at the range's mean SNR (``simulators.acoustics``, fading
drawn from the seed). The band keeps every exchange's time on the air per station (``Band.busy``), so a
test sees whether two stations' exchanges ever overlapped. A vehicle may be silent (hears and answers
nothing); what it answers a poll is up to its ``answer`` (default: full frames of its address).
"""

from __future__ import annotations

import asyncio
import random
from collections.abc import Callable
from dataclasses import dataclass, field

from simulators.acoustics import ChannelParameters, frame_error_rate
from tacit import modem as mm
from tacit import nmea, rates


def _full(address: int, rate: int, nframes: int) -> list[bytes]:
    return [bytes([address]) * rates.rate(rate).frame_bytes] * nframes


@dataclass
class SeaVehicle:
    address: int
    ranges: dict[str, float]  # m from each shore station, by name
    silent: bool = False
    answer: Callable[[int, int, int], list[bytes]] = _full  # (address, rate, frames) -> frames sent
    received: list[tuple[float, bytes]] = field(default_factory=list)  # frames heard: (time, data)


class Band:
    """The acoustic band the stations share."""

    def __init__(self, params: ChannelParameters | None = None) -> None:
        self.params = params or ChannelParameters(fading_sigma_db=0.0)
        self.random = random.Random(self.params.seed)
        self.vehicles: dict[int, SeaVehicle] = {}
        self.busy: list[tuple[str, float, float]] = []  # (station, start, end) of each exchange

    def add(self, vehicle: SeaVehicle) -> None:
        self.vehicles[vehicle.address] = vehicle

    def snr(self, range_m: float) -> float:
        return self.params.mean_snr_db(range_m) + self.random.gauss(0.0, self.params.fading_sigma_db or 1e-9)

    def arrives(self, range_m: float, rate: int) -> tuple[bool, float]:
        """Whether one frame at ``rate`` gets through at ``range_m``, and its SNR."""
        snr = self.snr(range_m)
        return self.random.random() >= frame_error_rate(snr, rate, self.params.fer_width_db), snr

    def overlaps(self) -> int:
        """Pairs of exchanges of two stations that overlapped in time."""
        spans = sorted(self.busy, key=lambda b: b[1])
        return sum(1 for i, a in enumerate(spans) for b in spans[i + 1 :] if b[0] != a[0] and b[1] < a[2])


class SeaModem:
    """One shore station's modem on the band."""

    def __init__(self, band: Band, name: str, address: int = 0) -> None:
        self.band = band
        self.name = name
        self.address = address
        self.listeners: list[Callable[[mm.Event], None]] = []
        self._lock = asyncio.Lock()

    @property
    def state(self) -> mm.LinkState:
        return mm.LinkState.READY

    def add_listener(self, listener: Callable[[mm.Event], None]) -> None:
        self.listeners.append(listener)

    def _now(self) -> float:
        return asyncio.get_running_loop().time()

    def _range(self, address: int) -> tuple[SeaVehicle | None, float]:
        vehicle = self.band.vehicles.get(address)
        return vehicle, (vehicle.ranges[self.name] if vehicle else 1000.0)

    async def send(
        self,
        dest: int,
        frames: list[bytes],
        rate: int = 0,
        ack: bool = True,
        ack_timeout: float | None = None,
    ) -> mm.TransmitResult:
        async with self._lock:
            start = self._now()
            vehicle, range_m = self._range(dest)
            out = rates.airtime_s(rates.CYCLE_INIT_BITS, 0) + rates.data_airtime_s(rate, len(frames))
            await asyncio.sleep(out)
            travel = range_m / self.band.params.sound_speed
            acked: set[int] = set()
            if vehicle is not None and not vehicle.silent:
                for i, frame in enumerate(frames):
                    if self.band.arrives(range_m, rate)[0]:
                        vehicle.received.append((self._now() + travel, frame))
                        if ack and self.band.arrives(range_m, 0)[0]:
                            acked.add(i)
            if ack:
                back = 2 * travel + rates.TURNAROUND_S + rates.airtime_s(rates.ACK_BITS, 0)
                await asyncio.sleep(back if acked else min(back, ack_timeout or 10.0))
            self.band.busy.append((self.name, start, self._now()))
            return mm.TransmitResult(dest, len(frames), True, frozenset(acked))

    async def poll(self, remote: int, rate: int = 0, ack: bool = False) -> None:
        """The cycle-init leaves; the answer's frames arrive later as events (as the real driver)."""
        asyncio.get_running_loop().create_task(self._answer(remote, rate))

    async def _answer(self, remote: int, rate: int) -> None:
        async with self._lock:
            start = self._now()
            vehicle, range_m = self._range(remote)
            travel = range_m / self.band.params.sound_speed
            await asyncio.sleep(rates.airtime_s(rates.CYCLE_INIT_BITS, 0) + travel)
            if vehicle is None or vehicle.silent:
                self.band.busy.append((self.name, start, self._now()))
                return
            frames = vehicle.answer(remote, rate, rates.rate(rate).frames)
            await asyncio.sleep(1.0 + rates.data_airtime_s(rate, len(frames)) + travel)
            heard = [(frame, *self.band.arrives(range_m, rate)) for frame in frames]
            now = self._now()
            for i, (frame, through, snr) in enumerate(heard):
                if through:
                    stats = _stats(rate, remote, self.address, len(frames), snr)
                    event = mm.ReceivedFrame(remote, self.address, True, i + 1, frame, stats, now)
                    for listener in self.listeners:
                        listener(event)
            await asyncio.sleep(rates.TURNAROUND_S + rates.airtime_s(rates.ACK_BITS, 0))
            self.band.busy.append((self.name, start, self._now()))

    async def ping(self, dest: int, timeout: float = 10.0) -> float | None:
        async with self._lock:
            start = self._now()
            vehicle, range_m = self._range(dest)
            travel = range_m / self.band.params.sound_speed
            took = 2 * rates.airtime_s(rates.PING_BITS, 0) + 2 * travel
            answered = vehicle is not None and not vehicle.silent and took <= timeout
            await asyncio.sleep(took if answered else timeout)  # the driver gives up after ``timeout``
            self.band.busy.append((self.name, start, self._now()))
            return travel if answered else None


def _stats(rate: int, src: int, dest: int, nframes: int, snr: float) -> nmea.RxStats:
    return nmea.RxStats(
        mode=0, toa="", clock_mode=0, mfd_peak=0, mfd_pow=0, mfd_ratio=0, spl=0, agn=0, ainp=0, ain=0,
        mfd_shift=0, p2b=0, rate=rate, src=src, dest=dest, psk_err=0, pkt_type=0, nframes=nframes, nbad=0,
        snr_rss=0, snr_in=round(snr, 1), snr_out=round(snr, 1), snr_sym=0.0, mse=0.0, dqf=0, doppler=0.0,
        noise=0, carrier=0, bw=0,
    )  # fmt: skip
