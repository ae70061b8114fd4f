"""The operator's 3D map (viser), served beside uvicorn in the same process.

Scene: x = east, y = north, z = up (z = -depth), metres from the fleet's origin. The map draws; what it
draws comes from the shore's services. It is made of layers, each its own module: the ground (water, axes,
depth scale: ``ground``), the vehicles (body, heading, label, prediction: ``vehicles``), their tracks and
the packets heard (``tracks``), where they are meant to go (missions, the separation check's paths, team
lanes: ``plans``), a center's gateways (``gateways``) and the water temperature (``field``: the samples,
and the estimate ``server.telemetry.field`` fits). Events reach the layers through one table by event
type (``OperatorMap.handle``); once a second the map lists the fleet (``Screens.fleet``) and the gateways,
and fits the view to them: it opens top-down on every vehicle and gateway, with room on the right for
the panel (``geometry.fit``), and "Fit all" returns there.

Each browser gets its own panel (``server.map.panel``): it acts for a signed-in operator only
(the API's tokens; observers watch), offers the same commands, fields, units and checks as the dashboard
(``server.screens.form``), and explains every item with a hint. The map reads through the screens'
service and sends through the command desk; it never opens a database session itself. viser runs its own
thread; its GUI callbacks run in its thread pool.
"""

from __future__ import annotations

import contextlib
import logging
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any, NamedTuple

from server.commands.models import CommandRecord
from server.commands.service import CommandDesk
from server.core.config import Settings
from server.core.events import (
    Bus,
    CommandChanged,
    Event,
    PacketHeard,
    PacketsSettled,
    TelemetryDecoded,
    VehicleReported,
)
from server.core.security import Lookup, Throttle
from server.map.field import Cloud, FieldLayer
from server.map.gateways import GatewayLayer, gateway_line
from server.map.geometry import PLAN_FOV, Point, far_plane, fit, top_down
from server.map.ground import Ground
from server.map.panel import OperatorPanel, colour_scale, fleet_html
from server.map.plans import PlanLayer
from server.map.tracks import TrackLayer
from server.map.vehicles import VehicleLayer
from server.missions.models import TeamMission
from server.safety.paths import Planned
from server.screens import fleet
from server.screens.service import Screens
from server.telemetry.field import TemperatureField
from server.vehicles.models import Vehicle
from tacit.navigation import Pose

log = logging.getLogger("tacit.server.map")

RECENT_COMMANDS = 10
PLANS_EVERY = 5.0  # s between drawings of the plans (each asks the separation check for every path)
FIT_EVERY = 10.0  # s between fits of the temperature field
REFIT = 10.0  # m: the view is fitted again when the fleet's extent changes by this much
PANEL_PX = 340  # the map's panel (viser's, at the right of the view): its width in pixels, with its margin
LABEL_PX = 160  # room left at the right for the label of what is furthest east
DEFAULT_ASPECT, DEFAULT_PANEL = 4 / 3, 0.35  # a view whose size is not known yet: narrow, a wide panel


