"""mmcsplat.storage.landmark_formats: TRC, landmark CSV and C3D read and written as the tools that use them expect."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.storage.landmark_formats import (
    read_c3d,
    read_landmark_csv,
    read_trc,
    write_c3d,
    write_landmark_csv,
    write_trc,
)

DEMO_TRC = Path(__file__).resolve().parents[2] / "shared" / "data" / "pose2sim_demo" / "joints_3d.trc"
NAMES = ("LWrist", "RAnkle", "Nose")


def _trajectories(count: int = 4, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    times = np.arange(count) / 30.0
    positions = rng.normal(scale=0.5, size=(count, len(NAMES), 3))
    positions[1, 2] = np.nan  # Nose unknown at the second frame
    return times, positions


def _parse_trc_independently(path: Path) -> dict:
    """A small TRC parser of the test's own: header lines checked cell by cell, data as file values."""
    lines = path.read_text(encoding="utf-8").split("\n")
    assert lines[-1] == "", "the file ends with a line break"
    lines = lines[:-1]
    rows = [line.split("\t") for line in lines]
    assert rows[0] == ["PathFileType", "4", "(X/Y/Z)", path.name]
    assert rows[1] == ["DataRate", "CameraRate", "NumFrames", "NumMarkers", "Units", "OrigDataRate", "OrigDataStartFrame", "OrigNumFrames"]
    header = dict(zip(rows[1], rows[2], strict=True))
    names = rows[3][2::3]
    assert rows[3][:2] == ["Frame#", "Time"]
    assert len(rows[3]) == 2 + 3 * len(names)
    assert all(rows[3][3 + 3 * i] == "" and rows[3][4 + 3 * i] == "" for i in range(len(names))), "two empty cells after each name"
    assert rows[4] == ["", ""] + [f"{axis}{i}" for i in range(1, len(names) + 1) for axis in "XYZ"]
    data = rows[5:]
    assert all(len(row) == 2 + 3 * len(names) for row in data)
    values = np.array([[float(cell) if cell else math.nan for cell in row[2:]] for row in data]).reshape(len(data), len(names), 3)
    return {"header": header, "names": tuple(names), "frames": [int(row[0]) for row in data], "times": [float(row[1]) for row in data], "values": values}


# --- TRC -----------------------------------------------------------------------------------------------------


def test_reads_the_pose2sim_demo_trc():
    if not DEMO_TRC.is_file():
        pytest.skip(f"the Pose2Sim demo TRC is not here ({DEMO_TRC}): shared data not checked out")
    data = read_trc(DEMO_TRC)
    assert len(data.names) == 21 and data.names[0] == "RHip" and data.names[-1] == "LWrist"
    assert data.positions.shape == (100, 21, 3) and data.times.shape == (100,)
    assert data.rate == 60 and data.units == "m"
    assert data.frame_numbers[0] == 1 and data.frame_numbers[-1] == 100
    raw = DEMO_TRC.read_text().splitlines()[5].split("\t")
    assert data.times[0] == float(raw[1])
    trc_x, trc_y, trc_z = (float(cell) for cell in raw[2:5])  # RHip in the file's axes
    assert tuple(data.positions[0, 0]) == (trc_z, trc_x, trc_y)  # world = (trc Z, trc X, trc Y)
    as_is = read_trc(DEMO_TRC, convention="none")
    assert tuple(as_is.positions[0, 0]) == (trc_x, trc_y, trc_z)
    assert np.isfinite(data.positions).all()
    assert np.nanmedian(as_is.positions[..., 1]) > 0.3  # Y up: a standing subject's joints sit above the floor


