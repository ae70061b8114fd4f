"""The one fairness rule of the polled MAC: which vehicle has the next slot, and what the slot carries.

Several vehicles share one acoustic channel, and only the shore speaks first (goby's polled MAC), so
sharing the channel is deciding, slot after slot, whom the shore addresses. The rule is stride
scheduling: each vehicle has a ``share`` (its weight, set by the operator) and a virtual time that
advances by ``1 / share`` with every slot it uses; the next slot goes to the vehicle whose virtual time,
less a lead for what it waits for, is lowest. Over time each vehicle gets slots in proportion to its
share, whatever it waits for, so no vehicle starves: one vehicle's full command queue, or its stream of
urgent data, only moves it ahead of the others by its lead, never past them for good.

The leads: commands first (an operator is waiting, ``COMMAND_LEAD`` strides), then a vehicle that
reported time-sensitive data or has a command in flight (sent but not yet confirmed by a check-point:
its check-point is what the operator waits for, ``URGENT_LEAD``), then each vehicle's data. A slot the
shore's own modem refused (busy acknowledging the last answer) was not used: the vehicle keeps its turn.

Within a vehicle's slots, commands go first but never for ever: after ``command_share`` command slots in
a row, its next slot is not a command's, whatever still waits: it polls (after the SYNC, if one is due);
the count starts again once the vehicle has been polled. Without this rule a long queue held every
slot of the vehicle (2,556 queued commands once meant 45 s with no poll and no telemetry).
"""

from __future__ import annotations

import enum
import time
from dataclasses import dataclass

from server.link.state import VehicleState

COMMAND_LEAD = 2.0  # strides a vehicle with a command to send is moved ahead
URGENT_LEAD = 1.0  # strides a vehicle with urgent data or a command in flight is moved ahead


class SlotReason(enum.StrEnum):
    """Why a vehicle's next slot is what it is."""

    COMMAND = "command"  # a command waits and commands have not had their share of its slots
    SYNC = "sync"  # its authenticated heartbeat is due
    URGENT = "urgent"  # it reported time-sensitive data, or a command of its is in flight: poll it sooner
    POLL = "poll"  # its data


@dataclass(frozen=True)
class Wants:
    """What a vehicle waits for, as the engine found it before choosing the slot."""

    command: bool = False  # a command to send
    in_flight: bool = False  # a command sent, not yet confirmed by a check-point
    sync: bool = False  # a SYNC is due


@dataclass
class Turn:
    """The schedule's record of one vehicle."""

    virtual: float = 0.0  # its virtual time: + 1/share per slot used
    in_a_row: int = 0  # command slots since its last poll
    last_polled: float | None = None
    last_commanded: float | None = None
    polls: int = 0  # slots that polled it for data, since the shore started
    reason: SlotReason = SlotReason.POLL  # what its next slot carries, as last planned


class Schedule:
    def __init__(self, command_share: int) -> None:
        self.command_share = command_share
        self.turns: dict[int, Turn] = {}  # by modem address

    def turn(self, vehicle: VehicleState) -> Turn:
        """The vehicle's record; a newcomer starts level with the others (no burst of catching up)."""
        if vehicle.address not in self.turns:
            start = min((t.virtual for t in self.turns.values()), default=0.0)
            self.turns[vehicle.address] = Turn(virtual=start)
        return self.turns[vehicle.address]

    def command_turn(self, vehicle: VehicleState) -> bool:
        """Whether the vehicle's slot may carry a command (commands have not had their share in a row)."""
        return self.turn(vehicle).in_a_row < self.command_share

    def reason(self, vehicle: VehicleState, wants: Wants) -> SlotReason:
        """What the vehicle's next slot would carry."""
        if wants.command and self.command_turn(vehicle):
            return SlotReason.COMMAND
        if wants.sync:
            return SlotReason.SYNC
        return SlotReason.URGENT if vehicle.urgent or wants.in_flight else SlotReason.POLL

    def order(self, wants: dict[int, tuple[VehicleState, Wants]]) -> list[tuple[VehicleState, SlotReason]]:
        """Every vehicle (``wants`` by modem address) in the order the next slots would go, with why; the
        first has the next slot."""
        planned = []
        for vehicle, want in wants.values():
            turn = self.turn(vehicle)
            turn.reason = self.reason(vehicle, want)
            lead = {SlotReason.COMMAND: COMMAND_LEAD, SlotReason.URGENT: URGENT_LEAD}.get(turn.reason, 0.0)
            planned.append((turn.virtual - lead / vehicle.share, vehicle.address, vehicle, turn.reason))
        return [(vehicle, reason) for _, _, vehicle, reason in sorted(planned, key=lambda p: p[:2])]

    def used(self, vehicle: VehicleState, reason: SlotReason) -> None:
        """The vehicle's slot went on the air carrying ``reason``'s traffic."""
        turn = self.turn(vehicle)
        turn.virtual += 1.0 / vehicle.share
        if reason is SlotReason.COMMAND:
            turn.in_a_row += 1
            turn.last_commanded = time.time()
        elif reason is not SlotReason.SYNC:
            turn.in_a_row = 0
            turn.last_polled = time.time()
            turn.polls += 1
            vehicle.urgent = False
