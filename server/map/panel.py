"""One browser's panel on the 3D map: built per client (viser has no authentication of its own), so
what one browser types or presses reaches only its own panel.

The panel acts for a signed-in operator only: its token is resolved by the shore's one rule
(``server.operators.service.Operators.actor``: the same tokens as the API, expiry and revocation
included) when signing in, through the map's ``Throttle``, and again at every send; each command
records the operator's name. Without a token, or with an observer's
(read) token, the map can be watched but nothing can be sent; a websocket client that skips the page
and sets the panel's values or presses its buttons directly meets the same check.

The command fields, their labels, units, ranges and hints come from ``server.screens.form``
(the control packet's field table narrowed by the vehicle's limits), the same spec the dashboard reads
from the API, and are checked by ``check_form`` before anything is sent.
"""

from __future__ import annotations

import html
import logging
import time
from typing import Any, Protocol

import numpy as np

from server.commands.models import CommandState
from server.commands.schemas import FLEET_COMMANDS, CommandIn
from server.commands.service import CommandDesk
from server.core.config import Settings
from server.core.errors import ApiError
from server.core.events import CommandChanged
from server.core.security import Actor, Role, Throttle
from server.map.geometry import OBLIQUE_FOV, PLAN_FOV, Point, far_plane, move_to, ray_to_depth_plane, top_down
from server.screens.form import SPEED_DEFAULT, check_form, command_form, field_specs
from server.vehicles.models import Vehicle
from tacit.navigation import Pose


