"""What an export's values mean, said the same way in every format: each column's attributes (CF names:
``units`` in UDUNITS spelling, ``long_name``, ``standard_name`` where CF has one, ``error_bound`` = the
channel's eps) and the file's (the vehicle, the stream and its period, where the data come from). NetCDF
writes them as variable and global attributes, Parquet as field and schema metadata, CSV as the units
in its header row and the error bounds in a response header."""

from __future__ import annotations

from dataclasses import dataclass, fields
from datetime import UTC, datetime
from typing import Any

from server.telemetry.models import SampleTrust
from tacit.codec import StreamSpec
from tacit.streams import UNITS

Attributes = dict[str, str | float | int]

STANDARD_NAME_VOCABULARY = "CF Standard Name Table v93"
TIME_UNITS = "seconds since 1970-01-01T00:00:00Z"  # UNIX seconds, UTC: CF's spelling of the epoch
#: The vehicle's unit spellings (``tacit.streams.UNITS``) that UDUNITS, and so CF, cannot read: MAVLink's
#: "mG" (milli-g; in SI, G is the gauss), and "°C" in ASCII, as NetCDF3 text has no encoding. Checked
#: with cf-units: each parses and converts to its standard name's canonical units.
UDUNITS = {"mG": "9.80665e-3 m s-2", "°C": "degree_Celsius"}
STANDARD_NAMES = {
    "temperature": "sea_water_temperature",
    "depth": "depth",
    "oxygen": "mass_concentration_of_oxygen_in_sea_water",
}
LONG_NAMES = {
    **{
        f"{axis}acc": f"acceleration along the vehicle's {axis} axis (MAVLink RAW_IMU, in milli-g)"
        for axis in "xyz"
    },
    **{f"{axis}gyro": f"angular rate about the vehicle's {axis} axis (MAVLink RAW_IMU)" for axis in "xyz"},
    **{f"{axis}mag": f"magnetic field along the vehicle's {axis} axis (MAVLink RAW_IMU)" for axis in "xyz"},
    "temperature": "sea water temperature",
    "depth": "depth below the sea surface",
    "oxygen": "dissolved oxygen",
}
CERTAIN = (
    "1: the value is within error_bound of what the sensor read; 0: a span the shore lost and "
    "cannot vouch for (no values)"
)
IN_TICK = (
    "0: the first (almost always the only) sample of its tick; 1, 2, ...: a further sample the vehicle "
    "measured within the same tick (a sensor faster than the stream's period, or jitter), in the order "
    "it measured them: a sample of its own, not a copy"
)
TRUST_MEANINGS = {
    SampleTrust.VERIFIED: "a check-point's MAC vouched for the packet it came in and for the packets "
    "it was decoded on",
    SampleTrust.PENDING: "no check-point has covered its packet yet",
    SampleTrust.UNVERIFIABLE: "its packet was vouched for but decoded on a state no check-point vouched "
    "for (or it has no packet on record): its values cannot be vouched for",
    SampleTrust.FORGED: "its packet is not the one a check-point vouched for (left out unless "
    "include_forged=true)",
}
PREDICTABLE = (
    "UNIX s: the vehicle's last verified check-point said every stream was predictable within its "
    "error_bound up to then; a sample not in the file before it is one the vehicle did not send yet"
)
VERIFICATION = "; ".join(f"{trust.value}: {meaning}" for trust, meaning in TRUST_MEANINGS.items())


@dataclass(frozen=True)
class About:
    """What the deployment's settings say of the data (``Settings``: its name, summary, creator, ...; an
    empty one is not said), and the fleet's origin (latitude, longitude), None when not known."""

    deployment: str = "tacit"
    summary: str = ""
    creator_name: str = ""
    creator_email: str = ""
    creator_url: str = ""
    institution: str = ""
    publisher_name: str = ""
    publisher_email: str = ""
    publisher_url: str = ""
    naming_authority: str = ""
    license: str = ""
    acknowledgment: str = ""
    origin: tuple[float, float] | None = None

    @classmethod
    def of(cls, settings: Any) -> About:
        """From the server's ``Settings`` (the fields of the same names; an unnamed deployment is
        "tacit")."""
        said = {f.name: getattr(settings, f.name) for f in fields(cls)}
        return cls(**{**said, "deployment": said["deployment"] or cls.deployment})


@dataclass(frozen=True)
class Dataset:
    """What an export holds: one vehicle's stream, and what the deployment says of it."""

    vehicle_id: int
    vehicle: str
    spec: StreamSpec
    about: About = About()
    # the silence the vehicle's last verified check-point of the export's window said (version 4): every
    # stream predictable within its error_bound up to then, UNIX s; None when none said it
    predictable_until: float | None = None


def units(channel: str) -> str:
    """A channel's unit as UDUNITS spells it."""
    unit = UNITS[channel]
    return UDUNITS.get(unit, unit)


