"""Micro-Modem NMEA: the real lines of REFERENCE §1, round trips of every sentence, and garbage."""

from __future__ import annotations

import dataclasses
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tacit import nmea

REAL_CST = (
    "$CACST,0,223413.0000,0,1440,25,0175,0166,75,01,01,01,03,1,007,006,0,3,3,0,146,03,04,"
    "-100,-1,000,-1.2,45,10000,2000"
)


def with_checksum(line: str) -> str:
    return f"{line}*{nmea.checksum(line[1:])}"


def test_real_lines_from_the_reference() -> None:
    assert nmea.parse("$CAMPA,1,2*5D") == nmea.PingHeard(1, 2)
    assert nmea.parse("$CAMPR,2,1,0.0101*7C") == nmea.PingReply(2, 1, 0.0101)
    assert nmea.parse("$CAMUA,1,2,1fab*20") == nmea.MiniPacketHeard(1, 2, "1fab")
    assert nmea.parse("$CAREV,000052,AUV,0.93.0.09*07") == nmea.Revision("000052", "AUV", "0.93.0.09")
    cst = nmea.parse(with_checksum(REAL_CST))
    assert isinstance(cst, nmea.RxStats)
    assert (cst.mode, cst.rate, cst.src, cst.dest, cst.nframes, cst.snr_out, cst.doppler) == (
        0,
        1,
        7,
        6,
        3,
        4.0,
        -1.2,
    )
    assert cst.carrier == 10000 and cst.bw == 2000


def test_examples_of_the_data_cycle() -> None:
    assert nmea.Cycle(1, 2, 0, True, 1).line() == "$CCCYC,0,1,2,0,1,1*5A\r\n"
    assert nmea.parse("$CACYC,0,1,2,0,1,1*58") == nmea.Cycle(1, 2, 0, True, 1)
    assert nmea.parse(with_checksum("$CCTXD,1,2,1,01AB")) == nmea.TxData(1, 2, True, b"\x01\xab")
    assert nmea.parse(with_checksum("$CATXD,1,2,1,32")) == nmea.TxDataEcho(1, 2, True, 32)
    assert nmea.parse(with_checksum("$CAACK,2,1,1,1")) == nmea.Ack(2, 1, 1, 1)
    assert nmea.parse(with_checksum("$CCCFG,SRC,1")) == nmea.Config("SRC", "1")
    assert nmea.parse(with_checksum("$CAMSG,BAD_CRC,0")) == nmea.Message("BAD_CRC", "0")
    assert nmea.parse(with_checksum("$CCTXD,1,2,1,")) == nmea.TxData(1, 2, True, b"")  # no data: stop DRQs
    with pytest.raises(nmea.FieldError, match="nbytes"):
        nmea.parse(with_checksum("$CATXD,1,2,1,"))


def example(cls: type[nmea.Sentence]) -> st.SearchStrategy[nmea.Sentence]:
    hints = nmea._HINTS[cls]
    token = st.text(alphabet="ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789._-", min_size=1, max_size=12)
    kinds = {
        int: st.integers(-(10**6), 10**6),
        float: st.floats(-1e4, 1e4, allow_nan=False).map(lambda x: round(x, 4)),
        bool: st.booleans(),
        bytes: st.binary(max_size=64),
        str: token,
    }
    return st.builds(cls, **{f.name: kinds[hints[f.name]] for f in dataclasses.fields(cls)})


@pytest.mark.parametrize("cls", nmea.SENTENCES, ids=lambda c: c.__name__)
@given(data=st.data())
@settings(max_examples=40)
def test_every_sentence_round_trips(cls: type[nmea.Sentence], data: st.DataObject) -> None:
    sentence = data.draw(example(cls))
    for talker in cls.TALKERS:
        line = sentence.line(talker)
        assert line.endswith("\r\n") and line.startswith("$" + talker + cls.SID)
        assert nmea.parse(line) == sentence


