"""A WHOI Micro-Modem emulator: the Micro-Modem's host NMEA dialect over the simulated channel.

Host side: ``$CCCFG``/``$CCCFQ`` (answered with ``$CACFG``), ``$CCCLK``, ``$CCCYC`` with the ``$CADRQ`` /
``$CCTXD`` exchange, ``$CCMPC`` pings, ``$CCMUC`` mini-packets, ``$CCMSC`` sleep/reboot; anything else
gets ``$CAERR``. Acoustic side: a data cycle is an FSK cycle-init followed by the data packet; the far
modem prints ``$CARXP``, ``$CACYC``, ``$CARXD`` per good frame (``$CAMSG,BAD_CRC`` per bad one) and
``$CACST``, and acknowledges good frames when asked (``$CAACK`` at the sender). A third-party poll
(``$CCCYC`` naming another modem as source) makes that modem ask its own host for data.
"""

from __future__ import annotations

import datetime as dt
import logging
from collections.abc import Callable
from dataclasses import dataclass, field

from simulators.channel import NO_LOSS, Channel, Kind, Reception, Transmission
from simulators.clock import Cancellable, Scheduler
from tacit import nmea, rates
from tacit.rates import RATES

log = logging.getLogger("simulators.modem")

REVISION = "0.94.0.52"
DEFAULT_CONFIG = {
    "SRC": "0", "CST": "1", "XST": "1", "REV": "1", "RXP": "1", "TXP": "1", "TXF": "1",
    "DTO": "5", "PTO": "10", "BND": "3", "FC0": "25000", "BW0": "5000", "AGC": "1",
}  # fmt: skip


@dataclass
class _Outgoing:
    """A data cycle this modem is collecting frames for (from its host) and will transmit."""

    src: int
    dest: int
    rate: int
    ack: bool
    nframes: int
    send_init: bool
    frames: list[bytes] = field(default_factory=list)
    timer: Cancellable | None = None


@dataclass
class _Ping:
    dest: int
    start: float
    airtime: float


