"""What the operator's two screens (the dashboard and the 3D map's panel) share, computed in one place.

- ``command_form``: which fields each command takes, with labels, units, ranges and hints, built from
  the control packet's field table (``tacit.packets.ControlPacket.FIELDS``) narrowed by the vehicle's
  limits. The dashboard reads it from the API, the map panel calls it; ``check_form`` is the page's
  rule in Python (the map's panel), ``server/web/app.js`` applies the same spec in the browser.
- ``STATES``: what each mission state means to an operator (``awaiting_command`` still follows the
  waypoints: it only means the vehicle reported unusual data and would take a command).
- ``estimate``: what the shore knows of a vehicle: the last reported pose and its age, and the pose
  predicted since (dead reckoning toward the current target) with an uncertainty that grows with silence.
- ``link_shares``: the link's airtime by use (commands, polls, check-points, priority data) and the
  bits saved by compression, from the database (so a restart keeps them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from sqlalchemy import func
from sqlmodel import Session, col, select

from server.models import Command, CommandEvent, Frame, Mission, Packet, Telemetry, Vehicle
from tacit import rates
from tacit.limits import Limits
from tacit.navigation import move_target
from tacit.packets import PACKET_SIZE, ControlPacket

#: The channels' units (RAW_IMU: mG, mrad/s, mGauss; environment: degC, m, mg/L).
UNITS = {"xacc": "mG", "yacc": "mG", "zacc": "mG", "xgyro": "mrad/s", "ygyro": "mrad/s", "zgyro": "mrad/s",
         "xmag": "mGauss", "ymag": "mGauss", "zmag": "mGauss", "temperature": "°C", "depth": "m",
         "oxygen": "mg/L"}  # fmt: skip

STATES = {
    "waiting": ("waiting", "Powered and listening; no mission started."),
    "preprogrammed": ("following waypoints", "Running the pre-programmed mission; data predictable."),
    "self_determined": ("deciding locally",
                        "Saw time-sensitive unusual data and steers toward it on its own (priority packet sent)."),
    "awaiting_command": ("following waypoints (unusual data)",
                         "Still following the waypoints; it reported unusual data and would take a command."),
    "commanded": ("following a command", "Steering to the target of the operator's last command."),
    "holding": ("holding", "Holding its position."),
    "returning": ("returning home", "Mission time is over or it was told to: heading home."),
    "link_lost": ("link lost", "Heard nothing from the shore for too long: holding, surfacing or returning."),
    "finished": ("finished", "Mission done and back home."),
    "aborted": ("aborted", "Mission aborted: holding where it was."),
}  # fmt: skip

COMMAND_HINTS = {
    "move": "Go a distance in a direction, optionally changing depth.",
    "goto_depth": "Change depth where it is.",
    "hold": "Stop and hold the position.",
    "resume": "Go back to the pre-programmed mission.",
    "start_mission": "Start a mission the vehicle has on board, by its number.",
    "abort_mission": "Abort the mission and hold where it is.",
    "return_home": "Head home now.",
    "set_param": "Set one of the vehicle's parameters (1 plume threshold, 2 check-point interval s, "
    "3 cruise speed m/s, 4 link-lost timeout s).",
    "request_checkpoint": "Ask for a check-point (the vehicle's state) now.",
}
FIELDS_OF = {"move": ("distance", "angle", "depth", "speed"), "goto_depth": ("depth",),
             "start_mission": ("param_id",), "set_param": ("param_id", "param_value")}  # fmt: skip
ANGLE_MODES = ("relative", "bearing")


def _field(name: str, label: str, lo: float, hi: float, hint: str, required: bool = True) -> dict:
    wire = ControlPacket.field(name)
    step = wire.resolution
    return {"name": name, "label": label, "unit": wire.unit or "", "min": round(lo, 6), "max": round(hi, 6),
            "step": step, "required": required, "hint": hint}  # fmt: skip


def command_form(limits: Limits | None = None) -> dict:
    """The commands and their fields for one vehicle (``limits``) or for the packet alone (None)."""
    lim = limits or Limits(max_depth=ControlPacket.field("depth").hi, max_distance=ControlPacket.field("distance").hi,
                           max_speed=ControlPacket.field("speed").hi)  # fmt: skip
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
        "speed": _field("speed", "Speed", 0.0, min(lim.max_speed, speed.hi),
                        "Metres per second; 0 = the vehicle's cruise speed.", required=False),
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
    return {"commands": commands, "angle_modes": list(ANGLE_MODES), "defaults": {"distance": 10.0, "angle": 0.0,
            "depth": 0.0, "speed": 0.0, "param_id": 1, "param_value": 0.0}}  # fmt: skip


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


# --- what the shore knows, how old it is, how sure it is ------------------------------------------------

DRIFT = 0.05  # m/s: how fast the uncertainty about a silent vehicle grows (currents, dead-reckoning error)
BASE_UNCERTAINTY = 1.0  # m: the reported position's own error (dead reckoning between fixes)
DEFAULT_SPEED = 0.5  # m/s when the vehicle's speed cannot be estimated from its check-points
MOVING = {"preprogrammed", "awaiting_command", "self_determined", "commanded", "returning"}


@dataclass(frozen=True)
class Estimate:
    north: float
    east: float
    depth: float
    radius: float  # m: the uncertainty (one circle, grows with silence)
    target: tuple[float, float, float] | None  # where the shore thinks the vehicle is going
    age: float  # s since the last report

    def as_dict(self) -> dict:
        return {"north": round(self.north, 2), "east": round(self.east, 2), "depth": round(self.depth, 2),
                "radius_m": round(self.radius, 2), "age_s": round(self.age, 1),
                "target": None if self.target is None else [round(x, 2) for x in self.target]}  # fmt: skip


def target_of(
    cp: dict, waypoints: list[dict] | None, command: dict | None
) -> tuple[float, float, float] | None:
    """Where the vehicle in check-point ``cp`` is steering: its mission's waypoint, home, the commanded
    target (``command``: the executing command and the pose it was given from), or None (staying put)."""
    state = cp.get("state")
    if state in ("preprogrammed", "awaiting_command") and waypoints:
        w = waypoints[min(int(cp.get("waypoint", 0)), len(waypoints) - 1)]
        return (w["north"], w["east"], w["depth"])
    if state == "returning":
        return (0.0, 0.0, cp["depth"])
    if state == "commanded" and command:
        if command["command"] == "goto_depth":
            return (cp["north"], cp["east"], command["depth"])
        if command["command"] == "move" and command.get("from"):
            f = command["from"]
            north, east = move_target(f["north"], f["east"], f["heading"], command["distance"], command["angle"],
                                      command.get("absolute_angle", False))  # fmt: skip
            return (north, east, f["depth"] + command["depth"])
    return None


def estimate(cp: dict, heard_at: float, now: float, target: tuple[float, float, float] | None,
             speed: float | None = None) -> Estimate:  # fmt: skip
    """Dead reckoning from the last report toward ``target`` at ``speed`` (m/s) for the time since."""
    age = max(0.0, now - heard_at)
    north, east, depth = cp["north"], cp["east"], cp["depth"]
    moving = cp.get("state") in MOVING
    if target is not None and moving:
        step = (speed if speed is not None else DEFAULT_SPEED) * age
        dn, de, dd = target[0] - north, target[1] - east, target[2] - depth
        dist = math.hypot(dn, de)
        f = 1.0 if dist <= step else step / dist
        north, east = north + f * dn, east + f * de
        depth += math.copysign(min(abs(dd), 0.2 * age), dd)  # vertical rate about 0.2 m/s
    return Estimate(north, east, depth, BASE_UNCERTAINTY + DRIFT * age, target if moving else None, age)


def speed_between(a: dict, a_at: float, b: dict, b_at: float) -> float | None:
    """The speed (m/s, shore clock) between two check-points received at ``a_at`` and ``b_at``."""
    if b_at - a_at <= 0:
        return None
    return math.hypot(b["north"] - a["north"], b["east"] - a["east"]) / (b_at - a_at)


def vehicle_estimate(s: Session, vehicle: Vehicle, now: float, time_scale: float = 1.0) -> dict:
    """The last reported check-point (from the database: it survives a shore restart), its age, and the
    shore's prediction since: ``{"reported": ..., "heard_at": ..., "age_s": ..., "predicted": ...}``."""
    rows = s.exec(select(Packet).where(Packet.vehicle_id == vehicle.id, Packet.type == "checkpoint", Packet.auth == "verified")
                  .order_by(col(Packet.id).desc()).limit(2)).all()  # fmt: skip
    if not rows:
        return {"reported": None, "heard_at": None, "age_s": None, "predicted": None}
    last = rows[0]
    cp = last.body
    speed = speed_between(rows[1].body, rows[1].at, cp, last.at) if len(rows) == 2 else None
    if speed is not None:
        speed = min(
            max(speed, 0.1 * time_scale), vehicle.max_speed * time_scale
        )  # shore clock: simulations run faster
    mission = s.exec(select(Mission).where(Mission.vehicle_id == vehicle.id, Mission.number == cp.get("mission_id"))
                     .order_by(col(Mission.id).desc())).first()  # fmt: skip
    target = target_of(cp, mission.plan.get("waypoints") if mission else None, _commanded(s, vehicle, cp))
    guess = estimate(cp, last.at, now, target, speed)
    label, hint = STATES.get(cp.get("state", ""), (cp.get("state", "?"), ""))
    return {"reported": cp, "heard_at": last.at, "age_s": round(guess.age, 1), "state_label": label,
            "state_hint": hint, "speed_mps": None if speed is None else round(speed, 2), "drift_mps": DRIFT,
            "predicted": guess.as_dict()}  # fmt: skip


