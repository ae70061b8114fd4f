"""The simulated BlueROV2's parameters: a real ArduSub's, read and set over MAVLink as ArduSub does.

``ardusub/parameters.csv`` holds every parameter ArduSub 4.1.1 reported to its ground station during a
recorded dive, in its own order and with its MAVLink type; the simulator adds its own after them
(``SIM_MODEM_LOSS``, as SITL adds its ``SIM_*``). A value is set as ArduPilot's ``AP_Param::set_float``
sets it: NaN and infinities are refused, an integer parameter takes the value plus 0.01 away from zero,
clamped to its type and truncated (so 2.999 as a float on the link is 3), a REAL32 one the value as a
32-bit float. A name ArduSub does not have is refused.
"""

from __future__ import annotations

import csv
import functools
import math
import struct
from collections.abc import Iterator, Mapping
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mavlink

TABLE = Path(__file__).resolve().parent / "ardusub" / "parameters.csv"
#: A simulated vehicle's parameter (PARAM_SET over MAVLink, as SITL's SIM_* failure parameters): the
#: probability 0..1 that a frame to or from the modem riding it is lost, on top of the channel's. 1 takes
#: the vehicle out of range of every other modem while it runs; 0 brings it back.
MODEM_LOSS = "SIM_MODEM_LOSS"
SIMULATOR = ((MODEM_LOSS, 0.0, mavlink.MAV_PARAM_TYPE_REAL32),)
FLOAT32_MAX = 3.4028234663852886e38
INTEGER_RANGES = {
    mavlink.MAV_PARAM_TYPE_INT8: (-(2**7), 2**7 - 1),
    mavlink.MAV_PARAM_TYPE_INT16: (-(2**15), 2**15 - 1),
    mavlink.MAV_PARAM_TYPE_INT32: (-(2**31), 2**31 - 1),
}


@functools.cache
def ardusub_table() -> tuple[tuple[str, float, int], ...]:
    """(name, value, MAV_PARAM_TYPE) of every parameter, ArduSub's in its order, then the simulator's."""
    with TABLE.open(newline="") as f:
        rows = csv.DictReader(line for line in f if not line.startswith("#"))
        table = tuple((row["name"], float(row["value"]), int(row["type"])) for row in rows)
    return table + SIMULATOR


class Parameters(Mapping[str, float]):
    """Values by name, in the autopilot's order (a ground station asks for them by name or by index)."""

    def __init__(self, table: tuple[tuple[str, float, int], ...]) -> None:
        self.names = [name for name, _, _ in table]
        self._index = {name: i for i, name in enumerate(self.names)}
        self._values = {name: value for name, value, _ in table}
        self.kinds = {name: kind for name, _, kind in table}

    @classmethod
    def ardusub(cls) -> Parameters:
        return cls(ardusub_table())

    def __getitem__(self, name: str) -> float:
        return self._values[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self.names)

    def __len__(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        return self._index[name]

    def set(self, name: str, value: float) -> bool:
        """Set ``name`` as ArduPilot would; False (nothing changed) for a name it lacks or a value that
        is not a number."""
        if name not in self._values or not math.isfinite(value) or abs(value) > FLOAT32_MAX:
            return False  # a value on the link is a 32-bit float: no larger one comes
        kind = self.kinds[name]
        if kind in INTEGER_RANGES:
            low, high = INTEGER_RANGES[kind]
            self._values[name] = float(int(min(high, max(low, value + math.copysign(0.01, value)))))
        else:
            self._values[name] = struct.unpack("<f", struct.pack("<f", value))[0]
        return True
