"""Command request and response bodies. Every range comes from the control packet's field table."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, Field, JsonValue, ValidationInfo, field_validator

from server.commands.models import CommandState, StepSource
from server.core.schemas import DB_INT_MAX, STRICT
from tacit.navigation import wrap180
from tacit.packets import FLOAT32_MAX, Command
from tacit.packets import ControlPacket as WIRE

#: What an operator may send: every command but the shore's own heartbeat.
COMMAND_NAMES = [c.name.lower() for c in Command if c.from_operator]
#: What may go to the whole fleet in one action (one command per vehicle): the fleet's stop is "abort all"
#: (docs/protocol.md says why there is no broadcast stop).
FLEET_COMMANDS = ("abort_mission", "return_home", "hold")


class CommandIn(BaseModel):
    model_config = STRICT
    command: str = Field(
        json_schema_extra={"enum": list[JsonValue](COMMAND_NAMES)}, description="what to ask of the vehicle"
    )
    absolute_angle: bool = Field(False, description="angle is a true bearing (0 .. 360), not a turn")
    distance: float = Field(0.0, ge=0, le=WIRE.field("distance").hi, description="m")
    angle: float = Field(
        0.0,
        ge=-180,
        le=360,
        description="deg; heading change (-180 .. 180, + clockwise), or true bearing "
        "(0 .. 360) if absolute_angle; stored and sent as the same direction in -180 .. 180",
    )
    depth: float = Field(
        0.0,
        ge=WIRE.field("depth").lo,
        le=WIRE.field("depth").hi,
        description="m; depth change (move) or target (goto_depth)",
    )
    speed: float = Field(0.0, ge=0, le=WIRE.field("speed").hi, description="m/s; 0 = vehicle default")
    param_id: int = Field(0, ge=0, le=int(WIRE.field("param_id").hi))
    param_value: float = Field(0.0, ge=-FLOAT32_MAX, le=FLOAT32_MAX, description="a float32")
    delay_sensitive: bool = False

    @field_validator("command")
    @classmethod
    def _known(cls, command: str) -> str:
        if command not in COMMAND_NAMES:
            raise ValueError(f"unknown command {command!r}; one of {', '.join(COMMAND_NAMES)}")
        return command

    @field_validator("angle")
    @classmethod
    def _one_turn(cls, angle: float, info: ValidationInfo) -> float:
        """A turn is -180 .. 180; a bearing 0 .. 360, and a bearing of 270 is the direction -90 (the
        packet's angle field holds -180 .. 180)."""
        if not info.data.get("absolute_angle") and angle > 180:
            raise ValueError("a turn from the heading is -180 .. 180 deg; for a bearing set absolute_angle")
        return wrap180(angle) if angle > 180 else angle

    def kind(self) -> Command:
        return Command[self.command.upper()]


class FleetCommandIn(BaseModel):
    """One operator action for several vehicles: the same command queued for each, each with its own
    sequence number, signature and status."""

    model_config = STRICT
    command: str = Field(
        json_schema_extra={"enum": list[JsonValue](FLEET_COMMANDS)},
        description="what to ask of every vehicle",
    )
    vehicle_ids: list[Annotated[int, Field(ge=1, le=DB_INT_MAX)]] | None = Field(
        None,
        min_length=1,
        max_length=127,  # a vehicle per modem address (1 .. 127): no fleet is larger
        description="the vehicles (default: every registered vehicle)",
    )

    @field_validator("command")
    @classmethod
    def _for_a_fleet(cls, command: str) -> str:
        if command not in FLEET_COMMANDS:
            raise ValueError(f"{command!r} does not go to a fleet; one of {', '.join(FLEET_COMMANDS)}")
        return command


class CommandOut(BaseModel):
    id: int
    vehicle_id: int
    seq: int
    command: str
    distance: float
    angle: float
    depth: float
    speed: float
    param_id: int
    param_value: float
    absolute_angle: bool
    status: CommandState
    reason: str
    attempts: int
    issued_by: str = Field(description="the operator who sent it")
    created_at: float
    updated_at: float


class CommandReport(BaseModel):
    """What the vehicle's check-point said with a status: when (its clock) and where."""

    time: float = Field(description="vehicle time, UNIX s (whole seconds): when the status changed on board")
    shore_time: float | None = Field(
        None,
        description="the latest shore time (UNIX s) it can have happened: the vehicle's time on the shore's "
        "clock (its offset from the vehicle's check-points), never after the shore heard it and never "
        "before its cause (server.telemetry.clock); None in reports stored before it was kept",
    )
    state: str = Field(description="the vehicle's mission state then")
    north: float = Field(description="m from home")
    east: float = Field(description="m from home")
    depth: float = Field(description="m, positive down")
    heading: float = Field(description="deg from north")


class CommandStepOut(BaseModel):
    """One step of a command's life, oldest first: queued; sent (one row per attempt, detail
    "attempt N"); acknowledged (the vehicle's modem ACKed); executing, executed, refused (with the vehicle's
    reason), superseded (from the vehicle's check-points, with ``report``); failed (detail: why);
    cancelled (detail "by <operator>", ``via`` the operator, ``at`` when; through gateways, cancelling
    first, then the gateway's word: cancelled "withdrawn from <gateway>: never sent", or sent)."""

    status: CommandState
    detail: str = Field(
        description="attempt number for sent, the vehicle's reason for refused, why for failed"
    )
    at: float = Field(description="shore time, UNIX s: when the shore learnt it")
    report: CommandReport | None = Field(
        None, description="for the steps a check-point reported: the vehicle's time and pose then"
    )
    source: StepSource = Field(
        description="who said it: operator (queued, cancelled), shore (the center's own decision), modem "
        "(the single shore's modem), gateway (a gateway's report, from the gateway the command went "
        "through), vehicle (a check-point whose MAC verified: the only source of executing, executed, "
        "refused)"
    )
    via: str = Field(description="the operator or the gateway it came by; empty when none")


class CommandDetail(CommandOut):
    history: list[CommandStepOut]


class CommandListed(CommandOut):
    history: list[CommandStepOut] | None = Field(
        None, description="with ?history=true: as GET /commands/{id}"
    )


class FleetCommandsOut(BaseModel):
    commands: list[CommandOut] = Field(description="one per vehicle, in the order of vehicle_ids (or of id)")
