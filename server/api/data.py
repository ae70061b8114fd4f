"""Packets, reconstructed telemetry (JSON pages and CSV export), link status, the live event stream."""

from __future__ import annotations

import asyncio
import csv
import io
from collections.abc import AsyncIterator, Iterator

from fastapi import APIRouter, Depends, Query
from fastapi.responses import StreamingResponse
from sqlalchemy import func
from sqlmodel import Session, select

from server.api.deps import BusDep, LinkDep, Offset, OptionalId, QueryId, ReadSession, ShoreDep
from server.auth import require_read
from server.errors import Refused
from server.models import Packet, Telemetry
from server.schemas import PacketOut, Page, TelemetryOut

router = APIRouter(prefix="/api/v1", tags=["data"])


def _page(s: Session, query, limit: int, offset: int, model) -> Page:  # noqa: ANN001
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
    query = _filtered(select(Packet).order_by(Packet.id.desc()), Packet.vehicle_id, Packet.at,  # type: ignore[union-attr]
                      vehicle_id, since, until)  # fmt: skip
    if type is not None:
        query = query.where(Packet.type == type)
    return _page(s, query, limit, offset, PacketOut)


def _filtered(
    query, vehicle_column, time_column, vehicle_id: int | None, since: float | None, until: float | None
):  # noqa: ANN001, ANN202  (a select and its columns)
    """The filters every data route shares: one vehicle, a time window."""
    if vehicle_id is not None:
        query = query.where(vehicle_column == vehicle_id)
    if since is not None:
        query = query.where(time_column >= since)
    if until is not None:
        query = query.where(time_column <= until)
    return query


def _telemetry_query(vehicle_id: int | None, stream: str | None, since: float | None, until: float | None):  # noqa: ANN202
    query = _filtered(select(Telemetry).order_by(Telemetry.time), Telemetry.vehicle_id, Telemetry.time,
                      vehicle_id, since, until)  # fmt: skip
    return query.where(Telemetry.stream == stream) if stream is not None else query


@router.get("/telemetry", response_model=Page, dependencies=[Depends(require_read)])
def telemetry(s: ReadSession, vehicle_id: OptionalId = None, stream: str | None = None,
              since: float | None = None, until: float | None = None, limit: int = Query(500, ge=1, le=5000),
              offset: Offset = 0) -> Page:  # fmt: skip
    """Reconstructed samples, one row per tick; ``certain`` false marks a span the shore cannot vouch for."""
    return _page(s, _telemetry_query(vehicle_id, stream, since, until), limit, offset, TelemetryOut)


@router.get("/telemetry.csv", dependencies=[Depends(require_read)], response_class=StreamingResponse)
def telemetry_csv(shore: ShoreDep, vehicle_id: QueryId, stream: str, since: float | None = None,
                  until: float | None = None) -> StreamingResponse:  # fmt: skip
    streams = {spec.name: spec for spec in shore.ingest.streams.values()}
    if stream not in streams:
        raise Refused(f"no stream {stream!r}; one of {sorted(streams)}", "stream")
    channels = streams[stream].channels
    query = _telemetry_query(vehicle_id, stream, since, until)

    def rows() -> Iterator[str]:
        out = io.StringIO()
        writer = csv.writer(out)
        writer.writerow(["time", "tick", "certain", *channels])
        with Session(shore.db) as s:
            for row in s.exec(query.execution_options(yield_per=1000)):
                writer.writerow([row.time, row.tick, int(row.certain), *(row.values or [""] * len(channels))])
                yield out.getvalue()
                out.seek(0)
                out.truncate()
        yield out.getvalue()

    return StreamingResponse(rows(), media_type="text/csv",
                             headers={"Content-Disposition": f"attachment; filename={stream}-{vehicle_id}.csv"})  # fmt: skip


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