@pytest.mark.parametrize("units", ["m", "mm"])
def test_written_trc_has_the_layout_tools_expect(tmp_path, units):
    times, positions = _trajectories()
    path = tmp_path / "walk.trc"
    write_trc(path, NAMES, times, positions, rate=30, units=units)
    parsed = _parse_trc_independently(path)
    assert parsed["header"]["DataRate"] == "30" and parsed["header"]["CameraRate"] == "30"
    assert parsed["header"]["NumFrames"] == "4" and parsed["header"]["OrigNumFrames"] == "4"
    assert parsed["header"]["NumMarkers"] == "3" and parsed["header"]["Units"] == units
    assert parsed["names"] == NAMES
    assert parsed["frames"] == [1, 2, 3, 4]
    assert parsed["times"] == times.tolist()
    scale = 1000.0 if units == "mm" else 1.0
    expected = np.stack([positions[..., 1], positions[..., 2], positions[..., 0]], axis=-1) * scale  # trc (X, Y, Z) = (world y, z, x)
    np.testing.assert_allclose(parsed["values"], expected, rtol=1e-15, equal_nan=True)
    assert np.isnan(parsed["values"][1, 2]).all() and np.isfinite(parsed["values"][0]).all()

    back = read_trc(path)
    assert back.names == NAMES and back.units == units and back.rate == 30
    assert back.frame_numbers.tolist() == [1, 2, 3, 4] and back.times.tolist() == times.tolist()
    np.testing.assert_allclose(back.positions, positions, rtol=1e-14, equal_nan=True)
    assert [p.name for p in tmp_path.iterdir()] == ["walk.trc"], "no temporary file left"


def test_trc_convention_none_keeps_the_axes(tmp_path):
    times, positions = _trajectories()
    path = tmp_path / "raw.trc"
    write_trc(path, NAMES, times, positions, rate=30, convention="none")
    np.testing.assert_array_equal(_parse_trc_independently(path)["values"], positions)
    np.testing.assert_array_equal(read_trc(path, convention="none").positions, positions)
    with pytest.raises(InputError, match="convention"):
        write_trc(path, NAMES, times, positions, rate=30, convention="z-up")


def test_demo_trc_survives_a_write_read_round_trip(tmp_path):
    if not DEMO_TRC.is_file():
        pytest.skip(f"the Pose2Sim demo TRC is not here ({DEMO_TRC}): shared data not checked out")
    data = read_trc(DEMO_TRC)
    write_trc(tmp_path / "again.trc", data.names, data.times, data.positions, data.rate)
    again = read_trc(tmp_path / "again.trc")
    assert again.names == data.names and again.rate == data.rate
    np.testing.assert_array_equal(again.positions, data.positions)
    np.testing.assert_array_equal(again.times, data.times)


# --- CSV -----------------------------------------------------------------------------------------------------


def test_landmark_csv_round_trip_with_missing_values_and_extra_columns(tmp_path):
    times, positions = _trajectories()
    frames = np.array([10, 11, 12, 13])
    spread = np.arange(12, dtype=float).reshape(4, 3)
    spread[2, 0] = np.nan
    confidence = np.linspace(0, 1, 12).reshape(4, 3)
    path = tmp_path / "landmarks.csv"
    write_landmark_csv(path, NAMES, frames, times, positions, extra={"spread_mm": spread, "confidence": confidence})
    lines = path.read_text().splitlines()
    assert lines[0] == "frame,time,name,x,y,z,spread_mm,confidence"
    assert len(lines) == 1 + 4 * 3
    assert lines[1 + 3 + 2].startswith("11,") and ",Nose,,,," in lines[1 + 3 + 2]  # a missing point: empty cells

    names, frames_back, times_back, positions_back, extra = read_landmark_csv(path)
    assert names == NAMES
    assert frames_back.tolist() == frames.tolist() and times_back.tolist() == times.tolist()
    np.testing.assert_array_equal(positions_back, positions)
    assert list(extra) == ["spread_mm", "confidence"]
    np.testing.assert_array_equal(extra["spread_mm"], spread)
    np.testing.assert_array_equal(extra["confidence"], confidence)


def test_landmark_csv_without_extra_and_with_absent_rows(tmp_path):
    path = tmp_path / "sparse.csv"
    path.write_text("frame,time,name,x,y,z\n2,0.1,A,1,2,3\n1,0.05,A,4,5,6\n1,0.05,B,7,8,9\n")
    names, frames, times, positions, extra = read_landmark_csv(path)
    assert names == ("A", "B") and frames.tolist() == [1, 2] and times.tolist() == [0.05, 0.1] and extra == {}
    np.testing.assert_array_equal(positions[0], [[4, 5, 6], [7, 8, 9]])
    assert positions[1, 0].tolist() == [1, 2, 3] and np.isnan(positions[1, 1]).all()  # B has no row at frame 2


