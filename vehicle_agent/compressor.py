"""The vehicle's compressor (the paper's Algorithm 1) and its environmental event detector.

Both streams (``tacit.streams``) run the dual predictors of ``tacit.codec``: only what the shore cannot
predict goes out, as priority packets. The plume detector watches the water temperature: a rise of more
than ``plume_threshold`` above a slow running baseline is a time-sensitive event, and a least-squares
fit of temperature over the recent positions gives the direction of warmer water for the vehicle to
turn towards (the paper's "decide locally").
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from tacit.codec import EncodedPacket, PacketEncoder, StreamSpec
from tacit.codec.format import MAX_WINDOW
from tacit.packets import NEWEST, Stream


@dataclass
class PlumeEvent:
    temperature: float
    baseline: float
    bearing: float | None  # deg: towards warmer water, when the fit could tell


class PlumeDetector:
    def __init__(self, threshold: float = 0.5, baseline_tau: float = 120.0, memory: int = 40) -> None:
        self.threshold = threshold
        self.baseline_tau = baseline_tau
        self.baseline: float | None = None
        self.samples: deque[tuple[float, float, float]] = deque(maxlen=memory)  # north, east, temperature
        self._last_time: float | None = None
        self.inside = False

    def add(self, now: float, north: float, east: float, temperature: float) -> PlumeEvent | None:
        """A new sample; a ``PlumeEvent`` the first time the water is warmer than the baseline allows."""
        self.samples.append((north, east, temperature))
        if self.baseline is None:
            self.baseline, self._last_time = temperature, now
            return None
        dt = max(0.0, now - (self._last_time or now))
        self._last_time = now
        rise = temperature - self.baseline
        if not self.inside:
            self.baseline += (temperature - self.baseline) * min(1.0, dt / self.baseline_tau)
        if rise > self.threshold and not self.inside:
            self.inside = True
            return PlumeEvent(temperature, self.baseline, self.warmer_bearing())
        if rise < self.threshold / 2:
            self.inside = False
        return None

    def warmer_bearing(self) -> float | None:
        """The direction of the temperature gradient. Along a straight leg only the along-track gradient
        can be known (a cross-track fit would be noise), so: the track's main direction, signed by the
        slope of temperature along it; a plane fit T = a + b n + c e only when the track spreads in both
        directions (over a metre across)."""
        if len(self.samples) < 5:
            return None
        data = np.array(self.samples)
        xy = data[:, :2] - data[:, :2].mean(axis=0)
        spreads, axes = np.linalg.eigh(xy.T @ xy / len(xy))
        if math.sqrt(max(spreads[-1], 0.0)) < 1.0:
            return None  # it has hardly moved: no direction to speak of
        if math.sqrt(max(spreads[0], 0.0)) < 1.0:
            along = axes[:, -1]
            slope = np.polyfit(xy @ along, data[:, 2], 1)[0]
            gradient = slope * along
        else:
            design = np.column_stack([np.ones(len(data)), xy])
            gradient = np.linalg.lstsq(design, data[:, 2], rcond=None)[0][1:]
        if math.hypot(*gradient) < 1e-9:
            return None
        return math.degrees(math.atan2(gradient[1], gradient[0])) % 360.0


class Compressor:
    """Every stream through one packet encoder: a packet carries the due samples of all streams (a quiet
    one rides along). Each sample is pushed at its sensor's own time and rate; a value that is None or
    NaN (a sensor without a reading) is coded as absent, and the shore stores it as absent."""

    def __init__(
        self,
        streams: dict[Stream, StreamSpec],
        max_latency: float = 10.0,
        max_silence: float = 60.0,
        urgent_threshold: float | None = 20.0,
        protocol: int = NEWEST,
    ) -> None:
        """``protocol``: the version the vehicle speaks (``tacit.packets.VERSIONS``)."""
        self.order = list(streams)
        self.max_silence = max_silence
        self.encoder = PacketEncoder(
            list(streams.values()), max_latency, urgent_threshold, max_silence, protocol
        )
        self.samples = 0

    def add(self, stream: Stream, time: float, values: list[float | None], urgent: bool = False) -> None:
        row = [float("nan") if v is None else v for v in values]
        if self.encoder.push(self.order.index(stream), time, row, urgent=urgent):
            self.samples += 1

    def ready(self, now: float, seq: int, room: int = MAX_WINDOW) -> list[tuple[Stream, EncodedPacket]]:
        """Packets to send now, numbered from ``seq`` (the vehicle's packet counter), at most ``room`` and
        as many as the window has room for (each stays in flight until ``resolve``), with the stream
        each header names."""
        out: list[tuple[Stream, EncodedPacket]] = []
        while len(out) < room and self.encoder.ready(now):
            encoded = self.encoder.take(seq + len(out))
            out.append((Stream(encoded.packet.stream), encoded))
        return out

    def resolve(self, seq: int, delivered: bool) -> list[int]:
        """The packet numbered ``seq`` was delivered or lost for good: the seqs of the packets after it
        that are coded again (``PacketEncoder.resolve``; the caller withdraws them)."""
        return self.encoder.resolve(delivered, seq)

    @property
    def window(self) -> int:
        return self.encoder.window

    def follow(self, packets: int) -> None:
        """Keep as many packets in flight as the shore's last poll could carry (version 4; version 3
        keeps one), so a poll at a fast rate brings as much as its rate carries."""
        if self.encoder.coding.window:
            self.encoder.set_window(packets)

    def silence_said(self, checkpoint_interval: float) -> None:
        """Version 4: check-points say the silence (``predictable_until``), so when they come at least as
        often as ``max_silence`` no packet leaves only to confirm a quiet stream."""
        said = self.encoder.coding.window and checkpoint_interval <= self.max_silence
        self.encoder.policy.max_silence = (
            None if said else max(self.max_silence, self.encoder.policy.max_latency)
        )

    def predictable_until(self, now: float) -> float:
        return self.encoder.predictable_until(now)

    def in_flight(self) -> list[int]:
        """The seqs of the packets in flight."""
        return [f.seq for f in self.encoder.in_flight]

    def restart_chains(self) -> list[int]:
        """The shore lost its decoder states (its SYNC asked): the streams start again from the initial
        state, so the next packet decodes without any history (``PacketEncoder.restart``). Returns the
        seqs of the packets in flight it forgot (version 4 codes their samples again; the caller
        withdraws them; version 3 forgets its one packet when it resolves)."""
        before = self.in_flight()
        self.encoder.restart()
        kept = set(self.in_flight())
        return [q for q in before if q not in kept]
