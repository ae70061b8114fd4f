"""What the operator's two screens (the dashboard and the 3D map) read, in one place: the command form
for a vehicle, what the shore knows of a vehicle and how sure (``estimate``), the link's airtime by use
(``airtime``), the link's status, the gateways (a center's; ``Routing.board``, the one source of ``GET
/api/v1/gateways``) and each vehicle's, the configuration the browser needs, and the recent commands.
The screens call this service (and the command desk to send); never a session or the link engine's dicts.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from sqlalchemy import Engine

from server.commands import repository as command_repo
from server.commands.models import CommandRecord
from server.core.config import Settings
from server.core.db import Tx, reading, saved_id
from server.link.engine import LinkEngine
from server.missions import repository as mission_repo
from server.routing.models import Assignment
from server.routing.service import GatewayStatus, Routing
from server.screens import airtime, estimate, fleet, states
from server.screens.form import command_form
from server.telemetry import clock
from server.telemetry import repository as telemetry
from server.telemetry import service as telemetry_service
from server.telemetry.models import Packet
from server.vehicles import repository as vehicle_repo
from server.vehicles import service as vehicles
from server.vehicles.models import Vehicle
from tacit.navigation import Origin, Pose
from tacit.streams import UNITS

REPORTED = (
    "reported",
    "heard_at",
    "age_s",
    "state_label",
    "state_hint",
    "predicted",
)  # estimate()'s, per row


COUNTS_TTL_S = 5.0  # s the fleet's airtime counts are kept before they are counted again


@dataclass(frozen=True)
class Channel:
    """What the link says of every vehicle, read once per listing of the fleet."""

    link: dict[str, dict[str, Any]]  # LinkEngine.status()'s vehicles, by name
    planned: dict[int, dict[str, Any]]  # LinkEngine.schedule_status()'s vehicles, by vehicle id
    frames_sent: dict[int, int]  # by modem address
    packets: dict[tuple[int, str], int]  # by (vehicle id, packet type)
    colours: dict[str, str]  # by vehicle name
    gateways: dict[int, Assignment]  # by vehicle id: its gateway (a center's; none on a single shore)

    def slots(self) -> list[tuple[float, float]]:
        """Each planned vehicle's (share, slot length)."""
        return [(p["share"], p["slot_s"]) for p in self.planned.values()]


