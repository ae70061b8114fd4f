"""What the codec does for each payload version: the vehicle and the shore build their coders for the
version the vehicle speaks (passed in where an encoder or decoder is made), so a mixed fleet is no flag
day. Version 3's payloads (today's vehicles) decode exactly as they always have; what came later is a
``Coding`` flag that version 3 leaves off.

Version 4 adds:

- **time tolerance** (``tacit.codec.encoder``): a stream may be given a time tolerance
  (``StreamSpec.time_tolerance``, protocol like the rest of the stream's definition, and shown in the
  exports' metadata as the time precision); the vehicle then dates a sample on the tick after the last
  sample's when that is within the tolerance of when it was taken, instead of its nearest tick. A
  sampler whose intervals wander about its period (a glider's CTD reporting every one, two or three of its
  own cycles) then costs a STEP per sample instead of SAME and JUMP tokens; a gap longer than the
  tolerance stays a gap. Nothing changes on the shore: any tick is decoded as before.
- **a window** (``tacit.codec.format``, ``tacit.codec.encoder``): a packet's state is named by the
  packet's seq, so the vehicle may keep several packets in flight, each coded on the state the one before
  it leaves, and a packet coded again after a loss never shares a name with the one it replaces.
- **timing** (``tacit.codec.models.Timing``): JUMP's count is coded as the stream's last one, the one
  before, or a new one, and the token after a sample is modelled by how long its run of equal tick deltas
  is (against that delta's run before); the tolerance above then prefers the tick the last delta (or,
  after a lone one, the one before) leads to. A glider's depth-binned schedule (5, 10, 20 s on a 5 s
  grid) and its gaps between dives cost about 40 % fewer bits beyond a regular clock's than in version 3.
- **the line** (``tacit.codec.prediction``): each channel may also predict by extending the line through
  its last three values (a profile's steady change with depth or time, which the Kalman filter fed
  reconstructions lags and hold follows a step at a time); both ends use it while it has lately missed
  and erred 20 % less than the prediction it replaces, so the choice costs no bits.
- **the profile** (``tacit.codec.profile``): in a stream with a depth channel (``StreamSpec.depth``),
  each other channel may predict from the vehicle's last pass (dive or climb): its last value plus how
  much the last pass changed between the last sample's depth and this one's, chosen the same way.
"""

from __future__ import annotations

from dataclasses import dataclass

from tacit.packets import NEWEST, VERSIONS

__all__ = ["NEWEST", "VERSIONS", "Coding", "coding"]


@dataclass(frozen=True)
class Coding:
    """What a payload version's coder does beyond version 3's."""

    version: int
    tolerance: bool = False  # date a sample on the next tick when within the stream's time tolerance
    trend: bool = False  # a channel may predict by extending the line through its last three values
    window: bool = False  # states named by packet seq: several packets in flight (``tacit.codec.format``)
    timing: bool = False  # a sample's tick delta is coded against the stream's last ones
    profile: bool = False  # a channel may predict from its last profile (a stream with a depth channel)


def coding(protocol: int) -> Coding:
    """What a vehicle speaking ``protocol`` codes; ValueError for a version this codec does not know."""
    if protocol == 3:
        return Coding(3)
    if protocol == 4:
        return Coding(4, tolerance=True, trend=True, window=True, timing=True, profile=True)
    raise ValueError(f"protocol {protocol}: this codec codes versions {', '.join(map(str, VERSIONS))}")
