"""Packets, reconstructed telemetry (JSON pages, CSV and Parquet export), link status, the live event stream."""

from __future__ import annotations

import asyncio
import csv
import io
from collections.abc import AsyncIterator, Iterator

from fastapi import APIRouter, Depends, Query
from fastapi.responses import Response, StreamingResponse
from sqlalchemy import func
from sqlmodel import Session, col, select

from server.api.deps import BusDep, LinkDep, Offset, OptionalId, QueryId, ReadSession, ShoreDep
from server.auth import require_read
from server.errors import Refused
from server.models import Packet, Telemetry
from server.schemas import PacketOut, Page, TelemetryOut
from server.shore import Shore

router = APIRouter(prefix="/api/v1", tags=["data"])


def _page(s: Session, query, limit: int, offset: int, model) -> Page:
    total = s.exec(select(func.count()).select_from(query.subquery())).one()
    rows = s.exec(query.offset(offset).limit(limit)).all()
    return Page(
        total=total,
        limit=limit,
        offset=offset,
        items=[model.model_validate(r, from_attributes=True) for r in rows],
    )


@router.get("/packets", response_model=Page, dependencies=[Depends(require_read)])
def packets(s: ReadSession, vehicle_id: OptionalId = None,
            type: str | None = Query(None, pattern="^(checkpoint|priority)$"), since: float | None = None,
            until: float | None = None, limit: int = Query(100, ge=1, le=1000), offset: Offset = 0) -> Page:  # fmt: skip
    query = _filtered(select(Packet).order_by(col(Packet.id).desc()), Packet.vehicle_id, Packet.at,
                      vehicle_id, since, until)  # fmt: skip
    if type is not None:
        query = query.where(Packet.type == type)
    return _page(s, query, limit, offset, PacketOut)


def _filtered(
    query, vehicle_column, time_column, vehicle_id: int | None, since: float | None, until: float | None
):
    """The filters every data route shares: one vehicle, a time window."""
    if vehicle_id is not None:
        query = query.where(vehicle_column == vehicle_id)
    if since is not None:
        query = query.where(time_column >= since)
    if until is not None:
        query = query.where(time_column <= until)
    return query


def _telemetry_query(vehicle_id: int | None, stream: str | None, since: float | None, until: float | None):
    query = _filtered(select(Telemetry).order_by(col(Telemetry.time)), Telemetry.vehicle_id, Telemetry.time,
                      vehicle_id, since, until)  # fmt: skip
    return query.where(Telemetry.stream == stream) if stream is not None else query


@router.get("/telemetry", response_model=Page, dependencies=[Depends(require_read)])
def telemetry(s: ReadSession, vehicle_id: OptionalId = None, stream: str | None = None,
              since: float | None = None, until: float | None = None, limit: int = Query(500, ge=1, le=5000),
              offset: Offset = 0) -> Page:  # fmt: skip
    """Reconstructed samples, one row per tick; ``certain`` false marks a span the shore cannot vouch for."""
    return _page(s, _telemetry_query(vehicle_id, stream, since, until), limit, offset, TelemetryOut)


EXPORT_ROWS = 5000  # rows per database fetch and per Parquet row group


def _export(shore: Shore, vehicle_id: int, stream: str, since: float | None, until: float | None):
    """The channels of ``stream`` and the rows to export, oldest first, fetched in pages."""
    streams = {spec.name: spec for spec in shore.ingest.streams.values()}
    if stream not in streams:
        raise Refused(f"no stream {stream!r}; one of {sorted(streams)}", "stream")
    channels = streams[stream].channels
    query = _telemetry_query(vehicle_id, stream, since, until).execution_options(yield_per=EXPORT_ROWS)

    def rows() -> Iterator[tuple[float, int, bool, list]]:
        """(time, tick, certain, one value per channel: None where the sample is absent)."""
        with Session(shore.db) as s:
            for row in s.exec(query):
                values = list(row.values or [])[: len(channels)]
                yield row.time, row.tick, row.certain, values + [None] * (len(channels) - len(values))

    return channels, rows