class MicroModemEmulator:
    def __init__(
        self,
        name: str,
        address: int,
        channel: Channel,
        scheduler: Scheduler,
        position: Callable[[], tuple[float, float, float]],
        hears_all: bool = False,
        loss: Callable[[], float] = lambda: NO_LOSS,
    ) -> None:
        """``hears_all``: report every data frame heard, whoever it is for (a recorder on the channel; it
        acknowledges only its own). ``loss``: the probability that a frame to or from this modem is lost, on
        top of the channel's (read at each arrival)."""
        self.name = name
        self.hears_all = hears_all
        self.channel = channel
        self.scheduler = scheduler
        self.config = dict(DEFAULT_CONFIG, SRC=str(address))
        self.output: Callable[[str], None] = lambda line: None
        self.clock_offset = 0.0
        self._epoch = dt.datetime.now(dt.UTC).timestamp()
        self._cycle: _Outgoing | None = None
        self._expecting: Cancellable | None = None
        self._announced = False  # a cycle-init for us was heard and printed
        self._ack_until = 0.0  # an acknowledgement is due or on the air until then
        self._ping: _Ping | None = None
        self.counters = {"host_lines": 0, "errors": 0, "tx": 0, "rx_frames": 0, "bad_frames": 0}
        channel.add_node(name, position, self._receive, loss, address)

    @property
    def address(self) -> int:
        return int(self.config["SRC"])

    # --- host side ------------------------------------------------------------------------------

    def boot(self) -> None:
        """Announce power-up as the real modem does: REV INIT, then the firmware revision."""
        self._cycle, self._ping = None, None
        self._emit(nmea.Revision(self._hhmmss(), "INIT", REVISION))
        self._emit(nmea.Revision(self._hhmmss(), "AUV", REVISION))

    def handle_line(self, raw: bytes) -> None:
        self.counters["host_lines"] += 1
        try:
            sentence = nmea.parse(raw, require_checksum=False)
        except nmea.NmeaError as exc:
            return self._error("NMEA", 1, str(exc))
        talker = nmea.split(raw, require_checksum=False)[0]
        if isinstance(sentence, nmea.Raw) or nmea.HOST not in sentence.TALKERS or talker != nmea.HOST:
            return self._error("NMEA", 2, f"unknown command {raw[:6].decode('ascii', 'replace')}")
        match sentence:
            case nmea.Config():
                self._on_config(sentence)
            case nmea.ConfigQuery():
                self._on_config_query(sentence)
            case nmea.Clock():
                self._on_clock(sentence)
            case nmea.Cycle():
                self._on_cycle(sentence)
            case nmea.TxData():
                self._on_txd(sentence)
            case nmea.Ping():
                self._on_ping(sentence)
            case nmea.MiniPacket():
                self._on_mini(sentence)
            case nmea.Sleep():
                self._on_sleep(sentence)
            case _:
                self._error("NMEA", 2, f"unsupported command CC{sentence.SID}")

    def _on_config(self, cfg: nmea.Config) -> None:
        name = cfg.name.upper()
        if name == "ALL" and cfg.value == "0":
            self.config = dict(DEFAULT_CONFIG, SRC=self.config["SRC"])
        elif name not in self.config:
            return self._error("CFG", 3, f"unknown parameter {cfg.name}")
        else:
            self.config[name] = cfg.value
        self._emit(nmea.Config(cfg.name, cfg.value))

    def _on_config_query(self, cfq: nmea.ConfigQuery) -> None:
        name = cfq.name.upper()
        if name == "ALL":
            for key, value in self.config.items():
                self._emit(nmea.Config(key, value))
        elif name in self.config:
            self._emit(nmea.Config(name, self.config[name]))
        else:
            self._error("CFQ", 3, f"unknown parameter {cfq.name}")

    def _on_clock(self, clk: nmea.Clock) -> None:
        try:
            wanted = dt.datetime(
                clk.year, clk.month, clk.day, clk.hour, clk.minute, clk.second, tzinfo=dt.UTC
            ).timestamp()
        except ValueError as exc:
            return self._error("CLK", 3, str(exc))
        self.clock_offset = wanted - self._wall()
        self._emit(clk)

    def _on_cycle(self, cyc: nmea.Cycle) -> None:
        if cyc.rate not in RATES or not 0 <= cyc.dest <= 127 or not 0 <= cyc.src <= 127:
            return self._error("CYC", 3, "bad rate or address")
        if self._cycle is not None or self.channel.busy(self.name) or self.scheduler.now() < self._ack_until:
            return self._error("CYC", 4, "BUSY")
        self._emit(cyc)
        if cyc.src != self.address:  # third-party poll: ask cyc.src to send to cyc.dest
            self._transmit_cycle_init(cyc.src, cyc.dest, cyc.rate, cyc.ack, cyc.nframes)
            return
        cycle = _Outgoing(cyc.src, cyc.dest, cyc.rate, cyc.ack, max(1, cyc.nframes), send_init=cyc.rate != 0)
        self._cycle = cycle
        if cyc.rate == 0:  # FSK: the cycle-init goes out first, then the modem asks for data
            self._transmit_cycle_init(
                cyc.src, cyc.dest, cyc.rate, cyc.ack, cycle.nframes, then=lambda: self._request_frame(cycle)
            )
        else:  # PSK: the cycle-init leads the data packet
            self._request_frame(cycle)

    def _on_txd(self, txd: nmea.TxData) -> None:
        cycle = self._cycle
        if cycle is None or cycle.timer is None:
            return self._error("TXD", 5, "no data request outstanding")
        cycle.timer.cancel()
        cycle.timer = None
        limit = RATES[cycle.rate].frame_bytes
        self._emit(nmea.TxDataEcho(txd.src, txd.dest, txd.ack, min(len(txd.data), limit)))
        if txd.data:
            cycle.frames.append(txd.data[:limit])
            cycle.ack = cycle.ack or txd.ack  # the ACK request travels per frame, in $CCTXD
        if txd.data and len(cycle.frames) < cycle.nframes:
            self._request_frame(cycle)
        elif cycle.frames:
            self._transmit_cycle(cycle)
        else:
            self._cycle = None

    def _on_ping(self, mpc: nmea.Ping) -> None:
        if self.channel.busy(self.name):
            return self._error("MPC", 4, "BUSY")
        self._emit(mpc)
        airtime = rates.airtime_s(rates.PING_BITS, 0)
        self._ping = _Ping(mpc.dest, self.scheduler.now(), airtime)
        self._send(Transmission(Kind.PING, self.address, mpc.dest, 0, airtime))

    def _on_mini(self, muc: nmea.MiniPacket) -> None:
        self._emit(muc)
        airtime = rates.airtime_s(rates.PING_BITS, 0)
        self._send(Transmission(Kind.MINI, self.address, muc.dest, 0, airtime, info={"data": muc.data}))

    def _on_sleep(self, msc: nmea.Sleep) -> None:
        self._emit(msc)
        if msc.minutes == 0:
            self.scheduler.call_later(0.5, self.boot)

    # --- the data cycle -------------------------------------------------------------------------

    def _request_frame(self, cycle: _Outgoing) -> None:
        frame = len(cycle.frames) + 1
        maxbytes = RATES[cycle.rate].frame_bytes
        self._emit(nmea.DataRequest(self._hhmmss(), cycle.src, cycle.dest, cycle.ack, maxbytes, frame))
        cycle.timer = self.scheduler.call_later(float(self.config["DTO"]), lambda: self._data_timeout(cycle))

    def _data_timeout(self, cycle: _Outgoing) -> None:
        if self._cycle is cycle:
            self._cycle = None
            self._error("DRQ", 6, "DATA_TIMEOUT")

    def _transmit_cycle(self, cycle: _Outgoing) -> None:
        if cycle.send_init:
            self._transmit_cycle_init(
                cycle.src,
                cycle.dest,
                cycle.rate,
                cycle.ack,
                len(cycle.frames),
                then=lambda: self._transmit_data(cycle),
            )
        else:
            self._transmit_data(cycle)

    def _transmit_cycle_init(
        self, src: int, dest: int, rate: int, ack: bool, nframes: int, then: Callable[[], None] | None = None
    ) -> None:
        info = {"src": src, "dest": dest, "rate": rate, "ack": ack, "nframes": nframes}
        airtime = rates.airtime_s(rates.CYCLE_INIT_BITS, 0)
        if src != self.address:  # we polled: the answer comes to us
            self._expect_data()
        self._send(
            Transmission(Kind.CYCLE_INIT, self.address, dest, 0, airtime, info=info),
            report_bytes=0,
            then=then,
        )

    def _transmit_data(self, cycle: _Outgoing) -> None:
        nbytes = sum(len(f) for f in cycle.frames)
        airtime = rates.data_airtime_s(cycle.rate, len(cycle.frames))
        tx = Transmission(
            Kind.DATA, cycle.src, cycle.dest, cycle.rate, airtime, list(cycle.frames), cycle.ack
        )
        self._send(tx, nbytes, then=lambda: self._data_sent(cycle, nbytes))

    def _data_sent(self, cycle: _Outgoing, nbytes: int) -> None:
        if self._cycle is cycle:
            self._cycle = None
        date = self._now_utc()
        self._emit_if(
            "XST",
            nmea.TxStats(
                date.strftime("%Y%m%d"),
                date.strftime("%H%M%S.%f")[:11],
                0,
                0,
                0,
                5000,
                25000,
                cycle.rate,
                cycle.src,
                cycle.dest,
                cycle.ack,
                len(cycle.frames),
                len(cycle.frames),
                0 if cycle.rate == 0 else 1,
                nbytes,
            ),
        )

    def _send(
        self, tx: Transmission, report_bytes: int | None = None, then: Callable[[], None] | None = None
    ) -> None:
        """Put a transmission on the channel: TXP now; at its end TXF (when ``report_bytes`` is given),
        then ``then``, in that order (one callback, so equal-time events cannot swap)."""
        self.counters["tx"] += 1
        if report_bytes is not None:
            self._emit_if("TXP", nmea.TxStarted(report_bytes))
        end = self.channel.transmit(self.name, tx)

        def finished() -> None:
            if report_bytes is not None:
                self._emit_if("TXF", nmea.TxFinished(report_bytes))
            if then is not None:
                then()

        self.scheduler.call_later(end - self.scheduler.now(), finished)

    # --- acoustic side --------------------------------------------------------------------------

    def _receive(self, rec: Reception) -> None:
        tx = rec.transmission
        handler = self._ACOUSTIC_HANDLERS[tx.kind]
        handler(self, rec)

    def _for_me(self, dest: int) -> bool:
        return dest in (self.address, 0)

    def _heard_cycle_init(self, rec: Reception) -> None:
        info = rec.transmission.info
        if not rec.heard:
            return
        src, dest = int(info["src"]), int(info["dest"])
        rate, ack, nframes = int(info["rate"]), bool(info["ack"]), int(info["nframes"])
        cycle = nmea.Cycle(src, dest, rate, ack, nframes)
        if src == self.address and self._cycle is None:  # we are polled
            self._emit(cycle)
            self._cycle = _Outgoing(src, dest, rate, ack, max(1, nframes), send_init=False)
            self._request_frame(self._cycle)
        elif self._for_me(dest):
            self._emit_if("RXP", nmea.RxStarted(0))
            self._emit(cycle)
            self._expect_data()
            self._announced = True

    def _expect_data(self) -> None:
        if self._expecting is not None:
            self._expecting.cancel()
        self._expecting = self.scheduler.call_later(float(self.config["PTO"]), self._packet_timeout)

    def _packet_timeout(self) -> None:
        self._expecting = None
        self._announced = False
        self._emit(nmea.Message("PACKET_TIMEOUT", "0"))
        self._emit_if("CST", self._cst(2, 0, 0, 0, 0, 0, -10.0))

    def _heard_data(self, rec: Reception) -> None:
        tx = rec.transmission
        if not (self._for_me(tx.dest) or self.hears_all) or not (rec.heard or self._expecting is not None):
            return
        if self._expecting is not None:
            self._expecting.cancel()
            self._expecting = None
        self._emit_if("RXP", nmea.RxStarted(sum(len(f) for f in tx.frames)))
        if not self._announced:  # no cycle-init heard (we polled, or it was lost): the header tells
            self._emit(nmea.Cycle(tx.src, tx.dest, tx.rate, tx.ack, len(tx.frames)))
        self._announced = False
        good: list[int] = []
        for number, (frame, ok) in enumerate(zip(tx.frames, rec.frames_ok, strict=False), start=1):
            if ok:
                good.append(number)
                self.counters["rx_frames"] += 1
                self._emit(nmea.RxData(tx.src, tx.dest, tx.ack, number, frame))
            else:
                self.counters["bad_frames"] += 1
                self._emit(nmea.Message("BAD_CRC", str(number)))
        nbad = len(tx.frames) - len(good)
        self._emit_if(
            "CST", self._cst(0 if not nbad else 1, tx.rate, tx.src, tx.dest, len(tx.frames), nbad, rec.snr_db)
        )
        if tx.ack and good and tx.dest == self.address:
            airtime = rates.airtime_s(rates.ACK_BITS, 0)
            ack = Transmission(Kind.ACK, self.address, tx.src, 0, airtime, info={"frames": good})
            self._ack_until = self.scheduler.now() + rates.TURNAROUND_S + airtime
            self.scheduler.call_later(rates.TURNAROUND_S, lambda: self._send(ack))

    def _heard_ack(self, rec: Reception) -> None:
        tx = rec.transmission
        if rec.heard and tx.dest == self.address:
            for number in tx.info["frames"]:
                self._emit(nmea.Ack(tx.src, self.address, int(number), 1))

    def _heard_ping(self, rec: Reception) -> None:
        tx = rec.transmission
        if not rec.heard or tx.dest != self.address:
            return
        self._emit(nmea.PingHeard(tx.src, tx.dest))
        airtime = rates.airtime_s(rates.PING_BITS, 0)
        reply = Transmission(Kind.PING_REPLY, self.address, tx.src, 0, airtime)
        self.scheduler.call_later(rates.TURNAROUND_S, lambda: self._send(reply))

    def _heard_ping_reply(self, rec: Reception) -> None:
        tx, ping = rec.transmission, self._ping
        if not rec.heard or tx.dest != self.address or ping is None or ping.dest != tx.src:
            return
        self._ping = None
        round_trip = self.scheduler.now() - ping.start - ping.airtime - rates.TURNAROUND_S - tx.airtime
        self._emit(nmea.PingReply(tx.src, self.address, round(round_trip / 2, 4)))

    def _heard_mini(self, rec: Reception) -> None:
        tx = rec.transmission
        if rec.heard and self._for_me(tx.dest):
            self._emit(nmea.MiniPacketHeard(tx.src, tx.dest, str(tx.info["data"])))

    _ACOUSTIC_HANDLERS: dict[Kind, Callable[[MicroModemEmulator, Reception], None]] = {
        Kind.CYCLE_INIT: _heard_cycle_init, Kind.DATA: _heard_data, Kind.ACK: _heard_ack,
        Kind.PING: _heard_ping, Kind.PING_REPLY: _heard_ping_reply, Kind.MINI: _heard_mini,
    }  # fmt: skip

    # --- output helpers -------------------------------------------------------------------------

    def _cst(
        self, mode: int, rate: int, src: int, dest: int, nframes: int, nbad: int, snr: float
    ) -> nmea.RxStats:
        toa = self._now_utc().strftime("%H%M%S.%f")[:11]
        snr = round(snr, 1)
        return nmea.RxStats(
            mode,
            toa,
            0,
            1440,
            25,
            175,
            166,
            75,
            1,
            1,
            1,
            3,
            rate,
            src,
            dest,
            0,
            0 if rate == 0 else 3,
            nframes,
            nbad,
            int(snr + 120),
            snr,
            round(snr + 3, 1),
            snr,
            -1.0,
            0,
            0.0,
            45,
            25000,
            5000,
        )

    def _error(self, module: str, number: int, message: str) -> None:
        self.counters["errors"] += 1
        self._emit(nmea.Error(self._hhmmss(), module, number, message.replace(",", ";").replace("*", "")))

    def _emit_if(self, flag: str, sentence: nmea.Sentence) -> None:
        if self.config.get(flag, "1") != "0":
            self._emit(sentence)

    def _emit(self, sentence: nmea.Sentence) -> None:
        self.output(sentence.line(nmea.talker_of(sentence, host=False)))

    def _wall(self) -> float:
        return self._epoch + self.scheduler.now()

    def _now_utc(self) -> dt.datetime:
        return dt.datetime.fromtimestamp(self._wall() + self.clock_offset, dt.UTC)

    def _hhmmss(self) -> str:
        return self._now_utc().strftime("%H%M%S")
