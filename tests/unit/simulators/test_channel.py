"""The simulated acoustic channel and Micro-Modem emulators, in virtual (exact) time."""

from __future__ import annotations

import pytest

from simulators import acoustics
from simulators.acoustics import ChannelParameters
from simulators.channel import Channel, Kind, Reception, Transmission
from simulators.clock import VirtualScheduler
from simulators.micromodem import MicroModemEmulator
from tacit import nmea, rates


def channel_with(positions: dict[str, tuple[float, float, float]], **params: object):
    sched = VirtualScheduler()
    channel = Channel(sched, ChannelParameters(**params))  # type: ignore[arg-type]
    heard: dict[str, list[tuple[float, Reception]]] = {name: [] for name in positions}
    for name, pos in positions.items():
        channel.add_node(name, lambda p=pos: p, lambda rec, n=name: heard[n].append((sched.now(), rec)))
    return sched, channel, heard


def data(src: int = 1, dest: int = 2, frames: int = 1) -> Transmission:
    return Transmission(Kind.DATA, src, dest, 0, rates.data_airtime_s(0, frames), [b"x" * 32] * frames)


@pytest.mark.parametrize("distance", [100.0, 1000.0, 3000.0])
def test_delay_is_range_over_sound_speed_plus_airtime(distance: float) -> None:
    sched, channel, heard = channel_with({"a": (0, 0, 0), "b": (distance, 0, 0)}, fading_sigma_db=0)
    tx = data()
    channel.transmit("a", tx)
    sched.run()
    ((when, rec),) = heard["b"]
    assert when == pytest.approx(distance / 1500.0 + tx.airtime, abs=1e-3)
    assert rec.range_m == pytest.approx(distance)


def loss_fraction(distance: float, trials: int = 300, seed: int = 7) -> float:
    sched, channel, heard = channel_with({"a": (0, 0, 0), "b": (distance, 0, 0)}, seed=seed)
    for i in range(trials):
        sched.call_later(i * 10.0, lambda: channel.transmit("a", data()))
    sched.run()
    return sum(not rec.frames_ok[0] for _, rec in heard["b"]) / trials


def test_frame_error_rate_rises_with_range() -> None:
    near, mid, far = loss_fraction(500), loss_fraction(3000), loss_fraction(4500)
    assert near < 0.02 and near < mid < far and far > 0.5


def test_collision_loses_both_frames() -> None:
    sched, channel, heard = channel_with({"a": (0, 0, 0), "b": (100, 0, 0), "c": (0, 100, 0)})
    channel.transmit("a", data(1, 3))
    sched.call_later(0.5, lambda: channel.transmit("b", data(2, 3)))
    sched.run()
    at_c = [rec for _, rec in heard["c"]]
    assert len(at_c) == 2 and all(rec.collided and not any(rec.frames_ok) for rec in at_c)
    assert channel.stats["collisions"] == 2


def test_half_duplex_a_transmitting_modem_is_deaf() -> None:
    sched, channel, heard = channel_with({"a": (0, 0, 0), "b": (100, 0, 0)})
    channel.transmit("a", data(1, 2))
    channel.transmit("b", data(2, 1))
    sched.run()
    assert not any(rec.frames_ok[0] for _, rec in heard["a"] + heard["b"])
    assert channel.stats["half_duplex"] == 2


def test_extra_loss_drops_the_configured_fraction() -> None:
    sched, channel, heard = channel_with({"a": (0, 0, 0), "b": (100, 0, 0)}, extra_loss=0.3, seed=3)
    for i in range(1000):
        sched.call_later(i * 10.0, lambda: channel.transmit("a", data()))
    sched.run()
    lost = sum(not rec.frames_ok[0] for _, rec in heard["b"]) / 1000
    assert 0.25 < lost < 0.35


def test_a_node_taken_out_of_range_and_back() -> None:
    """A node's own loss (read at each arrival) drops every frame to and from it while it is 1 (it is out
    of range of every node), and no frame between the others; back at 0 it is heard again."""
    sched = VirtualScheduler()
    channel = Channel(sched, ChannelParameters(fading_sigma_db=0))
    heard: dict[str, list[bool]] = {"shore": [], "far": [], "near": []}
    cut = [0.0]
    for name, east in (("shore", 0.0), ("far", 100.0), ("near", 200.0)):
        channel.add_node(
            name,
            lambda e=east: (0.0, e, 1.0),
            lambda rec, n=name: heard[n].append(rec.frames_ok[0]),
            loss=(lambda: cut[0]) if name == "far" else lambda: 0.0,
        )

    def exchange() -> None:
        channel.transmit("shore", data(1, 2))
        sched.run()
        channel.transmit("far", data(2, 1))
        sched.run()

    exchange()
    cut[0] = 1.0
    exchange()
    cut[0] = 0.0
    exchange()
    assert heard["far"] == [True, False, True]  # from the shore
    assert heard["shore"] == [True, False, True]  # from "far"
    assert heard["near"] == [True, True, True, False, True, True]  # the shore always, "far" when in range