EXPORT_DOC = """Reconstructed samples of one vehicle's stream (``imu`` or ``env``), oldest first: ``time`` (UNIX s),
``tick`` (the codec's tick number; ``time`` is what dates a sample, within half the stream's period:
the tick grid follows the sensor's clock), ``certain`` (false: a lost span the shore cannot vouch
for), one column per channel; an absent sample is empty. ``since`` / ``until`` (UNIX s) select a time window, e.g. a mission's."""


@router.get("/telemetry.csv", dependencies=[Depends(require_read)], response_class=StreamingResponse,
            description=EXPORT_DOC)  # fmt: skip
def telemetry_csv(shore: ShoreDep, vehicle_id: QueryId, stream: str, since: float | None = None,
                  until: float | None = None) -> StreamingResponse:  # fmt: skip
    channels, rows = _export(shore, vehicle_id, stream, since, until)

    def lines() -> Iterator[str]:
        out = io.StringIO()
        writer = csv.writer(out)
        writer.writerow(["time", "tick", "certain", *channels])
        for n, (at, tick, certain, values) in enumerate(rows()):
            writer.writerow([at, tick, int(certain), *values])  # None: an empty cell
            if n % 1000 == 999:
                yield out.getvalue()
                out.seek(0)
                out.truncate()
        yield out.getvalue()

    return StreamingResponse(lines(), media_type="text/csv",
                             headers={"Content-Disposition": f"attachment; filename={stream}-{vehicle_id}.csv"})  # fmt: skip


PARQUET = "application/vnd.apache.parquet"


@router.get("/telemetry.parquet", dependencies=[Depends(require_read)], response_class=Response,
            responses={200: {"content": {PARQUET: {}}}}, description=EXPORT_DOC)  # fmt: skip
def telemetry_parquet(shore: ShoreDep, vehicle_id: QueryId, stream: str, since: float | None = None,
                      until: float | None = None) -> Response:  # fmt: skip
    """The same as ``telemetry.csv`` as an Apache Parquet file (typed columns: float64 channels, null where
    absent), for pandas, polars, DuckDB or R's arrow."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    channels, rows = _export(shore, vehicle_id, stream, since, until)
    schema = pa.schema([("time", pa.float64()), ("tick", pa.int64()), ("certain", pa.bool_()),
                        *((name, pa.float64()) for name in channels)])  # fmt: skip
    sink = io.BytesIO()
    with pq.ParquetWriter(sink, schema, compression="zstd") as writer:
        for chunk in _chunks(rows(), EXPORT_ROWS):
            columns = list(
                zip(*((at, tick, certain, *values) for at, tick, certain, values in chunk), strict=True)
            )
            writer.write_table(pa.Table.from_arrays([pa.array(c, f.type) for c, f in zip(columns, schema, strict=True)],
                                                    schema=schema))  # fmt: skip
    return Response(sink.getvalue(), media_type=PARQUET,
                    headers={"Content-Disposition": f"attachment; filename={stream}-{vehicle_id}.parquet"})  # fmt: skip


def _chunks(items: Iterator, size: int) -> Iterator[list]:
    chunk: list = []
    for item in items:
        chunk.append(item)
        if len(chunk) == size:
            yield chunk
            chunk = []
    if chunk:
        yield chunk


@router.get("/link", dependencies=[Depends(require_read)])
def link_status(link: LinkDep) -> dict:
    """The shore modem's state and, per vehicle: last heard, SNR, range, packets per hour, bytes saved."""
    return link.status()


@router.get("/events", dependencies=[Depends(require_read)])
async def events(bus: BusDep) -> StreamingResponse:
    """Server-sent events (packet, command, telemetry, link, vehicle), authenticated by the Authorization
    header like every other route: a token in a URL would end up in access logs. (Browsers read this
    stream with ``fetch``, which can send the header, rather than ``EventSource``, which cannot.)"""
    queue = bus.subscribe()

    async def stream() -> AsyncIterator[str]:
        try:
            yield ": connected\n\n"
            while True:
                try:
                    event = await asyncio.wait_for(queue.get(), 15)
                    yield bus.sse(event)
                except TimeoutError:
                    yield ": keep-alive\n\n"
        finally:
            bus.unsubscribe(queue)

    return StreamingResponse(stream(), media_type="text/event-stream", headers={"Cache-Control": "no-cache"})
