"""The SQL of what the shore heard: frames, vehicle packets with their trust, reconstructed samples."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any

from sqlalchemy import ColumnElement, delete, func, insert, text, update
from sqlalchemy import select as sa_select
from sqlmodel import Session, SQLModel, col, select
from sqlmodel.sql.expression import SelectOfScalar

from server.telemetry.models import Frame, Packet, PacketTrust, SampleRow, Telemetry
from tacit.packets import PACKET_SIZE

EXPORT_ROWS = 5000  # rows per database fetch of an export
FIX_MARGIN = 600.0  # s: check-points this far outside an export's window still place its first and last rows


def add_frame(s: Session, row: dict[str, Any]) -> int:
    return int(s.execute(insert(Frame).returning(col(Frame.id)), [row]).scalar_one())


def reserve_ids(s: Session, table: type[SQLModel], n: int) -> list[int]:
    """``n`` ids for rows of ``table`` this transaction inserts later with their ids. PostgreSQL: from the
    id's sequence (never handed out twice; the unused ones are gaps, as a rollback leaves). SQLite: after
    the largest id, which no one else can add to before this transaction ends (``writing`` begins
    IMMEDIATE: it holds the database's write lock)."""
    if n <= 0:
        return []
    name = str(table.__tablename__)
    if s.get_bind().dialect.name == "postgresql":
        query = text("SELECT nextval(pg_get_serial_sequence(:name, 'id')) FROM generate_series(1, :n)")
        return [int(i) for i in s.execute(query, {"name": name, "n": n}).scalars()]
    top = s.execute(text(f"SELECT coalesce(max(id), 0) FROM {name}")).scalar_one()
    return list(range(int(top) + 1, int(top) + n + 1))


def add_frame_rows(s: Session, rows: list[dict[str, Any]]) -> None:
    """Frames with their ids (``reserve_ids``), in one statement."""
    if rows:
        s.execute(insert(Frame), rows)


def add_packet_rows(s: Session, rows: list[dict[str, Any]]) -> None:
    """Packets with their ids (``reserve_ids``), in one statement."""
    if rows:
        s.execute(insert(Packet), rows)


def decoded_later(s: Session, rows: list[dict[str, Any]]) -> None:
    """Stored packets decoded after they were stored: each row's ``id``, new ``body`` and ``origin``."""
    if rows:
        s.execute(update(Packet), rows)


def decoded_frames(s: Session, frame_ids: Sequence[int], chunk: int = 500) -> set[int]:
    """Of the frames, those with packets, none of them left undecoded (an ``error`` in its body)."""
    bodies: dict[int, list[dict[str, Any]]] = {}
    for i in range(0, len(frame_ids), chunk):
        query = sa_select(col(Packet.frame_id), col(Packet.body)).where(
            col(Packet.frame_id).in_(frame_ids[i : i + chunk])
        )
        for frame_id, body in s.execute(query).all():
            bodies.setdefault(int(frame_id), []).append(body)
    return {f for f, packets in bodies.items() if not any("error" in body for body in packets)}


RESEND_LOOKBACK = 2000  # frame ids: a retransmission comes within this many frames of the first copy


def resent_frames(s: Session, frame_ids: Sequence[int], chunk: int = 500) -> set[int]:
    """Of the incoming frames, those that only carried packets an earlier frame of the same vehicle
    carried, within ``RESEND_LOOKBACK`` frames: a retransmission (the vehicle did not get the shore
    modem's ACK), whose packets the decoder dropped as duplicates."""
    ids = sorted(set(frame_ids))
    by_src: dict[int, list[int]] = {}
    for i in range(0, len(ids), chunk):
        query = sa_select(col(Frame.src), col(Frame.id)).where(col(Frame.id).in_(ids[i : i + chunk]))
        for src, frame_id in s.execute(query).all():
            by_src.setdefault(int(src), []).append(int(frame_id))
    out: set[int] = set()
    for src, wanted in by_src.items():
        for low, high in _windows(sorted(wanted)):
            out |= _resent_in(s, src, low, high, set(wanted))
    return out


def _windows(wanted: list[int]) -> list[tuple[int, int]]:
    """The id spans to read for these frames: each with the lookback before it, overlapping ones merged."""
    spans: list[tuple[int, int]] = []
    for frame_id in wanted:
        low = frame_id - RESEND_LOOKBACK
        if spans and low <= spans[-1][1]:
            spans[-1] = (spans[-1][0], frame_id)
        else:
            spans.append((low, frame_id))
    return spans


def _resent_in(s: Session, src: int, low: int, high: int, wanted: set[int]) -> set[int]:
    seen: set[bytes] = set()
    out: set[int] = set()
    query = sa_select(col(Frame.id), col(Frame.data)).where(
        col(Frame.id).between(low, high), col(Frame.src) == src, col(Frame.direction) == "in"
    )
    for frame_id, data in s.execute(query.order_by(col(Frame.id))).all():
        chunks = {
            bytes(data[i : i + PACKET_SIZE]) for i in range(0, len(data) - PACKET_SIZE + 1, PACKET_SIZE)
        }
        if frame_id in wanted and chunks and chunks <= seen:
            out.add(int(frame_id))
        seen |= chunks
    return out


def packet_states(s: Session, packet_ids: Sequence[int]) -> dict[int, dict[str, Any]]:
    """Each stored packet's ``body``, ``origin``, ``auth`` and ``trusted``, by id (columns, not objects:
    a batch reads hundreds)."""
    if not packet_ids:
        return {}
    columns = sa_select(col(Packet.id), col(Packet.body), col(Packet.origin), col(Packet.auth),
                        col(Packet.trusted))  # fmt: skip
    rows = s.execute(columns.where(col(Packet.id).in_(packet_ids))).all()
    return {
        int(i): {"body": body, "origin": origin, "auth": PacketTrust(auth), "trusted": bool(trusted)}
        for i, body, origin, auth, trusted in rows
    }


def frames_from(s: Session, src: int, after: int) -> list[Frame]:
    """The frames received from modem address ``src`` after frame id ``after``, oldest first."""
    query = select(Frame).where(Frame.direction == "in", Frame.src == src, col(Frame.id) > after)
    return list(s.exec(query.order_by(col(Frame.id))).all())


def packets_of_frames(s: Session, frame_ids: Sequence[int]) -> dict[tuple[int, int, str], int]:
    """The packets stored from the frames: (frame id, seq, type) -> packet id."""
    if not frame_ids:
        return {}
    query = select(Packet.frame_id, Packet.seq, Packet.type, Packet.id).where(
        col(Packet.frame_id).in_(frame_ids)
    )
    return {(int(f), int(seq), str(kind)): int(i) for f, seq, kind, i in s.exec(query).all() if i is not None}


def last_frame_id(s: Session) -> int:
    return int(s.exec(select(func.max(Frame.id))).one() or 0)


def _strangers(known: Sequence[int]) -> SelectOfScalar[Any]:
    """The ids of frames received from modem addresses not in ``known``."""
    return select(Frame.id).where(Frame.direction == "in", col(Frame.src).not_in(known))


def count_strangers(s: Session, known: Sequence[int]) -> int:
    return int(s.exec(select(func.count()).select_from(_strangers(known).subquery())).one())


def drop_strangers(s: Session, known: Sequence[int], n: int, after: int) -> list[int]:
    """Delete the ``n`` oldest frames from unknown addresses (those after id ``after``: older ones are gone
    already); their ids."""
    query = _strangers(known).where(col(Frame.id) > after).order_by(col(Frame.id)).limit(n)
    ids = [i for i in s.exec(query) if i is not None]
    if ids:
        s.execute(delete(Frame).where(col(Frame.id).in_(ids)))
    return ids


def add_frames(s: Session, *frames: Frame) -> None:
    s.add_all(frames)


def add_packet(s: Session, row: dict[str, Any]) -> int:
    return int(s.execute(insert(Packet).returning(col(Packet.id)), [row]).scalar_one())


def add_samples(s: Session, rows: list[dict[str, Any]]) -> None:
    if rows:
        s.execute(insert(Telemetry), rows)


def set_trust(s: Session, packet_ids: Sequence[int], trust: PacketTrust) -> None:
    if packet_ids:
        s.execute(update(Packet).where(col(Packet.id).in_(packet_ids)).values(auth=trust.value))


def trust_data(s: Session, packet_ids: Sequence[int]) -> None:
    """The packets' data may be believed: they and their samples are marked so."""
    if packet_ids:
        s.execute(update(Packet).where(col(Packet.id).in_(packet_ids)).values(trusted=True))
        s.execute(update(Telemetry).where(col(Telemetry.packet_id).in_(packet_ids)).values(verified=True))


def checkpoints(s: Session, vehicle_id: int, n: int = 1, until: float | None = None) -> list[Packet]:
    """The vehicle's last ``n`` verified check-points, newest first by when they were heard (a late one,
    stored after newer ones, takes its place among them), received at or before ``until``."""
    query = select(Packet).where(
        Packet.vehicle_id == vehicle_id, Packet.type == "checkpoint", Packet.auth == PacketTrust.VERIFIED
    )
    if until is not None:
        query = query.where(Packet.at <= until)
    return list(s.exec(query.order_by(col(Packet.at).desc(), col(Packet.id).desc()).limit(n)).all())


def checkpoint_stored(s: Session, vehicle_id: int, body: dict[str, Any]) -> bool:
    """Whether the vehicle's check-point ``body`` (the same seq, time and MAC) was stored and verified
    before."""
    query = select(Packet.body).where(
        Packet.vehicle_id == vehicle_id, Packet.type == "checkpoint", Packet.seq == body["seq"],
        Packet.auth == PacketTrust.VERIFIED,
    )  # fmt: skip
    return any(b.get("mac") == body["mac"] and b.get("time") == body["time"] for b in s.exec(query))


def _window(
    vehicle_column: Any, time_column: Any, vehicle_id: int | None, since: float | None, until: float | None
) -> list[ColumnElement[bool]]:
    """The filters every data query shares: one vehicle, a time window."""
    return [
        *([vehicle_column == vehicle_id] if vehicle_id is not None else []),
        *([time_column >= since] if since is not None else []),
        *([time_column <= until] if until is not None else []),
    ]


def _page(s: Session, query: SelectOfScalar[Any], limit: int, offset: int) -> tuple[int, list[Any]]:
    total = s.exec(select(func.count()).select_from(query.subquery())).one()
    return int(total), list(s.exec(query.offset(offset).limit(limit)).all())


def packet_page(
    s: Session,
    vehicle_id: int | None,
    kind: str | None,
    since: float | None,
    until: float | None,
    limit: int,
    offset: int,
) -> tuple[int, list[Packet]]:
    query = select(Packet).where(*_window(Packet.vehicle_id, Packet.at, vehicle_id, since, until))
    query = query.order_by(col(Packet.id).desc())
    if kind is not None:
        query = query.where(Packet.type == kind)
    return _page(s, query, limit, offset)


def snr_of_frames(s: Session, frame_ids: Sequence[int]) -> dict[int, float | None]:
    """The frames' SNR in (dB; the kept copy's, for a frame several gateways heard), by frame id."""
    if not frame_ids:
        return {}
    query = select(Frame.id, Frame.snr_in).where(col(Frame.id).in_(frame_ids))
    return {int(i): snr for i, snr in s.exec(query) if i is not None}


def _samples(
    vehicle_id: int | None, stream: str | None, since: float | None, until: float | None
) -> SelectOfScalar[Telemetry]:
    query = select(Telemetry).where(*_window(Telemetry.vehicle_id, Telemetry.time, vehicle_id, since, until))
    query = query.order_by(col(Telemetry.time))
    return query.where(Telemetry.stream == stream) if stream is not None else query


def sample_page(
    s: Session,
    vehicle_id: int | None,
    stream: str | None,
    since: float | None,
    until: float | None,
    limit: int,
    offset: int,
) -> tuple[int, list[Telemetry]]:
    return _page(s, _samples(vehicle_id, stream, since, until), limit, offset)


_EXPORTED: tuple[Any, ...] = (
    Telemetry.time, Telemetry.tick, Telemetry.values, Telemetry.certain, Telemetry.verified, Telemetry.part,
    Packet.auth,
)  # fmt: skip


def all_samples(
    s: Session, vehicle_id: int, stream: str, since: float | None, until: float | None
) -> Iterator[tuple[SampleRow, PacketTrust | None]]:
    """Every sample in the window with its packet's trust (None: no packet on record), oldest first (the
    samples of one tick in the order they were stored: measured), fetched ``EXPORT_ROWS`` at a time."""
    query = (
        sa_select(*_EXPORTED)
        .outerjoin(Packet, col(Telemetry.packet_id) == Packet.id)
        .where(
            col(Telemetry.stream) == stream,
            *_window(Telemetry.vehicle_id, Telemetry.time, vehicle_id, since, until),
        )
        .order_by(col(Telemetry.time), col(Telemetry.id))
    )
    for time, tick, values, certain, verified, part, auth in s.execute(
        query.execution_options(yield_per=EXPORT_ROWS)
    ):
        trust = None if auth is None else PacketTrust(auth)
        yield SampleRow(time, tick, values, certain, verified, part), trust


def sample_span(s: Session, vehicle_id: int, stream: str) -> tuple[float, float] | None:
    """The first and last sample times of a vehicle's stream (None: no sample yet)."""
    query = select(func.min(Telemetry.time), func.max(Telemetry.time)).where(
        Telemetry.vehicle_id == vehicle_id, Telemetry.stream == stream
    )
    first, last = s.exec(query).one()
    return None if first is None else (float(first), float(last))


def frames_sent(s: Session) -> int:
    return int(s.exec(select(func.count()).select_from(Frame).where(Frame.direction == "out")).one())


def packets_by_type(s: Session) -> dict[str, int]:
    return {kind: int(n) for kind, n in s.exec(select(Packet.type, func.count()).group_by(Packet.type)).all()}


def frames_sent_by_dest(s: Session) -> dict[int, int]:
    """Frames the shore sent, by the modem address they went to."""
    query = select(Frame.dest, func.count()).where(Frame.direction == "out").group_by(col(Frame.dest))
    return {int(dest): int(n) for dest, n in s.exec(query).all()}


def packets_by_vehicle_and_type(s: Session) -> dict[tuple[int, str], int]:
    """Vehicle packets stored, by (vehicle id, type)."""
    query = select(Packet.vehicle_id, Packet.type, func.count()).group_by(
        col(Packet.vehicle_id), col(Packet.type)
    )
    return {(int(vehicle), kind): int(n) for vehicle, kind, n in s.exec(query).all() if vehicle is not None}


def certain_ticks_by_stream(s: Session) -> dict[str, int]:
    query = (
        select(Telemetry.stream, func.count())
        .where(col(Telemetry.certain).is_(True))
        .group_by(Telemetry.stream)
    )
    return {stream: int(n) for stream, n in s.exec(query).all()}


def fixes(
    s: Session, vehicle_id: int, since: float | None, until: float | None
) -> Iterator[tuple[float, float, float, float]]:
    """The vehicle's verified check-points heard within the window (UNIX s, ``FIX_MARGIN`` s wider either
    side) as (vehicle time, north, east, depth), in the order heard, fetched ``EXPORT_ROWS`` at a time."""
    query = select(Packet.body).where(
        Packet.vehicle_id == vehicle_id, Packet.type == "checkpoint", Packet.auth == PacketTrust.VERIFIED
    )
    if since is not None:
        query = query.where(col(Packet.at) >= since - FIX_MARGIN)
    if until is not None:
        query = query.where(col(Packet.at) <= until + FIX_MARGIN)
    for body in s.exec(
        query.order_by(col(Packet.at), col(Packet.id)).execution_options(yield_per=EXPORT_ROWS)
    ):
        if all(k in body for k in ("time", "north", "east", "depth")):
            yield float(body["time"]), float(body["north"]), float(body["east"]), float(body["depth"])
