import random

from common.messages import Depth, Header
from common.node import ServiceNode, run_offline
from common.ordering import EventTimeMerger
from system.config import PoseidonConfig


def _streams():
    rng = random.Random(3)
    streams = {"a": [], "b": [], "c": []}
    for name, period in (("a", 7), ("b", 5), ("c", 10)):
        t = rng.randrange(3)
        for seq in range(40):
            streams[name].append((t, seq))
            t += period if seq % 4 else 0  # some equal stamps within a stream
    return streams


def _merge(streams, rng, heartbeats: bool):
    m = EventTimeMerger(["a", "b", "c"])
    cursors = {k: 0 for k in streams}
    out = []
    live = [k for k in streams]
    while live:
        k = rng.choice(live)
        i = cursors[k]
        if i == len(streams[k]):
            m.end(k)
            live.remove(k)
        else:
            stamp, seq = streams[k][i]
            m.push(k, stamp, seq, (k, stamp, seq))
            cursors[k] += 1
            if heartbeats and rng.random() < 0.3 and cursors[k] < len(streams[k]):
                m.advance(k, streams[k][cursors[k]][0])
        out.extend(item for _k, _s, item in m.pop_ready())
    assert m.finished
    return out


def test_merge_is_independent_of_interleaving():
    streams = _streams()
    reference = sorted(((k, t, s) for k, v in streams.items() for t, s in v),
                       key=lambda x: (x[1], "abc".index(x[0]), x[2]))
    for trial in range(30):
        assert _merge(streams, random.Random(trial), heartbeats=trial % 2 == 0) == reference


def test_release_waits_for_every_stream():
    m = EventTimeMerger(["a", "b"])
    m.push("a", 10, 0, "a10")
    assert list(m.pop_ready()) == []  # b has said nothing yet
    m.advance("b", 10)  # b may still send a stamp-10 message, but it sorts after a's
    assert [x[2] for x in m.pop_ready()] == ["a10"]
    m.push("b", 20, 0, "b20")
    m.push("a", 20, 1, "a20")
    assert [x[2] for x in m.pop_ready()] == ["a20"]
    assert list(m.pop_ready()) == []
    m.end("a")
    assert [x[2] for x in m.pop_ready()] == ["b20"]


class _Echo(ServiceNode):
    name = "echo"
    inputs = ("x", "y")
    outputs = ("out",)

    def process(self, key, msg):
        self.publish("out", Depth(header=self.header("out", msg.header.stamp, key), depth=msg.depth))


def test_run_offline_orders_by_event_time_and_numbers_outputs():
    msgs = [("y", Depth(header=Header(seq=0, stamp=5), depth=1.0)),
            ("x", Depth(header=Header(seq=0, stamp=5), depth=2.0)),
            ("x", Depth(header=Header(seq=1, stamp=1), depth=3.0)),
            ("ignored", Depth(header=Header(seq=0, stamp=0), depth=9.0))]
    out = run_offline(_Echo(PoseidonConfig()), msgs)
    # offline, everything is buffered before release: pure (stamp, priority, seq) order
    assert [(m.header.frame_id, m.header.stamp, m.header.seq) for _k, m in out] == \
        [("x", 1, 0), ("x", 5, 1), ("y", 5, 2)]
