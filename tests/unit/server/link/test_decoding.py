"""The shore's decoding of a packet's spans into telemetry rows (``server.link.decoding``)."""

from __future__ import annotations

import numpy as np

from server.link import decoding
from server.link.batch import Batch
from server.link.state import VehicleState
from tacit.codec import DecodedSpan, PacketDecoder
from tacit.packets import Stream
from tacit.streams import default_streams


def test_the_rest_of_a_sample_sent_in_parts_is_stored_as_a_part() -> None:
    """A span whose first row completes the last row of the packet before (``continues``) stores that row
    as a part, so the exports join it to its sample; the rows after it, and the rows of a span that does
    not continue, are samples of their own."""
    env = default_streams()[Stream.ENVIRONMENTAL]
    vehicle = VehicleState(id=1, name="rov1", address=2, decoder=PacketDecoder([env]))
    batch = Batch()
    n = len(env.channels)
    for continues in (True, False):
        span = DecodedSpan(
            env,
            ticks=np.array([10, 11], dtype=np.int64),
            values=np.full((2, n), 1.0),
            lost=None,
            phases=np.zeros(2, dtype=np.int64),
            lost_phase=0,
            continues=continues,
        )
        decoding._samples(batch, vehicle, span, packet_id=7)
    assert [row["part"] for row in batch.samples] == [True, False, False, False]
    assert [row["tick"] for row in batch.samples] == [10, 11, 10, 11]
