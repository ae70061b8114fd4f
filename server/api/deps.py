"""Typed route dependencies: the shore's services (``server.shore.Shore``), the caller (an ``Actor``: name
and role) from its bearer token, and the bounded id and offset parameters every route shares."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Path, Query, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from server.commands.service import CommandDesk
from server.core.config import Settings
from server.core.errors import Forbidden, TooMany, Unauthorized, raises
from server.core.events import Bus
from server.core.schemas import DB_INT_MAX
from server.core.security import Actor, Role, Throttle, open_reads
from server.link.engine import LinkEngine
from server.missions.service import Missions
from server.missions.teams import Teams
from server.operators.service import Operators
from server.routing.service import Routing
from server.safety.service import Separation
from server.screens.service import Screens
from server.shore import Shore
from server.telemetry.service import TelemetryReader
from server.vehicles.service import Vehicles


def shore(request: Request) -> Shore:
    return request.app.state.shore


ShoreDep = Annotated[Shore, Depends(shore)]


def settings(shore: ShoreDep) -> Settings:
    return shore.settings


SettingsDep = Annotated[Settings, Depends(settings)]


def _vehicles(shore: ShoreDep) -> Vehicles:
    return shore.vehicles


def _commands(shore: ShoreDep) -> CommandDesk:
    return shore.commands


def _missions(shore: ShoreDep) -> Missions:
    return shore.missions


def _teams(shore: ShoreDep) -> Teams:
    return shore.teams


def _safety(shore: ShoreDep) -> Separation:
    return shore.safety


def _telemetry(shore: ShoreDep) -> TelemetryReader:
    return shore.telemetry


def _screens(shore: ShoreDep) -> Screens:
    return shore.screens


def _link(shore: ShoreDep) -> LinkEngine:
    return shore.link


def _bus(shore: ShoreDep) -> Bus:
    return shore.bus


def _operators(shore: ShoreDep) -> Operators:
    return shore.operators


def _routing(shore: ShoreDep) -> Routing:
    return shore.routing


def _sign_ins(shore: ShoreDep) -> Throttle:
    return shore.sign_ins


VehiclesDep = Annotated[Vehicles, Depends(_vehicles)]
CommandsDep = Annotated[CommandDesk, Depends(_commands)]
MissionsDep = Annotated[Missions, Depends(_missions)]
TeamsDep = Annotated[Teams, Depends(_teams)]
SafetyDep = Annotated[Separation, Depends(_safety)]
TelemetryDep = Annotated[TelemetryReader, Depends(_telemetry)]
ScreensDep = Annotated[Screens, Depends(_screens)]
LinkDep = Annotated[LinkEngine, Depends(_link)]
BusDep = Annotated[Bus, Depends(_bus)]
OperatorsDep = Annotated[Operators, Depends(_operators)]
RoutingDep = Annotated[Routing, Depends(_routing)]
SignInsDep = Annotated[Throttle, Depends(_sign_ins)]

bearer = HTTPBearer(
    auto_error=False,
    description="Authorization: Bearer <token>. Operators' tokens may "
    "write (commands, missions, vehicles); observers' tokens only read.",
)
Credentials = Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)]
BENCH = Actor("bench", Role.WRITE)  # the caller when no tokens are configured (reads only: writes need one)


def _actor(
    shore: Shore, request: Request, credentials: HTTPAuthorizationCredentials | None, needed: str
) -> Actor:
    """The caller; a missing token, a wrong one and an expired or revoked one (``Unauthorized``, saying
    when) are told apart; too many wrong ones from the caller's address are refused (``Throttle``)."""
    if credentials is None:
        raise Unauthorized(f"{needed} is required: send Authorization: Bearer <token>")
    client = request.client.host if request.client else "unknown"
    found = shore.sign_ins.actor(credentials.credentials, client)
    if found is None:
        raise Unauthorized("this token is not accepted here (mistyped, or not one of this shore's tokens)")
    return found


@raises(Unauthorized, TooMany)
def require_read(shore: ShoreDep, request: Request, credentials: Credentials) -> Actor:
    """Reads are open when no tokens are configured at all (a bench setup); otherwise any valid token."""
    if open_reads(shore.settings):
        return BENCH
    return _actor(shore, request, credentials, "a bearer token")


@raises(Unauthorized, Forbidden, TooMany)
def require_write(shore: ShoreDep, request: Request, credentials: Credentials) -> Actor:
    found = _actor(shore, request, credentials, "an operator's bearer token")
    if found.role is not Role.WRITE:
        raise Forbidden("this token may only read")
    return found


Id = Annotated[int, Path(ge=1, le=DB_INT_MAX)]
QueryId = Annotated[int, Query(ge=1, le=DB_INT_MAX)]
OptionalId = Annotated[int | None, Query(ge=1, le=DB_INT_MAX)]
Offset = Annotated[int, Query(ge=0, le=DB_INT_MAX)]
Reader = Annotated[Actor, Depends(require_read)]
Writer = Annotated[Actor, Depends(require_write)]
