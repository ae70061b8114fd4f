"""One shore station: the parts ``create_app`` builds once and the routes, the map and the launchers use.

Routes get the parts through the typed dependencies of ``server.api.deps``; nothing else reaches into
``app.state``.
"""

from __future__ import annotations

from dataclasses import dataclass

from sqlalchemy import Engine

from server.commands.service import CommandDesk
from server.core.config import Settings
from server.core.events import Bus, Watcher
from server.core.security import Throttle
from server.link.engine import LinkEngine
from server.link.ingest import Ingest
from server.missions.service import Missions
from server.missions.teams import Teams
from server.operators.service import Operators
from server.routing.service import Routing
from server.safety.service import Separation
from server.screens.service import Screens
from server.telemetry.metadata import About
from server.telemetry.service import TelemetryReader
from server.vehicles.service import Vehicles
from tacit.streams import default_streams


@dataclass
class Shore:
    settings: Settings
    db: Engine
    bus: Bus
    ingest: Ingest
    link: LinkEngine
    vehicles: Vehicles
    commands: CommandDesk
    missions: Missions
    telemetry: TelemetryReader
    screens: Screens
    operators: Operators
    sign_ins: Throttle  # the API's wrong tokens, by client address
    safety: Separation
    teams: Teams
    watcher: Watcher  # runs the safety checks and the team missions' steps off the event loop
    routing: Routing  # the center's gateways and each vehicle's (empty on a single shore)

    @classmethod
    def build(cls, settings: Settings, db: Engine, ingest_type: type[Ingest] = Ingest) -> Shore:
        """``ingest_type``: the center's ``RelayIngest`` (frames from the gateways), else the link's."""
        bus = Bus()
        ingest = ingest_type(db, bus, default_streams(), settings)
        vehicles = Vehicles(db)
        commands = CommandDesk(
            db, bus, ingest.pose, settings.max_queued_commands, withdrawable=ingest.relayed
        )
        link = LinkEngine(settings, db, bus, ingest, commands, vehicles)
        commands.wake = link.wake  # a queued command starts the next slot at once
        operators = Operators(settings, db)
        routing = Routing(db, settings, bus)
        screens = Screens(settings, db, link, routing)
        missions = Missions(db, commands)
        safety = Separation(settings, screens, vehicles, commands, missions, bus)
        commands.guard = safety.check  # every command's path, against the other vehicles'
        teams = Teams(settings, db, commands, vehicles, safety, bus)
        watcher = Watcher(bus, settings.separation_check_interval / settings.time_scale)
        watcher.on_event(safety.on_event)
        watcher.every(safety.recheck)
        watcher.on_event(teams.on_event)
        return cls(
            settings,
            db,
            bus,
            ingest,
            link,
            vehicles,
            commands,
            missions,
            TelemetryReader(db, ingest.streams, About.of(settings)),
            screens,
            operators,
            Throttle(settings, operators.actor),
            safety,
            teams,
            watcher,
            routing,
        )
