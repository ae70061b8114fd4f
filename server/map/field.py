"""The map's temperature layer: it draws what ``server.telemetry.field.TemperatureField`` knows.

The reported temperatures as a heatmap (grey squares until a check-point verifies their packet, then
coloured on the verified samples' range), and the field's estimate (fitted by the field, on verified
samples only): its mean as a cloud at the samples' depth, its front (black diamonds), and the most
uncertain place (a purple sphere: the suggested next sample). The estimate is shown per browser (off by
default: it covers the track); this layer keeps it ready for the panels.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from server.core.events import PacketsSettled, TelemetryDecoded
from server.telemetry.field import FieldEstimate, TemperatureField

PENDING_COLOUR = (150, 150, 150)  # a temperature sample no check-point has verified yet
SUGGESTED_COLOUR = (160, 40, 200)
Cloud = tuple[np.ndarray, np.ndarray, np.ndarray]  # points, colours, front (scene frame)


def colormap(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Blue (cold) to red (warm), as uint8 RGB."""
    t = np.clip((values - lo) / max(hi - lo, 1e-6), 0, 1)[:, None]
    cold, warm = np.array([40, 90, 220]), np.array([230, 50, 40])
    return (cold + t * (warm - cold)).astype(np.uint8)


def scene_points(rows: np.ndarray) -> np.ndarray:
    """Rows of (north, east, depth, ...) as scene points (east, north, -depth)."""
    return np.column_stack([rows[:, 1], rows[:, 0], -rows[:, 2]]).astype(np.float32)


class FieldLayer:
    def __init__(self, scene: Any, field: TemperatureField) -> None:
        self.scene = scene
        self.field = field
        self._pending_cloud: Any = None
        self.range: tuple[float, float] | None = None  # the colour scale's: the verified samples'
        self.estimate: Cloud | None = None  # for the panels that show it
        self.suggestion: tuple[float, float] | None = None  # (north, east)

    def checkpoint(self, cp: dict[str, Any]) -> None:
        """A check-point's own temperature is verified with it (0 is no reading)."""
        if cp.get("temperature"):
            self.field.verified((cp["north"], cp["east"], cp["depth"], cp["temperature"]))

    def decoded(self, event: TelemetryDecoded, where: dict[str, Any] | None) -> None:
        """A packet's temperatures at ``where`` (the vehicle's last check-point), pending until a
        check-point vouches for their packet; an absent sample is not drawn."""
        if event.stream != "env" or where is None:
            return
        self.field.heard(
            event.packet_id,
            [
                (where["north"], where["east"], depth, temperature)
                for temperature, depth, *_ in event.values
                if temperature is not None and depth is not None
            ],
        )
        self.draw()

    def settled(self, event: PacketsSettled) -> None:
        self.field.settle([*event.verified, *event.forged, *event.unverifiable], event.trusted)
        self.draw()

    def draw(self) -> bool:
        """The samples: verified ones coloured, pending ones grey. True if the colour scale's range changed."""
        verified, pending = self.field.samples()
        if len(pending):
            self._pending_cloud = self.scene.add_point_cloud(
                "/temperature/pending",
                scene_points(pending),
                PENDING_COLOUR,
                point_size=0.3,
                point_shape="square",
            )
        elif self._pending_cloud is not None:
            self._pending_cloud.remove()
            self._pending_cloud = None
        if not len(verified):
            return False
        lo, hi = float(verified[:, 3].min()), float(verified[:, 3].max())
        self.scene.add_point_cloud(
            "/temperature/samples",
            scene_points(verified),
            colormap(verified[:, 3], lo, hi),
            point_size=0.35,
            point_shape="rounded",
        )
        changed, self.range = self.range != (lo, hi), (lo, hi)
        return changed

    def fit(self) -> bool:
        """Ask the field for its estimate and draw the suggestion; True if there is one."""
        found = self.field.fit()
        if found is None:
            return False
        self.estimate = self._cloud(found)
        self.suggestion = found.suggestion
        north, east = found.suggestion
        self.scene.add_icosphere(
            "/temperature/suggested", radius=0.6, color=SUGGESTED_COLOUR, position=(east, north, -found.depth)
        )
        self.scene.add_label(
            "/temperature/suggested/label", "most uncertain: sample here", position=(0, 0, 1.0)
        )
        return True

    def _cloud(self, found: FieldEstimate) -> Cloud:
        lo, hi = self.range or (float(found.mean.min()), float(found.mean.max()))
        points = np.column_stack(
            [found.points[:, 1], found.points[:, 0], np.full(len(found.points), -found.depth - 0.05)]
        ).astype(np.float32)
        front = np.column_stack(
            [found.front[:, 1], found.front[:, 0], np.full(len(found.front), -found.depth + 0.05)]
        ).astype(np.float32)
        return points, colormap(found.mean, lo, hi), front
