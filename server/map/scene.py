"""The operator's 3D map (viser), served beside uvicorn in the same process.

Scene: x = east, y = north, z = up (z = -depth), metres from home. It shows the water surface and a
depth axis, the vehicle's last reported pose, its actual track (check-points), the track it is
predicted to follow during silence with an uncertainty ring that grows while nothing is heard, the
mission's waypoints, packet markers coloured by priority, the reported water temperatures as a
heatmap, and a Gaussian-process estimate of the temperature field: its mean, where it is most
uncertain (the suggested next target), and the front's boundary (the mean crossing the median).

The panel sends control packets (command, distance, angle, depth); clicking the water surface or the
vehicle's depth plane fills in distance and angle. Values outside the vehicle's limits are refused in
the panel with the reason; mission start, abort and return home take one click and a confirmation.
viser runs its own thread; work that touches the FastAPI loop goes through ``call_soon_threadsafe``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import sys
import threading
import time
from typing import TYPE_CHECKING, Any

import numpy as np
from sqlmodel import Session, select

from server.errors import ApiError
from server.map.panel import move_to, ray_to_depth_plane, refusal
from server.models import Mission, Vehicle
from server.schemas import COMMANDS, CommandIn
from tacit.navigation import Pose

if TYPE_CHECKING:
    from server.shore import Shore

log = logging.getLogger("tacit.server.map")

PRIORITY_COLOURS = {0: (70, 130, 230), 1: (240, 200, 40), 2: (245, 130, 30), 3: (220, 30, 30)}
DR_DRIFT = 0.05  # m/s: how fast the shore's uncertainty about a silent vehicle grows


def colormap(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Blue (cold) to red (warm), as uint8 RGB."""
    t = np.clip((values - lo) / max(hi - lo, 1e-6), 0, 1)[:, None]
    cold, warm = np.array([40, 90, 220]), np.array([230, 50, 40])
    return (cold + t * (warm - cold)).astype(np.uint8)


