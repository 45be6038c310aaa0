"""rostopic-echo CSV import: the real Girona logs and bad input."""
from __future__ import annotations

from pathlib import Path

import pytest

from common.messages import Depth, LinkquestDvl
from common.stamps import parse_stamp_ns
from missions.importers.errors import InputFormatError
from missions.importers.rostopic_csv import read_frame_timestamps, read_rostopic_csv

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "girona_caves"
needs_girona = pytest.mark.skipif(not DATA.is_dir(), reason=f"real Girona logs not present at {DATA}")


@needs_girona
def test_girona_dvl_every_record() -> None:
    recs = read_rostopic_csv(DATA / "dvl_linkquest.csv")
    assert len(recs) == 5564
    key, first = recs[0]
    assert key == "dvl_linkquest" and isinstance(first, LinkquestDvl)
    # first data line: 1372687208632644971,1245,1372687208633787539,0,1,1,1,0.0,2.0,2.0,2.1,...
    assert first.header.seq == 1245 and first.header.stamp == 1372687208633787539
    assert first.datagood == [0, 1, 1, 1]
    assert first.altitudebeam == [0.0, 2.0, 2.0, 2.1]
    assert first.velocityinst == [-0.2424, -0.1145, -0.0065] and first.velocityinstflag == 1
    assert first.soundspeed == 1500.0 and first.pressure == 2853823.582
    second = recs[1][1]
    assert isinstance(second, LinkquestDvl) and second.velocityinstflag == 0
    seqs = [m.header.seq for _, m in recs]
    assert seqs == sorted(seqs)


@needs_girona
def test_girona_depth_every_record() -> None:
    recs = read_rostopic_csv(DATA / "depth_sensor.csv", kind="depth_sensor")
    assert len(recs) == 19553
    assert all(isinstance(m, Depth) for _, m in recs)
    d0 = recs[0][1]
    assert isinstance(d0, Depth)
    assert d0.header.stamp == 1372687208474662296 and d0.depth == pytest.approx(12.9544916153)


@needs_girona
def test_girona_frame_timestamps() -> None:
    stamps = read_frame_timestamps(DATA / "camera_frame_timestamps.txt")
    assert stamps[0] == ("frame_000000.png", 1372687208617629000)
    assert len(stamps) == len((DATA / "camera_frame_timestamps.txt").read_text().split("\n")) - 1


def test_stamp_parsing_exact() -> None:
    assert parse_stamp_ns("1372687223.020753194") == 1372687223020753194
    assert parse_stamp_ns("12.5") == 12_500_000_000
    assert parse_stamp_ns("42") == 42
    with pytest.raises(ValueError):
        parse_stamp_ns("12.x")


def test_missing_column_names_file_and_column(tmp_path: Path) -> None:
    p = tmp_path / "depth.csv"
    p.write_text("%time,field.header.seq,field.header.stamp,field.pressure\n1,0,5,1.0\n")
    with pytest.raises(InputFormatError, match=r"depth\.csv.*field\.depth"):
        read_rostopic_csv(p, kind="depth_sensor")


def test_malformed_number_names_line_and_column(tmp_path: Path) -> None:
    p = tmp_path / "depth.csv"
    p.write_text("%time,field.header.seq,field.header.stamp,field.depth\n1,0,5,1.0\n2,1,6,abc\n")
    with pytest.raises(InputFormatError, match=r"depth\.csv: line 3, column 'field\.depth'.*'abc'"):
        read_rostopic_csv(p)


def test_undetectable_kind_and_empty(tmp_path: Path) -> None:
    p = tmp_path / "x.csv"
    p.write_text("%time,field.header.seq,field.header.stamp,field.foo\n")
    with pytest.raises(InputFormatError, match="cannot tell the message kind"):
        read_rostopic_csv(p)
    e = tmp_path / "e.csv"
    e.write_text("")
    with pytest.raises(InputFormatError, match="empty file"):
        read_rostopic_csv(e)


@pytest.mark.parametrize("bad", ["nan", "inf", "-inf", "1e308"])
def test_non_finite_or_absurd_values_are_rejected_naming_line_and_column(tmp_path: Path, bad: str) -> None:
    """nan/inf/1e308 in a rostopic CSV are an error, never imported silently."""
    p = tmp_path / "depth_sensor.csv"
    p.write_text("%time,field.header.seq,field.header.stamp,field.header.frame_id,field.depth\n"
                 "1372687208633787539,0,1372687208633787539,depth,1.5\n"
                 f"1372687208733787539,1,1372687208733787539,depth,{bad}\n")
    with pytest.raises(InputFormatError, match=rf"depth_sensor.csv: line 3, column 'field.depth': value '{bad}'"):
        read_rostopic_csv(p)
