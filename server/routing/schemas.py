"""The routing's request and response bodies."""

from __future__ import annotations

import math

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


class GatewayOut(BaseModel):
    name: str
    first_seen: float
    last_seen: float = Field(description="its last heartbeat or event (the center's clock, UNIX s)")
    alive: bool