class OperatorMap:
    def __init__(self, shore: Shore, host: str, port: int) -> None:
        self.shore = shore
        self.host = host
        self.wanted_port = port
        self.port: int | None = None
        self.server: Any = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._lock = threading.Lock()
        self.track: dict[str, list[tuple[float, float, float]]] = {}
        self.temperatures: list[tuple[float, float, float, float]] = []  # north, east, depth, degC
        self.markers: list[tuple[float, float, float, int]] = []
        self.last_heard: dict[str, float] = {}
        self.pending_confirm: str | None = None
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
        self._build_panel()
        self.shore.bus.on_event(self._on_event)
        self._ticker = threading.Thread(target=self._tick_loop, daemon=True)
        self._running = True
        self._ticker.start()
        log.info("operator map on http://%s:%d", self.host, self.port)

    def stop(self) -> None:
        self._running = False
        if self.server is not None:
            with contextlib.redirect_stdout(sys.stderr):
                self.server.stop()

    # --- scene ----------------------------------------------------------------------------------

    def _build_scene(self) -> None:
        scene = self.server.scene
        scene.set_up_direction("+z")
        scene.add_grid("/water", width=300, height=300, plane="xy", cell_size=5, section_size=25,
                       plane_color=(60, 130, 190), plane_opacity=0.18, cell_color=(150, 180, 210))  # fmt: skip
        axis = np.array([[[0, 0, 0], [0, 0, -30]]], dtype=np.float32)
        scene.add_line_segments("/depth_axis", axis, (30, 30, 30), thickness=0.08)
        for depth in range(0, 31, 10):
            scene.add_label(f"/depth_axis/{depth}", f"{depth} m", position=(0.5, 0, -depth))
        scene.add_label("/home", "home", position=(0, 0, 0.5))
        self.server.initial_camera.position = (-25.0, -35.0, 30.0)
        self.server.initial_camera.look_at = (10.0, 10.0, -2.0)

    def _build_panel(self) -> None:
        gui = self.server.gui
        gui.configure_theme(dark_mode=False, control_width="large")
        with gui.add_folder("Link"):
            self.link_md = gui.add_markdown("waiting for the link engine")
        with gui.add_folder("Command"):
            self.vehicle_dd = gui.add_dropdown("Vehicle", self._vehicle_names() or ["(none)"])
            self.command_dd = gui.add_dropdown("Command", COMMANDS, initial_value="move")
            self.distance_in = gui.add_number("Distance (m)", 10.0, min=0.0, max=6553.5, step=0.1)
            self.angle_in = gui.add_number("Angle (deg)", 0.0, min=-180.0, max=180.0, step=0.01)
            self.depth_in = gui.add_number("Depth (m)", 0.0, min=-327.68, max=327.67, step=0.01)
            self.param_in = gui.add_number("Param / mission id", 1, min=0, max=255, step=1)
            self.absolute_cb = gui.add_checkbox("Angle is a bearing", False)
            self.plane_dd = gui.add_dropdown("Click plane", ["vehicle depth", "surface"])
            send = gui.add_button("Send", color="blue")
            self.status_md = gui.add_markdown("")
        with gui.add_folder("Mission"):
            start = gui.add_button("Start mission")
            abort = gui.add_button("Abort mission", color="red")
            home = gui.add_button("Return home", color="orange")
            self.confirm_btn = gui.add_button("Confirm", color="red", visible=False)
            self.cancel_btn = gui.add_button("Cancel", visible=False)
            self.suggest_btn = gui.add_button("Go to suggested target", visible=False)
            self.estimate_cb = gui.add_checkbox("Show temperature estimate", True)
        with gui.add_folder("Commands"):
            self.commands_md = gui.add_markdown("none yet")
        send.on_click(lambda _e: self._send(self._panel_command()))
        start.on_click(lambda _e: self._ask("start_mission"))
        abort.on_click(lambda _e: self._ask("abort_mission"))
        home.on_click(lambda _e: self._ask("return_home"))
        self.confirm_btn.on_click(lambda _e: self._confirm())
        self.cancel_btn.on_click(lambda _e: self._ask(None))
        self.suggest_btn.on_click(
            lambda _e: self._fill_from_point(*self.suggestion) if self.suggestion else None
        )
        self.server.scene.on_click()(self._on_click)
        self.estimate_cb.on_update(lambda _e: self._gaussian_process())

    # --- panel actions --------------------------------------------------------------------------

    def _vehicle_names(self) -> list[str]:
        with Session(self.shore.db) as s:
            return [v.name for v in s.exec(select(Vehicle).order_by(Vehicle.id))]

    def _vehicle(self) -> Vehicle | None:
        with Session(self.shore.db) as s:
            return s.exec(select(Vehicle).where(Vehicle.name == self.vehicle_dd.value)).first()

    def _pose(self, vehicle: Vehicle) -> Pose | None:
        state = self.shore.ingest.vehicles.get(vehicle.address)
        return Pose.from_checkpoint(state.checkpoint if state else None)

    def _panel_command(self) -> CommandIn | str:
        try:
            return CommandIn(command=self.command_dd.value, distance=self.distance_in.value, angle=self.angle_in.value,
                             depth=self.depth_in.value, param_id=int(self.param_in.value),
                             absolute_angle=self.absolute_cb.value)  # fmt: skip
        except ValueError as exc:
            return f"invalid value: {exc.errors()[0]['msg'] if hasattr(exc, 'errors') else exc}"

    def _send(self, command: CommandIn | str) -> None:
        vehicle = self._vehicle()
        if isinstance(command, str) or vehicle is None:
            self.status_md.content = (
                f"**Refused**: {command if isinstance(command, str) else 'no vehicle registered'}"
            )
            return
        reason = refusal(command, vehicle, self._pose(vehicle))
        if reason:
            self.status_md.content = f"**Refused** by {vehicle.name}'s limits: {reason}"
            return
        try:
            queued = self.shore.commands.submit(vehicle.id, command)  # type: ignore[arg-type]
        except ApiError as exc:
            self.status_md.content = f"**Refused**: {exc.field}: {exc.detail}"
            return
        self.status_md.content = f"Command **{queued.command}** seq {queued.seq}: **queued**"
        self._last_sent = queued.id

    def _ask(self, action: str | None) -> None:
        self.pending_confirm = action
        self.confirm_btn.visible = self.cancel_btn.visible = action is not None
        if action:
            self.confirm_btn.label = f"Confirm: {action.replace('_', ' ')}"

    def _confirm(self) -> None:
        action, self.pending_confirm = self.pending_confirm, None
        self._ask(None)
        if action:
            self._send(CommandIn(command=action, param_id=int(self.param_in.value)))

    def _on_click(self, event: Any) -> None:
        vehicle = self._vehicle()
        pose = self._pose(vehicle) if vehicle else None
        depth = 0.0 if self.plane_dd.value == "surface" or pose is None else pose.depth
        point = ray_to_depth_plane(event.ray_origin, event.ray_direction, depth)
        if point is not None:
            self._fill_from_point(point[0], point[1], depth)

    def _fill_from_point(self, north: float, east: float, depth: float | None = None) -> None:
        vehicle = self._vehicle()
        pose = (self._pose(vehicle) if vehicle else None) or Pose(0.0, 0.0, 0.0, 0.0)
        command = move_to(pose, north, east, pose.depth if depth is None else depth, self.absolute_cb.value)
        self.command_dd.value = "move"
        self.distance_in.value, self.angle_in.value, self.depth_in.value = (
            command.distance,
            command.angle,
            command.depth,
        )
        self.server.scene.add_icosphere("/click_target", radius=0.4, color=(250, 200, 0),
                                        position=(east, north, -(pose.depth if depth is None else depth)))  # fmt: skip
        self.status_md.content = (
            f"Target set: {command.distance:.1f} m at {command.angle:+.1f} deg. Press **Send**."
        )

    # --- live updates ---------------------------------------------------------------------------

    def _on_event(self, event: dict) -> None:
        """Called on the FastAPI loop for every published event: update the scene (viser is thread-safe)."""
        kind = event["kind"]
        try:
            if kind == "vehicle":
                self._checkpoint(event["vehicle"], event["checkpoint"])
            elif kind == "packet":
                self._marker(event)
            elif kind == "command":
                self._command_status(event)
            elif kind == "telemetry" and event.get("stream") == "env":
                self._temperatures(event)
            elif kind == "link":
                self.last_heard[event.get("vehicle", "")] = time.time()
        except Exception:  # the map must never break the link engine's publishing
            log.exception("map update failed for %s", kind)

    def _checkpoint(self, name: str, cp: dict) -> None:
        north, east, depth, heading = cp["north"], cp["east"], cp["depth"], cp["heading"]
        with self._lock:
            track = self.track.setdefault(name, [])
            track.append((east, north, -depth))
            if cp.get("temperature") and cp["temperature"] != 0.0:
                self.temperatures.append((north, east, depth, cp["temperature"]))
        yaw = math.radians(90 - heading)  # heading from north, clockwise -> rotation about +z from +x
        wxyz = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
        scene = self.server.scene
        scene.add_frame(
            f"/vehicles/{name}", axes_length=1.5, axes_radius=0.08, position=(east, north, -depth), wxyz=wxyz
        )
        scene.add_label(f"/vehicles/{name}/label", f"{name}: {cp['state']}", position=(0, 0, 1.0))
        if len(track) >= 2:
            segments = np.array(
                [[a, b] for a, b in zip(track[:-1], track[1:], strict=True)], dtype=np.float32
            )
            scene.add_line_segments(f"/tracks/{name}/actual", segments, (20, 90, 200), thickness=0.15)
        self._planned(name, cp)

    def _planned(self, name: str, cp: dict) -> None:
        """The pre-programmed trajectory (waypoints) and the predicted track ahead during silence."""
        with Session(self.shore.db) as s:
            vehicle = s.exec(select(Vehicle).where(Vehicle.name == name)).first()
            mission = s.exec(select(Mission).where(Mission.vehicle_id == vehicle.id, Mission.status == "started")
                             .order_by(Mission.id.desc())).first() if vehicle else None  # type: ignore[union-attr]  # fmt: skip
        if mission and mission.plan.get("waypoints"):
            points = [(w["east"], w["north"], -w["depth"]) for w in mission.plan["waypoints"]]
            if len(points) >= 2:
                segments = np.array(
                    [[a, b] for a, b in zip(points[:-1], points[1:], strict=True)], dtype=np.float32
                )
                self.server.scene.add_line_segments(
                    f"/plans/{name}", segments, (120, 120, 120), thickness=0.06
                )
            nxt = points[min(cp.get("waypoint", 0), len(points) - 1)]
            here = (cp["east"], cp["north"], -cp["depth"])
            self.server.scene.add_line_segments(f"/tracks/{name}/predicted", np.array([[here, nxt]], dtype=np.float32),
                                                (250, 150, 30), thickness=0.1)  # fmt: skip

    def _marker(self, event: dict) -> None:
        state = self.shore.ingest.vehicles.get(event["address"])
        cp = state.checkpoint if state else None
        if not cp:
            return
        with self._lock:
            self.markers.append((cp["east"], cp["north"], -cp["depth"], int(event.get("priority", 0))))
            points = np.array([m[:3] for m in self.markers[-500:]], dtype=np.float32)
            colours = np.array([PRIORITY_COLOURS[m[3]] for m in self.markers[-500:]], dtype=np.uint8)
        self.server.scene.add_point_cloud("/markers", points + np.array([0, 0, 0.4], dtype=np.float32), colours,
                                          point_size=0.5, point_shape="circle")  # fmt: skip

    def _temperatures(self, event: dict) -> None:
        state = next((v for v in self.shore.ingest.vehicles.values() if v.name == event["vehicle"]), None)
        cp = state.checkpoint if state else None
        if not cp:
            return
        with self._lock:
            for row in event["values"]:
                self.temperatures.append((cp["north"], cp["east"], row[1], row[0]))
            data = np.array(self.temperatures[-2000:])
        points = np.column_stack([data[:, 1], data[:, 0], -data[:, 2]]).astype(np.float32)
        self.server.scene.add_point_cloud("/temperature/samples", points, colormap(data[:, 3], data[:, 3].min(),
                                          data[:, 3].max()), point_size=0.35, point_shape="rounded")  # fmt: skip

    def _command_status(self, event: dict) -> None:
        from server.models import Command

        with Session(self.shore.db) as s:
            rows = s.exec(select(Command).order_by(Command.id.desc()).limit(6)).all()
        lines = [f"- #{c.id} **{c.command}** seq {c.seq}: **{c.status}** {c.reason}" for c in rows]
        self.commands_md.content = "\n".join(lines) or "none yet"
        if getattr(self, "_last_sent", None) == event.get("id"):
            self.status_md.content = f"Command seq {event.get('seq')}: **{event['status']}**"

    # --- periodic: link panel, uncertainty ring, Gaussian-process field -------------------------

    def _tick_loop(self) -> None:
        while self._running:
            try:
                self._tick()
            except Exception:
                log.exception("map tick failed")
            time.sleep(1.0)

    def _tick(self) -> None:
        status = self.shore.link.status()
        names = list(status["vehicles"])
        if names and list(self.vehicle_dd.options) != names:
            self.vehicle_dd.options = names
        lines = [f"**Modem**: {status['modem']}"]
        for name, v in status["vehicles"].items():
            heard = f"{time.time() - v['last_heard']:.0f} s ago" if v["last_heard"] else "never"
            snr = f"{v['snr_in']:.1f} dB" if v["snr_in"] is not None else "-"
            rng = f"{v['range_m']:.0f} m" if v["range_m"] is not None else "-"
            lines.append(f"**{name}**: heard {heard}, SNR {snr}, range {rng}, {v['packets_per_hour']:.0f} packets/h, "
                         f"{v['bytes_saved']} bytes saved")  # fmt: skip
            self._uncertainty(name, v)
        self.link_md.content = "  \n".join(lines)
        if time.time() - self._gp_at > 10:
            self._gp_at = time.time()
            self._gaussian_process()

    def _uncertainty(self, name: str, v: dict) -> None:
        cp = v.get("checkpoint")
        if not cp or not v["last_heard"]:
            return
        radius = 0.5 + DR_DRIFT * (time.time() - v["last_heard"])
        angles = np.linspace(0, 2 * np.pi, 33)
        ring = np.column_stack([cp["east"] + radius * np.cos(angles), cp["north"] + radius * np.sin(angles),
                                np.full_like(angles, -cp["depth"])]).astype(np.float32)  # fmt: skip
        segments = np.stack([ring[:-1], ring[1:]], axis=1)
        self.server.scene.add_line_segments(
            f"/tracks/{name}/uncertainty", segments, (250, 150, 30), thickness=0.05
        )

    def _gaussian_process(self) -> None:
        """Fit the reported temperatures; draw the mean field, the front, the most uncertain place."""
        with self._lock:
            data = np.array(self.temperatures[-400:])
        if len(data) < 8 or np.ptp(data[:, :2], axis=0).max() < 2.0:
            return
        from sklearn.gaussian_process import GaussianProcessRegressor
        from sklearn.gaussian_process.kernels import RBF, WhiteKernel

        xy = data[:, :2]
        gp = GaussianProcessRegressor(RBF(length_scale=10.0, length_scale_bounds=(2.0, 100.0)) + WhiteKernel(0.01),
                                      normalize_y=True).fit(xy, data[:, 3])  # fmt: skip
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
        self.server.scene.add_point_cloud("/temperature/estimate", points, colormap(mean, mean.min(), mean.max()),
                                          point_size=0.45, point_shape="circle",
                                          visible=bool(self.estimate_cb.value))  # fmt: skip
        level = float(np.median(mean))
        field = mean.reshape(grid_n.shape) - level
        crossings = np.argwhere(np.sign(field[:-1, :]) != np.sign(field[1:, :]))
        if len(crossings):
            front = np.array([[grid_e[i, j], (grid_n[i, j] + grid_n[i + 1, j]) / 2, -depth + 0.05] for i, j in crossings],
                             dtype=np.float32)  # fmt: skip
            self.server.scene.add_point_cloud("/temperature/front", front, (20, 20, 20), point_size=0.5,
                                              point_shape="diamond")  # fmt: skip
        best = int(np.argmax(std))
        self.suggestion = (float(grid[best, 0]), float(grid[best, 1]))
        self.server.scene.add_icosphere("/temperature/suggested", radius=0.6, color=(160, 40, 200),
                                        position=(self.suggestion[1], self.suggestion[0], -depth))  # fmt: skip
        self.server.scene.add_label("/temperature/suggested/label", "most uncertain: sample here",
                                    position=(0, 0, 1.0))  # fmt: skip
        self.suggest_btn.visible = True
