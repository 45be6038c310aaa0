"""Small generated recordings shared by the tests of common/, the launcher, the player and the recorder."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from common.mcap_io import RecordingWriter
from common.messages import Depth, Header, Image, Imu, LinkquestDvl, Odometry, RangeImageBeam

#: frames a hostile or broken publisher may put on a key (the issue's b"D", b"D\x04\xff...")
HOSTILE = [b"D", b"D\x04\xff\xfe\xfd\xfc", b"D\x04\xff", b"D\x20poseidon_msgs/Image", b"D\x13poseidon_msgs/Image",
           b"D\x13poseidon_msgs/Imagex\xc1", b"D\x0bnot/a/type!\x80", b"W", b"W\x01\x02", b"W" + b"\xff" * 8,
           b"E\x00", b"", b"\x00", b"Z" * 50]

KEYS6 = ["camera/image_raw", "depth_sensor", "imu_adis_ros", "sonar_micron", "odometry", "dvl_linkquest"]


def payloads_by_key(path: Path) -> dict[str, list[bytes]]:
    """Every payload of a recording, per key, in file (arrival) order."""
    from mcap.reader import make_reader

    out: dict[str, list[bytes]] = {}
    with open(path, "rb") as f:
        for _schema, channel, msg in make_reader(f).iter_messages(log_time_order=False):
            out.setdefault(channel.topic, []).append(bytes(msg.data))
    return out


def dvl(header: Header, vx: float = 0.1) -> LinkquestDvl:
    return LinkquestDvl(header=header, datagood=[1, 1, 1, 1], altitudebeam=[2.0] * 4, bottomvelocitybeam=[0.0] * 4,
                        watervelocitybeam=[0.0] * 4, watervelocitycredit=[0.0] * 4, velocityinst=[vx, 0.0, 0.0],
                        velocityinstflag=1, velocityearth=[0.0] * 3, velocityearthflag=1,
                        watervelocityinst=[0.0] * 3, watervelocityinstflag=0, watervelocityearth=[0.0] * 3,
                        watervelocityearthflag=0, roll=0.0, pitch=0.0, heading=0.0, altitude=2.0,
                        temperature=15.0, pressure=1.0, salinity=0.0, soundspeed=1500.0)


def six_stream_recording(path: Path, n_messages: int, image_every: int = 25, seed: int = 0) -> dict[str, int]:
    """A recording of six streams (384x288 RGB images among them); returns counts per key."""
    rng = np.random.default_rng(seed)
    seqs: dict[str, int] = {}

    def hdr(key: str, stamp: int) -> Header:
        s = seqs.get(key, 0)
        seqs[key] = s + 1
        return Header(seq=s, stamp=stamp, frame_id=key)

    count = i = 0
    t0 = 1_372_687_208_000_000_000
    with RecordingWriter(path) as w:
        while count < n_messages:
            stamp = t0 + i * 10_000_000
            if i % image_every == 0:
                w.write("camera/image_raw", Image(header=hdr("camera/image_raw", stamp), height=288, width=384,
                                                  data=rng.integers(0, 255, (288, 384, 3), dtype=np.uint8)))
                count += 1
            w.write("depth_sensor", Depth(header=hdr("depth_sensor", stamp), depth=float(i) * 0.01))
            count += 1
            if i % 3 == 0:
                w.write("imu_adis_ros", Imu(header=hdr("imu_adis_ros", stamp + 1), roll=0.0, pitch=0.0, yaw=0.1,
                                            qx=0.0, qy=0.0, qz=0.0, qw=1.0))
                count += 1
            if i % 5 == 0:
                w.write("sonar_micron", RangeImageBeam(header=hdr("sonar_micron", stamp + 2), angle_grad=float(i % 400),
                                                       angle_rad=0.1, nbins=50, max_range=20,
                                                       beam_data=rng.integers(0, 100, 50).astype(np.int32)))
                count += 1
            if i % 7 == 0:
                w.write("odometry", Odometry(header=hdr("odometry", stamp + 3), position=[float(i), 0.0, 0.0],
                                             orientation=[0.0, 0.0, 0.0, 1.0]))
                count += 1
            if i % 11 == 0:
                w.write("dvl_linkquest", dvl(hdr("dvl_linkquest", stamp + 4)))
                count += 1
            i += 1
    return seqs


def inconsistent_image(header: Header, height: int = 4000, width: int = 4000) -> Image:
    """An Image whose header contradicts its data (2x2x3 bytes): built without validation,
    as a hostile or buggy publisher would send it."""
    return Image.model_construct(header=header, height=height, width=width, encoding="rgb8",
                                 data=np.zeros((2, 2, 3), np.uint8))


def with_inconsistent_image(src: Path, dst: Path, index: int = 3) -> int:
    """Copy ``src`` to ``dst`` replacing the ``index``-th camera frame by :func:`inconsistent_image`
    (same header).  Returns the seq of the replaced frame."""
    from common.codec import encode
    from common.mcap_io import read_messages

    seen = 0
    bad_seq = -1
    with RecordingWriter(dst) as w:
        for r in read_messages(src):
            if r.key == "camera/image_raw":
                if seen == index:
                    msg = r.message()
                    bad = inconsistent_image(msg.header)
                    w.write_encoded(r.key, r.type_name, encode(bad), r.stamp, r.seq)
                    bad_seq = msg.header.seq
                    seen += 1
                    continue
                seen += 1
            w.write_encoded(r.key, r.type_name, r.payload, r.stamp, r.seq)
    return bad_seq
