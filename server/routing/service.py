"""Routing: the gateways the center knows, which gateway each vehicle is on and why, operators' pins,
and the bookkeeping of each command's dispatches through the gateways.

The center calls ``seen`` for every gateway event (``beat`` for a heartbeat: what it says of the gateway
is kept for the screens, ``board``) and ``update`` after each batch of frames and on its dispatcher's
tick; ``update`` applies ``server.routing.choice`` to what every gateway heard of every vehicle in the
last ``routing_window`` s and saves what changed, with the reason. A heartbeat, a move and a pin are
published on the bus (``GatewayChanged``): the dashboard reads the gateways again.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Any

from sqlalchemy import Engine

from server.backhaul.subjects import COMMAND_MAX_AGE, GatewayState
from server.core.config import Settings
from server.core.db import Tx, reading, saved_id, writing
from server.core.errors import NotFound
from server.core.events import Bus, GatewayChanged
from server.routing import repository as repo
from server.routing.choice import Current, Decision, Quality, choose
from server.routing.models import Assignment, Dispatch, DispatchState, GatewayRecord
from server.vehicles import repository as vehicle_repo
from server.vehicles.models import Vehicle

log = logging.getLogger("tacit.server.routing")

ARRIVAL_SLACK = 5.0  # s: a check-point the vehicle stamped this long after an ACK was reported names
# the command as received, or later ones (the vehicle's clock is its SYNCs', within a second or two)


def _last_command(checkpoints: list[dict[str, Any]], after: float) -> int | None:
    """The last command (16 bits) named by the newest check-point stamped after ``after``; None if none."""
    later = [cp for cp in checkpoints if float(cp.get("time", 0)) >= after]
    newest = max(later, key=lambda cp: float(cp.get("time", 0)), default=None)
    return None if newest is None else int(newest.get("last_command", 0))


def _arrived(last: int, seq: int) -> bool:
    """A vehicle whose last command is ``last`` (16 bits) has received command ``seq``: ``last`` is it or
    one after it (within half the 16-bit circle)."""
    return (last - seq) % 65536 < 32768 if last else False


@dataclass(frozen=True)
class Route:
    """A vehicle's gateway, why, and how every gateway heard it."""

    vehicle: Vehicle
    gateway: str | None
    pinned: bool
    since: float | None
    reason: str
    heard: dict[str, Quality] = field(default_factory=dict)


@dataclass(frozen=True)
class GatewayStatus:
    """A gateway as the screens show it: its record (what its last heartbeat said), whether it beats,
    the frames it relayed (the records kept), the vehicles assigned to it (id, name, pinned), and why it
    is routed around ("": it is not)."""

    record: GatewayRecord
    alive: bool
    frames: int
    vehicles: list[tuple[int, str, bool]]
    faulty: str = ""


