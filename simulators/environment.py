"""Water temperature and dissolved oxygen over space, depth and time (the paper's river and lake).

temperature(n, e, z, t) = surface temperature
                          - thermocline drop * (1 + tanh((z - thermocline depth) / thickness)) / 2
                          + front step * (1 + tanh(distance across the front / front width)) / 2
                          + plume excess * exp(-(horizontal distance to the drifting plume)^2 / 2 s^2
                                               - (z - plume depth)^2 / 2 sz^2)
                          + a few small seeded sinusoids (patchiness)
Dissolved oxygen falls as water warms (about -0.2 mg/L per degC near 20 degC) and with depth below the
thermocline. Parameters come from a seed (``Environment.generate``) or a JSON file of the same fields.
"""

from __future__ import annotations

import json
import math
import random
from dataclasses import asdict, dataclass, field
from pathlib import Path

from tacit.config import check_keys


@dataclass
class Environment:
    surface_temp: float = 22.0
    thermocline_depth: float = 6.0
    thermocline_thickness: float = 1.5
    thermocline_drop: float = 4.0
    front_angle_deg: float = 90.0  # direction the front's normal points (warm side), from north
    front_offset: float = 60.0  # metres from home along that normal
    front_width: float = 8.0
    front_step: float = 1.0
    plume_north: float = 30.0
    plume_east: float = 25.0
    plume_depth: float = 2.0
    plume_sigma: float = 8.0
    plume_sigma_z: float = 3.0
    plume_excess: float = 3.0
    plume_drift: tuple[float, float] = (0.0, 0.0)  # m/s north, east
    surface_oxygen: float = 8.5
    oxygen_per_degc: float = -0.2
    oxygen_drop_below_thermocline: float = 2.0
    patches: list[tuple[float, float, float, float]] = field(default_factory=list)  # amp, kn, ke, phase

    @classmethod
    def generate(cls, seed: int = 1, kind: str = "river") -> Environment:
        """A seeded environment: ``river`` (front and plume), ``lake`` (stratified, calm)."""
        rng = random.Random(seed)
        patches = [
            (
                rng.uniform(0.02, 0.08),
                rng.uniform(-0.1, 0.1),
                rng.uniform(-0.1, 0.1),
                rng.uniform(0, 2 * math.pi),
            )
            for _ in range(3)
        ]
        if kind == "lake":
            return cls(front_step=0.0, plume_excess=0.0, thermocline_drop=6.0, patches=patches)
        if kind != "river":
            raise ValueError(f"unknown environment kind {kind!r} (river or lake)")
        return cls(
            front_angle_deg=rng.uniform(0, 360),
            front_offset=rng.uniform(40, 80),
            plume_north=rng.uniform(15, 35),
            plume_east=rng.uniform(15, 35),
            plume_excess=rng.uniform(2.0, 4.0),
            patches=patches,
        )

    @classmethod
    def load(cls, path: str | Path) -> Environment:
        data = json.loads(Path(path).read_text())
        check_keys(str(path), data, cls)
        if "plume_drift" in data:
            data["plume_drift"] = tuple(data["plume_drift"])
        if "patches" in data:
            data["patches"] = [tuple(p) for p in data["patches"]]
        return cls(**data)

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(asdict(self), indent=2))

    def plume_centre(self, t: float) -> tuple[float, float]:
        return self.plume_north + self.plume_drift[0] * t, self.plume_east + self.plume_drift[1] * t

    def temperature(self, north: float, east: float, depth: float, t: float = 0.0) -> float:
        strat = (
            self.thermocline_drop
            * (1 + math.tanh((depth - self.thermocline_depth) / self.thermocline_thickness))
            / 2
        )
        a = math.radians(self.front_angle_deg)
        across = north * math.cos(a) + east * math.sin(a) - self.front_offset
        front = self.front_step * (1 + math.tanh(across / self.front_width)) / 2
        pn, pe = self.plume_centre(t)
        d2 = (north - pn) ** 2 + (east - pe) ** 2
        plume = self.plume_excess * math.exp(
            -d2 / (2 * self.plume_sigma**2) - (depth - self.plume_depth) ** 2 / (2 * self.plume_sigma_z**2)
        )
        patch = sum(amp * math.sin(kn * north + ke * east + ph) for amp, kn, ke, ph in self.patches)
        return self.surface_temp - strat + front + plume + patch

    def oxygen(self, north: float, east: float, depth: float, t: float = 0.0) -> float:
        warm = self.temperature(north, east, depth, t) - self.surface_temp
        below = (
            self.oxygen_drop_below_thermocline * (1 + math.tanh((depth - self.thermocline_depth) / 1.5)) / 2
        )
        return max(0.0, self.surface_oxygen + self.oxygen_per_degc * warm - below)
