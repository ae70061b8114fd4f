"""The routing's request and response bodies."""

from __future__ import annotations

import math
from typing import Any

from pydantic import BaseModel, Field

from server.core.schemas import STRICT
from server.routing.service import Route


class PinIn(BaseModel):
    model_config = STRICT

    gateway: str = Field(min_length=1, max_length=64, description="the gateway to pin the vehicle to")


class Hearing(BaseModel):
    gateway: str
    frames: int = Field(description="the vehicle's frames it heard in the routing window")
    snr: float = Field(description="their mean SNR in (dB)")
    share: float = Field(description="of the vehicle's frames any gateway heard in the window")
    score: float | None = Field(description="snr + 10 log10(share) dB: the assignment compares these")
    alive: bool = Field(description="a heartbeat or event within gateway_timeout")


class RouteOut(BaseModel):
    vehicle_id: int
    vehicle: str
    address: int
    gateway: str | None = Field(description="the gateway its commands go through first")
    pinned: bool = Field(description="an operator chose it: kept whatever the scores")
    since: float | None = Field(description="when it came to this gateway (UNIX s)")
    reason: str = Field(description="why it is on this gateway (or why it did not move)")
    heard: list[Hearing]

    @classmethod
    def of(cls, route: Route, alive: set[str]) -> RouteOut:
        heard = [
            Hearing(
                gateway=g,
                frames=q.heard,
                snr=round(q.snr, 2),
                share=round(q.share, 3),
                score=round(q.score, 2) if math.isfinite(q.score) else None,
                alive=g in alive,
            )
            for g, q in sorted(route.heard.items(), key=lambda item: -item[1].score)
        ]
        vehicle = route.vehicle
        assert vehicle.id is not None
        return cls(
            vehicle_id=vehicle.id,
            vehicle=vehicle.name,
            address=vehicle.address,
            gateway=route.gateway,
            pinned=route.pinned,
            since=route.since,
            reason=route.reason,
            heard=heard,
        )


class Place(BaseModel):
    north: float = Field(description="m north of the fleet's origin")
    east: float = Field(description="m east of the fleet's origin")
    depth: float = Field(description="m")


class Outage(BaseModel):
    lasted_s: float = Field(description="how long the gateway's backhaul was down (its own account)")
    ended: float | None = Field(description="when it came back (the gateway's clock, UNIX s)")
    backlog: int | None = Field(description="messages its outbox held then, sent since")


class Assigned(BaseModel):
    id: int
    name: str
    pinned: bool = Field(description="an operator pinned it to this gateway")


class GatewayOut(BaseModel):
    """A gateway as both screens show it (``Screens.gateways``)."""

    name: str
    alive: bool = Field(description="a heartbeat or event within gateway_timeout")
    state: str = Field(description="up: its heartbeats come (sent only while its backhaul is up); silent")
    since: float = Field(
        description="up: its first heartbeat after its last silence; silent: its last (UNIX s)"
    )
    for_s: float = Field(description="how long it has been up, or silent (s)")
    first_seen: float
    last_seen: float = Field(description="its last heartbeat or event (UNIX s)")
    place: Place | None = Field(description="where its modem is (tacit gateway --position); None: not told")
    latlon: list[float] | None = Field(description="[lat, lon] of its place, the fleet's origin known")
    address: int | None = Field(description="its modem's address")
    modem: str | None = Field(description="its modem's state (ready, not_responding, ...)")
    outbox: int | None = Field(description="messages waiting to go up, at its last heartbeat")
    last_outage: Outage | None = Field(description="its last backhaul outage; None: none since it started")
    mac: dict[str, Any] | None = Field(
        description="its MAC at its last heartbeat (docs/link.md): exchanges and outcomes by kind, airtime by "
        'kind (s), late turns, why the plan in force is refused ("": it is not), and per vehicle address '
        "the range it measured, the rate of its next poll, the SNR it heard, its share and polls; None: no modem"
    )
    frames: int = Field(description="frames it relayed (every copy; the records retention keeps)")
    colour: str = Field(description="#rrggbb on both screens (server.screens.fleet)")
    vehicles: list[Assigned] = Field(description="the vehicles whose commands go through it")
    faulty: str = Field(
        description="why it is routed around: what the center could check refuted its word (an ACK the "
        "vehicle's check-points show never arrived, a command held for gateway_faulty_slots of its slots "
        "without a word); empty: it is not. Lasts gateway_quarantine s after the fault"
    )
    faulty_at: float | None = Field(description="when it was last found faulty (UNIX s); None: never")
    foreign_reports: int = Field(
        description="its reports of commands that went through another gateway: ignored, counted"
    )