class MapOwner(Protocol):
    """What a panel asks of the map it sits on (``server.map.scene.OperatorMap``)."""

    settings: Settings
    desk: CommandDesk
    sign_ins: Throttle

    @property
    def suggestion(self) -> tuple[float, float] | None: ...

    @property
    def estimate_cloud(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None: ...

    def view_for(self, width: int | None, height: int | None) -> tuple[Point, Point, float] | None: ...

    def vehicle_names(self) -> list[str]: ...

    def vehicle(self, name: str) -> Vehicle | None: ...

    def pose(self, vehicle: Vehicle) -> Pose | None: ...

    def focus(self) -> tuple[float, float]: ...

    def command_list(self) -> str: ...


log = logging.getLogger("tacit.server.map")

NOT_SIGNED_IN = (
    "**Watching only.** Paste the **operator token** above and press **Sign in** to send "
    "commands (`tacit demo` prints it; it is also in the demo's `secrets.json`)."
)
ANGLE_MODES = {"turn from heading": "relative", "bearing (true)": "bearing"}
FLEET_LABELS = {"abort_mission": "Abort all", "return_home": "Return all home", "hold": "Hold all"}
assert set(FLEET_LABELS) == set(FLEET_COMMANDS), "a button for every fleet command"
FLEET = "all:"  # a confirmation's prefix for an action that goes to every vehicle
INPUTS = ("distance", "angle", "depth", "speed", "param_id", "param_value")
ZOOM_OUT = 0.8  # the farthest the camera may zoom out, as a share of its far plane (the scene stays drawn)

LEGEND = """\
**In the scene** (x east, y north, z up; metres from the fleet's origin; opens top-down, north up, on every vehicle and gateway: **Fit all** returns there)
- **red arrow from home**: north (N); **dark arrow**: east (E); grid: 5 m cells, 25 m sections
- **depth scale**: the black line south-west of home, with its labels stepped aside
- **fleet origin (0, 0)**: the one origin every vehicle's position is measured from (latitude, longitude when known)
- **vehicle**: box in its colour (grey while overdue); **yellow arrow outlined in black** = its heading; label = name, state, age of the report (labels of vehicles close together are stacked, each joined to its vehicle by a thin line)
- **line in the vehicle's colour**: the track it reported (check-points); the same colour as its row on the dashboard
- **grey line**: the mission's planned waypoints; **thicker line in the vehicle's colour**: the path the separation check plans for it (queued commands, team lanes to come)
- **dark grey outline**: a team mission's survey area (its name and state at its north-west corner), each member's lanes as a thin line in its colour
- **orange**: where the shore predicts it is now (sphere), the line from its last report to there, and a circle = how unsure (grows with silence)
- **dots above the track**: packets by priority (blue routine, yellow, orange, red time-sensitive)
- **coloured dots**: verified water temperatures (scale below); **grey squares**: not yet verified (left out of the estimate)
- **estimate** (when ticked): coloured cloud at the vehicle's depth, **black diamonds** its front
- **purple sphere**: where the temperature estimate is most uncertain (a good place to sample next)
- **yellow sphere**: the point you clicked (the command's target)
- **box with a label** (a center's): a gateway at its shore modem's place, dark while its heartbeats come, light grey once silent; **thin line in a vehicle's colour**: from the vehicle to the gateway its commands go through
"""


def fleet_html(known: dict[str, Any]) -> str:
    """The fleet's listing (``Screens.fleet``) as HTML: per vehicle its colour, name, state, its gateway (a
    center's), last report and its age, predicted pose with its uncertainty, battery and link; greyed while
    overdue."""
    rows = [_fleet_row(v) for v in known["vehicles"]]
    return "".join(rows) or "no vehicle registered"


def _fleet_row(v: dict[str, Any]) -> str:
    cp, p = v["reported"], v["predicted"]
    style = "color:#777;background:#e4e4e4" if v["overdue"] else ""
    swatch = f'<span style="display:inline-block;width:10px;height:10px;background:{v["colour"]}"></span>'
    late = " <b>(overdue)</b>" if v["overdue"] else ""
    pinned = " (pinned)" if v["gateway_pinned"] else ""
    via = f"; via gateway {html.escape(v['gateway'])}{pinned}" if v["gateway"] else ""
    head = f"{swatch} <b>{html.escape(v['name'])}</b>: {html.escape(_state(v))}{late}{via}"
    if cp is None or p is None:
        return f'<div style="font-size:0.8em;{style}">{head}</div>'
    snr = "-" if v["snr_in"] is None else f"{v['snr_in']:.0f}"
    offset = "" if v["clock_offset_s"] is None else f" ({clock_words(v['clock_offset_s'])})"
    return (
        f'<div style="font-size:0.8em;margin-bottom:4px;{style}">{head}<br>'
        f"report {v['age_s']:.0f} s ago{offset}: N {cp['north']:.1f}, E {cp['east']:.1f}, {cp['depth']:.1f} m deep; "
        f"battery {cp['battery']:.1f} V, SNR {snr} dB<br>"
        f"predicted N {p['north']:.1f}, E {p['east']:.1f} m <b>± {p['radius_m']:.1f} m</b></div>"
    )


def _state(v: dict[str, Any]) -> str:
    """Its state's label; before its first check-point, whether it is due yet."""
    if v["state_label"]:
        return str(v["state_label"])
    if v["awaited"]:
        return f"waiting for its first report (due by {time.strftime('%H:%M:%SZ', time.gmtime(v['first_report_due']))})"
    return "no report yet"


def clock_words(offset: float) -> str:
    """The vehicle's clock against the shore's in words. ``offset`` is a lower bound of vehicle minus shore
    (``server.telemetry.clock``: a check-point's stamp against when it was heard, its wait included): so
    ``vehicle clock at most 41.6 s behind the shore's``, or ``at least 3.2 s ahead of``."""
    if offset >= 0:
        return f"vehicle clock at least {offset:.1f} s ahead of the shore's"
    return f"vehicle clock at most {-offset:.1f} s behind the shore's"


def colour_scale(lo: float | None, hi: float | None) -> str:
    """The temperature colour scale (blue cold, red warm) as HTML."""
    labels = ("-", "-") if lo is None or hi is None else (f"{lo:.2f} °C", f"{hi:.2f} °C")
    return (
        '<div style="font-size:0.8em">water temperature (verified samples)</div>'
        '<div style="height:10px;background:linear-gradient(to right, rgb(40,90,220), rgb(230,50,40))"></div>'
        f'<div style="display:flex;justify-content:space-between;font-size:0.8em"><span>{labels[0]}</span>'
        f"<span>{labels[1]}</span></div>"
    )


class OperatorPanel:
    def __init__(self, owner: MapOwner, client: Any) -> None:
        self.map = owner
        self.client = client
        self.gui = client.gui
        self.token: str | None = None
        self.role: str | None = None
        self.pending_confirm: str | None = None
        self.last_sent: int | None = None
        self.estimate_handle: Any = None
        self.unfitted = (
            True  # the view is fitted to the fleet once, when both the fleet and the window are known
        )
        self.size: tuple[int, int] | None = None  # the browser's view in pixels, as its camera reports it
        self.form = command_form()
        self.ranges: dict[str, tuple[float, float]] = {}
        self._build()
        self._apply_form()
        self._show_role()

    # --- building ------------------------------------------------------------------------------

    def _build(self) -> None:
        gui = self.gui
        with gui.add_folder("Sign in"):
            self.token_in = gui.add_text(
                "Token",
                "",
                hint="The operator's token sends commands; an observer's "
                "token (or none) only watches. Cleared from the box after signing in.",
            )
            self.sign_in_btn = gui.add_button("Sign in", hint="Check the token with the shore server")
            self.role_md = gui.add_markdown(NOT_SIGNED_IN)
        with gui.add_folder("View"):
            fit_all = gui.add_button(
                "Fit all",
                hint="Look down on every vehicle and gateway at once, north up (the view the map opens with)",
            )
            top = gui.add_button(
                "Top-down view",
                hint="Look straight down on the vehicle, north "
                "up, as the map opens (from high with a narrow lens: close to a plan)",
            )
            side = gui.add_button(
                "Oblique view", hint="Back to the view from the south-west, above the water"
            )
            self.estimate_cb = gui.add_checkbox(
                "Temperature estimate (verified samples)",
                False,
                hint="The shore's estimate of the water temperature at the "
                "vehicle's depth, fitted to the verified samples only (a sample "
                "waits, grey, until a check-point vouches for its packet; colour scale "
                "below), and its front (black diamonds: where it crosses its "
                "median). Off by default: it covers the track.",
            )
            self.scale_html = gui.add_html(colour_scale(None, None))
            gui.add_markdown(LEGEND)
        with gui.add_folder("Fleet"):
            self.fleet_html = gui.add_html("waiting for the vehicles' check-points")
            self.fleet_btns = {
                command: gui.add_button(label, color="red" if command == "abort_mission" else None,
                                        hint=f"{label}: one command per vehicle, each with its own status")
                for command, label in FLEET_LABELS.items()
            }  # fmt: skip
        with gui.add_folder("Link"):
            self.link_md = gui.add_markdown("waiting for the link engine")
        with gui.add_folder("Command"):
            names = self.map.vehicle_names() or ["(none)"]
            self.vehicle_dd = gui.add_dropdown("Vehicle", names, hint="The vehicle the command goes to")
            self.command_dd = gui.add_dropdown(
                "Command",
                list(self.form["commands"]),
                initial_value="move",
                hint="What to ask of the vehicle",
            )
            d = self.form["defaults"]
            self.inputs = {
                "distance": gui.add_number("Distance (m)", d["distance"]),
                "angle_mode": gui.add_dropdown("Angle is", list(ANGLE_MODES), hint="A turn relative to the "
                                               "vehicle's heading, or a true bearing from north"),
                "angle": gui.add_number("Angle (deg)", d["angle"]),
                "depth": gui.add_number("Depth (m)", d["depth"]),
                "speed": gui.add_number("Speed (m/s)", 1.0, disabled=True),
                "param_id": gui.add_number("Number", d["param_id"], step=1),
                "param_value": gui.add_number("Value", d["param_value"]),
            }  # fmt: skip
            self.speed_cb = gui.add_checkbox(
                "Set speed",
                False,
                hint="Off: nothing is sent and the vehicle "
                f"keeps its cruise speed ({SPEED_DEFAULT}); on: the speed below",
            )
            self.plane_dd = gui.add_dropdown(
                "Click plane",
                ["vehicle depth", "surface"],
                hint="Clicking the scene fills distance and angle toward the point "
                "where the click meets this plane",
            )
            self.send_btn = gui.add_button(
                "Send", color="blue", hint="Check the fields and queue the command"
            )
            self.status_md = gui.add_markdown("")
        with gui.add_folder("Mission"):
            self.start_btn = gui.add_button("Start mission", hint="Start the mission numbered in Number")
            self.abort_btn = gui.add_button("Abort mission", color="red", hint="Abort and hold where it is")
            self.home_btn = gui.add_button("Return home", color="orange", hint="Head home now")
            self.confirm_btn = gui.add_button("Confirm", color="red", visible=False)
            self.cancel_btn = gui.add_button("Cancel", visible=False)
            self.suggest_btn = gui.add_button(
                "Go to suggested target",
                visible=False,
                hint="Fill a move toward the purple sphere: where the temperature estimate is most uncertain",
            )
        with gui.add_folder("Commands"):
            self.commands_md = gui.add_markdown(self.map.command_list())
            self.cancel_in = gui.add_number(
                "Command #", 0, min=0, step=1, hint="The command to take back (the last one sent from here)"
            )
            self.withdraw_btn = gui.add_button(
                "Cancel queued command",
                hint="Take it back while it waits: it ends cancelled and is never sent (too late once it is "
                "signed for transmission: it goes on as sent)",
            )
        self.sign_in_btn.on_click(lambda _e: self.sign_in(self.token_in.value))
        fit_all.on_click(lambda _e: self.fit_all())
        top.on_click(lambda _e: self.top_down())
        side.on_click(lambda _e: self.oblique())
        self.estimate_cb.on_update(lambda _e: self.show_estimate())
        self.command_dd.on_update(lambda _e: self._apply_form())
        self.inputs["angle_mode"].on_update(lambda _e: self._apply_form())
        self.speed_cb.on_update(lambda _e: self._apply_form())
        self.vehicle_dd.on_update(lambda _e: self._apply_form())
        self.send_btn.on_click(lambda _e: self.send_form())
        self.withdraw_btn.on_click(lambda _e: self.cancel_command(int(self.cancel_in.value or 0)))
        self.start_btn.on_click(lambda _e: self.ask("start_mission"))
        self.abort_btn.on_click(lambda _e: self.ask("abort_mission"))
        self.home_btn.on_click(lambda _e: self.ask("return_home"))
        self.confirm_btn.on_click(lambda _e: self.confirm())
        self.cancel_btn.on_click(lambda _e: self.ask(None))
        for command, button in self.fleet_btns.items():
            button.on_click(lambda _e, command=command: self.ask(FLEET + command))
        self.suggest_btn.on_click(
            lambda _e: self.fill_from_point(*self.map.suggestion) if self.map.suggestion else None
        )
        scene = getattr(self.client, "scene", None)
        if scene is not None and hasattr(scene, "on_click"):
            scene.on_click()(self.on_scene_click)
        camera = getattr(self.client, "camera", None)
        if camera is not None:
            camera.on_update(self._camera_moved)

    def _camera_moved(self, camera: Any) -> None:
        """The browser reports its camera (and its view's size): the first time, the view is fitted."""
        self.size = (camera.image_width, camera.image_height)
        if self.unfitted:
            self.fit_all()

    # --- sign-in -------------------------------------------------------------------------------

    def sign_in(self, token: str) -> str | None:
        """Check ``token`` (the same operator and observer tokens as the API); the box is cleared."""
        token = (token or "").strip()
        self.token_in.value = ""
        try:
            found = self.map.sign_ins.actor(token, "map clients") if token else None
        except ApiError as exc:  # too many wrong tokens; an expired or revoked one
            self.token, self.role, self.role_md.content = None, None, f"**Not signed in**: {exc.detail}"
            return None
        self.token, self.role = (token, found.role) if found else (None, None)
        self._show_role(rejected=bool(token) and found is None)
        who = f"{found.name} ({found.role})" if found else "nobody"
        log.info("map client %s signed in as %s", getattr(self.client, "client_id", "?"), who)
        return self.role

    def may_act(self) -> Actor | None:
        """The signed-in operator, checked again now (not just at sign-in: it may have expired or been
        revoked since); None if the panel may not send."""
        if self.token is None:
            return None
        try:
            found = self.map.sign_ins.still(self.token)
        except ApiError:
            return None
        return found if found.role is Role.WRITE else None

    def _show_role(self, rejected: bool = False) -> None:
        if self.role is Role.WRITE:
            self.role_md.content = "Signed in as **operator**: commands enabled."
        elif self.role is Role.READ:
            self.role_md.content = (
                "Signed in as **observer**: watching only (an observer's token cannot send)."
            )
        else:
            self.role_md.content = ("**Token not accepted.** " if rejected else "") + NOT_SIGNED_IN
        write = self.role is Role.WRITE
        for button in (
            self.send_btn,
            self.start_btn,
            self.abort_btn,
            self.home_btn,
            self.confirm_btn,
            self.suggest_btn,
            *self.fleet_btns.values(),
        ):
            button.disabled = not write

    # --- the form ------------------------------------------------------------------------------

    def vehicle(self) -> Any:
        return self.map.vehicle(self.vehicle_dd.value)

    def angle_mode(self) -> str:
        return ANGLE_MODES.get(self.inputs["angle_mode"].value, "relative")

    def _apply_form(self) -> None:
        """Show the command's fields with their labels, ranges and hints from the form spec."""
        vehicle = self.vehicle()
        self.form = command_form(vehicle.limits() if vehicle else None)
        command = self.command_dd.value
        specs = {s["name"]: s for s in field_specs(self.form, command, self.angle_mode())}
        for name in INPUTS:
            handle, spec = self.inputs[name], specs.get(name)
            handle.visible = spec is not None
            if spec is None:
                continue
            unit = f" ({spec['unit']})" if spec["unit"] else ""
            handle.label = f"{spec['label']}{unit}"
            handle.hint = f"{spec['hint']} Range {spec['min']:g} .. {spec['max']:g}{unit}."
            self.ranges[name] = (spec["min"], spec["max"])  # checked at send (check_form), shown in the hint
        self.inputs["angle_mode"].visible = "angle" in specs
        self.speed_cb.visible = "speed" in specs
        self.inputs["speed"].disabled = not self.speed_cb.value

    def values(self) -> dict[str, float | None]:
        """The fields' values; the speed only when "Set speed" is ticked (a number box cannot be blank)."""
        values = {name: self.inputs[name].value for name in INPUTS}
        return {**values, "speed": values["speed"] if self.speed_cb.value else None}

    def send_form(self) -> str:
        """Check the visible fields against the spec, then send; returns what the status line says."""
        try:
            body = check_form(self.form, self.command_dd.value, self.values(), self.angle_mode())
            command = CommandIn(**body)
        except ValueError as exc:
            return self._status(f"**Not sent**: {exc}")
        return self.send(command)

    def send(self, command: CommandIn) -> str:
        actor = self.may_act()
        if actor is None:
            return self._status("**Not sent**: sign in with an operator's token to send commands.")
        vehicle = self.vehicle()
        if vehicle is None:
            return self._status("**Not sent**: no vehicle registered")
        try:
            queued = self.map.desk.submit(vehicle.id, command, actor.name)
        except ApiError as exc:
            return self._status(f"**Refused**: {exc.field}: {exc.detail}")
        self.last_sent = self.cancel_in.value = queued.id
        waiting = self.map.desk.pending(vehicle.id)
        return self._status(
            f"Command #{queued.id} **{queued.command}** seq {queued.seq}: **queued** "
            f"({waiting} / {self.map.desk.max_queued} of {vehicle.name}'s commands waiting for the link)"
        )

    def cancel_command(self, command_id: int) -> str:
        """Take back a queued command (``CommandDesk.cancel``): cancelled, or why it is too late."""
        actor = self.may_act()
        if actor is None:
            return self._status("**Not cancelled**: sign in with an operator's token.")
        try:
            command = self.map.desk.cancel(command_id, actor.name)
        except ApiError as exc:
            return self._status(f"**Not cancelled**: {exc.detail}")
        if command.status == CommandState.CANCELLING:
            return self._status(
                f"Command #{command.id} seq {command.seq}: **cancelling**: withdrawn from the gateway that holds "
                "it, cancelled unless that gateway sent it first"
            )
        return self._status(f"Command #{command.id} seq {command.seq}: **cancelled**, never sent")

    def send_fleet(self, command: str) -> str:
        """One command per vehicle (``CommandDesk.submit_fleet``), each followed in the command list."""
        actor = self.may_act()
        if actor is None:
            return self._status("**Not sent**: sign in with an operator's token to send commands.")
        try:
            queued = self.map.desk.submit_fleet(None, CommandIn(command=command), actor.name)
        except ApiError as exc:
            return self._status(f"**Refused**: {exc.detail}")
        each = ", ".join(f"#{c.id}" for c in queued)
        return self._status(f"**{FLEET_LABELS[command]}**: {len(queued)} commands queued ({each})")

    def _status(self, text: str) -> str:
        self.status_md.content = text
        return text

    def command_status(self, event: CommandChanged, lines: str) -> None:
        self.commands_md.content = lines
        if self.last_sent is not None and self.last_sent == event.id:
            reason = f": {event.reason}" if event.reason else ""
            self._status(f"Command #{event.id} seq {event.seq}: **{event.status}**{reason}")

    # --- missions, confirmations ---------------------------------------------------------------

    def ask(self, action: str | None) -> None:
        self.pending_confirm = action
        self.confirm_btn.visible = self.cancel_btn.visible = action is not None
        if action:
            fleet = action.removeprefix(FLEET)
            what = FLEET_LABELS[fleet].lower() if action.startswith(FLEET) else action.replace("_", " ")
            self.confirm_btn.label = f"Confirm: {what}"

    def confirm(self) -> None:
        action, self.pending_confirm = self.pending_confirm, None
        self.ask(None)
        if not action:
            return
        if action.startswith(FLEET):
            self.send_fleet(action.removeprefix(FLEET))
            return
        try:
            param = int(self.inputs["param_id"].value) if action == "start_mission" else 0
            command = CommandIn(command=action, param_id=param)
        except (TypeError, ValueError) as exc:  # a blank or out-of-range mission number (pydantic's too)
            self._status(f"**Refused**: the mission number is not a mission number ({exc})")
            return
        self.send(command)

    # --- the scene -----------------------------------------------------------------------------

    def on_scene_click(self, event: Any) -> None:
        vehicle = self.vehicle()
        pose = self.map.pose(vehicle) if vehicle else None
        depth = 0.0 if self.plane_dd.value == "surface" or pose is None else pose.depth
        point = ray_to_depth_plane(event.ray_origin, event.ray_direction, depth)
        if point is not None:
            self.fill_from_point(point[0], point[1], depth)

    def fill_from_point(self, north: float, east: float, depth: float | None = None) -> None:
        vehicle = self.vehicle()
        pose = (self.map.pose(vehicle) if vehicle else None) or Pose(0.0, 0.0, 0.0, 0.0)
        command = move_to(
            pose, north, east, pose.depth if depth is None else depth, self.angle_mode() == "bearing"
        )
        self.command_dd.value = "move"
        self._apply_form()
        angle = command.angle % 360.0 if self.angle_mode() == "bearing" else command.angle
        self.inputs["distance"].value, self.inputs["angle"].value, self.inputs["depth"].value = (
            command.distance,
            round(angle, 2),
            command.depth,
        )
        self.client.scene.add_icosphere(
            "/click_target",
            radius=0.4,
            color=(250, 200, 0),
            position=(east, north, -(pose.depth if depth is None else depth)),
        )
        self._status(f"Target set: {command.distance:.1f} m, angle {angle:.1f} deg. Press **Send**.")

    def fit_all(self) -> None:
        """Every vehicle and gateway in view, for this browser's window, its panel's side left free."""
        view = self.map.view_for(*(self.size or (None, None)))
        if view is not None:
            self.unfitted = False
            self._look(view[0], view[1], PLAN_FOV, view[2])

    def top_down(self) -> None:
        self._look(*top_down(*self.map.focus()), PLAN_FOV)

    def oblique(self) -> None:
        north, east = self.map.focus()
        self._look((east - 25.0, north - 35.0, 30.0), (east, north, -2.0), OBLIQUE_FOV)

    def _look(self, position: Point, look_at: Point, fov: float, far: float | None = None) -> None:
        """Move this browser's camera; the far plane stays beyond the fitted view's (zooming out from a
        close view must reach the whole fleet), and zooming out stops short of it (``ZOOM_OUT``)."""
        view = self.map.view_for(*(self.size or (None, None)))
        camera = self.client.camera
        with self.client.atomic():
            camera.far = far or (view[2] if view is not None else far_plane(position[2]))
            camera.max_orbit_distance = ZOOM_OUT * camera.far
            camera.up_direction = (0.0, 0.0, 1.0)
            camera.fov = fov
            camera.position = position
            camera.look_at = look_at

    def show_estimate(self) -> None:
        """The temperature estimate in this client's scene only while its box is ticked."""
        cloud = self.map.estimate_cloud
        if self.estimate_cb.value and cloud is not None:
            points, colours, front = cloud
            scene = self.client.scene
            self.estimate_handle = [
                scene.add_point_cloud("/temperature/estimate", points, colours, point_size=0.45,
                                      point_shape="circle"),
                scene.add_point_cloud("/temperature/estimate/front", front, (20, 20, 20), point_size=0.5,
                                      point_shape="diamond"),
            ]  # fmt: skip
        elif self.estimate_handle is not None:
            for handle in self.estimate_handle:
                handle.remove()
            self.estimate_handle = None
