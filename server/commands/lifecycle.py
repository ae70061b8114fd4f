"""The command lifecycle: the transitions allowed between ``CommandState``s, and what a check-point's
report means for them. Pure rules, no I/O.

    queued -> sent (each attempt) -> acknowledged (the vehicle's modem ACKed in hardware)
           -> executing -> executed | refused   (from the vehicle's check-points)
    queued / sent -> failed (no ACK after the configured attempts); superseded (a newer command
    replaced it before it ran)
    queued -> cancelled (an operator took it back before it was signed for transmission; final)
    queued -> cancelling (one a gateway holds: withdrawn from it) -> cancelled (the gateway had not sent
           it), or sent / acknowledged / failed (it had: the cancel lost, it goes on as sent)

The states from the vehicle win over the modem's: a check-point that says "executed" is final even if
a late ACK arrives afterwards. A failed command that a check-point shows ran after all becomes what
the vehicle says.
"""

from __future__ import annotations

from collections.abc import Mapping

from server.commands.models import CommandState
from tacit.packets import CommandStatus

PENDING = (CommandState.QUEUED, CommandState.SENT)  # waiting for the link
NOT_STARTED = (*PENDING, CommandState.ACKNOWLEDGED)  # the vehicle has not said it runs it
FINAL = frozenset({CommandState.EXECUTED, CommandState.REFUSED, CommandState.SUPERSEDED})
_FROM_VEHICLE = frozenset({CommandState.EXECUTING, *FINAL})
NEXT: Mapping[CommandState, frozenset[CommandState]] = {
    CommandState.QUEUED: frozenset({CommandState.SENT, CommandState.FAILED, CommandState.CANCELLING, CommandState.CANCELLED, *_FROM_VEHICLE}),
    CommandState.CANCELLING: frozenset({CommandState.CANCELLED, CommandState.SENT, CommandState.ACKNOWLEDGED, CommandState.FAILED, *_FROM_VEHICLE}),
    CommandState.SENT: frozenset({CommandState.SENT, CommandState.ACKNOWLEDGED, CommandState.FAILED, *_FROM_VEHICLE}),
    # sent again when no check-point confirmed it (the modem ACKs even when the vehicle's host is down)
    CommandState.ACKNOWLEDGED: frozenset({CommandState.SENT, *_FROM_VEHICLE}),
    CommandState.EXECUTING: FINAL,
    CommandState.FAILED: _FROM_VEHICLE,  # the vehicle got it after all: its check-point says so
    **{final: frozenset() for final in FINAL},
    CommandState.CANCELLED: frozenset(),  # never signed: no transmission, no report can follow
}  # fmt: skip
#: What the vehicle's check-point reports, as the shore's state of the command.
FROM_CHECKPOINT = {
    CommandStatus.EXECUTING: CommandState.EXECUTING,
    CommandStatus.EXECUTED: CommandState.EXECUTED,
    CommandStatus.REFUSED: CommandState.REFUSED,
    CommandStatus.SUPERSEDED: CommandState.SUPERSEDED,
}
#: What a command's history keeps of the check-point that reported a status (``report_of``).
REPORT_FIELDS = ("time", "state", "north", "east", "depth", "heading")


def allowed(current: str, new: CommandState) -> bool:
    """Whether a command in state ``current`` may move to ``new``."""
    return new in NEXT[CommandState(current)]


def report_of(checkpoint: Mapping[str, object]) -> dict:
    """What a command's history keeps of the check-point that reported its status: the vehicle's time
    (UNIX s, when the status changed on board) and its mission state and pose at that moment."""
    return {key: checkpoint[key] for key in REPORT_FIELDS if key in checkpoint}
