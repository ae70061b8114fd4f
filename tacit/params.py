"""The vehicle's parameters a SET_PARAM control packet sets (``param_id``, ``param_value``), defined once
for the agent that applies them and the shore that checks and describes them."""

from __future__ import annotations

import enum
import math

CHECKPOINT_INTERVAL = 60.0  # s between a vehicle's check-points unless its agent is told otherwise


class Param(enum.IntEnum):
    """A parameter's ``param_id``; its name in lower case is the agent's setting it overrides."""

    PLUME_THRESHOLD = 1  # degC above the background that marks the warm plume
    CHECKPOINT_INTERVAL = 2  # s between check-points
    CRUISE_SPEED = 3  # m/s
    LINK_LOST_TIMEOUT = 4  # s of the shore's silence before the lost-link action
    LOST_ACTION = 5  # what the vehicle does when the link is lost: a ``LostAction`` value

    @property
    def setting(self) -> str:
        return self.name.lower()

    @property
    def hint(self) -> str:
        return PARAM_HINTS[self]


class LostAction(enum.StrEnum):
    """What the vehicle does when it has not heard the shore for its link-lost timeout: the agent's
    ``lost_action`` setting; ``code`` is its ``Param.LOST_ACTION`` value (its place here)."""

    HOLD = "hold"  # hold where it is
    SURFACE = "surface"  # rise where it is
    RETURN = "return"  # go home, at the surface

    @property
    def code(self) -> int:
        return list(LostAction).index(self)

    @classmethod
    def named(cls, setting: str) -> LostAction:
        """The action an agent's ``lost_action`` setting names (``ValueError`` for any other word)."""
        try:
            return cls(setting)
        except ValueError:
            raise ValueError(f"lost_action is {', '.join(cls)}; not {setting!r}") from None

    @classmethod
    def of_code(cls, value: float) -> LostAction | None:
        """The action a SET_PARAM's ``param_value`` names (None: not one)."""
        actions = list(cls)
        if not math.isfinite(value) or value != int(value) or not 0 <= value < len(actions):
            return None
        return actions[int(value)]


PARAM_HINTS = {
    Param.PLUME_THRESHOLD: "plume threshold",
    Param.CHECKPOINT_INTERVAL: "check-point interval s",
    Param.CRUISE_SPEED: "cruise speed m/s",
    Param.LINK_LOST_TIMEOUT: "link-lost timeout s",
    Param.LOST_ACTION: "lost-link action: " + ", ".join(f"{a.code} {a}" for a in LostAction),
}