def test_single_frame_csv_form(tmp_path):
    path = tmp_path / "reference.csv"
    path.write_text("name,x,y,z\nLWrist,0.1,0.2,0.3\nRAnkle,,,\n")
    names, frames, times, positions, extra = read_landmark_csv(path)
    assert names == ("LWrist", "RAnkle") and frames.tolist() == [0] and times.tolist() == [0.0] and extra == {}
    assert positions.shape == (1, 2, 3)
    assert positions[0, 0].tolist() == [0.1, 0.2, 0.3] and np.isnan(positions[0, 1]).all()


# --- C3D -----------------------------------------------------------------------------------------------------


def test_c3d_round_trip_through_ezc3d(tmp_path):
    ezc3d = pytest.importorskip("ezc3d")
    times, positions = _trajectories()
    path = tmp_path / "walk.c3d"
    write_c3d(path, NAMES, times, positions, rate=30)
    assert [p.name for p in tmp_path.iterdir()] == ["walk.c3d"], "no temporary file left"

    raw = ezc3d.c3d(str(path))
    point = raw["parameters"]["POINT"]
    assert [label.strip() for label in point["LABELS"]["value"]] == list(NAMES)
    assert point["UNITS"]["value"] == ["mm"]
    assert float(point["RATE"]["value"][0]) == 30
    values = raw["data"]["points"][:3]  # [3, L, T], millimetres, world axes unchanged
    np.testing.assert_allclose(values[:, 0, 0], positions[0, 0] * 1000, rtol=1e-6)
    residuals = raw["data"]["meta_points"]["residuals"][0]  # [L, T]
    assert residuals[2, 1] == -1 and (np.delete(residuals.ravel(), 2 * 4 + 1) == 0).all()
    assert np.isnan(values[:, 2, 1]).all()  # ezc3d reads an invalid point as NaN

    names, back, rate = read_c3d(path)
    assert names == NAMES and rate == 30
    np.testing.assert_allclose(back, positions, atol=1e-7, equal_nan=True)  # C3D stores float32 millimetres


def test_c3d_refuses_times_with_gaps(tmp_path):
    times, positions = _trajectories()
    times[3] += 1.0
    with pytest.raises(InputError, match="evenly spaced"):
        write_c3d(tmp_path / "gap.c3d", NAMES, times, positions, rate=30)
    assert list(tmp_path.iterdir()) == []


# --- errors --------------------------------------------------------------------------------------------------

GOOD_TRC = (
    "PathFileType\t4\t(X/Y/Z)\tx.trc\n"
    "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames\n"
    "30\t30\t2\t2\tm\t30\t1\t2\n"
    "Frame#\tTime\tA\t\t\tB\t\t\n"
    "\t\tX1\tY1\tZ1\tX2\tY2\tZ2\n"
    "1\t0.0\t1\t2\t3\t4\t5\t6\n"
    "2\t0.0333\t1\t2\t3\t\t\t\n"
)


def _one_line_error(call, path: Path, line: int | None) -> str:
    with pytest.raises(InputError) as caught:
        call(path)
    message = str(caught.value)
    assert "\n" not in message and str(path) in message
    if line is not None:
        assert f"line {line}:" in message, message
    return message


def test_the_error_fixture_itself_reads(tmp_path):
    path = tmp_path / "good.trc"
    path.write_text(GOOD_TRC)
    data = read_trc(path, convention="none")
    assert data.names == ("A", "B") and data.positions[0, 1].tolist() == [4, 5, 6] and np.isnan(data.positions[1, 1]).all()


@pytest.mark.parametrize(("start", "first_time", "frame"), [
    ("0", "0.0333", 0),  # Pose2Sim before its trimming: Frame# 1, 2, … and OrigDataStartFrame 0 (the demo's TRC)
    ("12", "0.4", 12),   # today's Pose2Sim, a trial trimmed to where the subject is seen: frame 12 on
    ("1", "0.0333", 1),  # today's Pose2Sim from frame 1: its first row one frame in
    ("1", "0.0", 0),     # OpenCap, OpenSim, mmcsplat's export: numbered from 1, the first row at time 0
])
def test_a_trcs_first_row_is_the_capture_frame_its_writer_meant(tmp_path, start, first_time, frame):
    path = tmp_path / "start.trc"
    path.write_text(GOOD_TRC.replace("30\t30\t2\t2\tm\t30\t1\t2", f"30\t30\t2\t2\tm\t30\t{start}\t2").replace("1\t0.0\t1", f"1\t{first_time}\t1"))
    assert read_trc(path, convention="none").first_frame == frame


