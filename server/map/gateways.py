"""The map's gateways layer (a center's): each gateway at its modem's place, a box in its own colour while
its heartbeats come (light grey once silent) with a short label, and a thin line in each vehicle's colour
from its last reported position to the gateway its commands go through. The panel's Link folder lists
each gateway in full (``gateway_line``)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from server.map.geometry import MIN_VIEW
from server.screens import fleet

GATEWAY_SIZE = (4.0, 4.0, 4.0)  # m: a gateway's marker, seen from a few hundred metres
MARKER_SHRINK = 2.0  # its marker grows with the view, this many times less
Rgb = tuple[int, int, int]
Point = tuple[float, float, float]


def gateway_line(g: dict[str, Any]) -> str:
    """A gateway (a row of ``Screens.gateways``) in one line: its state and for how long, its outbox and
    modem, its vehicles."""
    vehicles = ", ".join(v["name"] + (" (pinned)" if v["pinned"] else "") for v in g["vehicles"]) or "none"
    return (
        f"**Gateway {g['name']}**: {_state(g)}, {g['outbox'] if g['outbox'] is not None else '?'} waiting to go "
        f"up; modem {g['address'] if g['address'] is not None else '?'} {g['modem'] or '?'}; vehicles {vehicles}"
    )


def gateway_label(g: dict[str, Any]) -> str:
    """``Gateway ship: up for 12 s`` (its label on the map)."""
    return f"Gateway {g['name']}: {_state(g)}"


def _state(g: dict[str, Any]) -> str:
    return f"up for {g['for_s']:.0f} s" if g["alive"] else f"silent for {g['for_s']:.0f} s"


def place(g: dict[str, Any]) -> Point | None:
    """A gateway's place in the scene (east, north, -depth); None where it did not say."""
    p = g["place"]
    return None if p is None else (p["east"], p["north"], -p["depth"])


class GatewayLayer:
    def __init__(self, scene: Any, colour: Callable[[str], Rgb]) -> None:
        self.scene = scene
        self.colour = colour  # a vehicle's, by name
        self._links: dict[str, Any] = {}  # by vehicle name: the line to its gateway
        self.scale = 1.0  # the markers' size: larger in a wide view, to be seen (``resize``)

    def resize(self, seen: float) -> None:
        """Size the markers for a view ``seen`` metres high (drawn so at the next ``draw``)."""
        self.scale = max(1.0, seen / MIN_VIEW / MARKER_SHRINK)

    def draw(self, gateways: list[dict[str, Any]], vehicles: list[dict[str, Any]]) -> None:
        places: dict[str, Point] = {}
        for g in gateways:
            here = place(g)
            if here is None:
                continue
            places[g["name"]] = here
            self.scene.add_box(
                f"/gateways/{g['name']}",
                color=fleet.rgb(g["colour"]),
                dimensions=GATEWAY_SIZE,
                position=here,
                scale=self.scale,
            )
            self.scene.add_label(f"/gateways/{g['name']}/label", gateway_label(g), position=(0, 0, 3.0))
        for v in vehicles:
            cp, there = v["reported"], places.get(v["gateway"] or "")
            old = self._links.pop(v["name"], None)
            if cp is None or there is None:
                if old is not None:
                    old.remove()
                continue
            segment = np.array([[(cp["east"], cp["north"], -cp["depth"]), there]], dtype=np.float32)
            self._links[v["name"]] = self.scene.add_line_segments(
                f"/gateway_links/{v['name']}", segment, self.colour(v["name"]), thickness=0.05
            )