def columns(spec: StreamSpec) -> dict[str, Attributes]:
    """Each column's attributes, in the exports' column order."""
    return {
        "time": {
            "standard_name": "time",
            "long_name": "time of the sample (UTC)",
            "units": TIME_UNITS,
            "axis": "T",
            "calendar": "standard",
            "coverage_content_type": "coordinate",
        },  # fmt: skip
        "tick": {
            "long_name": "the codec's tick number (time dates a sample within the stream's time_precision)",
            "units": "1",
            "coverage_content_type": "auxiliaryInformation",
        },
        "in_tick": {
            "long_name": "the sample's place among the samples dated at its time",
            "units": "1",
            "coverage_content_type": "auxiliaryInformation",
            "comment": IN_TICK,
        },
        "certain": {
            "long_name": "whether the value is within error_bound",
            "coverage_content_type": "qualityInformation",
            "comment": CERTAIN,
        },
        "verification": {
            "long_name": "how far the sample may be believed",
            "coverage_content_type": "qualityInformation",
            "comment": VERIFICATION,
        },
        **{channel: _channel(channel, eps) for channel, eps in zip(spec.channels, spec.eps, strict=True)},
    }


def _channel(channel: str, eps: float) -> Attributes:
    standard = {"standard_name": STANDARD_NAMES[channel]} if channel in STANDARD_NAMES else {}
    return {
        **standard,
        "long_name": LONG_NAMES[channel],
        "units": units(channel),
        **({"positive": "down"} if channel == "depth" else {}),
        "coverage_content_type": "physicalMeasurement",
        "error_bound": eps,
        "comment": "within error_bound (same units) of what the sensor read where certain",
    }


#: The vehicle's position at each sample (the NetCDF export, when the fleet's origin is known), and its
#: depth where the stream has no depth channel: interpolated between its verified check-points.
TRACK_COMMENT = "interpolated in time between the vehicle's verified check-points (dead reckoning); NaN before the first and after the last"
TRACK: dict[str, Attributes] = {
    "lat": {"standard_name": "latitude", "long_name": "the vehicle's latitude", "units": "degrees_north", "axis": "Y"},
    "lon": {"standard_name": "longitude", "long_name": "the vehicle's longitude", "units": "degrees_east", "axis": "X"},
    "depth": {"standard_name": "depth", "long_name": "the vehicle's depth", "units": "m", "positive": "down", "axis": "Z"},
}  # fmt: skip


def attributes(d: Dataset) -> Attributes:
    """The file's attributes (ACDD/CF names where they have one), what the deployment's settings say
    included; the coverage, which only the rows give, is ``export.Coverage``'s."""
    a = d.about
    said = {  # the deployment's own words, those it said
        f.name: getattr(a, f.name)
        for f in fields(About)
        if f.name not in ("deployment", "summary", "origin") and getattr(a, f.name)
    }
    now = datetime.now(UTC).isoformat(timespec="seconds")
    return {
        "title": f"{d.spec.name} telemetry of vehicle {d.vehicle} ({a.deployment})",
        "summary": a.summary or _summary(d),
        "keywords": ", ".join(["underwater vehicle", "acoustic telemetry", *_keywords(d.spec)]),
        "source": "Tacit shore control center: samples reconstructed from acoustic-modem packets, each "
        "within its channel's error_bound of what the vehicle's sensor read",
        "comment": CERTAIN + "; verification: " + VERIFICATION,
        "processing_level": "reconstructed from compressed packets: within error_bound of the sensor where "
        "certain; positions interpolated between the vehicle's verified check-points",
        "project": a.deployment,
        "platform": "underwater vehicle",
        "vehicle_name": d.vehicle,
        "vehicle_id": d.vehicle_id,
        "stream": d.spec.name,
        "stream_period": d.spec.period,
        "stream_period_units": "s",
        "time_precision": d.spec.time_precision,  # half a period, or the stream's time tolerance
        "time_precision_units": "s",
        **(
            {}
            if d.predictable_until is None
            else {"predictable_until": d.predictable_until, "predictable_until_comment": PREDICTABLE}
        ),
        "standard_name_vocabulary": STANDARD_NAME_VOCABULARY,
        "date_created": now,
        "history": f"{now} exported by Tacit",
        **said,
    }


def _summary(d: Dataset) -> str:
    channels = ", ".join(f"{c} ({units(c)})" for c in d.spec.channels)
    return (
        f"The {d.spec.name} stream of underwater vehicle {d.vehicle} in deployment {d.about.deployment}: "
        f"{channels}, one sample every {d.spec.period:g} s, as the shore reconstructed it from the compressed "
        "packets the vehicle sent over its acoustic modem, each value within its channel's error_bound of "
        "what the sensor read where certain, with how far each sample may be believed (verification)."
    )


def _keywords(spec: StreamSpec) -> list[str]:
    return [STANDARD_NAMES[c] for c in spec.channels if c in STANDARD_NAMES]


def error_bounds(spec: StreamSpec) -> str:
    """Each channel's eps for an HTTP header: ``temperature=0.05, depth=0.05, oxygen=0.05``."""
    return ", ".join(f"{channel}={eps:g}" for channel, eps in zip(spec.channels, spec.eps, strict=True))


def csv_header(spec: StreamSpec) -> list[str]:
    """The CSV header row: each column's name with its units in parentheses, ``depth (m)`` (ERDDAP's
    ``.csvp``): one plain row that every CSV reader takes as it is, and the units stay with the file."""
    return [
        f"{name} ({a['units']})" if a.get("units", "1") != "1" else name for name, a in columns(spec).items()
    ]