class OperatorMap:
    def __init__(
        self,
        screens: Screens,
        desk: CommandDesk,
        bus: Bus,
        settings: Settings,
        lookup: Lookup,
        paths: Callable[[], list[Planned]],
        teams: Callable[[], list[TeamMission]],
    ) -> None:
        """``lookup``: the shore's one rule for tokens (``Operators.actor``), asked through a throttle of
        the map's own: every map client as one, as viser does not tell their addresses. ``paths``: the
        separation check's plans (``Separation.paths``); ``teams``: the team missions (``Teams.every``)."""
        self.screens = screens
        self.desk = desk
        self.bus = bus
        self.settings = settings
        self.paths = paths
        self.teams = teams
        self.sign_ins = Throttle(settings, lookup)
        self.field = TemperatureField()
        self.host = settings.host
        self.wanted_port = settings.map_port
        self.port: int | None = None
        self.server: Any = None
        self._updates = ThreadPoolExecutor(max_workers=1, thread_name_prefix="tacit-map")  # one: in order
        self._running = False
        self.reports: dict[str, dict] = {}  # by vehicle name: its last verified check-point
        self.colours: dict[str, str] = {}  # by vehicle name: as on the dashboard (server.screens.fleet)
        self.panels: dict[int, OperatorPanel] = {}  # by viser client id: one panel per browser
        self.last_pose: tuple[float, float] = (10.0, 10.0)  # north, east: where the views look
        self.fitted: list[tuple[float, float]] = []  # (north, east) of every vehicle and gateway
        self._fitted_to: tuple[tuple[int, int], ...] = ()
        self._gp_at = self._plans_at = 0.0
        self._handlers: dict[type[Event], Callable[[Any], None]] = {
            VehicleReported: self._reported,
            PacketHeard: self._heard,
            CommandChanged: self._command_status,
            TelemetryDecoded: self._decoded,
            PacketsSettled: self._settled,
        }

    # --- lifecycle ------------------------------------------------------------------------------

    def start(self) -> None:
        import viser

        with contextlib.redirect_stdout(sys.stderr):  # viser prints a banner; stdout belongs to our callers
            server = viser.ViserServer(host=self.host, port=self.wanted_port, verbose=False)
        self.port = server.get_port()  # viser takes the next free port if the wanted one is busy
        self.attach(server)
        server.on_client_connect(self._connected)
        server.on_client_disconnect(self._gone)
        self.bus.on_event(self._on_event)
        self._ticker = threading.Thread(target=self._tick_loop, daemon=True)
        self._running = True
        self._ticker.start()
        log.info("operator map on http://%s:%d", self.host, self.port)

    def attach(self, server: Any) -> None:
        """Draw on ``server`` (viser's): the ground (water, axes) and the layers."""
        self.server = server
        scene = server.scene
        self.ground = Ground(scene, self._origin_text())
        self.vehicles = VehicleLayer(scene, self._colour)
        self.tracks = TrackLayer(scene, self._colour)
        self.routes = PlanLayer(scene, self._colour)
        self.gateways = GatewayLayer(scene, self._colour)
        self.temperatures = FieldLayer(scene, self.field)
        self.ground.build()
        self._look(server.initial_camera, *top_down(*self.last_pose), far_plane(330.0))

    def stop(self) -> None:
        self._running = False
        self._updates.shutdown(wait=True, cancel_futures=True)
        if self.server is not None:
            with contextlib.redirect_stdout(sys.stderr):
                self.server.stop()

    def _origin_text(self) -> str:
        """The fleet's one origin (north = east = 0 for every vehicle), with its latitude and longitude when
        known."""
        origin = self.settings.origin
        return "fleet origin (0, 0)" + ("" if origin is None else f", {fleet.latlon_text(*origin)}")

    def _connected(self, client: Any) -> None:
        """A browser opened the map: its own panel, signed out, and the view fitted to the fleet."""
        try:
            panel = OperatorPanel(self, client)
        except Exception:
            log.exception("map panel for client %s failed", client.client_id)
            return
        self.panels[client.client_id] = panel
        panel.scale_html.content = colour_scale(*(self.temperatures.range or (None, None)))

    def _gone(self, client: Any) -> None:
        self.panels.pop(client.client_id, None)

    # --- what panels ask --------------------------------------------------------------------------

    def vehicle_names(self) -> list[str]:
        return [v.name for v in self.screens.vehicles()]

    def vehicle(self, name: str) -> Vehicle | None:
        return self.screens.vehicle(name)

    def pose(self, vehicle: Vehicle) -> Pose | None:
        return self.screens.pose(vehicle)

    def focus(self) -> tuple[float, float]:
        """(north, east) the views centre on: the vehicle's last reported position."""
        return self.last_pose

    def view_for(self, width: int | None, height: int | None) -> View | None:
        """The top-down view showing every vehicle and gateway in a browser's view ``width`` x ``height``
        pixels (unknown: a 4:3 one), the panel's ``PANEL_PX`` at its right left free; None before any is
        known."""
        if not self.fitted:
            return None
        aspect, panel = DEFAULT_ASPECT, DEFAULT_PANEL
        if width and height:
            aspect, panel = width / height, min(0.5, (PANEL_PX + LABEL_PX) / width)
        position, look_at, _seen = fit(self.fitted, aspect=aspect, panel=panel)
        return View(position, look_at, far_plane(position[2]))

    @property
    def suggestion(self) -> tuple[float, float] | None:
        return self.temperatures.suggestion

    @property
    def estimate_cloud(self) -> Cloud | None:
        return self.temperatures.estimate

    def command_list(self) -> str:
        """The panels' list of recent commands (markdown), newest first."""
        rows = self.screens.recent_commands(RECENT_COMMANDS)
        names = {v.id: v.name for v in self.screens.vehicles()}
        return "\n".join(f"- {command_line(c, names.get(c.vehicle_id, '?'))}" for c in rows) or "none yet"

    # --- live updates ---------------------------------------------------------------------------

    def _on_event(self, event: Event) -> None:
        """Called on the FastAPI loop for every published event: handed to the map's own thread, in order,
        so that the scene's database reads never hold up the loop that serves the modem."""
        if not self._running:  # events published while the server stops (the modem closing) are not drawn
            return
        with contextlib.suppress(RuntimeError):  # stop() shut the map's thread down meanwhile
            self._updates.submit(self.handle, event)

    def handle(self, event: Event) -> None:
        """Update the scene for one event (viser is thread-safe), by its type; other events draw nothing."""
        handler = self._handlers.get(type(event))
        if handler is None:
            return
        try:
            handler(event)
        except Exception:  # the map must never break the link engine's publishing
            log.exception("map update failed for %s", event.kind)

    def _reported(self, event: VehicleReported) -> None:
        name, cp = event.vehicle, event.checkpoint
        self.reports[name] = cp
        self.last_pose = (cp["north"], cp["east"])
        self.vehicles.checkpoint(name, cp)
        self.tracks.checkpoint(name, cp)
        self.temperatures.checkpoint(cp)
        vehicle = self.screens.vehicle(name)
        self.routes.route(name, self.screens.route(vehicle.id) if vehicle and vehicle.id else [])

    def _heard(self, event: PacketHeard) -> None:
        self.tracks.heard(event, self.reports.get(event.vehicle))

    def _decoded(self, event: TelemetryDecoded) -> None:
        self.temperatures.decoded(event, self.reports.get(event.vehicle))
        self._scale()

    def _settled(self, event: PacketsSettled) -> None:
        self.temperatures.settled(event)
        self._scale()

    def _scale(self) -> None:
        """The panels' colour scale, when the verified samples' range changed."""
        if self.temperatures.draw():
            for panel in list(self.panels.values()):
                panel.scale_html.content = colour_scale(*(self.temperatures.range or (None, None)))

    def _command_status(self, event: CommandChanged) -> None:
        lines = self.command_list()
        for panel in list(self.panels.values()):
            panel.command_status(event, lines)

    def _colour(self, name: str) -> tuple[int, int, int]:
        """The vehicle's colour (the dashboard's too: ``server.screens.fleet``'s one palette) as RGB."""
        if name not in self.colours:
            self.colours = self.screens.colours()
        return fleet.rgb(self.colours.get(name, fleet.PALETTE[0]))

    # --- periodic: the fleet, the link, the view, the plans and the temperature field -------------

    def _tick_loop(self) -> None:
        while self._running:
            try:
                self.tick()
            except Exception:
                log.exception("map tick failed")
            time.sleep(1.0)

    def tick(self) -> None:
        known, gateways = self.screens.fleet(), self.screens.gateways()
        vehicles = known["vehicles"]
        self.colours = {v["name"]: v["colour"] for v in vehicles}
        self.gateways.draw(gateways, vehicles)
        for v in vehicles:
            if v["reported"] and v["predicted"]:
                self.vehicles.label(v["name"], v["reported"], v["age_s"], v["overdue"])
                self.vehicles.predicted(v["name"], v["reported"], v["predicted"])
        self._fit(vehicles, gateways)
        self._panels([v["name"] for v in vehicles], fleet_html(known), self._link_lines(vehicles, gateways))
        now = time.time()
        if now - self._plans_at > PLANS_EVERY:
            self._plans_at = now
            self.routes.draw(self.paths(), self.teams())
        if now - self._gp_at > FIT_EVERY:
            self._gp_at = now
            self._estimate()

    def _link_lines(self, vehicles: list[dict[str, Any]], gateways: list[dict[str, Any]]) -> list[str]:
        status = self.screens.link_status()
        lines = [gateway_line(g) for g in gateways] or [f"**Modem**: {status['modem']}"]
        for name, v in status["vehicles"].items():
            heard = f"{time.time() - v['last_heard']:.0f} s ago" if v["last_heard"] else "never"
            snr = f"{v['snr_in']:.1f} dB" if v["snr_in"] is not None else "-"
            rng = f"{v['range_m']:.0f} m" if v["range_m"] is not None else "-"
            lines.append(f"**{name}**: heard {heard}, SNR {snr}, range {rng}")
        for v in vehicles:
            share = v["airtime_share"] * 100
            lines.append(f"airtime **{v['name']}**: {v['airtime_s']['total']:.0f} s ({share:.0f} %)")
        return lines

    def _panels(self, names: list[str], listing: str, lines: list[str]) -> None:
        for panel in list(self.panels.values()):
            if names and list(panel.vehicle_dd.options) != names:
                panel.vehicle_dd.options = names
            panel.link_md.content = "  \n".join(lines)
            panel.fleet_html.content = listing

    def _fit(self, vehicles: list[dict[str, Any]], gateways: list[dict[str, Any]]) -> None:
        """Fit the view to every vehicle (where it reported, else its home) and gateway; the map opens
        there and "Fit all" goes there. Refitted when the fleet's extent changes."""
        points = [(v["reported"]["north"], v["reported"]["east"]) if v["reported"] else tuple(v["home"])
                  for v in vehicles]  # fmt: skip
        points += [(g["place"]["north"], g["place"]["east"]) for g in gateways if g["place"]]
        box = _box(points)
        if not points or box == self._fitted_to:
            return
        self._fitted_to, self.fitted = box, points
        _position, _look_at, seen = fit(points, aspect=DEFAULT_ASPECT, panel=DEFAULT_PANEL)
        self.vehicles.resize(seen)
        self.gateways.resize(seen)
        self.ground.cover(points)
        self.ground.rescale(seen)
        view = self.view_for(None, None)
        if view is not None:
            self._look(self.server.initial_camera, *view)
        for panel in list(self.panels.values()):
            if panel.unfitted and panel.size is not None:  # else when its camera first reports
                panel.fit_all()

    @staticmethod
    def _look(camera: Any, position: Point, look_at: Point, far: float) -> None:
        camera.far = far
        camera.position, camera.look_at = position, look_at
        camera.fov = PLAN_FOV

    def _estimate(self) -> None:
        """Ask the field for its estimate; the panels that show it redraw it."""
        if self.temperatures.fit():
            for panel in list(self.panels.values()):
                panel.suggest_btn.visible = True
                panel.show_estimate()


