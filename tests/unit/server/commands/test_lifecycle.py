"""The command lifecycle's allowed transitions: the vehicle has the last word."""

from __future__ import annotations

from server.commands.lifecycle import allowed
from server.commands.models import CommandState as Status


def test_the_vehicle_has_the_last_word() -> None:
    assert allowed("queued", Status.SENT) and allowed("sent", Status.ACKNOWLEDGED)
    assert allowed("acknowledged", Status.EXECUTING) and allowed("executing", Status.EXECUTED)
    assert allowed("failed", Status.EXECUTED)  # a check-point shows it ran after all
    assert not allowed("executed", Status.REFUSED)  # final: a later packet cannot flip it
    assert not allowed("executing", Status.ACKNOWLEDGED)  # a late ACK does not undo the vehicle's word
    assert not allowed("refused", Status.SENT)
