"""The map's vehicles layer: each vehicle's body in its colour (grey while overdue), its heading (a
yellow arrow outlined in black), its label, and where the shore predicts it is now (an orange sphere, the
line to it from the last report, and a ring as wide as the prediction's uncertainty).

Labels stay legible when vehicles are close: the labels of vehicles nearer each other than a label's
height (``label_gap``, a share of the view's height) are stacked north of each other
(``geometry.stack``), each joined to its vehicle by a thin line.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from server.map.geometry import MIN_VIEW, stack
from server.screens import states

OVERDUE_COLOUR = (170, 170, 170)  # a vehicle's body while it is overdue (the dashboard greys its row)
PREDICTED_COLOUR = (250, 150, 30)
LABEL_HEIGHT = 1.2  # m above the vehicle
LABELS_PER_VIEW = 22.0  # a label's height, as a share of the view's (stacked labels are this far apart)
MARKER_SHRINK = 2.5  # a vehicle's marker grows with the view, this many times less (so neighbours stay apart)
Rgb = tuple[int, int, int]


def label_text(name: str, cp: dict[str, Any], age: float, overdue: bool) -> str:
    """``rov1: holding, 12 s ago`` (short: labels of a fleet seen from high above stay apart; the panel's
    fleet list says the rest); an overdue vehicle's says so."""
    label, _hint = states.label(cp.get("state", ""))
    return f"{name}: {label}, {age:.0f} s ago" + (" (OVERDUE)" if overdue else "")


class VehicleLayer:
    def __init__(self, scene: Any, colour: Callable[[str], Rgb]) -> None:
        self.scene = scene
        self.colour = colour
        self._lock = threading.Lock()  # the event thread and the tick thread both move the nodes
        self._nodes: dict[str, dict[str, Any]] = {}
        self.places: dict[str, tuple[float, float]] = {}  # by name: (north, east) last reported
        self.depths: dict[str, float] = {}  # by name: its depth last reported
        self.label_gap = 4.0  # m between stacked labels: set from the view (``OperatorMap.fit``)
        self.scale = 1.0  # the markers' size: larger in a wide view, to be seen (``resize``)

    def checkpoint(self, name: str, cp: dict[str, Any]) -> None:
        """Move the vehicle to its check-point, turned to its heading."""
        north, east, depth, heading = cp["north"], cp["east"], cp["depth"], cp["heading"]
        yaw = math.radians(90 - heading)  # heading from north, clockwise -> rotation about +z from +x
        node = self._node(name)
        node["frame"].position = (east, north, -depth)
        node["frame"].wxyz = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
        self.places[name], self.depths[name] = (north, east), depth
        self.label(name, cp, 0.0)
        self.declutter()

    def resize(self, seen: float) -> None:
        """Size the markers and space the labels for a view ``seen`` metres high."""
        self.scale = max(1.0, seen / MIN_VIEW / MARKER_SHRINK)
        self.label_gap = seen / LABELS_PER_VIEW
        for node in list(self._nodes.values()):
            for marker in node["markers"]:
                marker.scale = self.scale
        self.declutter()

    def label(self, name: str, cp: dict[str, Any], age: float, overdue: bool = False) -> None:
        node = self._node(name)
        node["label"].text = label_text(name, cp, age, overdue)
        node["body"].color = OVERDUE_COLOUR if overdue else self.colour(name)

    def declutter(self) -> None:
        """Stack the labels of vehicles closer than ``label_gap``: each label north of its vehicle as far as
        it must go (``geometry.stack``), joined to it by a thin line in its colour. Labels stand in the
        scene's frame, not the vehicle's: the vehicle's turn and size do not move them."""
        names = list(self.places)
        lifted = stack([self.places[n] for n in names], self.label_gap)
        for name, (north, east) in zip(names, lifted, strict=True):
            node = self._nodes[name]
            depth = self.depths[name]
            node["label"].position = (east, north, -depth + LABEL_HEIGHT)
            if north > self.places[name][0]:
                node["leader"] = self.scene.add_line_segments(
                    f"/labels/{name}/leader",
                    np.array(
                        [[(east, self.places[name][0], -depth), (east, north, -depth)]], dtype=np.float32
                    ),
                    self.colour(name),
                    thickness=0.04,
                )
            elif node.get("leader") is not None:
                node.pop("leader").remove()

    def predicted(self, name: str, cp: dict[str, Any], p: dict[str, Any]) -> None:
        """Where the shore thinks the vehicle is now (``p``: ``Screens.fleet``'s ``predicted``) and how sure."""
        here, there = (cp["east"], cp["north"], -cp["depth"]), (p["east"], p["north"], -p["depth"])
        self.scene.add_icosphere(
            f"/predicted/{name}/now", radius=0.45, color=PREDICTED_COLOUR, position=there
        )
        self.scene.add_line_segments(
            f"/predicted/{name}/path",
            np.array([[here, there]], dtype=np.float32),
            PREDICTED_COLOUR,
            thickness=0.1,
        )
        angles = np.linspace(0, 2 * np.pi, 49)
        radius = p["radius_m"]
        ring = np.column_stack(
            [
                p["east"] + radius * np.cos(angles),
                p["north"] + radius * np.sin(angles),
                np.full_like(angles, -p["depth"]),
            ]
        ).astype(np.float32)
        self.scene.add_line_segments(
            f"/predicted/{name}/uncertainty",
            np.stack([ring[:-1], ring[1:]], axis=1),
            PREDICTED_COLOUR,
            thickness=0.06,
        )

    def _node(self, name: str) -> dict[str, Any]:
        """The vehicle's body, heading arrow and label, made once and moved after (both the event thread
        and the tick thread update them: re-adding the nodes would race)."""
        with self._lock:
            node = self._nodes.get(name)
            if node is None:
                node = self._nodes[name] = self._make(name)
        return node

    def _make(self, name: str) -> dict[str, Any]:
        scene = self.scene
        frame = scene.add_frame(f"/vehicles/{name}", show_axes=False)
        body = scene.add_box(
            f"/vehicles/{name}/body", color=self.colour(name), dimensions=(1.4, 0.9, 0.6), scale=self.scale
        )
        # the heading: a bright arrow on a larger black one, which outlines it seen from above
        outline = scene.add_arrows(
            f"/vehicles/{name}/heading_outline",
            np.array([[[0.5, 0, 0], [5.6, 0, 0]]], dtype=np.float32),
            (0, 0, 0),
            shaft_radius=0.4,
            head_radius=1.15,
            head_length=2.1,
            scale=self.scale,
        )
        heading = scene.add_arrows(
            f"/vehicles/{name}/heading",
            np.array([[[0.7, 0, 0.35], [5.1, 0, 0.35]]], dtype=np.float32),
            (255, 225, 0),
            shaft_radius=0.25,
            head_radius=0.8,
            head_length=1.6,
            scale=self.scale,
        )
        label = scene.add_label(
            f"/labels/{name}", name, position=(0.0, 0.0, LABEL_HEIGHT), anchor="bottom-left"
        )
        return {
            "frame": frame,
            "label": label,
            "body": body,
            "markers": [body, outline, heading],
            "leader": None,
        }