class Screens:
    def __init__(self, settings: Settings, db: Engine, link: LinkEngine, routing: Routing) -> None:
        self.settings = settings
        self.db = db
        self.link = link
        self.routing = routing
        self.map_port: Callable[[], int | None] = lambda: None  # set when the map runs
        self.listening = time.time()  # when this shore began to listen: a silence counts from here at most
        self._counted: tuple[float, dict[int, int], dict[tuple[int, str], int]] = (-1e18, {}, {})

    # --- vehicles ---------------------------------------------------------------------------------

    def vehicles(self) -> list[Vehicle]:
        with reading(self.db) as s:
            return vehicle_repo.every(s)

    def vehicle(self, name: str) -> Vehicle | None:
        with reading(self.db) as s:
            return vehicle_repo.by_name(s, name)

    def pose(self, vehicle: Vehicle) -> Pose | None:
        """The pose the vehicle last reported (None before its first check-point)."""
        return self.link.ingest.pose(vehicle.address)

    def form(self, vehicle_id: int | None = None) -> dict[str, Any]:
        """Each command's fields for the vehicle (its limits), or for the packet alone (None)."""
        if vehicle_id is None:
            return command_form()
        with reading(self.db) as s:
            return command_form(vehicles.get(s, vehicle_id).limits())

    def estimate(self, vehicle_id: int, now: float | None = None) -> dict[str, Any]:
        """The last verified check-point (from the database: it survives a shore restart), its age, and
        the shore's prediction since: ``{"reported", "heard_at", "age_s", "predicted", ...}``."""
        with reading(self.db) as s:
            vehicle = vehicles.get(s, vehicle_id)
            rows = telemetry.checkpoints(s, vehicle_id, 2)
            if not rows:
                return {"reported": None, "heard_at": None, "age_s": None, "predicted": None}
            last, cp = rows[0], rows[0].body
            mission = mission_repo.numbered(s, vehicle_id, int(cp.get("mission_id", 0)))
            followed = _commanded(s, vehicle, cp)
        speed = _speed(rows, vehicle, self.settings.time_scale)
        waypoints = mission.plan.get("waypoints") if mission else None
        target = estimate.target_of(cp, waypoints, followed, vehicle.home)
        guess = estimate.estimate(cp, last.at, time.time() if now is None else now, target, speed)
        label, hint = states.label(cp.get("state", ""))
        return {
            "reported": cp,
            "heard_at": last.at,
            "age_s": round(guess.age, 1),
            "state_label": label,
            "state_hint": hint,
            "speed_mps": None if speed is None else round(speed, 2),
            "drift_mps": estimate.DRIFT,
            "predicted": guess.as_dict(),
        }

    def route(self, vehicle_id: int) -> list[tuple[float, float, float]]:
        """The waypoints (north, east, depth) of the vehicle's started mission, in the fleet's frame (a
        plan's are relative to the vehicle's home)."""
        with reading(self.db) as s:
            vehicle = vehicles.get(s, vehicle_id)
            mission = mission_repo.started(s, vehicle_id)
        north, east = vehicle.home
        return [
            (north + w["north"], east + w["east"], w["depth"])
            for w in (mission.plan.get("waypoints", []) if mission else [])
        ]

    def recent_commands(self, n: int = 6) -> list[CommandRecord]:
        with reading(self.db) as s:
            return command_repo.page(s, None, n)

    # --- the fleet --------------------------------------------------------------------------------

    def fleet(self, now: float | None = None) -> dict[str, Any]:
        """Every vehicle as both screens list it, in order of registration (its colour's order), with the
        fleet's one origin (latitude and longitude, None when not known) and the palette."""
        now = time.time() if now is None else now
        channel = self._channel()
        rows = [self._member(v, channel, now) for v in self.vehicles()]
        total = sum(r["airtime_s"]["total"] for r in rows)
        for row in rows:
            row["airtime_share"] = round(row["airtime_s"]["total"] / total, 4) if total else 0.0
        origin = self.settings.origin
        return {
            "origin": None if origin is None else {"lat": origin[0], "lon": origin[1]},
            "palette": list(fleet.PALETTE),
            "vehicles": rows,
        }

    def _channel(self) -> Channel:
        planned = {p["vehicle_id"]: p for p in self.link.schedule_status()["vehicles"]}
        sent, packets = self._counts()
        return Channel(
            self.link.status()["vehicles"], planned, sent, packets, self.colours(), self.routing.assignments()
        )

    def _counts(self) -> tuple[dict[int, int], dict[tuple[int, str], int]]:
        """Frames sent by address and packets by vehicle and type, counted again at most every
        ``COUNTS_TTL_S``: the map lists the fleet every second, and the counts scan whole tables."""
        if time.monotonic() - self._counted[0] > COUNTS_TTL_S:
            with reading(self.db) as s:
                counts = telemetry.frames_sent_by_dest(s), telemetry.packets_by_vehicle_and_type(s)
            self._counted = (time.monotonic(), *counts)
        return self._counted[1], self._counted[2]

    def colours(self) -> dict[str, str]:
        """Each vehicle's colour by name: the palette in order of registration (``fleet.colour``)."""
        return {v.name: fleet.colour(i) for i, v in enumerate(self.vehicles())}

    def _member(self, vehicle: Vehicle, channel: Channel, now: float) -> dict[str, Any]:
        """One vehicle's row: what it last reported, its link, whether it is overdue, its airtime."""
        vehicle_id = saved_id(vehicle)
        known = self.estimate(vehicle_id, now)
        with reading(self.db) as s:
            heard = [r.at for r in telemetry.checkpoints(s, vehicle_id, clock.WINDOW)]
            offset = telemetry_service.clock_offset(s, vehicle_id)
            waiting = command_repo.pending_count(s, vehicle_id)
        plan = channel.planned.get(vehicle_id)
        return {
            "id": vehicle_id,
            "name": vehicle.name,
            "address": vehicle.address,
            "colour": channel.colours[vehicle.name],
            "home": list(vehicle.home),
            **_gateway(channel.gateways.get(vehicle_id)),
            **self._reported(known, offset),
            **self._heard(vehicle, channel, heard, now),
            "next_slot": None if plan is None else plan["next_slot"],
            "share": vehicle.share,
            "airtime_s": _airtime(vehicle, plan, channel),
            "queued": waiting,
            "queue_cap": self.settings.max_queued_commands,
        }

    def _reported(self, known: dict[str, Any], offset: float | None) -> dict[str, Any]:
        """What the vehicle last reported (``estimate``), its time on the shore's clock with the vehicle's
        clock offset, and the prediction in latitude and longitude."""
        cp, predicted = known["reported"], known["predicted"]
        return {
            **{k: known.get(k) for k in REPORTED},
            "predicted_latlon": None if predicted is None else self.latlon(predicted["north"], predicted["east"]),
            "reported_shore_time": None if cp is None else clock.on_shore_clock(cp["time"], known["heard_at"], offset),
            "clock_offset_s": None if offset is None else round(offset, 2),
            "battery_v": None if cp is None else cp.get("battery"),
        }  # fmt: skip

    # --- the gateways (a center's) -----------------------------------------------------------------

    def gateways(self, now: float | None = None) -> list[dict[str, Any]]:
        """Every gateway the center knows (none on a single shore), as both screens show it and ``GET
        /api/v1/gateways`` lists it: beating (``up``, since its first heartbeat after a silence) or
        ``silent`` (since its last), its place, modem, outbox, last outage, frames and vehicles."""
        now = time.time() if now is None else now
        board = sorted(self.routing.board(now), key=lambda g: g.record.name)
        return [self._gateway(g, i, now) for i, g in enumerate(board)]

    def _gateway(self, g: GatewayStatus, index: int, now: float) -> dict[str, Any]:
        r = g.record
        since = (r.beating_since or r.first_seen) if g.alive else r.last_seen
        place = None if r.north is None or r.east is None else (r.north, r.east, r.depth or 0.0)
        outage = None if r.outage_s is None else (r.outage_s, r.outage_ended, r.outage_backlog)
        return {
            "name": r.name, "alive": g.alive, "state": "up" if g.alive else "silent", "since": since,
            "for_s": round(max(0.0, now - since), 1), "first_seen": r.first_seen, "last_seen": r.last_seen,
            "place": None if place is None else dict(zip(("north", "east", "depth"), place, strict=True)),
            "latlon": None if place is None else self.latlon(place[0], place[1]),
            "address": r.address, "modem": r.modem or None, "outbox": r.outbox,
            "last_outage": None if outage is None else dict(zip(("lasted_s", "ended", "backlog"), outage, strict=True)),
            "mac": r.mac,
            "frames": g.frames, "colour": fleet.gateway_colour(index, g.alive),
            "vehicles": [{"id": i, "name": name, "pinned": pinned} for i, name, pinned in g.vehicles],
            "faulty": g.faulty, "faulty_at": r.faulty_at, "foreign_reports": r.foreign_reports,
        }  # fmt: skip

    def latlon(self, north: float, east: float) -> list[float] | None:
        """A point of the fleet's frame in latitude and longitude, when the origin is known."""
        origin = self.settings.origin
        return None if origin is None else [round(x, 7) for x in Origin(*origin).to_global(north, east)]

    # --- the link ---------------------------------------------------------------------------------

    def link_status(self) -> dict[str, Any]:
        return self.link.status()

    def shares(self) -> dict[str, Any]:
        """The link's airtime by use, counted from the stored frames, packets and samples (so a restart
        keeps them) and the link engine's poll counter since it started."""
        channels = {spec.name: len(spec.channels) for spec in self.link.ingest.streams.values()}
        with reading(self.db) as s:
            sent, by_type, ticks = (
                telemetry.frames_sent(s),
                telemetry.packets_by_type(s),
                telemetry.certain_ticks_by_stream(s),
            )
        samples = sum(channels.get(stream, 1) * n for stream, n in ticks.items())
        return airtime.link_shares(
            sent,
            int(self.link.counters["polls"]),
            by_type.get("checkpoint", 0),
            by_type.get("priority", 0),
            samples,
        )

    def config(self) -> dict[str, Any]:
        """What the browser needs (no secrets): the map's port and public address (``map_url``: none when
        the browser reaches it on the dashboard's host), the streams' channels with units, what
        the mission states mean, the commands' fields and the simulated time scale (1 when real)."""
        streams = {
            s.name: {
                "channels": list(s.channels),
                "eps": list(s.eps),
                "period": s.period,
                "units": [UNITS.get(c, "") for c in s.channels],
            }
            for s in self.link.ingest.streams.values()
        }
        labels = {
            state.name.lower(): {"label": label, "hint": hint}
            for state, (label, hint) in states.LABELS.items()
        }
        return {
            "map_port": self.map_port(),
            "map_url": (self.settings.map_url or None) if self.map_port() is not None else None,
            "streams": streams,
            "states": labels,
            "form": command_form(),
            "time_scale": self.settings.time_scale,
        }

    def _heard(self, vehicle: Vehicle, channel: Channel, heard: list[float], now: float) -> dict[str, Any]:
        """The vehicle's link (last frame heard, SNR, range) and whether it is overdue for its place in the
        schedule (``fleet``: ``heard`` are its last check-points' arrival times), or awaited: never
        reported and its first report not due yet."""
        link = channel.link.get(vehicle.name, {})
        gap = fleet.report_gap(heard) or vehicle.report_interval / self.settings.time_scale
        limit = fleet.overdue_after(gap, fleet.slot_interval(vehicle.share, channel.slots()))
        last = link.get("last_heard")
        quiet = fleet.silence(last, self.listening, vehicle.created_at, now)
        awaited = last is None and not heard and quiet <= limit
        return {
            **{k: link.get(k) for k in ("last_heard", "snr_in", "snr_out", "range_m")},
            "overdue": quiet > limit,
            "overdue_after_s": round(limit, 1),
            "awaited": awaited,
            "first_report_due": round(now - quiet + limit, 1) if awaited else None,
        }


