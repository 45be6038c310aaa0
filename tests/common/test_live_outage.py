"""The outage rule of :class:`common.live.LiveSource` on one local session: a key whose last
consumer left holds its frames (bounded, drop-oldest, counted) and sends them again, oldest
first and before anything newer, when a consumer is back."""
import time

from common.bus import Bus, open_local_session
from common.codec import decode_frame
from common.live import LiveSource
from common.messages import Header, Imu


def _imu(i: int) -> Imu:
    return Imu(header=Header(seq=i + 1, stamp=1_000_000 + i, frame_id="imu"), roll=0.0, pitch=0.0, yaw=0.0, qx=0.0,
               qy=0.0, qz=0.0, qw=1.0, gx=float(i), gy=0.0, gz=0.0, ax=0.0, ay=0.0, az=0.0)


def _wait(cond, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def test_a_key_without_consumers_holds_its_frames_and_sends_them_when_one_is_back():
    session = open_local_session()
    bus = Bus(session=session)
    got: list[tuple[str, int]] = []

    def on_sample(sample):
        f = decode_frame(sample.payload.to_bytes())
        got.append((f.kind, f.index if f.kind in ("data", "replay") else -1))

    try:
        source = LiveSource(bus, 0, outage_frames=5)
        source.publish("imu", _imu(-1))  # nobody ever listened: sent (and lost) as always
        sub = session.declare_subscriber("poseidon/imu", on_sample)
        pub = source.publishers()[0]
        _wait(lambda: source._matching["imu"])
        for i in range(3):
            source.publish("imu", _imu(i))
        _wait(lambda: len(got) == 3)
        sub.undeclare()
        _wait(lambda: not source._matching["imu"])
        for i in range(3, 11):  # 8 held; the buffer of 5 pushes out the 3 sent ones, then 3 held
            source.publish("imu", _imu(i))
        assert source.outages == {"imu": 1} and source.dropped_outage == {"imu": 3}
        assert source.send_watermarks(10**18) == 0  # no promise past the held frames
        got.clear()
        sub = session.declare_subscriber("poseidon/imu", on_sample)
        _wait(lambda: source._matching["imu"])
        source.publish("imu", _imu(11))
        _wait(lambda: sum(k == "data" for k, _i in got) == 6)
        # the transport index counts from 0 with the unheard frame: held ones are 7..11, the new one 12
        assert [i for k, i in got if k in ("data", "replay")] == [7, 7, 8, 9, 10, 11, 12]
        assert got[0][0] == "replay"
        assert source.delivered_late == {"imu": 5} and source.resent == {}
        assert source.published == {"imu": 13}
        assert len(pub.retained) == 5
        sub.undeclare()
        _wait(lambda: not source._matching["imu"])
        source.publish("imu", _imu(12))
        source.end()  # still cut off at the end: what is held never reaches anyone
        assert source.dropped_outage == {"imu": 4}
    finally:
        bus.close()
        session.close()
