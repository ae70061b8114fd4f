"""A priority packet's samples, decoded on the vehicle's chain (``tacit.codec``) into telemetry rows.

Decoding problems are stored and published as such, never raised. A packet whose base state the shore
does not hold (``UnknownBase``: it was down while the vehicle's modem was ACKed) is stored undecoded and
the vehicle is asked, in a SYNC control packet (``needs_restart``, sent by the link engine), to
restart its chains. A priority packet is not authenticated, so anyone can send one with an unknown
base: such a request is raised at most once per ``restart_min_interval``.

A *late* packet (heard before a frame stored already: it came through a gateway behind a backhaul
outage) is decoded if its base state is still held, and leaves the states of the newer packets as they
were: a late packet that restarted the chain (base 0) must not forget them, nor one whose state id the
chain has reused since (ids cycle through 63) replace it. A late packet whose base is gone asks for no
restart: the vehicle's chain has moved on and the newer packets decode.

A version-4 vehicle keeps a window of packets in flight and names each state by the seq of the packet
that left it (``tacit.codec.format``), so no id is ever reused by another branch. A packet whose base is
newer than every state held (``PacketDecoder.ahead``: the packet before it in the window was lost, or
comes later) waits without asking for a restart: it is decoded when its base comes (a retransmission),
and never if the vehicle codes its samples again from an earlier state.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any

from server.core.events import Event, LinkNotice, TelemetryDecoded
from server.link.batch import Batch
from server.link.state import VehicleState
from tacit import packets
from tacit.codec import CodecError, DecodedSpan, UnknownBase, chain_ids
from tacit.packets import PriorityPacket

log = logging.getLogger("tacit.server.ingest")


@dataclass
class Decoded:
    """What decoding a priority packet gave: the packet's body additions, the packet its decoder state
    came from (``origin``), and the events to publish."""

    body: dict[str, Any] = field(default_factory=dict)
    origin: int | None = None
    events: list[Event] = field(default_factory=list)


def decode(
    batch: Batch,
    v: VehicleState,
    pp: PriorityPacket,
    at: float,
    packet_id: int,
    restart_every: float,
    late: bool = False,
) -> Decoded:
    """Decode on the vehicle's chain; an unknown base asks for a chain restart (once per ``restart_every``
    s at most), unless the packet is ``late``. A packet whose base is unknown waits (``LinkRecord.wait``)
    for a late packet that may leave it."""
    base, own = chain_ids(pp.payload, pp.seq)
    late = late and not v.decoder.coding.window  # version 4's states are named once: none is reused
    held = v.decoder.mark() if late else None
    try:
        if late and v.link.made.get(base, -math.inf) > at:  # its base id was left by a newer packet since
            raise UnknownBase(base)
        spans = v.decoder.decode(pp.payload, at, pp.seq)
    except CodecError as exc:
        return _undecodable(batch, v, pp, at, exc, restart_every, late, packet_id)
    v.decoder_saved = None
    out = Decoded(origin=v.link.producers.get(base) if base else None)  # the packet whose state this built on
    if held is None:
        v.link.producers = {own: packet_id} if not base else {**v.link.producers, own: packet_id}
        v.link.made[own] = at
    elif v.link.made.get(own, -math.inf) > at:  # a newer packet's state has its id: the newer stays
        v.decoder.undo(held)
    else:  # the newer states stay; the late one's is added as the least recent
        v.decoder.undo({own: v.decoder.mark()[own], **{k: c for k, c in held.items() if k != own}})
        v.link.producers[own], v.link.made[own] = packet_id, at
    carried = []
    for span in spans:
        if span.lost:  # the shore cannot vouch for these ticks: stored as uncertain, without values
            batch.samples.extend(
                {
                    "vehicle_id": v.id,
                    "stream": span.spec.name,
                    "tick": k,
                    "time": float(t),
                    "values": [],
                    "certain": False,
                    "packet_id": packet_id,
                    "verified": False,
                }
                for k, t in zip(range(*span.lost), span.lost_times, strict=True)
            )
        if len(span.ticks) or span.lost:
            carried.append(span.spec.name)
            out.events.append(_samples(batch, v, span, packet_id))
    main = next((s for s in spans if s.spec.stream == pp.stream and len(s.ticks)), None)
    main = main or next((s for s in spans if len(s.ticks)), spans[0])
    out.body = {
        "stream_name": main.spec.name,
        "streams": carried,
        "first_tick": main.first_tick,
        "ticks": sum(len(s.ticks) for s in spans),
        "lost": list(main.lost) if main.lost else None,
    }
    return out


def _samples(batch: Batch, v: VehicleState, span: DecodedSpan, packet_id: int) -> TelemetryDecoded:
    spec = span.spec
    times = [float(t) for t in span.times]
    # an absent channel is stored as absent (None), never as a made-up value
    rows = [[None if x != x else round(float(x), 6) for x in values] for values in span.values]
    batch.samples.extend(
        {
            "vehicle_id": v.id,
            "stream": spec.name,
            "tick": int(k),
            "time": t,
            "certain": True,
            "values": row,
            "packet_id": packet_id,
            "verified": False,
            "part": i == 0 and span.continues,
        }
        for i, (k, t, row) in enumerate(zip(span.ticks, times, rows, strict=True))
    )
    v.bytes_saved += max(0, int((span.values == span.values).sum()) * 2 - packets.PACKET_SIZE)
    return TelemetryDecoded(
        packet_id=packet_id,
        vehicle=v.name,
        stream=spec.name,
        channels=list(spec.channels),
        period=spec.period,
        times=times,
        values=[[None if x is None else round(x, 4) for x in r] for r in rows],
        lost=list(span.lost) if span.lost else None,
    )


def _undecodable(
    batch: Batch,
    v: VehicleState,
    pp: PriorityPacket,
    at: float,
    exc: CodecError,
    restart_every: float,
    late: bool,
    packet_id: int,
) -> Decoded:
    stream = pp.stream.name.lower()
    batch.events.append(
        {"vehicle_id": v.id, "kind": "undecodable", "at": at, "detail": {"stream": stream, "error": str(exc)}}
    )
    behind = isinstance(exc, UnknownBase) and v.decoder.ahead(exc.base, pp.seq)  # in the window
    if isinstance(exc, UnknownBase) and not v.link.made.get(exc.base, -math.inf) > at:
        v.link.wait(packet_id, pp.encode(), at)  # a late packet may yet leave its base
    if behind:
        log.info("vehicle %s: priority packet seq %d waits for the packet it continues from", v.name, pp.seq)
    elif late:
        log.warning("vehicle %s: late priority packet seq %d not decoded: %s", v.name, pp.seq, exc)
    elif isinstance(exc, UnknownBase) and not v.link.needs_restart and at - v.restart_raised >= restart_every:
        v.link.needs_restart = True  # the engine's next SYNCs ask the vehicle to restart its chains
        v.restart_raised = at
        log.warning("vehicle %s: sample chain state lost: asking the vehicle to restart its chains", v.name)
    notice = LinkNotice(event="undecodable", vehicle=v.name, detail={"stream": stream, "error": str(exc)})
    return Decoded(body={"error": str(exc)}, events=[notice])