class View(NamedTuple):
    """A camera's placement: where it is, what it looks at, its far clipping distance."""

    position: Point
    look_at: Point
    far: float


def _box(points: list[tuple[float, float]]) -> tuple[tuple[int, int], ...]:
    """The points' bounding box, to ``REFIT`` metres: the view is refitted when it changes."""
    if not points:
        return ()
    lo = (min(p[0] for p in points), min(p[1] for p in points))
    hi = (max(p[0] for p in points), max(p[1] for p in points))
    return tuple((round(a / REFIT), round(b / REFIT)) for a, b in (lo, hi))


def command_line(c: CommandRecord, vehicle: str) -> str:
    """One command as the panel lists it, with its vehicle, parameters and times (UTC, the shore's clock),
    e.g. ``#12 rov1 move 10 m, turn +45°, 1 m deeper: executed 12:03:04Z (queued 12:02:50Z)``."""
    queued, last = _utc(c.created_at), _utc(c.updated_at)
    since = "" if c.status == "queued" else f" (queued {queued})"
    reason = f": {c.reason}" if c.reason else ""
    return f"#{c.id} {vehicle} {_parameters(c)}: **{c.status}** {last}{since}{reason}"


def _parameters(c: CommandRecord) -> str:
    if c.command == "move":
        angle = f"bearing {c.angle % 360:g}°" if c.absolute_angle else f"turn {c.angle:+g}°"
        depth = f", {abs(c.depth):g} m {'deeper' if c.depth > 0 else 'shallower'}" if c.depth else ""
        speed = f", {c.speed:g} m/s" if c.speed else ""  # 0: the vehicle's cruise speed
        return f"move {c.distance:g} m, {angle}{depth}{speed}"
    if c.command == "goto_depth":
        return f"go to depth {c.depth:g} m"
    if c.command == "start_mission":
        return f"start mission {c.param_id}"
    if c.command == "set_param":
        return f"set parameter {c.param_id} = {c.param_value:g}"
    return c.command.replace("_", " ")


def _utc(at: float) -> str:
    return time.strftime("%H:%M:%SZ", time.gmtime(at))
