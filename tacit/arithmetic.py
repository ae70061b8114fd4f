"""Integer arithmetic coding with adaptive frequency models (Witten, Neal and Cleary, 1987).

Pure integer arithmetic, so the vehicle's encoder and the shore's decoder agree bit for bit on any
platform. The encoder knows at every moment how many bits its output would take if finished now
(``bits_if_finished``), so a packet can be filled to the last bit.
"""

from __future__ import annotations

from dataclasses import dataclass, field

_BITS = 32
_TOP = (1 << _BITS) - 1
_HALF = 1 << (_BITS - 1)
_QUARTER = 1 << (_BITS - 2)
_THREE_QUARTERS = 3 * _QUARTER
MAX_TOTAL = 1 << 16


@dataclass(slots=True)
class AdaptiveModel:
    """Symbol frequencies that follow the data: +``increment`` per use, halved past ``limit``. ``total``
    is their sum, kept with them (summing them for every symbol took much of the coder's time)."""

    freqs: list[int]
    increment: int = 24
    limit: int = 4096
    total: int = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.total = sum(self.freqs)

    def interval(self, symbol: int) -> tuple[int, int, int]:
        low = sum(self.freqs[:symbol])
        return low, low + self.freqs[symbol], self.total

    def find(self, target: int) -> tuple[int, int, int]:
        """The symbol whose interval holds ``target`` (a cumulative count), with its interval."""
        low = 0
        symbol = 0
        for freq in self.freqs:
            high = low + freq
            if target < high:
                return symbol, low, high
            low = high
            symbol += 1
        raise ValueError("target beyond the model's total")

    def update(self, symbol: int) -> None:
        freqs = self.freqs
        freqs[symbol] += self.increment
        self.total += self.increment
        if self.total > self.limit:
            self.freqs = [max(1, f // 2) for f in freqs]
            self.total = sum(self.freqs)

    def copy(self) -> AdaptiveModel:
        out = AdaptiveModel.__new__(AdaptiveModel)
        out.freqs, out.increment, out.limit, out.total = self.freqs[:], self.increment, self.limit, self.total
        return out


@dataclass
class Encoder:
    low: int = 0
    high: int = _TOP
    pending: int = 0
    bits: list[int] = field(default_factory=list)

    def copy(self) -> Encoder:
        return Encoder(self.low, self.high, self.pending, list(self.bits))

    def encode(self, low: int, high: int, total: int) -> None:
        span = self.high - self.low + 1
        self.high = self.low + span * high // total - 1
        self.low = self.low + span * low // total
        while True:
            if self.high < _HALF:
                self._emit(0)
            elif self.low >= _HALF:
                self._emit(1)
                self.low -= _HALF
                self.high -= _HALF
            elif self.low >= _QUARTER and self.high < 3 * _QUARTER:
                self.pending += 1
                self.low -= _QUARTER
                self.high -= _QUARTER
            else:
                break
            self.low <<= 1
            self.high = (self.high << 1) | 1

    def encode_symbol(self, model: AdaptiveModel, symbol: int) -> None:
        self.encode(*model.interval(symbol))
        model.update(symbol)

    def encode_bit(self, bit: int) -> None:
        """An equiprobable bit (used for escaped magnitudes)."""
        self.encode(bit, bit + 1, 2)

    def _emit(self, bit: int) -> None:
        self.bits.append(bit)
        self.bits.extend([1 - bit] * self.pending)
        self.pending = 0

    @property
    def bits_if_finished(self) -> int:
        return len(self.bits) + self.pending + 2

    def finish(self) -> list[int]:
        out = self.copy()
        out.pending += 1
        out._emit(0 if out.low < _QUARTER else 1)
        return out.bits


class Decoder:
    """The encoder's inverse. The data are held as one integer (``_code``): bit ``i`` of the data, most
    significant first, is its bit ``_size - 1 - i``; bits past the end read as 0."""

    def __init__(self, data: bytes) -> None:
        self._size = 8 * len(data)
        self._code = int.from_bytes(data, "big")
        self._pos = 0
        self.low, self.high, self.value = 0, _TOP, 0
        for _ in range(_BITS):
            self.value = (self.value << 1) | self._next_bit()

    def _next_bit(self) -> int:
        pos = self._pos
        self._pos = pos + 1
        return (self._code >> (self._size - 1 - pos)) & 1 if pos < self._size else 0

    def _target(self, total: int) -> int:
        return ((self.value - self.low + 1) * total - 1) // (self.high - self.low + 1)

    def _narrow(self, low: int, high: int, total: int) -> None:
        """Take the interval [low, high) of ``total`` and renormalise, reading a bit per doubling."""
        lo, hi, value = self.low, self.high, self.value
        span = hi - lo + 1
        hi = lo + span * high // total - 1
        lo = lo + span * low // total
        while True:
            if hi < _HALF:
                pass
            elif lo >= _HALF:
                lo -= _HALF
                hi -= _HALF
                value -= _HALF
            elif lo >= _QUARTER and hi < _THREE_QUARTERS:
                lo -= _QUARTER
                hi -= _QUARTER
                value -= _QUARTER
            else:
                break
            lo <<= 1
            hi = (hi << 1) | 1
            value = (value << 1) | self._next_bit()
        self.low, self.high, self.value = lo, hi, value

    def decode_symbol(self, model: AdaptiveModel) -> int:
        total = model.total
        symbol, low, high = model.find(self._target(total))
        self._narrow(low, high, total)
        model.update(symbol)
        return symbol

    def decode_bit(self) -> int:
        bit = 1 if self._target(2) >= 1 else 0
        self._narrow(bit, bit + 1, 2)
        return bit


def pack_bits(bits: list[int], size: int) -> bytes:
    """Bits, most significant first, zero-padded to ``size`` bytes."""
    if len(bits) > size * 8:
        raise ValueError(f"{len(bits)} bits do not fit in {size} bytes")
    padded = bits + [0] * (size * 8 - len(bits))
    return bytes(int("".join(map(str, padded[i : i + 8])), 2) for i in range(0, len(padded), 8))
