"""The map's plans layer: where the vehicles are meant to go.

- each vehicle's started mission, its waypoints as a thin grey line;
- the path the separation check plans for it (``server.safety.paths``: from where it is predicted,
  through its queued commands' targets and its team's lanes still to come), a line in its colour;
- each team mission not yet ended, its survey area outlined in dark grey with its name and state, and each
  member's lanes (its waypoints) as a line in the member's colour.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from server.map.tracks import segments
from server.missions.models import TeamMission, TeamStatus
from server.safety.paths import Planned

ROUTE_COLOUR = (120, 120, 120)
AREA_COLOUR = (60, 60, 60)
SHOWN = (TeamStatus.CREATED, TeamStatus.REFUSED, TeamStatus.STARTED)  # a team's lanes while it may run
Rgb = tuple[int, int, int]
Point = tuple[float, float, float]


def scene(p: Sequence[float]) -> Point:
    """(north, east, depth) as a scene point (east, north, -depth)."""
    return (p[1], p[0], -p[2])


class PlanLayer:
    def __init__(self, scene_api: Any, colour: Callable[[str], Rgb]) -> None:
        self.scene = scene_api
        self.colour = colour
        self._drawn: dict[str, Any] = {}  # node name: handle, to remove what is no longer planned

    def route(self, name: str, waypoints: list[tuple[float, float, float]]) -> None:
        """The vehicle's started mission's waypoints (north, east, depth)."""
        if len(waypoints) >= 2:
            self.scene.add_line_segments(
                f"/plans/{name}", segments([scene(w) for w in waypoints]), ROUTE_COLOUR, thickness=0.06
            )

    def draw(self, planned: list[Planned], teams: list[TeamMission]) -> None:
        """The separation check's paths and the teams' lanes; what is no longer planned goes."""
        drawn: dict[str, Any] = {}
        for p in planned:
            points = [scene(c) for c in p.centre]
            if len(points) >= 2:
                node = f"/planned/{p.name}"
                drawn[node] = self.scene.add_line_segments(
                    node, segments(points), self.colour(p.name), thickness=0.1
                )
        for team in teams:
            if team.status in SHOWN:
                drawn.update(self._team(team))
        for node in set(self._drawn) - set(drawn):
            self._drawn[node].remove()
        self._drawn = drawn

    def _team(self, team: TeamMission) -> dict[str, Any]:
        key = f"/teams/{team.id}"
        ring = [(east, north, -team.depth) for north, east in [*team.area, team.area[0]]]
        drawn = {
            f"{key}/area": self.scene.add_line_segments(
                f"{key}/area", segments(ring), AREA_COLOUR, thickness=0.08
            )
        }
        north = max(n for n, _ in team.area)
        west = min(e for n, e in team.area if n == north)
        drawn[f"{key}/label"] = self.scene.add_label(
            f"{key}/label",
            f"team {team.name}: {team.status.value}",
            position=(west, north, 0.5),
            anchor="bottom-left",
        )
        for m in team.members:
            points = [scene(w) for w in m["waypoints"]]
            if len(points) >= 2:
                node = f"{key}/lanes/{m['name']}"
                drawn[node] = self.scene.add_line_segments(
                    node, segments(points), self.colour(m["name"]), thickness=0.05
                )
        return drawn