def run_log(seed: int) -> list[dict[str, object]]:
    sched, channel, _ = channel_with({"a": (0, 0, 0), "b": (3200, 0, 0)}, seed=seed)
    for i in range(50):
        sched.call_later(i * 10.0, lambda: channel.transmit("a", data()))
    sched.run()
    return channel.log


def test_same_seed_same_outcome() -> None:
    assert run_log(5) == run_log(5)
    assert run_log(5) != run_log(6)


class Pair:
    """Two emulated modems in virtual time, with their host-side output captured."""

    def __init__(self, distance: float, **params: object) -> None:
        self.sched = VirtualScheduler()
        self.channel = Channel(self.sched, ChannelParameters(fading_sigma_db=0, **params))  # type: ignore[arg-type]
        self.out: dict[int, list[tuple[float, nmea.Sentence]]] = {1: [], 2: []}
        self.modems = {
            1: MicroModemEmulator("shore", 1, self.channel, self.sched, lambda: (0.0, 0.0, 1.0)),
            2: MicroModemEmulator("vehicle", 2, self.channel, self.sched, lambda: (distance, 0.0, 1.0)),
        }
        for address, modem in self.modems.items():
            modem.output = lambda line, a=address: self.out[a].append((self.sched.now(), nmea.parse(line)))

    def host(self, address: int, sentence: nmea.Sentence) -> None:
        self.modems[address].handle_line(sentence.line(nmea.HOST).encode())

    def send_frame(self, src: int, dest: int, ack: bool, data: bytes) -> None:
        """What a host does: start the cycle, wait for the data request, answer it."""
        self.host(src, nmea.Cycle(src, dest, 0, ack, 1))
        while not self.of(src, nmea.DataRequest):
            self.sched.run(until=self.sched.now() + 1e-4)
        self.host(src, nmea.TxData(src, dest, ack, data))

    def of(self, address: int, kind: type) -> list[tuple[float, nmea.Sentence]]:
        return [(t, s) for t, s in self.out[address] if isinstance(s, kind)]


@pytest.mark.parametrize("distance", [100.0, 1000.0, 3000.0])
def test_data_cycle_with_ack_end_to_end(distance: float) -> None:
    pair = Pair(distance, noise_level_db=80.0)  # a quiet channel: timing, not loss, is under test
    pair.send_frame(1, 2, True, bytes(range(32)))
    ((drq_time, drq),) = pair.of(1, nmea.DataRequest)
    assert (drq.src, drq.dest, drq.maxbytes, drq.frame) == (1, 2, 32, 1)
    ((init_done, _),) = [(t, s) for t, s in pair.out[1] if isinstance(s, nmea.TxFinished) and s.nbytes == 0]
    assert drq_time == init_done == pytest.approx(rates.airtime_s(rates.CYCLE_INIT_BITS, 0))
    pair.sched.run()
    ((_, rxd),) = pair.of(2, nmea.RxData)
    assert rxd.data == bytes(range(32)) and (rxd.src, rxd.dest) == (1, 2)
    assert [type(s).__name__ for _, s in pair.out[2]][:2] == ["RxStarted", "Cycle"]
    ((when, ack),) = pair.of(1, nmea.Ack)
    assert (ack.src, ack.dest, ack.frame) == (2, 1, 1)
    assert when == pytest.approx(acoustics.cycle_with_ack_s(distance), abs=1e-3)
    ((_, cst),) = pair.of(2, nmea.RxStats)
    assert cst.mode == 0 and cst.snr_in > 0


def test_ping_travel_time_matches_range() -> None:
    pair = Pair(1234.0)
    pair.host(1, nmea.Ping(1, 2))
    pair.sched.run()
    ((_, reply),) = pair.of(1, nmea.PingReply)
    assert reply.travel_time == pytest.approx(1234.0 / 1500.0, rel=0.01)
    assert pair.of(2, nmea.PingHeard)


def test_third_party_poll_makes_the_vehicle_ask_its_host() -> None:
    pair = Pair(500.0)
    pair.host(1, nmea.Cycle(2, 1, 0, False, 1))
    pair.sched.run(until=5.0)
    ((_, drq),) = pair.of(2, nmea.DataRequest)
    assert (drq.src, drq.dest) == (2, 1)
    pair.host(2, nmea.TxData(2, 1, False, b"\x07" * 32))
    pair.sched.run()
    ((_, rxd),) = pair.of(1, nmea.RxData)
    assert rxd.data == b"\x07" * 32
    cycles = [s for _, s in pair.out[1] if isinstance(s, nmea.Cycle)]
    assert cycles[-1] == nmea.Cycle(2, 1, 0, False, 1)  # printed as the polled data arrives


