"""One shore station: the parts ``create_app`` builds once and the routes, the map and the launchers use.

Routes get the parts through the typed dependencies of ``server.api.deps``; nothing else reaches into
``app.state``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from sqlalchemy import Engine

from server.events import EventBus
from server.link.engine import LinkEngine
from server.link.ingest import Ingest
from server.services.commands import CommandDesk
from server.settings import Settings
from tacit.streams import default_streams

if TYPE_CHECKING:
    from server.map.scene import OperatorMap


@dataclass
class Shore:
    settings: Settings
    db: Engine
    bus: EventBus
    ingest: Ingest
    link: LinkEngine
    commands: CommandDesk
    map: OperatorMap | None = None

    @classmethod
    def build(cls, settings: Settings, db: Engine) -> Shore:
        bus = EventBus()
        ingest = Ingest(db, bus, default_streams())
        link = LinkEngine(settings, db, bus, ingest)
        commands = CommandDesk(db, bus, ingest.pose, link.wake)
        return cls(settings, db, bus, ingest, link, commands)
