"""The one factory of a run's workers (system.services.build_worker), used by both launchers."""
import pytest

from common.runtime import NodeRunner
from common.worker import Sink, Source, Worker
from services.player.player import Player
from services.recorder.recorder import Recorder
from system.config import PoseidonConfig
from system.services import UnknownService, WorkerSpec, build_node, build_worker
from tests.common.recordings import six_stream_recording

pytestmark = pytest.mark.timeout(60)


@pytest.fixture
def config():
    cfg = PoseidonConfig(service_classes={"slow_echo": "tests.common.nodes:SlowEcho"})
    cfg.player.rate = 2.0
    cfg.bus.drain_timeout_s = 7.0
    return cfg


def test_each_kind_is_built_by_name(tmp_path, bus, config):
    src = tmp_path / "small.mcap"
    six_stream_recording(src, 30)
    player = build_worker("player", config, bus, WorkerSpec(input=src, keys=["depth_sensor"], wait_for=["x"]))
    recorder = build_worker("recorder", config, bus, WorkerSpec(out=tmp_path / "out.mcap", expect=["depth_sensor"]))
    runner = build_worker("slow_echo", config, bus)
    assert isinstance(player, Player) and isinstance(player, Source)
    assert isinstance(recorder, Recorder) and isinstance(recorder, Sink)
    assert isinstance(runner, NodeRunner) and isinstance(runner, Sink) and isinstance(runner, Source)
    assert all(isinstance(w, Worker) for w in (player, recorder, runner))
    assert (player.name, recorder.name, runner.name) == ("player", "recorder", "slow_echo")
    assert player.keys == ["depth_sensor"] and player.wait_for == ["x"] and player.rate == 2.0
    assert recorder.expect == {"depth_sensor"}
    assert runner.node.inputs == ("depth_sensor", "camera/image_raw")


def test_the_spec_says_what_the_configuration_does_not(tmp_path, bus, config):
    src = tmp_path / "small.mcap"
    six_stream_recording(src, 30)
    player = build_worker("player", config, bus, WorkerSpec(input=src, rate=0.0, drain=True))
    assert player.rate == 0.0 and player.drain_timeout_s == 7.0  # its own process: it drains
    assert player.keys == sorted(six_stream_recording(tmp_path / "again.mcap", 30))  # every key recorded
    node = build_node("slow_echo", config)
    runner = build_worker("slow_echo", config, bus, WorkerSpec(node=node))
    assert runner.node is node and runner.drain_timeout_s == 0.0  # embedded: no drain


def test_an_unknown_name_is_a_clear_error(bus, config):
    with pytest.raises(UnknownService) as err:
        build_worker("nosuch", config, bus)
    assert isinstance(err.value, KeyError)
    text = str(err.value)
    assert text.startswith("unknown service 'nosuch'; services: player, recorder, encoder")
    assert "service_classes" in text


def test_player_and_recorder_need_their_files(bus, config):
    with pytest.raises(ValueError, match="input recording"):
        build_worker("player", config, bus)
    with pytest.raises(ValueError, match="output file"):
        build_worker("recorder", config, bus)


def test_each_node_is_built_from_its_own_section_and_explicit_cross_section_values():
    """Item 4 of the architecture: a node sees its own section; what it needs from another
    section arrives as a named argument filled in by the launcher's wiring."""
    from system.config import load_config
    from system.services import WIRING

    cfg = load_config(overrides=["posecells.distance_between_neurons=[0.5,0.25,0.2]", "sync.sync_stale_sec=0.4",
                                 "robot_state.axis_remap=xyz", "robot_state.axis_sign_z=1", "encoder.cnn_backbone=efficientnet_lite0",
                                 "encoder.untrained=true"])
    for name, wiring in WIRING.items():
        node = build_node(name, cfg)
        assert node.config is wiring.section(cfg), name
        assert not isinstance(node.config, PoseidonConfig), name
    expmap = build_node("expmap", cfg)
    assert expmap.graph.lattice_spacing == (0.5, 0.25, 0.2)        # from posecells, explicitly
    assert expmap.images.slop_ns == round(min(0.4, cfg.expmap.image.sync_slop) * 1e9)  # from sync, explicitly
    assert expmap.sweeps.head_sign == 1.0                          # from robot_state, explicitly
    encoder = build_node("encoder", cfg)
    assert encoder.core.clock.stale_ns == 400_000_000              # from sync, explicitly


def test_debug_knobs_reach_only_the_service_that_uses_them(bus):
    """``debug.fault_jump_*`` go to robot_state as named arguments, ``debug.slow_*`` to the runner
    of the slowed service of a live run; neither is part of a service's own section."""
    from system.config import load_config

    cfg = load_config(overrides=["debug.fault_jump_at_s=12", "debug.fault_jump_m=[1,2,3]",
                                 "debug.slow_service=posecells", "debug.slow_ms=40"])
    rs = build_node("robot_state", cfg)
    assert (rs.fault_jump_at_s, rs.fault_jump_m) == (12.0, [1.0, 2.0, 3.0])
    assert "fault_jump_at_s" not in type(cfg.robot_state).model_fields
    slowed = build_worker("posecells", cfg, bus, WorkerSpec(live=True))
    other = build_worker("posecells", load_config(overrides=["debug.slow_service=expmap", "debug.slow_ms=40"]), bus,
                         WorkerSpec(live=True))
    assert isinstance(slowed, NodeRunner) and isinstance(other, NodeRunner)
    assert (slowed.delay_s, other.delay_s) == (0.04, 0.0)
