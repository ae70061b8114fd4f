"""What the operator's screens read beyond the raw data: the command form for a vehicle (fields, units,
ranges from the packet table and the vehicle's limits), what the shore knows of a vehicle and how sure
it is, and the link's airtime by use. See ``server.operator``."""

from __future__ import annotations

import time

from fastapi import APIRouter, Depends

from server import operator
from server.api.deps import Id, LinkDep, ReadSession, ShoreDep
from server.auth import require_read
from server.services import vehicles
from server.services.commands import limits_of

router = APIRouter(prefix="/api/v1", tags=["data"], dependencies=[Depends(require_read)])


@router.get("/vehicles/{vehicle_id}/form")
def command_form(vehicle_id: Id, s: ReadSession) -> dict:
    """Each command's fields with label, unit, range and hint (the packet's ranges narrowed by this
    vehicle's limits): what both the dashboard and the map's panel offer and check before sending."""
    return operator.command_form(limits_of(vehicles.get(s, vehicle_id)))


@router.get("/vehicles/{vehicle_id}/estimate")
def estimate(vehicle_id: Id, s: ReadSession, shore: ShoreDep) -> dict:
    """The last reported check-point with its age, and the shore's predicted pose since (dead reckoning
    toward the current target) with an uncertainty radius that grows with silence."""
    return operator.vehicle_estimate(s, vehicles.get(s, vehicle_id), time.time(), shore.settings.time_scale)


@router.get("/link/shares")
def link_shares(s: ReadSession, link: LinkDep, shore: ShoreDep) -> dict:
    """The link's airtime by use (commands, polls, check-points, priority data) as seconds and shares,
    and the bits saved against sending every sample; counted from the database, polls since start."""
    channels = {spec.name: len(spec.channels) for spec in shore.ingest.streams.values()}
    return operator.shares_from_db(s, int(link.counters["polls"]), channels)
