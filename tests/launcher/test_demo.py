"""`poseidon demo`: the checks it prints and the mission cache (the full demo is run by hand:
it takes minutes; its figures are in the README and docs/DECISIONS.md)."""
from __future__ import annotations

import json

import pytest

import launcher.demo as demo


def _run(events, nodes, false, ate_map, ate_dr, f1=1.0):
    return {"path": "x", "wall_s": 10.0, "mission_s": 100.0, "real_time_factor": 10.0, "events": events,
            "nodes": nodes, "edges": nodes, "loop_closures": {"accepted": 3, "true": 3 - false, "false": false,
                                                              "recall": 0.1},
            "ate_rmse_m": {"map": ate_map, "dead_reckoning": ate_dr}, "audit_f1": f1}


def test_checks_pass_only_when_the_method_holds():
    good = {"on": _run(100, 100, 0, 0.4, 2.0), "off": _run(150, 150, 1, 0.5, 2.0)}
    assert all(demo._checks(good).values())
    cases = {
        "no false loop closure with the VPR Guard ON": {"on": _run(100, 100, 1, 0.4, 2.0)},
        "fewer events ON than OFF": {"on": _run(150, 100, 0, 0.4, 2.0)},
        "fewer experiences ON than OFF": {"on": _run(100, 150, 0, 0.4, 2.0)},
        "map error below dead reckoning's (ON)": {"on": _run(100, 100, 0, 2.5, 2.0)},
        "audit F1 = 1.0 (off)": {"off": _run(150, 150, 0, 0.5, 2.0, f1=0.99)},
    }
    for name, change in cases.items():
        checks = demo._checks({**good, **change})
        assert checks[name] is False, name
        assert sum(not v for v in checks.values()) == 1, (name, checks)
    missing = demo._checks({**good, "on": _run(100, 100, 0, None, 2.0)})
    assert missing["map error below dead reckoning's (ON)"] is False


def test_mission_is_cached_by_recipe(tmp_path, monkeypatch):
    calls = {"sim": 0, "transform": 0}

    def fake_sim(argv):
        calls["sim"] += 1
        out = argv[argv.index("--out") + 1]
        open(out, "wb").write(b"sim")
        return 0

    def fake_transform(src, out, **kw):
        calls["transform"] += 1
        assert kw["areas"] == 1
        out.write_bytes(b"tr")

    import missions.sim.cli
    import missions.transform
    monkeypatch.setattr(missions.sim.cli, "main", fake_sim)
    monkeypatch.setattr(missions.transform, "transform", fake_transform)
    m1, cached1 = demo.ensure_mission(tmp_path, seed=4)
    m2, cached2 = demo.ensure_mission(tmp_path, seed=4)
    assert (cached1, cached2) == (False, True) and m1 == m2 and calls == {"sim": 1, "transform": 1}
    # a changed recipe (e.g. another version) remakes both files
    stamps = json.loads((tmp_path / "cache" / "demo_cache.json").read_text())
    stamps = {k: dict(v, version=0) for k, v in stamps.items()}
    (tmp_path / "cache" / "demo_cache.json").write_text(json.dumps(stamps))
    _, cached3 = demo.ensure_mission(tmp_path, seed=4)
    assert cached3 is False and calls == {"sim": 2, "transform": 2}
    # another seed is another mission
    m4, _ = demo.ensure_mission(tmp_path, seed=5)
    assert m4 != m1


def test_failed_simulation_is_an_error(tmp_path, monkeypatch):
    import missions.sim.cli
    monkeypatch.setattr(missions.sim.cli, "main", lambda argv: 2)
    with pytest.raises(RuntimeError, match="simulation failed"):
        demo.ensure_mission(tmp_path, seed=1)


def test_compile_kernels_warms_up_only_the_services_that_have_kernels(monkeypatch):
    """The background compilation builds a throwaway node of each service that overrides
    warm_up and calls it; services without one (the encoder: seconds of model loading for
    nothing) are not even built."""
    import system.services as services
    from common.node import ServiceNode

    warmed, built = [], []

    class WithKernels(ServiceNode):
        def warm_up(self):
            warmed.append(self.tag)

    class Plain(ServiceNode):
        pass

    classes = {"htm": WithKernels, "encoder": Plain, "robot_state": WithKernels}

    def fake_build(name, config):
        built.append(name)
        node = classes[name].__new__(classes[name])
        node.tag = name
        return node

    monkeypatch.setattr(services, "available_services", lambda config: list(classes))
    monkeypatch.setattr(services, "node_class", lambda name, config: classes[name])
    monkeypatch.setattr(services, "build_node", fake_build)
    demo.compile_kernels(demo.PoseidonConfig().model_dump_json())
    assert warmed == ["htm", "robot_state"] and built == ["htm", "robot_state"]
