"""``poseidon info``'s summary of a recording (launcher/info.py)."""
from launcher.info import format_info, recording_info
from tests.eval import handmade as hm


def test_recording_info_of_a_complete_recording(tmp_path):
    path = hm.write_run(tmp_path / "hm.mcap")
    info = recording_info(path)
    assert info["complete"] and info["damage"] == ""
    assert list(info)[:5] == ["counts", "types", "start_ns", "end_ns", "duration_s"]
    assert "digests" not in info and "recovered" not in info
    assert set(info["types"]) == set(info["counts"])


def test_format_info_lists_each_key_with_its_count_and_type(tmp_path):
    path = hm.write_run(tmp_path / "hm.mcap")
    info = recording_info(path, digests=True)
    lines = format_info(path, info)
    assert lines[0] == f"{path}: {info['duration_s']:.1f} s"
    key, n = next(iter(sorted(info["counts"].items())))
    assert lines[1].split()[:2] == [key, str(n)]
    assert sum(line.startswith("  sha256 ") for line in lines) == len(info["digests"])
