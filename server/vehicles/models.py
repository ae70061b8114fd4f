"""The vehicle table: its modem address, its keys (with a staged rotation), its limits and its share of the
channel (the polled MAC's weight, ``server.link.schedule``)."""

from __future__ import annotations

from sqlalchemy import false
from sqlmodel import AutoString, Field, SQLModel

from server.core.db import now
from tacit.limits import Limits
from tacit.packets import NEWEST
from tacit.params import CHECKPOINT_INTERVAL, LostAction


class Vehicle(SQLModel, table=True):
    id: int | None = Field(default=None, primary_key=True)
    name: str = Field(unique=True, max_length=64)
    address: int = Field(unique=True, ge=1, le=127)
    key_hex: str = Field(max_length=128)
    key_version: int = Field(default=1, sa_column_kwargs={"server_default": "1"})
    # During a staged rotation: the last key the vehicle confirmed (version key_version - 1); commands
    # are signed with it until a check-point signed with the new key arrives. None: nothing staged.
    previous_key_hex: str | None = Field(default=None, max_length=128)
    rotation_since: float | None = None  # when the staged rotation began
    # Its last check-point signed with the confirmed key said it holds the staged one (version
    # key_version): commands and SYNCs are signed with the new key from then on.
    next_key_held: bool = Field(default=False, sa_column_kwargs={"server_default": false()})
    next_seq: int = Field(default=1)
    max_depth: float = Limits.max_depth
    max_distance: float = Limits.max_distance
    max_speed: float = Limits.max_speed
    geofence_radius: float = Limits.geofence_radius
    share: float = Field(default=1.0, sa_column_kwargs={"server_default": "1"})  # its weight in the MAC
    # where it starts, m north and east of the fleet's origin (its agent's [nav] home): its mission's
    # waypoints and its return home are relative to it, its check-points in the fleet's frame
    home_north: float = Field(default=0.0, sa_column_kwargs={"server_default": "0"})
    home_east: float = Field(default=0.0, sa_column_kwargs={"server_default": "0"})
    # what it does when the link is lost: its agent's lost_action, then each SET_PARAM it executed
    lost_action: LostAction = Field(
        default=LostAction.HOLD, sa_type=AutoString(16), sa_column_kwargs={"server_default": "hold"}
    )
    # the protocol version its agent speaks (``tacit.packets.VERSIONS``): the shore decodes its packets in
    # it; registered with it (the newest by default; vehicles registered before versions were kept: 3)
    protocol: int = Field(default=NEWEST, sa_column_kwargs={"server_default": "3"})
    # s between its check-points (its agent's checkpoint_interval, on the vehicle's clock): until its first
    # is due the screens say it is awaited, not overdue
    report_interval: float = Field(
        default=CHECKPOINT_INTERVAL, sa_column_kwargs={"server_default": str(CHECKPOINT_INTERVAL)}
    )
    created_at: float = Field(default_factory=now)

    @property
    def home(self) -> tuple[float, float]:
        """(north, east) of its home in the fleet's frame."""
        return self.home_north, self.home_east

    def limits(self) -> Limits:
        """The vehicle's limits as the shore holds them (set through the API)."""
        return Limits(self.max_depth, self.max_distance, self.geofence_radius, self.max_speed)
