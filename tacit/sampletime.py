"""When the vehicle measured a sample: the autopilot's own time stamp, on the vehicle's clock.

A MAVLink message reaches the agent some time after the autopilot stamped it (``time_usec``,
``time_boot_ms``: seconds since it booted), and that delay varies: a busy Pi, a TCP buffer or a router
hands over several messages at once. Dated by arrival, samples measured a period apart would share a
tick and a time on the shore (issue 22: one sample per stream per time). So a sample is dated by its
stamp, mapped onto the local clock by the smallest arrival delay seen over the last ``WINDOW`` s (the
least delayed message is the best estimate of the offset between the clocks; the window lets it follow
the two crystals' drift). A date is never later than the arrival. The agent dates the samples it
codes with it, and ``analysis.series.measured_samples`` the samples of its logs, the same way.
"""

from __future__ import annotations

from collections import deque

WINDOW = 30.0  # s of arrivals the clocks' offset is the smallest delay of
REBOOT = 1.0  # s: a stamp this far before the previous one is a new boot of the autopilot


def boot_seconds(message: object) -> float | None:
    """A MAVLink message's own time stamp, seconds since the autopilot booted (None: it has none)."""
    usec = getattr(message, "time_usec", None)
    if usec:
        return float(usec) / 1e6
    msec = getattr(message, "time_boot_ms", None)
    return float(msec) / 1e3 if msec else None


class SampleClock:
    """Dates one message type's samples: its stamps onto the clock they arrive by."""

    def __init__(self) -> None:
        self._delays: deque[tuple[float, float]] = deque()  # (arrival, delay), delays increasing
        self._last: float | None = None

    def date(self, boot: float | None, arrival: float) -> float:
        """The time a sample stamped ``boot`` (None: unstamped) and received at ``arrival`` was taken."""
        if boot is None:
            return arrival
        if self._last is not None and boot < self._last - REBOOT:
            self._delays.clear()  # the autopilot rebooted: its stamps start again
        self._last = boot
        delay = arrival - boot
        while self._delays and self._delays[-1][1] >= delay:
            self._delays.pop()
        self._delays.append((arrival, delay))
        while self._delays[0][0] < arrival - WINDOW:
            self._delays.popleft()
        return boot + self._delays[0][1]
