"""``--foxglove PORT``: a Foxglove WebSocket client subscribes to the server's channels and
receives the map, trajectory and image messages the view logs, one per change."""
from __future__ import annotations

import json
import struct
import time
from pathlib import Path

import pytest

from common.mcap_io import read_messages
from services.viewer.config import ViewConfig
from services.viewer.foxglove_live import FoxgloveLive
from services.viewer.model import ViewModel
from tests.viewer.runs import write_run

sync_client = pytest.importorskip("websockets.sync.client", reason="websockets (dev extra) is not installed")


def test_a_foxglove_client_receives_map_trajectory_and_images(tmp_path: Path) -> None:
    run = tmp_path / "run.mcap"
    counts = write_run(run, seconds=10.0)
    fox = FoxgloveLive("127.0.0.1", 0, backlog=1000)  # the client reads after the updates: keep them all
    try:
        with sync_client.connect(f"ws://127.0.0.1:{fox.port}", subprotocols=["foxglove.sdk.v1"],  # type: ignore[list-item]
                                 open_timeout=10) as ws:
            channels: dict[int, str] = {}
            deadline = time.monotonic() + 10
            while len(channels) < 8 and time.monotonic() < deadline:
                msg = json.loads(ws.recv(timeout=5))
                if msg["op"] == "advertise":
                    channels.update({c["id"]: c["topic"] for c in msg["channels"]})
            assert {"/map", "/trajectory/dead_reckoning", "/trajectory/truth", "/camera", "/scan", "/pose"} <= set(
                channels.values())
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                {"id": cid, "channelId": cid} for cid in channels]}))
            time.sleep(0.5)  # the subscription reaches the server before anything is logged
            model = ViewModel(ViewConfig())
            updates = swept = 0
            for rec in read_messages(run):  # an update after every camera frame (2 Hz)
                model.apply(rec.key, rec.message())
                if rec.key == "camera/image_raw":
                    fox.update(model)
                    updates += 1
                    swept += bool(model.sonar)  # the first frame comes before the first sonar beam
            want = {"/camera": counts["camera/image_raw"], "/map": counts["map"], "/trajectory/dead_reckoning": updates,
                    "/scan": swept}
            got: dict[str, int] = {}
            deadline = time.monotonic() + 10
            while any(got.get(k, 0) < n for k, n in want.items()) and time.monotonic() < deadline:
                try:
                    data = ws.recv(timeout=2)
                except TimeoutError:
                    break  # what is missing is named by the assertions below
                if isinstance(data, bytes) and data[0] == 1:
                    sub = struct.unpack_from("<I", data, 1)[0]
                    got[channels[sub]] = got.get(channels[sub], 0) + 1
    finally:
        fox.stop()
    assert got["/camera"] == counts["camera/image_raw"] == updates  # a new frame at every update
    assert got["/map"] == fox.sent["map"] == counts["map"]  # one scene per published map
    assert got["/trajectory/dead_reckoning"] == updates and got["/scan"] == swept == updates - 1


def test_the_recording_s_final_state_reaches_foxglove_once(tmp_path: Path) -> None:
    """After ``poseidon run --view``'s run the recording's final state replaces the live one
    (:meth:`LiveFeed.finish`): the Foxglove server logs its map and trajectories again, not the
    camera frame it already sent."""
    from services.viewer.recording import final_model
    run = tmp_path / "run.mcap"
    write_run(run, seconds=10.0)
    live = ViewModel(ViewConfig())
    for rec in read_messages(run, end_ns=min(r.stamp for r in read_messages(run, keys=["map"])) + 1):
        live.apply(rec.key, rec.message())  # the live view saw up to the first map
    fox = FoxgloveLive("127.0.0.1", 0, backlog=10)
    try:
        fox.update(live)
        fox.update(live)
        before = dict(fox.sent)
        assert before["map"] == 1 and before["camera"] == 1
        final = final_model(run, ViewConfig())
        final.continue_from(live)
        fox.update(final)
        assert fox.sent["map"] == 2 and fox.sent["trajectory/dead_reckoning"] == 2
        assert fox.sent["camera"] == 1  # the final state keeps the frame already shown
    finally:
        fox.stop()
