"""The operator's 3D map (viser), served beside uvicorn in the same process.

Scene: x = east, y = north, z = up (z = -depth), metres from home. It shows the water surface and a
depth axis, the vehicle's last reported pose, its actual track (check-points), the track it is
predicted to follow during silence with an uncertainty ring that grows while nothing is heard, the
mission's waypoints, packet markers coloured by priority, the reported water temperatures as a
heatmap (grey until a check-point verifies them), and a Gaussian-process estimate of the temperature
field, fitted on verified samples only: its mean, where it is most uncertain (the suggested next
target), and the front's boundary (the mean crossing the median). A center's gateways stand at their
modems' places (``Screens.gateways``, what ``GET /api/v1/gateways`` lists), each vehicle joined to its
gateway by a thin line in the vehicle's colour.

Each browser gets its own panel (``server.map.panel``): it acts for a signed-in operator only
(the API's tokens; observers watch), offers the same commands, fields, units and checks as the dashboard
(``server.screens.form``), and explains every item with a hint. The map reads through the screens'
service and sends through the command desk; it never opens a database session itself. The scene is shared: a north arrow and
labelled north/east/depth axes, the vehicle drawn with its heading, the temperature estimate off by
default (per browser) with a colour scale. viser runs its own thread; its GUI callbacks run in its
thread pool.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import sys
import threading
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from server.commands.models import CommandRecord
from server.commands.service import CommandDesk
from server.core.config import Settings
from server.core.events import (
    Bus,
    CommandChanged,
    Event,
    LinkNotice,
    PacketHeard,
    PacketsSettled,
    TelemetryDecoded,
    VehicleReported,
)
from server.core.security import Lookup, Throttle
from server.map.geometry import PLAN_FOV, top_down
from server.map.panel import OperatorPanel, colour_scale, fleet_html
from server.screens import fleet, states
from server.screens.service import Screens
from server.vehicles.models import Vehicle
from tacit.navigation import Pose

log = logging.getLogger("tacit.server.map")

PRIORITY_COLOURS = {0: (70, 130, 230), 1: (240, 200, 40), 2: (245, 130, 30), 3: (220, 30, 30)}
DEPTH_SCALE = (-14.0, -6.0)  # (east, north) of the depth scale: off the side of the area, away from home
DEPTH_LABEL_STEP = 4.0  # metres south between depth labels: apart when seen from above
PENDING_COLOUR = (150, 150, 150)  # a temperature sample no check-point has verified yet
OVERDUE_COLOUR = (170, 170, 170)  # a vehicle's body while it is overdue (the dashboard greys its row)
PENDING_PACKETS = 500  # packets whose samples wait for a check-point (older ones were never covered)
Sample = tuple[float, float, float, float]  # north, east, depth, degC
RECENT_COMMANDS = 10
GATEWAY_SIZE = (4.0, 4.0, 4.0)  # m: a gateway's marker, seen from a few hundred metres


def colormap(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Blue (cold) to red (warm), as uint8 RGB."""
    t = np.clip((values - lo) / max(hi - lo, 1e-6), 0, 1)[:, None]
    cold, warm = np.array([40, 90, 220]), np.array([230, 50, 40])
    return (cold + t * (warm - cold)).astype(np.uint8)