@pytest.mark.parametrize(("text", "line", "words"), [
    ("name,x,y,z\nA,1,2,3\n", 1, "not a TRC file"),
    (GOOD_TRC.replace("DataRate\tCameraRate\tNumFrames", "Rate\tCameraRate\tFrames"), 2, "lack"),
    (GOOD_TRC.replace("\tm\t30", "\tcm\t30"), 3, "Units 'cm'"),
    (GOOD_TRC.replace("30\t30\t2\t2", "30\t30\t2\t3"), 4, "NumMarkers"),
    (GOOD_TRC.replace("1\t0.0\t1\t2\t3\t4\t5\t6", "1\t0.0\t1\t2\t3\t4\t5"), 6, "7 cells, expected 8"),
    (GOOD_TRC.replace("\t4\t5\t6\n", "\t4\tfive\t6\n"), 6, "Y of B 'five' is not a number"),
    (GOOD_TRC.replace("30\t30\t2\t2", "30\t30\t3\t2"), 3, "NumFrames"),
    (GOOD_TRC.split("Frame#")[0], 4, "ends inside"),
])
def test_trc_errors_name_the_file_and_line(tmp_path, text, line, words):
    path = tmp_path / "bad.trc"
    path.write_text(text)
    assert words in _one_line_error(read_trc, path, line)


@pytest.mark.parametrize(("text", "line", "words"), [
    ("", 1, "empty"),
    ("frame,name,x\n1,A,2\n", 1, "neither"),
    ("frame,time,name,x,y,z\n0,0,A,1,2,3\n1,0.1,A,1,2\n", 3, "5 cells, expected 6"),
    ("frame,time,name,x,y,z\n0,0,A,1,two,3\n", 2, "y 'two' is not a number"),
    ("frame,time,name,x,y,z\n0.5,0,A,1,2,3\n", 2, "not a whole number"),
    ("frame,time,name,x,y,z\n0,0,A,1,2,3\n0,0,A,1,2,3\n", 3, "second row"),
    ("frame,time,name,x,y,z\n0,0,A,1,2,3\n0,0.5,B,1,2,3\n", 3, "differs"),
    ("name,x,y,z,confidence\nA,1,2,3,high\n", 2, "confidence 'high'"),
    ("frame,time,name,x,y,z\n", 2, "no landmark rows"),
])
def test_csv_errors_name_the_file_and_line(tmp_path, text, line, words):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    assert words in _one_line_error(read_landmark_csv, path, line)


def test_other_errors_are_one_line_and_name_the_file(tmp_path):
    missing = tmp_path / "absent.trc"
    with pytest.raises(MissingFileError, match="absent.trc"):
        read_trc(missing)
    with pytest.raises(MissingFileError, match="absent.csv"):
        read_landmark_csv(tmp_path / "absent.csv")
    garbage = tmp_path / "garbage.c3d"
    garbage.write_bytes(b"\x00\x01 not a c3d file" * 8)
    _one_line_error(read_c3d, garbage, None)
    binary = tmp_path / "binary.trc"
    binary.write_bytes(b"\xff\xfe\x00PathFileType")
    _one_line_error(read_trc, binary, None)

    times, positions = _trajectories()
    out = tmp_path / "out.trc"
    with pytest.raises(InputError, match="shape"):
        write_trc(out, NAMES[:2], times, positions, rate=30)
    with pytest.raises(InputError, match="repeat"):
        write_landmark_csv(tmp_path / "out.csv", ("A", "A", "B"), np.arange(4), times, positions)
    with pytest.raises(InputError, match="extra column"):
        write_landmark_csv(tmp_path / "out.csv", NAMES, np.arange(4), times, positions, extra={"confidence": np.zeros(4)})
    with pytest.raises(InputError, match="units"):
        write_trc(out, NAMES, times, positions, rate=30, units="cm")
    assert not out.exists() and not (tmp_path / "out.csv").exists()


@pytest.mark.parametrize("first", [0, 1, 12])
def test_a_written_trc_says_which_capture_frame_it_starts_at(tmp_path, first):
    """``mmcsplat export --trc`` of a session that starts later in its capture: read back, its rows are those frames."""
    times, positions = _trajectories()
    write_trc(tmp_path / "j.trc", NAMES, times + first / 30.0, positions, 30.0, first_frame=first)
    assert read_trc(tmp_path / "j.trc").first_frame == first