def test_lost_data_is_reported_as_bad_crc_and_no_ack() -> None:
    pair = Pair(100.0, extra_loss_by_kind={"data": 1.0})
    pair.send_frame(1, 2, True, b"z" * 32)
    pair.sched.run()
    assert not pair.of(2, nmea.RxData) and not pair.of(1, nmea.Ack)
    assert any(m.type == "BAD_CRC" for _, m in pair.of(2, nmea.Message))
    assert pair.of(2, nmea.RxStats)[0][1].mode == 1


def test_poll_unanswered_by_the_vehicle_host_times_out_at_the_shore() -> None:
    pair = Pair(100.0)
    pair.host(1, nmea.Cycle(2, 1, 0, False, 1))  # the vehicle's host never answers its DRQ
    pair.sched.run()
    assert any(e.message == "DATA_TIMEOUT" for _, e in pair.of(2, nmea.Error))
    assert any(m.type == "PACKET_TIMEOUT" for _, m in pair.of(1, nmea.Message))
    assert pair.of(1, nmea.RxStats)[-1][1].mode == 2


def test_bad_host_input_gets_caerr_and_changes_nothing() -> None:
    pair = Pair(100.0)
    modem = pair.modems[1]
    for line in (b"$CCXYZ,1*00", b"garbage", b"$CCCYC,0,1,2,9,0,1", b"$CCTXD,1,2,0,AB", b"$CACFG,SRC,5"):
        modem.handle_line(line)
    errors = pair.of(1, nmea.Error)
    assert len(errors) == 5 and modem.address == 1 and modem._cycle is None


def test_config_query_all_and_reboot() -> None:
    pair = Pair(100.0)
    pair.host(1, nmea.Config("CST", "0"))
    pair.host(1, nmea.ConfigQuery("ALL"))
    configs = {s.name: s.value for _, s in pair.of(1, nmea.Config)}
    assert configs["SRC"] == "1" and configs["CST"] == "0"
    pair.host(1, nmea.Sleep(1, 1, 0))
    pair.sched.run()
    assert [s.ident for _, s in pair.of(1, nmea.Revision)] == ["INIT", "AUV"]


def test_a_recorder_reports_every_data_frame_and_acknowledges_none() -> None:
    pair = Pair(100.0, noise_level_db=80.0)
    recorder = MicroModemEmulator(
        "recorder", 7, pair.channel, pair.sched, lambda: (50.0, 10.0, 1.0), hears_all=True
    )
    heard: list[nmea.Sentence] = []
    recorder.output = lambda line: heard.append(nmea.parse(line))
    pair.send_frame(1, 2, True, bytes(range(32)))
    pair.sched.run()
    (rxd,) = [s for s in heard if isinstance(s, nmea.RxData)]
    assert rxd.data == bytes(range(32)) and (rxd.src, rxd.dest) == (1, 2)
    assert [ack.src for _, ack in pair.of(1, nmea.Ack)] == [2]  # the vehicle's ACK alone: no collision


def test_frames_are_counted_at_the_modem_each_transmission_is_for_and_add_up() -> None:
    """A shore (1) polls a vehicle (2) beside another (3): each transmission's frames are counted once at
    its addressee (arrived + lost in collisions + lost while transmitting + lost to noise) and once more
    at every other modem (overheard)."""
    sched = VirtualScheduler()
    channel = Channel(sched, ChannelParameters(seed=3))
    for name, address, place in (("shore", 1, (0, 0, 0)), ("rov2", 2, (300, 0, 0)), ("rov3", 3, (0, 300, 0))):
        channel.add_node(name, lambda p=place: p, lambda rec: None, address=address)
    poll = Transmission(Kind.CYCLE_INIT, 1, 1, 0, 1.0, info={"src": 2, "dest": 1, "rate": 0, "ack": False})
    assert poll.addressee == 2 and data(2, 1).addressee == 1
    channel.transmit("shore", poll)
    sched.call_later(30.0, lambda: channel.transmit("rov2", data(2, 1, frames=3)))
    sched.call_later(60.0, lambda: channel.transmit("rov3", data(3, 1)))  # these two collide at the shore
    sched.call_later(60.2, lambda: channel.transmit("rov2", data(2, 1)))
    sched.call_later(90.0, lambda: channel.transmit("shore", data(1, 2)))  # each deaf to the other
    sched.call_later(90.0, lambda: channel.transmit("rov2", data(2, 1)))
    sched.run()
    s = channel.stats
    assert s["transmissions"] == 6
    assert s["addressed"] == 1 + 3 + 1 + 1 + 1 + 1  # frames, each counted at its one addressee
    assert s["overheard"] == 8  # and at the one other modem
    assert s["receptions"] == 12 and s["addressed"] + s["overheard"] == 12 + 2 * 2  # 3 frames in one
    assert s["addressed_collided"] == 2 and s["addressed_deaf"] == 2
    assert s["addressed_collided"] + s["addressed_deaf"] <= s["addressed_lost"] <= s["addressed"]
    assert s["addressed_lost"] + s["overheard_lost"] == s["lost"]
