"""What each of the vehicle's mission states (``tacit.packets.MissionState``) means to an operator:
a short label and a hint. ``awaiting_command`` still follows the waypoints: it only means the vehicle
reported unusual data and would take a command."""

from __future__ import annotations

from tacit.packets import MissionState

LABELS: dict[MissionState, tuple[str, str]] = {
    MissionState.WAITING: ("waiting", "Powered and listening; no mission started."),
    MissionState.PREPROGRAMMED: ("following waypoints", "Running the pre-programmed mission; data predictable."),
    MissionState.SELF_DETERMINED: ("deciding locally",
                        "Saw time-sensitive unusual data and steers toward it on its own (priority packet sent)."),
    MissionState.AWAITING_COMMAND: ("following waypoints (unusual data)",
                         "Still following the waypoints; it reported unusual data and would take a command."),
    MissionState.COMMANDED: ("following a command", "Steering to the target of the operator's last command."),
    MissionState.HOLDING: ("holding", "Holding its position."),
    MissionState.RETURNING: ("returning home", "Mission time is over or it was told to: heading home."),
    MissionState.LINK_LOST: ("link lost", "Heard nothing from the shore for too long: holding, surfacing or returning."),
    MissionState.FINISHED: ("finished", "Mission done and back home."),
    MissionState.ABORTED: ("aborted", "Mission aborted: holding where it was."),
}  # fmt: skip


def label(state: str) -> tuple[str, str]:
    """(label, hint) of a state named as a check-point's body names it (lower case)."""
    try:
        return LABELS[MissionState[state.upper()]]
    except KeyError:
        return state or "?", ""


assert set(LABELS) == set(MissionState), "every mission state has its label"