class Routing:
    def __init__(self, db: Engine, settings: Settings, bus: Bus | None = None) -> None:
        self.db = db
        self.settings = settings
        self.bus = bus

    # --- gateways -------------------------------------------------------------------------------

    def seen(self, gateway: str, at: float | None = None) -> None:
        """``gateway`` was heard from (a heartbeat, an event) at ``at`` (the center's clock, default now)."""
        with writing(self.db) as s:
            repo.touch_gateway(s, gateway, time.time() if at is None else at)
            s.commit()

    def beat(self, gateway: str, at: float, beat: GatewayState) -> None:
        """A heartbeat of ``gateway`` at ``at``: what it says is kept (an older one than the last event is
        only counted as seen), and whether it beats since its last silence."""
        with writing(self.db) as s:
            row = repo.gateway(s, gateway)
            if row is None:
                row = GatewayRecord(name=gateway, first_seen=at, last_seen=at)
            elif at < row.last_seen:  # a late copy: what it says is older than what is kept
                return
            if row.beating_since is None or at - row.last_seen > self.settings.gateway_timeout:
                row.beating_since = at
            place, outage = beat.place, beat.outage
            row.last_seen, row.address, row.modem, row.outbox = at, beat.address, beat.modem, beat.outbox
            row.mac = beat.link
            row.north, row.east, row.depth = (
                (place.north, place.east, place.depth) if place else (None, None, None)
            )
            if outage is not None:
                row.outage_s, row.outage_ended, row.outage_backlog = (
                    outage.lasted,
                    outage.ended,
                    outage.backlog,
                )
            repo.save_gateway(s, row)
            s.commit()
        self._changed(gateway, "heartbeat")

    def gateways(self) -> list[GatewayRecord]:
        with reading(self.db) as s:
            return repo.gateways(s)

    def board(self, now: float | None = None) -> list[GatewayStatus]:
        """Every gateway the center knows, as the screens show it."""
        alive = self.alive(now)
        with reading(self.db) as s:
            rows, frames, current = repo.gateways(s), repo.frames_by_gateway(s), repo.assignments(s)
            names = {saved_id(v): v.name for v in vehicle_repo.every(s)}
        vehicles: dict[str, list[tuple[int, str, bool]]] = {}
        for vehicle_id, a in sorted(current.items()):
            vehicles.setdefault(a.gateway, []).append((vehicle_id, names.get(vehicle_id, "?"), a.pinned))
        return [
            GatewayStatus(
                row,
                row.name in alive,
                frames.get(row.name, 0),
                vehicles.get(row.name, []),
                self.faulty(row, time.time() if now is None else now),
            )
            for row in rows
        ]

    def assignments(self) -> dict[int, Assignment]:
        """Each vehicle's gateway (by vehicle id); a vehicle no gateway has heard has none."""
        with reading(self.db) as s:
            return repo.assignments(s)

    def _changed(self, gateway: str, what: str, vehicle: str | None = None) -> None:
        if self.bus is not None:
            self.bus.publish(GatewayChanged(gateway=gateway, what=what, vehicle=vehicle))

    def alive(self, now: float | None = None) -> set[str]:
        """The gateways heard from within ``gateway_timeout`` s."""
        limit = (time.time() if now is None else now) - self.settings.gateway_timeout
        return {g.name for g in self.gateways() if g.last_seen >= limit}

    def faulty(self, row: GatewayRecord, now: float) -> str:
        """Why the gateway is routed around ("": it is not): its last fault within ``gateway_quarantine``."""
        recent = row.faulty_at is not None and now < row.faulty_at + self.settings.gateway_quarantine
        return row.faulty if recent else ""

    def usable(self, now: float | None = None) -> set[str]:
        """The live gateways that are not faulty: those the vehicles are assigned to and commands go
        through."""
        now = time.time() if now is None else now
        limit = now - self.settings.gateway_timeout
        return {g.name for g in self.gateways() if g.last_seen >= limit and not self.faulty(g, now)}

    # --- a gateway's word against what the center can check ----------------------------------------

    def audit(self, now: float | None = None) -> list[Dispatch]:
        """Check the gateways' word against the vehicles': a gateway is faulty (routed around for
        ``gateway_quarantine`` s, and shown so) when

        * it reported a command acknowledged, and a verified check-point the vehicle stamped
          ``ARRIVAL_SLACK`` s after the center took that report, and heard a frame of slots after it (a
          check-point made before the command came has been sent at a poll by then), names an older command as
          its last (the command never arrived): the dispatch is ``refuted``; these are returned, for
          their commands to go again through another gateway;
        * it has held a command (stored or sent, no final outcome) for ``gateway_faulty_slots`` of its
          slots (a slot of each live gateway in turn), reported nothing of any command in that time, and
          nothing verified of the vehicle came through it: the dispatch is ``unanswered``, and the
          command goes through the next gateway."""
        now = time.time() if now is None else now
        frame = self.settings.tdma_slot * max(1, len(self.alive(now)))  # a slot of each live gateway
        with writing(self.db) as s:
            refuted, faults = self._refuted(s, now, max(ARRIVAL_SLACK, frame))
            faults += self._held(s, now, self.settings.gateway_faulty_slots * frame)
            for gateway, why in faults:
                repo.set_faulty(s, gateway, why, now)
            s.commit()
        for gateway, why in faults:
            log.error("gateway %s is faulty, routed around: %s", gateway, why)
            self._changed(gateway, "faulty")
        return refuted

    @staticmethod
    def _refuted(s: Tx, now: float, heard_after: float) -> tuple[list[Dispatch], list[tuple[str, str]]]:
        """The ACKs of the commands still only acknowledged that a later verified check-point (heard
        ``heard_after`` s after the report, stamped ``ARRIVAL_SLACK`` s after it) refutes: those
        dispatches, and their gateways' faults."""
        refuted, faults = [], []
        for row, command in repo.acked_since(s, now - COMMAND_MAX_AGE):
            checkpoints = repo.checkpoints(s, command.vehicle_id, row.updated_at + heard_after)
            last = _last_command(checkpoints, row.updated_at + ARRIVAL_SLACK)
            if last is None or _arrived(last, command.seq):
                continue
            repo.set_dispatch(s, row, DispatchState.REFUTED)
            refuted.append(row)
            faults.append((row.gateway, f"reported command {command.seq} acknowledged; the vehicle's "
                           f"check-points since name command {last} as their last: it never arrived"))  # fmt: skip
        return refuted, faults

    def _held(self, s: Tx, now: float, span: float) -> list[tuple[str, str]]:
        """The gateways that held a command for ``span`` s without a report of any command or a verified
        frame of its vehicle: their dispatches unanswered, and their faults."""
        faults = []
        for row, command in repo.held_since(s, now - span):
            vehicle = vehicle_repo.get(s, command.vehicle_id)
            if (
                vehicle is None
                or repo.reported_since(s, row.gateway, now - span)
                or repo.heard_through(s, vehicle.address, row.gateway, now - span)
            ):
                continue
            repo.set_dispatch(s, row, DispatchState.UNANSWERED)
            faults.append((row.gateway, f"held command {command.seq} for {span:.0f} s (its "
                           f"{self.settings.gateway_faulty_slots} slots) without a word of it, nor a verified "
                           "frame of the vehicle"))  # fmt: skip
        return faults

    # --- assignment ------------------------------------------------------------------------------

    def _heard(self, s: Tx, now: float) -> dict[int, dict[str, Quality]]:
        """By vehicle address, by gateway: how it heard the vehicle in the window. Only frames that
        verified count (a tag or a check-point's MAC held, on a packet heard for the first time), each at
        most at ``routing_snr_cap`` dB: what a gateway claims of a frame is not evidence."""
        since = now - self.settings.routing_window
        totals = repo.frames_sent(s, since)
        heard: dict[int, dict[str, Quality]] = {}
        for src, gateway, n, snr in repo.hearing(s, since, self.settings.routing_snr_cap):
            share = n / max(1, totals.get(src, n))
            heard.setdefault(src, {})[gateway] = Quality(n, snr if snr is not None else 0.0, min(1.0, share))
        return heard

    def update(self, now: float | None = None) -> list[Route]:
        """Apply the rule to every vehicle; the routes that moved."""
        now = time.time() if now is None else now
        alive = self.usable(now)
        moved: list[Route] = []
        with writing(self.db) as s:
            heard, current = self._heard(s, now), repo.assignments(s)
            for vehicle in vehicle_repo.every(s):
                row = current.get(saved_id(vehicle))
                was = Current(row.gateway, row.since, row.pinned) if row else None
                decision = choose(
                    was, heard.get(vehicle.address, {}), alive, now,
                    self.settings.routing_margin, self.settings.routing_dwell,
                )  # fmt: skip
                if self._apply(s, vehicle, row, decision, now):
                    moved.append(Route(vehicle, decision.gateway, False, now, decision.reason))
            s.commit()
        for route in moved:
            log.info("vehicle %s now on gateway %s: %s", route.vehicle.name, route.gateway, route.reason)
            self._changed(route.gateway or "", "assignment", route.vehicle.name)
        return moved

    @staticmethod
    def _apply(s: Tx, vehicle: Vehicle, row: Assignment | None, decision: Decision, now: float) -> bool:
        """Save the decision (its reason even when nothing moved); whether the vehicle moved."""
        if decision.gateway is None:
            return False
        if decision.moved or row is None:
            repo.save_assignment(
                s,
                Assignment(
                    vehicle_id=saved_id(vehicle), gateway=decision.gateway, since=now, reason=decision.reason
                ),
            )
            return True
        if row.reason != decision.reason:
            row.reason = decision.reason
            repo.save_assignment(s, row)
        return False

    def routes(self, now: float | None = None) -> list[Route]:
        """Every vehicle's gateway, why, and how each gateway heard it."""
        now = time.time() if now is None else now
        with reading(self.db) as s:
            heard, current = self._heard(s, now), repo.assignments(s)
            vehicles = vehicle_repo.every(s)
        routes = []
        for vehicle in vehicles:
            row = current.get(saved_id(vehicle))
            routes.append(
                Route(
                    vehicle,
                    row.gateway if row else None,
                    row.pinned if row else False,
                    row.since if row else None,
                    row.reason if row else "no gateway has heard it",
                    heard.get(vehicle.address, {}),
                )
            )
        return routes

    def pin(self, vehicle_id: int, gateway: str | None) -> Route:
        """Pin the vehicle to ``gateway`` (an operator's choice, kept whatever the scores), or unpin it
        (``None``: the rule chooses again from the next update). NotFound for an unknown vehicle or
        gateway."""
        with writing(self.db) as s:
            vehicle = vehicle_repo.get(s, vehicle_id)
            if vehicle is None:
                raise NotFound(f"no vehicle {vehicle_id}", "vehicle_id")
            row = repo.assignments(s).get(vehicle_id)
            if gateway is None:
                if row is not None:
                    row.pinned, row.reason = False, "unpinned by an operator"
                    repo.save_assignment(s, row)
            else:
                if repo.gateway(s, gateway) is None:
                    raise NotFound(f"no gateway {gateway!r}", "gateway")
                repo.save_assignment(
                    s,
                    Assignment(vehicle_id=vehicle_id, gateway=gateway, pinned=True, since=time.time(),
                               reason="pinned by an operator"),
                )  # fmt: skip
            s.commit()
        route = next(r for r in self.routes() if saved_id(r.vehicle) == vehicle_id)
        self._changed(route.gateway or "", "pin" if gateway else "unpin", route.vehicle.name)
        return route

    def candidates(self, vehicle: Vehicle, now: float | None = None) -> list[str]:
        """The live gateways not faulty to send the vehicle's command through, in order: its own first,
        then the others that heard it in the window, best first."""
        now = time.time() if now is None else now
        alive = self.usable(now)
        route = next((r for r in self.routes(now) if saved_id(r.vehicle) == saved_id(vehicle)), None)
        heard = route.heard if route else {}
        ranked = sorted((g for g in heard if g in alive), key=lambda g: -heard[g].score)
        own = [route.gateway] if route and route.gateway in alive else []
        return own + [g for g in ranked if g not in own]

    # --- dispatches ------------------------------------------------------------------------------

    def dispatches(self, command_id: int) -> list[Dispatch]:
        with reading(self.db) as s:
            return repo.dispatches(s, command_id)

    def add_dispatch(self, row: Dispatch) -> None:
        with writing(self.db) as s:
            repo.add_dispatch(s, row)
            s.commit()

    def set_dispatch(self, dispatch_id: str, state: DispatchState) -> Dispatch | None:
        """A gateway's report of one dispatch: moved forward to ``state`` (never back, never out of a
        final state); the dispatch if it moved."""
        report = self.report(dispatch_id, state, 0)
        return report.dispatch if report is not None and report.moved else None

    def report(
        self, dispatch_id: str, state: DispatchState | None, attempt: int, reporter: str | None = None
    ) -> Report | None:
        """What gateway ``reporter`` said of a dispatch (None: the center's own verdict): its state moved
        forward (or from unanswered to acked: the ACK came after the center had given up on the gateway),
        and whether attempt number ``attempt`` is news (an event delivered twice is counted once). None
        for an unknown dispatch. A gateway's word counts only for the dispatches that went through it:
        another's is ignored, logged and counted (the reporter's ``foreign_reports``), the dispatch left
        alone."""
        with writing(self.db) as s:
            row = repo.dispatch(s, dispatch_id)
            if row is None:
                log.warning("gateway %s reported an unknown command %s", reporter, dispatch_id[:128])
                return None
            if reporter is not None and reporter != row.gateway:
                repo.count_foreign_report(s, reporter)
                s.commit()
                log.error(
                    "gateway %s reported %s of dispatch %s, which went through %s: ignored",
                    reporter, state, row.id, row.gateway,
                )  # fmt: skip
                return Report(row, moved=False, fresh_attempt=False, foreign=True)
            fresh = attempt > row.attempts
            # the center took the gateway for down, but it got the vehicle's ACK: its word wins
            late_ack = row.state == DispatchState.UNANSWERED and state == DispatchState.ACKED
            moved = state is not None and (late_ack or (not row.final and _RANK[state] > _RANK[row.state]))
            if fresh:
                row.attempts = attempt
            if moved and state is not None:
                repo.set_dispatch(s, row, state)
            elif fresh:
                repo.set_dispatch(s, row, row.state)
            s.commit()
            return Report(row, moved, fresh)


@dataclass(frozen=True)
class Report:
    dispatch: Dispatch
    moved: bool
    fresh_attempt: bool
    foreign: bool = False  # reported by a gateway the dispatch did not go through: ignored


_RANK = {
    DispatchState.PUBLISHED: 0,
    DispatchState.STORED: 1,
    DispatchState.SENT: 2,
    **dict.fromkeys((state for state in DispatchState if state.final), 3),
}