@pytest.mark.parametrize(
    "line, error",
    [
        ("$CAMPA,1,2*5E", nmea.ChecksumError),
        ("$CAMPA,1,2", nmea.FramingError),
        ("CAMPA,1,2*5D", nmea.FramingError),
        ("$CAMPA,1*" + nmea.checksum("CAMPA,1"), nmea.FieldError),
        ("$CAMPA,1,2,3*" + nmea.checksum("CAMPA,1,2,3"), nmea.FieldError),
        ("$CAMPA,x,2*" + nmea.checksum("CAMPA,x,2"), nmea.FieldError),
        ("$CARXD,2,1,0,1,ZZ*" + nmea.checksum("CARXD,2,1,0,1,ZZ"), nmea.FieldError),
        ("$CARXD,2,1,0,1,ABC*" + nmea.checksum("CARXD,2,1,0,1,ABC"), nmea.FieldError),
        ("$CACYC,0,1,2,0,7,1*" + nmea.checksum("CACYC,0,1,2,0,7,1"), nmea.FieldError),
        ("$CAMP", nmea.FramingError),
        ("$ca,1*" + nmea.checksum("ca,1"), nmea.FramingError),
        ("$CAMPA,1,2*5", nmea.FramingError),
        ("$" + "A" * 2000, nmea.FramingError),
    ],
)
def test_malformed_lines_raise_typed_errors(line: str, error: type[Exception]) -> None:
    with pytest.raises(error):
        nmea.parse(line)


def test_binary_noise_raises_framing_error() -> None:
    with pytest.raises(nmea.FramingError):
        nmea.parse(b"\xff\xfe$CAMPA\x00")


def test_unknown_sentence_is_raw_not_an_error() -> None:
    raw = nmea.parse(with_checksum("$CAXYZ,1,2,3"))
    assert raw == nmea.Raw("CA", "XYZ", ("1", "2", "3"))
    assert nmea.parse(raw.line()) == raw


@given(st.binary(max_size=200))
@settings(max_examples=500)
def test_random_bytes_never_escape_as_anything_but_nmea_error(data: bytes) -> None:
    try:
        nmea.parse(data)
    except nmea.NmeaError:
        pass


@given(st.sampled_from(nmea.SENTENCES).flatmap(example), st.integers(0, 200), st.characters(codec="ascii"))
@settings(max_examples=300)
def test_mutated_sentences_are_parsed_or_rejected(sentence, position: int, char: str) -> None:
    line = sentence.line(sentence.TALKERS[0]).rstrip("\r\n")
    position %= len(line)
    mutated = line[:position] + char + line[position + 1 :]
    try:
        nmea.parse(mutated)
    except nmea.NmeaError:
        pass


@pytest.mark.parametrize(
    "body",
    [
        "CARXD," + "9" * 900 + ",1,0,1,00",  # an address no column can hold
        "CARXD,2," + "1" * 30 + ",0,1,00",
        "CAMPR,2,1,nan",
        "CAMPR,2,1,inf",
        "CAMPR,2,1,-Infinity",
        "CAMPR,2,1,1e999",
        "CAMPR,2,1," + "0." + "1" * 40,
    ],
)
def test_overlong_and_non_finite_numbers_are_field_errors(body: str) -> None:
    with pytest.raises(nmea.FieldError):
        nmea.parse(f"${body}*{nmea.checksum(body)}")


def test_nan_snr_in_cst_is_rejected_not_parsed() -> None:
    body = REAL_CST[1:].replace(",-1.2,", ",nan,")
    with pytest.raises(nmea.FieldError, match="finite"):
        nmea.parse(f"${body}*{nmea.checksum(body)}")


@given(
    st.sampled_from(nmea.SENTENCES),
    st.integers(0, 40),
    st.one_of(
        st.text(alphabet="0123456789", min_size=1, max_size=2000),
        st.sampled_from(["nan", "NaN", "inf", "-inf", "Infinity", "1e999", "-1e999", "1e-999", "+0", "-0"]),
        st.text(alphabet="0123456789.eE+-", min_size=1, max_size=60),
    ),
)
@settings(max_examples=400)
def test_fuzzed_numeric_fields_parse_to_bounded_finite_values_or_field_errors(
    cls, index: int, text: str
) -> None:
    """Any field replaced with a numeric-looking string: the line parses with every int short and every
    float finite, or it is rejected with an ``NmeaError`` (never OverflowError, never a nan)."""
    names = [f.name for f in dataclasses.fields(cls)]
    fields = ["1"] * (len(cls.PREFIX) + len(names))
    fields[index % len(fields)] = text
    body = cls.TALKERS[0] + cls.SID + "," + ",".join(fields)
    try:
        parsed = nmea.parse(f"${body}*{nmea.checksum(body)}")
    except nmea.NmeaError:
        return
    for value in dataclasses.astuple(parsed) if dataclasses.is_dataclass(parsed) else ():
        if isinstance(value, float):
            assert math.isfinite(value)
        elif isinstance(value, int):
            assert abs(value) < 2**63  # fits a database integer column