def _commanded(s: Session, vehicle: Vehicle, cp: dict) -> dict | None:
    """The command the check-point says the vehicle follows, with the pose it was given from (the last
    check-point before it was first sent)."""
    if cp.get("state") != "commanded" or not cp.get("last_command"):
        return None
    command = s.exec(
        select(Command).where(Command.vehicle_id == vehicle.id, Command.seq == cp["last_command"])
    ).first()
    if command is None:
        return None
    sent = s.exec(select(CommandEvent.at).where(CommandEvent.command_id == command.id, CommandEvent.status == "sent")
                  .order_by(col(CommandEvent.id))).first()  # fmt: skip
    before = s.exec(select(Packet).where(Packet.vehicle_id == vehicle.id, Packet.type == "checkpoint", Packet.auth == "verified",
                                         Packet.at <= (sent or command.created_at))
                    .order_by(col(Packet.id).desc())).first()  # fmt: skip
    return {"command": command.command, "distance": command.distance, "angle": command.angle,
            "depth": command.depth, "absolute_angle": command.absolute_angle,
            "from": before.body if before else None}  # fmt: skip


def shares_from_db(s: Session, polls: int, channels: dict[str, int]) -> dict:
    """``link_shares`` counted from the stored frames, packets and telemetry (``channels``: per stream
    name, its channel count; ``polls``: the link engine's counter since it started, the one use the
    database does not hold)."""
    sent = s.exec(select(func.count()).select_from(Frame).where(Frame.direction == "out")).one()
    by_type = dict(s.exec(select(Packet.type, func.count()).group_by(Packet.type)).all())
    samples = 0
    rows = s.exec(select(Telemetry.stream, func.count()).where(Telemetry.certain == True)  # noqa: E712
                  .group_by(Telemetry.stream)).all()  # fmt: skip
    for stream, ticks in rows:
        samples += channels.get(stream, 1) * int(ticks)
    return link_shares(
        int(sent), polls, int(by_type.get("checkpoint", 0)), int(by_type.get("priority", 0)), samples
    )