class OperatorMap:
    def __init__(
        self, screens: Screens, desk: CommandDesk, bus: Bus, settings: Settings, lookup: Lookup
    ) -> None:
        """``lookup``: the shore's one rule for tokens (``Operators.actor``), asked through a throttle of
        the map's own: every map client as one, as viser does not tell their addresses."""
        self.screens = screens
        self.desk = desk
        self.bus = bus
        self.settings = settings
        self.sign_ins = Throttle(settings, lookup)
        self.host = settings.host
        self.wanted_port = settings.map_port
        self.port: int | None = None
        self.server: Any = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._updates = ThreadPoolExecutor(max_workers=1, thread_name_prefix="tacit-map")  # one: in order
        self._running = False
        self._lock = threading.RLock()
        self.track: dict[str, list[tuple[float, float, float]]] = {}
        self.temperatures: list[Sample] = []  # verified: the estimate is fitted on these only
        self.pending: dict[int, list[Sample]] = {}  # by packet id: samples no check-point settled yet
        self._pending_cloud: Any = None
        self.markers: list[tuple[float, float, float, int]] = []
        self.last_heard: dict[str, float] = {}
        self.reports: dict[str, dict] = {}  # by vehicle name: its last verified check-point
        self.colours: dict[str, str] = {}  # by vehicle name: as on the dashboard (server.screens.fleet)
        self._nodes: dict[str, dict[str, Any]] = {}
        self._links: dict[str, Any] = {}  # by vehicle name: the line to its gateway
        self.panels: dict[int, OperatorPanel] = {}  # by viser client id: one panel per browser
        self.estimate_cloud: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # points, colours, front
        self.temperature_range: tuple[float, float] | None = None
        self.last_pose: tuple[float, float] = (10.0, 10.0)  # north, east: where the views look
        self._gp_at = 0.0
        self.suggestion: tuple[float, float] | None = None

    # --- lifecycle ------------------------------------------------------------------------------

    def start(self) -> None:
        import viser

        self._loop = asyncio.get_running_loop()
        with contextlib.redirect_stdout(sys.stderr):  # viser prints a banner; stdout belongs to our callers
            self.server = viser.ViserServer(host=self.host, port=self.wanted_port, verbose=False)
        self.port = self.server.get_port()  # viser takes the next free port if the wanted one is busy
        self._build_scene()
        self.server.on_client_connect(self._connected)
        self.server.on_client_disconnect(lambda client: self.panels.pop(client.client_id, None))
        self.bus.on_event(self._on_event)
        self._ticker = threading.Thread(target=self._tick_loop, daemon=True)
        self._running = True
        self._ticker.start()
        log.info("operator map on http://%s:%d", self.host, self.port)

    def stop(self) -> None:
        self._running = False
        self._updates.shutdown(wait=True, cancel_futures=True)
        if self.server is not None:
            with contextlib.redirect_stdout(sys.stderr):
                self.server.stop()

    # --- scene ----------------------------------------------------------------------------------

    def _build_scene(self) -> None:
        """The water, the axes and the labels; the view opens top-down on the area (the operator's main
        screen). Labels are anchored away from home so that they never lie across a track near it."""
        scene = self.server.scene
        scene.set_up_direction("+z")
        scene.add_grid(
            "/water",
            width=300,
            height=300,
            plane="xy",
            cell_size=5,
            section_size=25,
            plane_color=(60, 130, 190),
            plane_opacity=0.18,
            cell_color=(150, 180, 210),
        )
        self._depth_scale()
        arrows = np.array([[[0, 0, 0.05], [0, 12, 0.05]], [[0, 0, 0.05], [12, 0, 0.05]]], dtype=np.float32)
        scene.add_arrows(
            "/axes/north_east",
            arrows,
            np.array([[200, 20, 20], [40, 40, 40]], dtype=np.uint8),
            shaft_radius=0.12,
            head_radius=0.45,
            head_length=1.2,
        )
        scene.add_label("/axes/north", "N (north, +y)", position=(-1.0, 12.0, 0.3), anchor="center-right")
        scene.add_label("/axes/east", "E (east, +x)", position=(12.0, -1.0, 0.3), anchor="top-center")
        for metres in (25, 50, 100):
            scene.add_label(
                f"/axes/grid/n{metres}", f"{metres} m N", position=(-1.0, metres, 0.1), anchor="center-right"
            )
            scene.add_label(
                f"/axes/grid/e{metres}", f"{metres} m E", position=(metres, -1.0, 0.1), anchor="top-center"
            )
        scene.add_label("/home", self._origin_text(), position=(-1.0, -1.0, 0.8), anchor="top-right")
        camera = self.server.initial_camera
        camera.position, camera.look_at = top_down(*self.last_pose)
        camera.fov = PLAN_FOV

    def _origin_text(self) -> str:
        """The fleet's one origin (north = east = 0 for every vehicle), with its latitude and longitude when
        known."""
        origin = self.settings.origin
        return "fleet origin (0, 0)" + ("" if origin is None else f", {fleet.latlon_text(*origin)}")

    def _depth_scale(self) -> None:
        """The depth scale, off to the south-west of home (``DEPTH_SCALE``): a vertical line with its labels
        stepped south, one per 10 m, so that seen from above they neither cover each other nor the track."""
        east, north = DEPTH_SCALE
        scene = self.server.scene
        scene.add_line_segments(
            "/axes/depth",
            np.array([[[east, north, 0], [east, north, -30]]], dtype=np.float32),
            (30, 30, 30),
            thickness=0.08,
        )
        ticks = []
        for step, depth in enumerate((10, 20, 30, 33), start=1):
            at = (east - 0.5, north - DEPTH_LABEL_STEP * step, -depth)
            text = "depth" if depth == 33 else f"{depth} m deep"
            scene.add_label(f"/axes/depth/{depth}", text, position=at, anchor="center-right")
            ticks.append([(east, north, -depth), at])
        scene.add_line_segments(
            "/axes/depth/ticks", np.array(ticks, dtype=np.float32), (30, 30, 30), thickness=0.04
        )

    def _connected(self, client: Any) -> None:
        """A browser opened the map: its own panel, signed out."""
        try:
            panel = OperatorPanel(self, client)
        except Exception:
            log.exception("map panel for client %s failed", client.client_id)
            return
        self.panels[client.client_id] = panel
        panel.scale_html.content = colour_scale(*(self.temperature_range or (None, None)))

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

    # --- live updates ---------------------------------------------------------------------------

    def _on_event(self, event: Event) -> None:
        """Called on the FastAPI loop for every published event: handed to the map's own thread, in order,
        so that the scene's database reads never hold up the loop that serves the modem."""
        if not self._running:  # events published while the server stops (the modem closing) are not drawn
            return
        with contextlib.suppress(RuntimeError):  # stop() shut the map's thread down meanwhile
            self._updates.submit(self._handle, event)

    def _handle(self, event: Event) -> None:
        """Update the scene for one event (viser is thread-safe)."""
        try:
            if isinstance(event, VehicleReported):
                self._checkpoint(event.vehicle, event.checkpoint)
            elif isinstance(event, PacketHeard):
                self._marker(event)
            elif isinstance(event, CommandChanged):
                self._command_status(event)
            elif isinstance(event, TelemetryDecoded) and event.stream == "env":
                self._temperatures(event)
            elif isinstance(event, PacketsSettled):
                self._settled(event)
            elif isinstance(event, LinkNotice) and event.vehicle:
                self.last_heard[event.vehicle] = time.time()
        except Exception:  # the map must never break the link engine's publishing
            log.exception("map update failed for %s", event.kind)

    def _checkpoint(self, name: str, cp: dict) -> None:
        north, east, depth, heading = cp["north"], cp["east"], cp["depth"], cp["heading"]
        with self._lock:
            self.reports[name] = cp
            track = self.track.setdefault(name, [])
            track.append((east, north, -depth))
            if cp.get("temperature") and cp["temperature"] != 0.0:
                self.temperatures.append((north, east, depth, cp["temperature"]))
        self.last_pose = (north, east)
        yaw = math.radians(90 - heading)  # heading from north, clockwise -> rotation about +z from +x
        node = self._vehicle_node(name)
        node["frame"].position = (east, north, -depth)
        node["frame"].wxyz = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
        self._label(name, cp, 0.0)
        scene = self.server.scene
        if len(track) >= 2:
            segments = np.array(
                [[a, b] for a, b in zip(track[:-1], track[1:], strict=True)], dtype=np.float32
            )
            scene.add_line_segments(f"/tracks/{name}/actual", segments, self._colour(name), thickness=0.15)
        self._planned(name, cp)

    def _colour(self, name: str) -> tuple[int, int, int]:
        """The vehicle's colour (the dashboard's too: ``server.screens.fleet``'s one palette) as RGB."""
        if name not in self.colours:
            self.colours = self.screens.colours()
        return fleet.rgb(self.colours.get(name, fleet.PALETTE[0]))

    def _vehicle_node(self, name: str) -> dict[str, Any]:
        """The vehicle's body, heading arrow and label, made once and moved after (both the event loop and
        the tick thread update them: re-adding the nodes would race)."""
        with self._lock:
            node = self._nodes.get(name)
            if node is None:
                scene = self.server.scene
                frame = scene.add_frame(f"/vehicles/{name}", show_axes=False)
                body = scene.add_box(
                    f"/vehicles/{name}/body", color=self._colour(name), dimensions=(1.4, 0.9, 0.6)
                )
                # the heading: a bright arrow on a larger black one, which outlines it seen from above
                scene.add_arrows(
                    f"/vehicles/{name}/heading_outline",
                    np.array([[[0.5, 0, 0], [5.6, 0, 0]]], dtype=np.float32),
                    (0, 0, 0),
                    shaft_radius=0.4,
                    head_radius=1.15,
                    head_length=2.1,
                )
                scene.add_arrows(
                    f"/vehicles/{name}/heading",
                    np.array([[[0.7, 0, 0.35], [5.1, 0, 0.35]]], dtype=np.float32),
                    (255, 225, 0),
                    shaft_radius=0.25,
                    head_radius=0.8,
                    head_length=1.6,
                )
                label = scene.add_label(f"/vehicles/{name}/label", name, position=(0, 0, 1.2))
                node = self._nodes[name] = {"frame": frame, "label": label, "body": body}
        return node

    def _label(self, name: str, cp: dict, age: float, overdue: bool = False) -> None:
        """The vehicle's label; an overdue vehicle (``server.screens.fleet``) is greyed and says so."""
        label, _hint = states.label(cp.get("state", ""))
        late = " (OVERDUE: not heard as its schedule allows)" if overdue else ""
        text = f"{name}: {label}, heading {cp['heading']:.0f}°, reported {age:.0f} s ago{late}"
        node = self._vehicle_node(name)
        node["label"].text = text
        node["body"].color = OVERDUE_COLOUR if overdue else self._colour(name)

    def _planned(self, name: str, cp: dict) -> None:
        """The pre-programmed trajectory (the mission's waypoints)."""
        vehicle = self.screens.vehicle(name)
        route = self.screens.route(vehicle.id) if vehicle and vehicle.id else []
        if route:
            points = [(east, north, -depth) for north, east, depth in route]
            if len(points) >= 2:
                segments = np.array(
                    [[a, b] for a, b in zip(points[:-1], points[1:], strict=True)], dtype=np.float32
                )
                self.server.scene.add_line_segments(
                    f"/plans/{name}", segments, (120, 120, 120), thickness=0.06
                )

    def _marker(self, event: PacketHeard) -> None:
        cp = self.reports.get(event.vehicle)
        if not cp:
            return
        with self._lock:
            self.markers.append((cp["east"], cp["north"], -cp["depth"], event.priority))
            points = np.array([m[:3] for m in self.markers[-500:]], dtype=np.float32)
            colours = np.array([PRIORITY_COLOURS[m[3]] for m in self.markers[-500:]], dtype=np.uint8)
        self.server.scene.add_point_cloud(
            "/markers",
            points + np.array([0, 0, 0.4], dtype=np.float32),
            colours,
            point_size=0.5,
            point_shape="circle",
        )

    def _temperatures(self, event: TelemetryDecoded) -> None:
        """A priority packet's temperatures, drawn grey and kept out of the estimate until a check-point
        vouches for their packet (``_settled``)."""
        cp = self.reports.get(event.vehicle)
        if not cp:
            return
        # an absent sample is not drawn
        samples = [
            (cp["north"], cp["east"], depth, temperature)
            for temperature, depth, *_ in event.values
            if temperature is not None and depth is not None
        ]
        with self._lock:
            self.pending.setdefault(event.packet_id, []).extend(samples)
            while len(self.pending) > PENDING_PACKETS:
                del self.pending[min(self.pending)]
        self._draw_temperatures()

    def _settled(self, event: PacketsSettled) -> None:
        """A check-point settled packets: the trusted ones' samples join the verified ones; the rest (forged,
        decoded on a chain nobody vouched for, or out of every check-point's reach) are dropped."""
        trusted = set(event.trusted)
        with self._lock:
            for packet_id in [*event.verified, *event.forged, *event.unverifiable]:
                samples = self.pending.pop(packet_id, [])
                if packet_id in trusted:
                    self.temperatures.extend(samples)
        self._draw_temperatures()

    def _draw_temperatures(self) -> None:
        """The verified samples coloured by temperature (the scale's range is theirs), the pending ones grey."""
        with self._lock:
            verified = np.array(self.temperatures[-2000:]).reshape(-1, 4)
            pending = np.array([x for samples in self.pending.values() for x in samples]).reshape(-1, 4)
        scene = self.server.scene
        if len(pending):
            self._pending_cloud = scene.add_point_cloud(
                "/temperature/pending",
                _scene_points(pending),
                PENDING_COLOUR,
                point_size=0.3,
                point_shape="square",
            )
        elif self._pending_cloud is not None:
            self._pending_cloud.remove()
            self._pending_cloud = None
        if not len(verified):
            return
        lo, hi = float(verified[:, 3].min()), float(verified[:, 3].max())
        scene.add_point_cloud(
            "/temperature/samples",
            _scene_points(verified),
            colormap(verified[:, 3], lo, hi),
            point_size=0.35,
            point_shape="rounded",
        )
        if self.temperature_range != (lo, hi):
            self.temperature_range = (lo, hi)
            for panel in list(self.panels.values()):
                panel.scale_html.content = colour_scale(lo, hi)

    def command_list(self) -> str:
        """The panels' list of recent commands (markdown), newest first."""
        rows = self.screens.recent_commands(RECENT_COMMANDS)
        names = {v.id: v.name for v in self.screens.vehicles()}
        return "\n".join(f"- {command_line(c, names.get(c.vehicle_id, '?'))}" for c in rows) or "none yet"

    def _command_status(self, event: CommandChanged) -> None:
        lines = self.command_list()
        for panel in list(self.panels.values()):
            panel.command_status(event, lines)

    # --- periodic: link and vehicle panels, prediction, Gaussian-process field ------------------

    def _tick_loop(self) -> None:
        while self._running:
            try:
                self._tick()
            except Exception:
                log.exception("map tick failed")
            time.sleep(1.0)

    def _tick(self) -> None:
        status, known, gateways = self.screens.link_status(), self.screens.fleet(), self.screens.gateways()
        self.colours = {v["name"]: v["colour"] for v in known["vehicles"]}
        names = [v["name"] for v in known["vehicles"]]
        self._gateways(gateways, known["vehicles"])
        lines = [gateway_line(g) for g in gateways] or [f"**Modem**: {status['modem']}"]
        for name, v in status["vehicles"].items():
            heard = f"{time.time() - v['last_heard']:.0f} s ago" if v["last_heard"] else "never"
            snr = f"{v['snr_in']:.1f} dB" if v["snr_in"] is not None else "-"
            rng = f"{v['range_m']:.0f} m" if v["range_m"] is not None else "-"
            lines.append(f"**{name}**: heard {heard}, SNR {snr}, range {rng}")
        for vehicle in known["vehicles"]:
            self._prediction(vehicle)
            share = vehicle["airtime_share"] * 100
            lines.append(
                f"airtime **{vehicle['name']}**: {vehicle['airtime_s']['total']:.0f} s ({share:.0f} %)"
            )
        listing = fleet_html(known)
        for panel in list(self.panels.values()):
            if names and list(panel.vehicle_dd.options) != names:
                panel.vehicle_dd.options = names
            panel.link_md.content = "  \n".join(lines)
            panel.fleet_html.content = listing
        if time.time() - self._gp_at > 10:
            self._gp_at = time.time()
            self._gaussian_process()

    def _gateways(self, gateways: list[dict[str, Any]], vehicles: list[dict[str, Any]]) -> None:
        """Each gateway at its modem's place (dark while it beats, grey once silent) with its label, and a
        thin line in each vehicle's colour from its last reported position to its gateway."""
        scene = self.server.scene
        places: dict[str, tuple[float, float, float]] = {}
        for g in gateways:
            if g["place"] is None:
                continue
            here = places[g["name"]] = (g["place"]["east"], g["place"]["north"], -g["place"]["depth"])
            scene.add_box(f"/gateways/{g['name']}", color=fleet.rgb(g["colour"]), dimensions=GATEWAY_SIZE,
                          position=here)  # fmt: skip
            scene.add_label(
                f"/gateways/{g['name']}/label", gateway_line(g).replace("**", ""), position=(0, 0, 3.0)
            )
        for v in vehicles:
            cp, there = v["reported"], places.get(v["gateway"] or "")
            old = self._links.pop(v["name"], None)
            if cp is None or there is None:
                if old is not None:
                    old.remove()
                continue
            segment = np.array([[(cp["east"], cp["north"], -cp["depth"]), there]], dtype=np.float32)
            self._links[v["name"]] = scene.add_line_segments(
                f"/gateway_links/{v['name']}", segment, self._colour(v["name"]), thickness=0.05
            )

    def _prediction(self, vehicle: dict[str, Any]) -> None:
        """Draw where the shore thinks the vehicle (a row of ``Screens.fleet``) is now and how sure."""
        cp, p, name = vehicle["reported"], vehicle["predicted"], vehicle["name"]
        if not cp or not p:
            return
        self._label(name, cp, vehicle["age_s"], vehicle["overdue"])
        scene = self.server.scene
        here, there = (cp["east"], cp["north"], -cp["depth"]), (p["east"], p["north"], -p["depth"])
        scene.add_icosphere(f"/predicted/{name}/now", radius=0.45, color=(250, 150, 30), position=there)
        scene.add_line_segments(
            f"/predicted/{name}/path",
            np.array([[here, there]], dtype=np.float32),
            (250, 150, 30),
            thickness=0.1,
        )
        angles = np.linspace(0, 2 * np.pi, 49)
        radius = p["radius_m"]
        ring = np.column_stack(
            [
                p["east"] + radius * np.cos(angles),
                p["north"] + radius * np.sin(angles),
                np.full_like(angles, -p["depth"]),
            ]
        ).astype(np.float32)
        scene.add_line_segments(
            f"/predicted/{name}/uncertainty",
            np.stack([ring[:-1], ring[1:]], axis=1),
            (250, 150, 30),
            thickness=0.06,
        )

    def _gaussian_process(self) -> None:
        """Fit the verified temperatures (a sample waits for a check-point to vouch for its packet); the mean field (for panels that show it), the front, and the
        most uncertain place (the suggested next target)."""
        with self._lock:
            data = np.array(self.temperatures[-400:])
        if len(data) < 8 or np.ptp(data[:, :2], axis=0).max() < 2.0:
            return
        from sklearn.exceptions import ConvergenceWarning
        from sklearn.gaussian_process import GaussianProcessRegressor
        from sklearn.gaussian_process.kernels import RBF, WhiteKernel

        xy = data[:, :2]
        with warnings.catch_warnings():  # a length scale at its bound is expected for a sharp front: not news
            warnings.simplefilter("ignore", ConvergenceWarning)
            gp = GaussianProcessRegressor(
                RBF(length_scale=10.0, length_scale_bounds=(2.0, 100.0)) + WhiteKernel(0.01), normalize_y=True
            ).fit(xy, data[:, 3])
        lo, hi = xy.min(axis=0) - 10, xy.max(axis=0) + 10
        grid_n, grid_e = np.meshgrid(
            np.linspace(lo[0], hi[0], 30), np.linspace(lo[1], hi[1], 30), indexing="ij"
        )
        grid = np.column_stack([grid_n.ravel(), grid_e.ravel()])
        mean, std = gp.predict(grid, return_std=True)
        depth = float(np.median(data[:, 2]))
        points = np.column_stack([grid[:, 1], grid[:, 0], np.full(len(grid), -depth - 0.05)]).astype(
            np.float32
        )
        t_lo, t_hi = self.temperature_range or (float(mean.min()), float(mean.max()))
        level = float(np.median(mean))
        field = mean.reshape(grid_n.shape) - level
        crossings = np.argwhere(np.sign(field[:-1, :]) != np.sign(field[1:, :]))
        front = np.array(
            [[grid_e[i, j], (grid_n[i, j] + grid_n[i + 1, j]) / 2, -depth + 0.05] for i, j in crossings],
            dtype=np.float32,
        ).reshape(-1, 3)
        self.estimate_cloud = (points, colormap(mean, t_lo, t_hi), front)
        best = int(np.argmax(std))
        self.suggestion = (float(grid[best, 0]), float(grid[best, 1]))
        self.server.scene.add_icosphere(
            "/temperature/suggested",
            radius=0.6,
            color=(160, 40, 200),
            position=(self.suggestion[1], self.suggestion[0], -depth),
        )
        self.server.scene.add_label(
            "/temperature/suggested/label", "most uncertain: sample here", position=(0, 0, 1.0)
        )
        for panel in list(self.panels.values()):
            panel.suggest_btn.visible = True
            panel.show_estimate()


def gateway_line(g: dict[str, Any]) -> str:
    """A gateway (a row of ``Screens.gateways``) in one line: its state and for how long, its outbox and
    modem, its vehicles."""
    state = f"up for {g['for_s']:.0f} s" if g["alive"] else f"**silent for {g['for_s']:.0f} s**"
    vehicles = ", ".join(v["name"] + (" (pinned)" if v["pinned"] else "") for v in g["vehicles"]) or "none"
    return (
        f"**Gateway {g['name']}**: {state}, {g['outbox'] if g['outbox'] is not None else '?'} waiting to go "
        f"up; modem {g['address'] if g['address'] is not None else '?'} {g['modem'] or '?'}; vehicles {vehicles}"
    )


def _scene_points(samples: np.ndarray) -> np.ndarray:
    """Rows of (north, east, depth, ...) as scene points (east, north, -depth)."""
    return np.column_stack([samples[:, 1], samples[:, 0], -samples[:, 2]]).astype(np.float32)


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
