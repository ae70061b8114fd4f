"""A minimal vehicle host for server tests: the real driver and VehicleLink on a simulated modem's pty,
in a thread with its own event loop (the agent without MAVLink)."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Coroutine
from concurrent.futures import Future
from typing import Any, TypeVar

from tacit import auth, modem
from tacit.packets import CheckpointPacket, Command, ControlPacket
from vehicle_agent.link import VehicleLink

T = TypeVar("T")


class VehicleSide:
    def __init__(self, pty: str, address: int, key: bytes) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        self.controls: list[ControlPacket] = []  # commands (the shore's SYNC heartbeats are in syncs)
        self.syncs: list[ControlPacket] = []
        self.key, self.address = key, address
        self.results: list[bool] = []
        settings = modem.DriverSettings(
            url=pty, address=address, echo_timeout=2, reconnect_min=0.2, keepalive=60
        )
        self.driver = modem.ModemDriver(settings)
        self.link = VehicleLink(self.driver, auth.ControlReceiver(key, address))
        self.link.on_control = lambda p: (self.syncs if p.command is Command.SYNC else self.controls).append(
            p
        )
        self.call(self.driver.start())

    def call(self, coro: Coroutine[Any, Any, T]) -> T:
        future: Future[T] = asyncio.run_coroutine_threadsafe(coro, self.loop)
        return future.result(timeout=30)

    def send(self, packet: bytes, urgent: bool = False) -> None:
        self.loop.call_soon_threadsafe(lambda: self.link.send(packet, urgent, self.results.append))

    def signed(self, checkpoint: CheckpointPacket, covered: list[bytes] = ()) -> bytes:  # type: ignore[assignment]
        """A check-point signed with this vehicle's key (version 1), covering these priority packets."""
        hashes = [auth.packet_hash(p) for p in covered]
        return auth.sign_checkpoint(checkpoint, self.key, 1, self.address, hashes)

    def close(self) -> None:
        self.call(self.driver.stop())
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(timeout=5)
