"""``poseidon path`` over a map of two sessions: across the sonar-verified link when
the sessions are linked, never across the chain edge into the second session's first node; a
clear refusal naming the sessions when they are not linked.  Hand-made two-session chamber of
tests/expmap/test_sessions.py (session A: nodes 0..39, session B: 40..79)."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from common.mcap_io import RecordingWriter
from common.messages import Header, MapSessions, SessionLinkInfo
from services.expmap.graph import ExperienceMap, quickest_path
from services.expmap.node import map_message
from services.expmap.path import main as path_main
from services.expmap.routes import SessionsNotLinked
from tests.expmap.test_sessions import FRAME_B, OFF_TRUE, cfg, lap, session_a


def two_sessions(linked: bool) -> ExperienceMap:
    em = session_a(cfg())
    em.begin_session()
    lap(em, 100, range(40), FRAME_B, OFF_TRUE, sweeps=linked)   # no sweeps: no link
    em.settle()
    assert em.n_sessions == 2 and len(em.session_links) == int(linked)
    return em


def recording(em: ExperienceMap, path: Path) -> Path:
    """A run recording holding the map and its map_sessions, as the expmap node publishes them."""
    stamp = int(em.stamps[-1])
    links = [SessionLinkInfo(session=lk.session, to_session=lk.to_session, source=lk.m, target=lk.n, stamp=lk.stamp,
                             delta=[float(v) for v in lk.delta], shift=[float(v) for v in lk.shift],
                             rotation_deg=lk.rotation_deg, inlier_fraction=lk.inlier_fraction)
             for lk in em.session_links]
    with RecordingWriter(path) as w:
        w.write("map", map_message(em, Header(seq=0, stamp=stamp, frame_id="map")))
        w.write("map_sessions", MapSessions(header=Header(seq=0, stamp=stamp, frame_id="map"),
                                            node_session=[int(v) for v in em.sessions], loaded_nodes=40, links=links))
    return path


def test_linked_sessions_plan_across_the_link(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    em = two_sessions(linked=True)
    link = em.session_links[0]
    em.save(tmp_path / "expmap.npz")
    rec = recording(em, tmp_path / "run.mcap")
    for src in (tmp_path / "expmap.npz", rec):
        assert path_main([str(src), "--from", "0", "--to", "79", "--json"]) == 0
        res = json.loads(capsys.readouterr().out)
        nodes = res["nodes"]
        assert nodes[0] == 0 and nodes[-1] == 79
        assert res["sessions"] == [0, 1] and res["crossings"] == [[link.m, link.n]]
        k = nodes.index(link.m)
        assert nodes[k + 1] == link.n                     # through the link
        assert [39, 40] not in [nodes[i:i + 2] for i in range(len(nodes) - 1)]
    # the chain edge 39 -> 40 joins the two frames: never a route, even between its own ends
    nodes, _d, _l = quickest_path(em, 39, 40)
    assert len(nodes) > 2 and all({a, b} != {39, 40} for a, b in zip(nodes, nodes[1:]))
    assert path_main([str(tmp_path / "expmap.npz"), "--from", "3", "--to", "7"]) == 0
    assert "sessions:" not in capsys.readouterr().out   # within one session: printed as before


def test_unlinked_sessions_are_refused_naming_them(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    em = two_sessions(linked=False)
    em.save(tmp_path / "expmap.npz")
    rec = recording(em, tmp_path / "run.mcap")
    for src in (tmp_path / "expmap.npz", rec):
        assert path_main([str(src), "--from", "0", "--to", "79", "--json"]) == 2
        out = capsys.readouterr()
        assert out.out == ""
        assert "node 0 is in session 0 and node 79 in session 1, which are not linked" in out.err
        # within one session a path still exists
        assert path_main([str(src), "--from", "41", "--to", "79", "--json"]) == 0
        res = json.loads(capsys.readouterr().out)
        assert res["sessions"] == [1] and res["crossings"] == [] and min(res["nodes"]) >= 40
    with pytest.raises(SessionsNotLinked) as err:
        quickest_path(em, 39, 40)
    assert (err.value.source_session, err.value.target_session, err.value.groups) == (0, 1, [[0], [1]])