def _gateway(assignment: Assignment | None) -> dict[str, Any]:
    """The vehicle's gateway (a center's) and whether an operator pinned it there."""
    return {
        "gateway": None if assignment is None else assignment.gateway,
        "gateway_pinned": assignment is not None and assignment.pinned,
    }


def _airtime(vehicle: Vehicle, plan: dict[str, Any] | None, channel: Channel) -> dict[str, float]:
    """The vehicle's seconds on the air by use (what was sent to it, polls since start), and their total."""
    vehicle_id = saved_id(vehicle)
    seconds = airtime.by_use(
        channel.frames_sent.get(vehicle.address, 0),
        0 if plan is None else plan["polls"],
        channel.packets.get((vehicle_id, "checkpoint"), 0),
        channel.packets.get((vehicle_id, "priority"), 0),
    )
    return {**{k: round(v, 1) for k, v in seconds.items()}, "total": round(sum(seconds.values()), 1)}


def _speed(rows: list[Packet], vehicle: Vehicle, time_scale: float) -> float | None:
    """The vehicle's speed between its last two check-points (shore clock: simulations run faster),
    bounded to what it can do."""
    if len(rows) < 2:
        return None
    speed = estimate.speed_between(rows[1].body, rows[1].at, rows[0].body, rows[0].at)
    return None if speed is None else min(max(speed, 0.1 * time_scale), vehicle.max_speed * time_scale)


def _commanded(s: Tx, vehicle: Vehicle, cp: dict) -> dict | None:
    """The command the check-point says the vehicle follows, with the pose it was given from (the last
    check-point before it was first sent)."""
    if estimate.state_of(cp) is not estimate.MissionState.COMMANDED or not cp.get("last_command"):
        return None
    command = command_repo.by_seq(s, vehicle.id or 0, cp["last_command"])
    if command is None:
        return None
    sent = command_repo.first_sent_at(s, command.id)
    before = telemetry.checkpoints(s, vehicle.id or 0, 1, until=sent or command.created_at)
    return {
        "command": command.command,
        "distance": command.distance,
        "angle": command.angle,
        "depth": command.depth,
        "absolute_angle": command.absolute_angle,
        "from": before[0].body if before else None,
    }
