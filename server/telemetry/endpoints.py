"""Packets and reconstructed telemetry: JSON pages, and CSV, Parquet and NetCDF exports of one stream."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Query
from fastapi.responses import StreamingResponse

from server.api.deps import Offset, OptionalId, QueryId, TelemetryDep, require_read
from server.core.schemas import Page
from server.telemetry import export, metadata
from server.telemetry.metadata import Dataset
from server.telemetry.schemas import PacketOut, TelemetryOut
from server.telemetry.service import Exported, Window
from tacit.streams import UNITS

router = APIRouter(prefix="/api/v1", tags=["data"], dependencies=[Depends(require_read)])


@router.get("/packets", response_model=Page[PacketOut])
def packets(
    reader: TelemetryDep,
    vehicle_id: OptionalId = None,
    type: str | None = Query(None, pattern="^(checkpoint|priority)$"),
    since: float | None = None,
    until: float | None = None,
    limit: int = Query(100, ge=1, le=1000),
    offset: Offset = 0,
) -> Page[PacketOut]:
    """Vehicle packets, newest first, with their trust (``auth``) and how their frame was heard: its SNR
    and, from a center, each gateway that heard it with its SNR (the kept copy marked)."""
    total, rows = reader.packets(vehicle_id, type, Window(since, until), limit, offset)
    return Page(
        total=total,
        limit=limit,
        offset=offset,
        items=[PacketOut.model_validate(r) for r in rows],
    )


@router.get("/telemetry", response_model=Page[TelemetryOut])
def telemetry(
    reader: TelemetryDep,
    vehicle_id: OptionalId = None,
    stream: str | None = None,
    since: float | None = None,
    until: float | None = None,
    limit: int = Query(500, ge=1, le=5000),
    offset: Offset = 0,
) -> Page[TelemetryOut]:
    """Reconstructed samples, one row per tick; ``certain`` false marks a span the shore cannot vouch for."""
    total, rows = reader.samples(vehicle_id, stream, Window(since, until), limit, offset)
    return Page(
        total=total,
        limit=limit,
        offset=offset,
        items=[TelemetryOut.model_validate(r, from_attributes=True) for r in rows],
    )


EXPORT_DOC = f"""Reconstructed samples of one vehicle's stream (``imu`` or ``env``), oldest first: ``time`` (UNIX s,
UTC), ``tick`` (the codec's tick number; ``time`` is what dates a sample, within half the stream's
period: the tick grid follows the sensor's clock), ``certain`` (false: a lost span the shore cannot vouch
for), ``verification`` ({metadata.VERIFICATION}), one column per channel; an absent value is empty (CSV),
null (Parquet) or NaN, the ``_FillValue`` (NetCDF).

Units (UDUNITS spellings, as CF wants them): {", ".join(f"{c} {metadata.units(c)}" for c in UNITS)}.
A value is within its channel's error bound eps (same units) of what the sensor read where ``certain``:
the ``Tacit-Error-Bounds`` response header gives each channel's (``temperature=0.05, ...``); Parquet and
NetCDF also carry units, eps, the vehicle, the stream and its period in their metadata; the CSV header
names each column with its units, ``depth (m)`` (ERDDAP's ``.csvp`` form).

``since`` / ``until`` (UNIX s) select a time window, e.g. a mission's. An unknown vehicle is a 404; an
unknown stream, an inverted window or one that holds none of the stream's samples a 422 that says where
its samples are."""


def _headers(d: Dataset, suffix: str) -> dict[str, str]:
    said = {} if d.predictable_until is None else {"Tacit-Predictable-Until": f"{d.predictable_until:.0f}"}
    return {
        "Content-Disposition": f"attachment; filename={d.spec.name}-{d.vehicle_id}.{suffix}",
        "Tacit-Error-Bounds": metadata.error_bounds(d.spec),
        **said,
    }


def exported(
    reader: TelemetryDep,
    vehicle_id: QueryId,
    stream: str,
    since: float | None = None,
    until: float | None = None,
    include_forged: Annotated[bool, Query(description="also the samples of forged packets")] = False,
) -> Exported:
    """What every export route takes and checks (404 / 422 before anything is sent), and the samples."""
    return reader.export(vehicle_id, stream, Window(since, until), include_forged)


Export = Annotated[Exported, Depends(exported)]


@router.get(
    "/telemetry.csv",
    response_class=StreamingResponse,
    description=EXPORT_DOC,
    responses={200: {"content": {"text/csv": {}}}},
)
def telemetry_csv(out: Export) -> StreamingResponse:
    d = out.dataset
    return StreamingResponse(
        export.csv_lines(d, out.samples), media_type="text/csv", headers=_headers(d, "csv")
    )


@router.get(
    "/telemetry.parquet",
    response_class=StreamingResponse,
    description=EXPORT_DOC,
    responses={200: {"content": {export.PARQUET: {}}}},
)
def telemetry_parquet(out: Export) -> StreamingResponse:
    """The same as ``telemetry.csv`` as an Apache Parquet file (typed columns: float64 channels, null where
    absent), for pandas, polars, DuckDB or R's arrow."""
    d = out.dataset
    return StreamingResponse(
        export.parquet(d, out.samples), media_type=export.PARQUET, headers=_headers(d, "parquet")
    )


@router.get(
    "/telemetry.nc",
    response_class=StreamingResponse,
    description=EXPORT_DOC,
    responses={200: {"content": {export.NETCDF: {}}}},
)
def telemetry_netcdf(out: Export) -> StreamingResponse:
    """The same as ``telemetry.csv`` as a NetCDF file following the CF conventions (CF-1.8, a trajectory)
    with the ACDD-1.3 discovery attributes (the deployment's settings, the time covered, and with the
    fleet's origin known, each row's latitude and longitude and the area covered), for xarray, the IOOS
    tools or Panoply."""
    d = out.dataset
    return StreamingResponse(
        export.netcdf(d, out.samples, out.fixes), media_type=export.NETCDF, headers=_headers(d, "nc")
    )
