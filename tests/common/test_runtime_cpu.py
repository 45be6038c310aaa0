"""A runner says where its service's CPU went: start-up, the node's own work, the frames' path."""
import time

import pytest

from common.messages import Depth, Header
from system.config import PoseidonConfig
from tests.common.nodes import Burner, start_local_runner

pytestmark = pytest.mark.timeout(60)


def test_the_node_work_the_start_up_and_the_frame_path_are_told_apart():
    cpu_before = time.process_time()
    session, bus, t, result = start_local_runner(Burner(PoseidonConfig()))
    depth = bus.publisher("depth_sensor")
    for i in range(6):
        depth.send(Depth(header=Header(seq=i, stamp=10 + i), depth=float(i)))
    depth.send_eos()
    t.join(timeout=30)
    bus.close()
    session.close()
    assert not t.is_alive()
    st = result["stats"].as_dict()
    assert st["published"] == {"burner/depth": 6}
    # six inputs at 0.05 s each, in the node; the 0.15-s warm-up before the service was alive
    assert 0.3 <= st["node_cpu_s"] < 0.6
    assert st["startup_cpu_s"] >= cpu_before + 0.15
    # decoding, merging and publishing six small frames costs far less than the node's work
    assert 0.0 <= st["frame_path_cpu_s"] < 0.1
