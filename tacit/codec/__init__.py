"""The sample codec: what goes in a priority packet's 29 bytes of samples, and how the shore gets it back.

The vehicle quantises each sample against a prediction both ends make, so every value the shore holds is
within its channel's eps, and codes what is left with adaptive arithmetic coding: what is regular
becomes almost free, and the 80 bit/s link carries what the shore could not predict. One concept per
module:

- ``spec``: ``StreamSpec``, what both ends agree on for a stream, and the quantisation;
- ``prediction``: the dual predictor (per-channel predictor plus cross-channel regression);
- ``grid``: the tick grid a sample's time is placed on, and its phase;
- ``format``: the payload's layout, its header and its errors;
- ``tokens``: the kinds of token a stream's section is made of;
- ``grammar``: the tokens of a stream's section and the coding of a sample, written and read;
- ``models``: the adaptive models both ends keep per stream, and their contexts;
- ``state``: the chain of states packets continue from, and how the shore saves it;
- ``policy``: when a packet leaves (latency, silence, urgency);
- ``encoder`` and ``decoder``: the vehicle's and the shore's side.
"""

from tacit.codec.decoder import DecodedSpan, PacketDecoder, StreamDecoder
from tacit.codec.encoder import EncodedPacket, PacketEncoder, StreamEncoder
from tacit.codec.format import FORMAT, CodecError, UnknownBase, chain_ids
from tacit.codec.policy import SendPolicy
from tacit.codec.spec import StreamSpec

__all__ = [
    "FORMAT",
    "CodecError",
    "DecodedSpan",
    "EncodedPacket",
    "PacketDecoder",
    "PacketEncoder",
    "SendPolicy",
    "StreamDecoder",
    "StreamEncoder",
    "StreamSpec",
    "UnknownBase",
    "chain_ids",
]
