"""The link's routes: its status, the MAC's schedule and the live event stream."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator

from fastapi import APIRouter, Depends
from fastapi.responses import StreamingResponse

from server.api.deps import BusDep, LinkDep, ScreensDep, require_read
from server.link.schemas import LinkSchedule
from server.screens.schemas import LinkStatus

router = APIRouter(prefix="/api/v1", tags=["data"], dependencies=[Depends(require_read)])


@router.get("/link", response_model=LinkStatus)
def link_status(screens: ScreensDep) -> LinkStatus:
    """The shore modem's state and, per vehicle: last heard, SNR, range, packets per hour, bytes saved."""
    return LinkStatus.model_validate(screens.link_status())


@router.get("/link/schedule", response_model=LinkSchedule)
def link_schedule(link: LinkDep) -> LinkSchedule:
    """The polled MAC's plan, next slot first: per vehicle its share, when it was last polled and
    commanded, when its next slot is expected and why (command / sync / urgent / poll)."""
    return LinkSchedule.model_validate(link.schedule_status())


@router.get(
    "/events", response_class=StreamingResponse, responses={200: {"content": {"text/event-stream": {}}}}
)
async def events(bus: BusDep) -> StreamingResponse:
    """Server-sent events (packet, command, telemetry, link, vehicle), authenticated by the Authorization
    header like every other route: a token in a URL would end up in access logs. (Browsers read this
    stream with ``fetch``, which can send the header, rather than ``EventSource``, which cannot.)"""
    queue = bus.subscribe()

    async def stream() -> AsyncIterator[str]:
        try:
            yield ": connected\n\n"
            while True:
                try:
                    event = await asyncio.wait_for(queue.get(), 15)
                    yield bus.sse(event)
                except TimeoutError:
                    yield ": keep-alive\n\n"
        finally:
            bus.unsubscribe(queue)

    return StreamingResponse(stream(), media_type="text/event-stream", headers={"Cache-Control": "no-cache"})