# --- the link's airtime by use -------------------------------------------------------------------------

FRAME_S = rates.data_airtime_s(0, 1)  # one 32-byte rate-0 frame, acquisition included
POLL_S = rates.airtime_s(rates.CYCLE_INIT_BITS, 0)
ACK_S = rates.airtime_s(rates.ACK_BITS, 0)


def link_shares(commands_sent: int, polls: int, checkpoints: int, priority: int, samples: int) -> dict:
    """Airtime by use (seconds and shares), and bits saved against sending every sample (16 bits each)."""
    airtime = {"commands": commands_sent * (FRAME_S + ACK_S), "polls": polls * POLL_S,
               "checkpoints": checkpoints * FRAME_S, "priority": priority * FRAME_S}  # fmt: skip
    total = sum(airtime.values())
    raw_bits, sent_bits = samples * 16, priority * PACKET_SIZE * 8
    return {
        "airtime_s": {k: round(v, 1) for k, v in airtime.items()},
        "shares": {k: (round(v / total, 4) if total else 0.0) for k, v in airtime.items()},
        "counts": {"commands": commands_sent, "polls": polls, "checkpoints": checkpoints, "priority": priority,
                   "samples": samples},
        "bits": {"every_sample": raw_bits, "sent": sent_bits,
                 "saved_share": round(1 - sent_bits / raw_bits, 4) if raw_bits else None},
    }  # fmt: skip
