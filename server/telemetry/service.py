"""Reading what the shore heard: pages of packets and samples, and one stream's samples for an export.
A window or a vehicle that cannot hold data is an error (404 / 422), never an empty answer."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from itertools import zip_longest
from typing import Any

from sqlalchemy import Engine

from server.backhaul import repository as relayed
from server.backhaul.models import RelayedFrame
from server.core.db import Tx, reading
from server.core.errors import Refused
from server.telemetry import clock
from server.telemetry import repository as repo
from server.telemetry.metadata import About, Dataset
from server.telemetry.models import Packet, PacketTrust, SampleRow, SampleTrust, Telemetry
from server.vehicles import service as vehicles
from tacit.codec import StreamSpec
from tacit.packets import Stream

Sample = tuple[SampleRow, SampleTrust]
Fix = tuple[float, float, float, float]  # a verified check-point: vehicle time, north, east, depth


@dataclass(frozen=True)
class Exported:
    """An export's dataset, its samples and the vehicle's check-points, each read as it is consumed."""

    dataset: Dataset
    samples: Iterator[Sample]
    fixes: Iterator[Fix]


def clock_offset(s: Tx, vehicle_id: int, *latest: tuple[float, float]) -> float | None:
    """The vehicle's clock offset (``clock.offset``) over its last verified check-points and ``latest``
    (vehicle time, shore time heard) pairs not stored yet."""
    rows = repo.checkpoints(s, vehicle_id, clock.WINDOW)
    stored = [(float(r.body["time"]), r.at) for r in rows if "time" in r.body]
    return clock.offset([*latest, *stored])


@dataclass(frozen=True)
class Window:
    """A time window (UNIX s); either end may be open."""

    since: float | None = None
    until: float | None = None

    def check(self) -> None:
        if self.since is not None and self.until is not None and self.since > self.until:
            raise Refused(f"the window starts ({self.since}) after it ends ({self.until})", "since")


class TelemetryReader:
    def __init__(self, db: Engine, streams: dict[Stream, StreamSpec], about: About) -> None:
        self.db = db
        self.about = about  # what the deployment's settings say of the exported data
        self.streams = {spec.name: spec for spec in streams.values()}

    def spec(self, stream: str) -> StreamSpec:
        if stream not in self.streams:
            raise Refused(f"no stream {stream!r}; one of {sorted(self.streams)}", "stream")
        return self.streams[stream]

    def packets(
        self, vehicle_id: int | None, kind: str | None, window: Window, limit: int, offset: int
    ) -> tuple[int, list[dict[str, Any]]]:
        """A page of packets, each with how it was heard: its frame's SNR (the best copy's) and, from a
        center, every gateway that heard the frame with its SNR, the kept copy marked."""
        window.check()
        with reading(self.db) as s:
            if vehicle_id is not None:
                vehicles.get(s, vehicle_id)
            total, rows = repo.packet_page(s, vehicle_id, kind, window.since, window.until, limit, offset)
            frames = sorted({r.frame_id for r in rows})
            snr, copies = repo.snr_of_frames(s, frames), relayed.copies_of(s, frames)
        return total, [_heard(r, snr.get(r.frame_id), copies.get(r.frame_id, [])) for r in rows]

    def samples(
        self, vehicle_id: int | None, stream: str | None, window: Window, limit: int, offset: int
    ) -> tuple[int, list[Telemetry]]:
        window.check()
        if stream is not None:
            self.spec(stream)
        with reading(self.db) as s:
            if vehicle_id is not None:
                vehicles.get(s, vehicle_id)
            return repo.sample_page(s, vehicle_id, stream, window.since, window.until, limit, offset)

    def export(self, vehicle_id: int, stream: str, window: Window, include_forged: bool = False) -> Exported:
        """What the export holds and its samples in the window with their trust, oldest first, fetched in
        pages as they are read; forged ones only if asked; the vehicle's verified check-points around it.
        The vehicle, the stream and the window are checked before anything is sent."""
        spec = self.spec(stream)
        window.check()
        with reading(self.db) as s:
            vehicle = vehicles.get(s, vehicle_id)
            span = repo.sample_span(s, vehicle_id, stream)
            said = repo.checkpoints(s, vehicle_id, 1, window.until)
        mark = said[0].body.get("predictable_until") if said else None
        if span is None:
            raise Refused(f"vehicle {vehicle_id} has sent no {stream} samples yet", "stream")
        if (window.since or span[0]) > span[1] or (
            window.until if window.until is not None else span[1]
        ) < span[0]:
            raise Refused(
                f"no {stream} samples of vehicle {vehicle_id} in the window: they span {span[0]:.3f} .. "
                f"{span[1]:.3f} (UNIX s)",
                "since",
            )

        def rows() -> Iterator[Sample]:
            with reading(self.db) as s:
                for sample, trust in whole(
                    repo.all_samples(s, vehicle_id, stream, window.since, window.until)
                ):
                    if include_forged or trust is not SampleTrust.FORGED:
                        yield sample, trust

        def fixes() -> Iterator[Fix]:
            with reading(self.db) as s:
                yield from repo.fixes(s, vehicle_id, window.since, window.until)

        return Exported(Dataset(vehicle_id, vehicle.name, spec, self.about, mark), rows(), fixes())


def whole(samples: Iterator[tuple[SampleRow, PacketTrust | None]]) -> Iterator[Sample]:
    """The samples with their trust, a sample sent in parts (``Telemetry.part``) as one row: the part's
    channels fill the ones the row before it lacks; the row is as certain and as trusted as its least."""
    held: Sample | None = None
    for row, auth in samples:
        sample = row, SampleTrust.of(row.verified, auth)
        if held is not None and row.part and row.tick == held[0].tick:
            sample = _joined(held, sample)
        elif held is not None:
            yield held
        held = sample
    if held is not None:
        yield held


def _joined(first: Sample, rest: Sample) -> Sample:
    (a, trust_a), (b, trust_b) = first, rest
    values = [x if x is not None else y for x, y in zip_longest(a.values, b.values)]
    row = a._replace(values=values, certain=a.certain and b.certain, verified=a.verified and b.verified)
    return row, max(trust_a, trust_b, key=list(SampleTrust).index)


def _heard(packet: Packet, snr: float | None, copies: list[RelayedFrame]) -> dict[str, Any]:
    """A packet's row with its frame's reception (``copies``: ``relayedframe`` rows)."""
    heard = [{"gateway": c.gateway, "snr": c.snr_in, "kept": c.kept} for c in copies]
    return {**{name: getattr(packet, name) for name in Packet.model_fields}, "snr": snr, "heard": heard}
