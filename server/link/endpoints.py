"""The link's routes: its status, the MAC's schedule and the live event stream."""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import AsyncIterator

from fastapi import APIRouter, Depends
from fastapi.responses import StreamingResponse

from server.api.deps import BusDep, Credentials, LinkDep, Reader, ScreensDep, SignInsDep, require_read
from server.core.errors import Unauthorized
from server.core.events import StreamEnded
from server.link.schemas import LinkSchedule
from server.screens.schemas import LinkStatus

router = APIRouter(prefix="/api/v1", tags=["data"], dependencies=[Depends(require_read)])
KEEP_ALIVE_S = 15.0  # an idle event stream's comment line, so proxies keep it open
RECHECK_S = 1.0  # an event stream's token is asked again at most this often (a database read)


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
async def events(
    bus: BusDep, sign_ins: SignInsDep, reader: Reader, credentials: Credentials
) -> StreamingResponse:
    """Server-sent events (packet, command, telemetry, link, vehicle), authenticated by the Authorization
    header like every other route: a token in a URL would end up in access logs. (Browsers read this
    stream with ``fetch``, which can send the header, rather than ``EventSource``, which cannot.) The
    token is checked again before each event is sent (at most every ``RECHECK_S``) and when it expires:
    once it is revoked or expired, the stream sends an ``end`` event saying why and closes."""
    queue = bus.subscribe()
    token = credentials.credentials if credentials is not None else None

    async def ended() -> str | None:
        """Why the stream's token no longer holds (None: it does, or reads are open)."""
        if token is None:
            return None
        try:
            await asyncio.to_thread(sign_ins.still, token)
        except Unauthorized as exc:
            return exc.detail
        return None

    async def stream() -> AsyncIterator[str]:
        checked = -math.inf  # the first event is checked
        try:
            yield ": connected\n\n"
            while True:
                wait = KEEP_ALIVE_S
                if reader.expires_at is not None:
                    wait = min(wait, max(0.0, reader.expires_at - time.time()))
                try:
                    text = bus.sse(await asyncio.wait_for(queue.get(), wait))
                except TimeoutError:
                    text = ": keep-alive\n\n"
                expired = reader.expires_at is not None and reader.expires_at <= time.time()
                if expired or time.monotonic() - checked >= RECHECK_S:
                    checked = -math.inf  # the first event is checked
                    why = await ended()
                    if why is not None:
                        yield bus.sse(StreamEnded(detail=why))
                        return
                yield text
        finally:
            bus.unsubscribe(queue)

    return StreamingResponse(stream(), media_type="text/event-stream", headers={"Cache-Control": "no-cache"})
