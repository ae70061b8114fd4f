"""The link's response bodies: the MAC's schedule."""

from __future__ import annotations

from pydantic import BaseModel, Field

from server.link.schedule import SlotReason


class ScheduledVehicle(BaseModel):
    vehicle_id: int
    name: str
    address: int
    share: float = Field(description="its weight: slots in proportion to it (PUT /vehicles/{id}/share)")
    next_slot: SlotReason = Field(
        description="what its next slot carries: command, sync, urgent (a poll moved "
        "ahead: time-sensitive data or a command in flight) or poll"
    )
    expected_at: float = Field(description="when its next slot is expected (UNIX s)")
    slot_s: float = Field(description="how long its slot lasts at its range (wall-clock s)")
    range_m: float = Field(
        description="the range its slot lengths are timed for (measured, else the default)"
    )
    last_polled: float | None = Field(description="when it was last polled for data (UNIX s)")
    last_commanded: float | None = Field(description="when a command was last sent to it (UNIX s)")
    polls: int = Field(description="slots that polled it for data since the shore started")


class LinkSchedule(BaseModel):
    """The polled MAC's plan (``server.link.schedule``), next slot first."""

    command_share: int = Field(description="command slots in a row a vehicle gets before it is polled")
    planned_at: float | None = Field(
        description="when the plan was made (before the last slot); None: not yet"
    )
    vehicles: list[ScheduledVehicle]
