"""Reliability, class 1: no silent wrong result. Each bad input ends in exit 2 and one line naming the
file, camera, frame or key at fault — never in a number computed from zeros or from a shifted frame."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import rig_fixtures as rig
from fitting_scene import write_config, write_fitted_run, write_session

from mmcsplat.cli.main import main
from mmcsplat.storage.calibration import write_calibration
from mmcsplat.storage.session import SessionReader


@pytest.fixture
def fitted(tmp_path) -> tuple[Path, Path]:
    session = write_session(tmp_path / "s.zarr", frames=2)
    return session, write_fitted_run(tmp_path / "run", session)


def test_a_missing_image_chunk_is_an_error_and_metrics_are_kept(fitted, capsys):
    session, run = fitted
    assert main(["evaluate", str(run)]) == 0
    metrics = (run / "metrics.json").read_text()
    (session / "cameras" / "cam_1" / "rgb" / "c.0.0.0.0").unlink()
    assert main(["evaluate", str(run)]) == 2
    assert "camera 'cam_1' rgb, frame 0: its data is missing from the store" in capsys.readouterr().err
    assert (run / "metrics.json").read_text() == metrics  # not overwritten with numbers from a black image


def test_a_corrupt_mask_chunk_names_the_array(fitted, capsys):
    session, run = fitted
    chunk = session / "cameras" / "cam_2" / "mask" / "c.0.0.0"
    chunk.write_bytes(b"not zstd at all")
    with pytest.raises(ValueError, match="camera 'cam_2' mask, frame 0: its stored data does not decode"):
        SessionReader(session).frame(0, "cam_2")


def test_a_missing_tracks_chunk_is_an_error(fitted, capsys):
    _, run = fitted
    assert main(["track", str(run), "--dynamics", "iterative", "--set", "dynamics.iterations=2", "--no-progress"]) == 0
    (run / "tracks.zarr" / "means" / "c.1.0.0").unlink()
    assert main(["evaluate", str(run)]) == 2
    assert "tracks.zarr: means, frame 1: its data is missing" in capsys.readouterr().err


def test_a_missing_image_file_shifts_nothing(tmp_path, capsys):
    capture = tmp_path / "capture"
    cameras = rig.ring_cameras(("c1", "c2"))
    capture.mkdir()
    write_calibration(capture / "calibration.toml", cameras)
    rig.write_image_folders(capture, cameras, 4)
    (capture / "c2" / "frame2.png").unlink()
    assert main(["ingest", str(capture), str(tmp_path / "s.zarr")]) == 2
    assert "camera 'c2' has no image numbered 2" in capsys.readouterr().err and not (tmp_path / "s.zarr").exists()
    assert main(["ingest", str(capture), str(tmp_path / "s.zarr"), "--set", "missing_frames=absent"]) == 0
    session = SessionReader(tmp_path / "s.zarr")
    assert session.present("c2").tolist() == [True, True, False, True] and session.present("c1").all()
    # Each stored frame is its own file's (the fixture's grey level encodes the frame), none moved up.
    for t in (0, 1, 3):
        assert abs(float(np.median(session.frame(t, "c2").rgb)) - rig.background_level(t)) <= 1


def test_a_calibration_in_millimetres_read_as_metres_is_refused(tmp_path, capsys):
    capture = tmp_path / "capture"
    capture.mkdir()
    cameras = rig.ring_cameras(("c1", "c2"))
    write_calibration(capture / "calibration.toml", cameras, units="mm")
    rig.write_image_folders(capture, cameras, 2)
    assert main(["ingest", str(capture), str(tmp_path / "s.zarr")]) == 2
    assert "pass --units mm" in capsys.readouterr().err
    assert main(["ingest", str(capture), str(tmp_path / "s.zarr"), "--units", "mm"]) == 0


@pytest.mark.parametrize("override, message", [
    ("nosection.x=3", "unknown table(s) 'nosection'"),
    ("fitt.iterations=3", "unknown table(s) 'fitt'"),
    ("fit.iterations=-5", "iterations must be ≥ 1, got -5"),
    ("fit.iterations=0", "iterations must be ≥ 1, got 0"),
])
def test_settings_that_would_be_ignored_or_meaningless_are_refused(fitted, tmp_path, capsys, override, message):
    session, _ = fitted
    out = tmp_path / "new"
    assert main(["fit", str(session), "--config", str(write_config(tmp_path / "c.toml", iterations=5)), "--out", str(out),
                 "--set", override, "--no-progress"]) == 2
    assert message in capsys.readouterr().err and not (out / "run.json").exists()


@pytest.mark.parametrize("threshold", ["-5", "nan"])
def test_a_threshold_that_empties_the_masks_is_refused_and_masks_are_kept(fitted, capsys, threshold):
    session, _ = fitted
    before = SessionReader(session).frame(0, "cam_1").mask.copy()
    assert main(["segment", str(session), "--segmenter", "background", "--set", f"threshold={threshold}"]) == 2
    assert "segmenter 'background': threshold must be a finite number > 0" in capsys.readouterr().err
    assert (SessionReader(session).frame(0, "cam_1").mask == before).all()
    assert json.loads((session / "zarr.json").read_text())["attributes"]["complete"] is True


def test_a_video_damaged_in_its_middle_is_refused_naming_it(tmp_path, capsys):
    capture = tmp_path / "capture"
    rig.make_capture(capture, frames=30)
    video = capture / "cam_a.mp4"
    data = bytearray(video.read_bytes())
    middle = len(data) // 2
    data[middle : middle + 2000] = bytes((7 * b + 13) % 256 for b in data[middle : middle + 2000])  # a few kB overwritten
    video.write_bytes(bytes(data))
    assert main(["ingest", str(capture), str(tmp_path / "s.zarr")]) == 2
    assert f"video {video}: damaged at frame" in capsys.readouterr().err and not (tmp_path / "s.zarr").exists()


def test_missing_or_garbled_metadata_names_the_array(fitted):
    session, _ = fitted
    (session / "cameras" / "cam_1" / "rgb" / "zarr.json").unlink()
    with pytest.raises(ValueError, match="array cameras/cam_1/rgb is missing from the store"):
        SessionReader(session).frame(0, "cam_1")
    (session / "cameras" / "cam_2" / "mask" / "zarr.json").write_text("{garbled")
    with pytest.raises(ValueError, match="the metadata of array cameras/cam_2/mask is garbled"):
        SessionReader(session).frame(0, "cam_2")
    (session / "zarr.json").write_text("{garbled")
    with pytest.raises(ValueError, match=r"the store's metadata \(zarr.json\) is garbled"):
        SessionReader(session)
