"""Every domain's tables, imported once so that SQLModel's metadata (alembic's target) holds them all."""

from server.backhaul.models import RelayedFrame
from server.commands.models import CommandRecord, CommandStep
from server.link.models import LinkEvent, SavedLinkState
from server.missions.models import Mission, TeamMission, TeamProposal
from server.operators.models import Operator
from server.routing.models import Assignment, Dispatch, GatewayRecord
from server.telemetry.models import Frame, Packet, Telemetry
from server.vehicles.models import Vehicle

__all__ = [
    "Assignment",
    "Dispatch",
    "GatewayRecord",
    "CommandRecord",
    "CommandStep",
    "Frame",
    "LinkEvent",
    "Mission",
    "Operator",
    "Packet",
    "RelayedFrame",
    "SavedLinkState",
    "TeamMission",
    "TeamProposal",
    "Telemetry",
    "Vehicle",
]
