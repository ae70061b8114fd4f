"""The command form both screens offer (the dashboard reads it from the API, the map's panel calls it):
which fields each command takes, with labels, units, ranges and hints, built from the control packet's
field table (``tacit.packets.ControlPacket.FIELDS``) narrowed by the vehicle's limits. ``check_form`` is
the page's rule in Python (the map's panel); ``web/app.js`` applies the same spec in the browser.
"""

from __future__ import annotations

import math

from tacit.limits import Limits
from tacit.packets import ControlPacket
from tacit.params import Param

COMMAND_HINTS = {
    "move": "Go a distance in a direction, optionally changing depth.",
    "goto_depth": "Change depth where it is.",
    "hold": "Stop and hold the position.",
    "resume": "Go back to the pre-programmed mission.",
    "start_mission": "Start a mission the vehicle has on board, by its number.",
    "abort_mission": "Abort the mission and hold where it is.",
    "return_home": "Head home now.",
    "set_param": "Set one of the vehicle's parameters ("
    + ", ".join(f"{p.value} {p.hint}" for p in Param)
    + ").",
    "request_checkpoint": "Ask for a check-point (the vehicle's state) now.",
}
FIELDS_OF = {
    "move": ("distance", "angle", "depth", "speed"),
    "goto_depth": ("depth",),
    "start_mission": ("param_id",),
    "set_param": ("param_id", "param_value"),
}
ANGLE_MODES = ("relative", "bearing")
SPEED_DEFAULT = "default (cruise)"


def _field(
    name: str, label: str, lo: float, hi: float, hint: str, required: bool = True, placeholder: str = ""
) -> dict:
    """A field's spec; ``placeholder``: what a blank optional field means (it is not sent)."""
    wire = ControlPacket.field(name)
    step = wire.resolution
    return {
        "name": name,
        "label": label,
        "unit": wire.unit or "",
        "min": round(lo, 6),
        "max": round(hi, 6),
        "step": step,
        "required": required,
        "hint": hint,
        "placeholder": placeholder,
    }


def command_form(limits: Limits | None = None) -> dict:
    """The commands and their fields for one vehicle (``limits``) or for the packet alone (None)."""
    lim = limits or Limits(
        max_depth=ControlPacket.field("depth").hi,
        max_distance=ControlPacket.field("distance").hi,
        max_speed=ControlPacket.field("speed").hi,
    )
    dist, depth, speed = (
        ControlPacket.field("distance"),
        ControlPacket.field("depth"),
        ControlPacket.field("speed"),
    )
    max_depth = min(lim.max_depth, depth.hi)
    fields = {
        "distance": _field("distance", "Distance", dist.lo, min(lim.max_distance, dist.hi),
                           "How far to go, in metres, per command."),
        "angle": {
            "relative": _field("angle", "Turn from heading", -180.0, 180.0,
                               "Degrees from the vehicle's heading: + turns clockwise (right), - left."),
            "bearing": {**_field("angle", "Bearing (true)", 0.0, 360.0,
                                 "Compass direction to go: 0 north, 90 east, 180 south, 270 west."), "unit": "deg"},
        },
        "depth": {
            "move": _field("depth", "Depth change", -max_depth, max_depth,
                           f"Metres deeper (+) or shallower (-) than now; the target must stay within 0 .. {max_depth:g} m."),
            "goto_depth": _field("depth", "Target depth", 0.0, max_depth,
                                 f"The depth to go to, 0 (surface) .. {max_depth:g} m."),
        },
        "speed": _field("speed", "Speed", 0.0, min(lim.max_speed, speed.hi), "Metres per second; leave it blank "
                        "for the vehicle's cruise speed.", required=False, placeholder=SPEED_DEFAULT),
        "param_id": _field("param_id", "Number", 0, 255, "Mission number (start mission) or parameter id."),
        "param_value": {"name": "param_value", "label": "Value", "unit": "", "min": -3.4e38, "max": 3.4e38,
                        "step": "any", "required": True, "hint": "The parameter's new value."},
    }  # fmt: skip
    commands = {}
    for name, hint in COMMAND_HINTS.items():
        specs = []
        for field in FIELDS_OF.get(name, ()):
            if field == "angle":
                specs.append({"name": "angle", "modes": fields["angle"]})
            else:
                specs.append(fields[field][name] if field == "depth" else fields[field])
        commands[name] = {"hint": hint, "fields": specs}
    # no default speed: blank, nothing is sent and the vehicle keeps its cruise speed (0 would read as "stop")
    return {
        "commands": commands,
        "angle_modes": list(ANGLE_MODES),
        "defaults": {"distance": 10.0, "angle": 0.0, "depth": 0.0, "param_id": 1, "param_value": 0.0},
    }


def field_specs(form: dict, command: str, angle_mode: str = "relative") -> list[dict]:
    """The fields of ``command`` in ``form``, with the angle's spec for ``angle_mode``."""
    out = []
    for spec in form["commands"][command]["fields"]:
        out.append(spec["modes"][angle_mode] if "modes" in spec else spec)
    return out


def check_form(
    form: dict, command: str, values: dict[str, float | None], angle_mode: str = "relative"
) -> dict:
    """The body of ``POST .../commands`` from a form's values, or ``ValueError`` naming the field: a
    blank required field or a value outside its range is refused before anything is sent."""
    if command not in form["commands"]:
        raise ValueError(f"command: unknown command {command!r}")
    if angle_mode not in ANGLE_MODES:
        raise ValueError(f"angle: mode is one of {ANGLE_MODES}")
    body: dict = {"command": command}
    for spec in field_specs(form, command, angle_mode):
        value = values.get(spec["name"])
        if value is None or (isinstance(value, str) and not value.strip()):
            if spec["required"]:
                raise ValueError(f"{spec['name']}: {spec['label']} is required")
            continue
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"{spec['name']}: {spec['label']} must be a number") from None
        if not math.isfinite(number) or not spec["min"] <= number <= spec["max"]:
            raise ValueError(
                f"{spec['name']}: {spec['label']} must be {spec['min']:g} .. {spec['max']:g} {spec['unit']}".rstrip()
            )
        body[spec["name"]] = int(number) if spec["name"] == "param_id" else number
    if "angle" in body:
        body["absolute_angle"] = angle_mode == "bearing"
    return body
