"""The command line speaks in one voice: a warning is one line ``mmcsplat COMMAND: warning: …`` (no
Python category or source path) and stays a warning tests can catch; a plate fit without plates names
``mmcsplat plates``."""

from __future__ import annotations

import subprocess
import sys
import warnings
from pathlib import Path

import pytest
import rig_fixtures as rig
from fitting_scene import write_config, write_session

from mmcsplat.cli import main
from mmcsplat.storage.calibration import write_calibration


def _uneven_capture(folder: Path) -> Path:
    """Two cameras' image folders of 3 and 2 frames: ingesting it warns that it truncates them."""
    cameras = rig.ring_cameras(["cam_01", "cam_02"])
    folder.mkdir()
    write_calibration(folder / "calibration.toml", cameras)
    rig.write_image_folders(folder, cameras, 3)
    (folder / "cam_02" / "frame2.png").unlink()
    return folder


def test_a_warning_prints_as_one_line_in_mmcsplats_voice(tmp_path):
    source = _uneven_capture(tmp_path / "capture")
    entry = "import sys; from mmcsplat.cli import main; sys.exit(main())"  # what the console script runs
    done = subprocess.run([sys.executable, "-c", entry, "ingest", str(source), str(tmp_path / "s.zarr"), "--set", "fps=30",
                           "--no-progress"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    lines = done.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("mmcsplat ingest: warning: ") and "truncating every camera to 2 frames" in lines[0]
    assert "UserWarning" not in done.stderr and ".py:" not in done.stderr


def test_warnings_stay_catchable_and_the_format_is_restored(tmp_path):
    source = _uneven_capture(tmp_path / "capture")
    before = warnings.formatwarning
    with pytest.warns(UserWarning, match="truncating every camera to 2 frames"):
        assert main(["ingest", str(source), str(tmp_path / "s.zarr"), "--no-progress"]) == 0
    assert warnings.formatwarning is before


def test_a_plate_fit_without_plates_names_mmcsplat_plates(tmp_path, capsys):
    session = write_session(tmp_path / "bare.zarr")
    config = write_config(tmp_path / "fit.toml", background='"plate"')
    assert main(["fit", str(session), "--config", str(config), "--out", str(tmp_path / "run"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert f"estimate the plates from the sequence with `mmcsplat plates {session}`" in err and "--plates DIR" in err
    assert err.count("\n") == 1


def test_a_closed_pipe_on_stdout_ends_the_command_quietly():
    # `mmcsplat plugins | head`: the reader goes away; the command stops as a SIGPIPE would, with no error line.
    entry = ("import os, sys; from mmcsplat.cli import main; read, write = os.pipe(); os.close(read); "
             "os.dup2(write, sys.stdout.fileno()); sys.exit(main())")
    done = subprocess.run([sys.executable, "-c", entry, "plugins"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 141
    assert done.stderr == ""


def test_a_broken_pipe_elsewhere_is_still_an_error(monkeypatch, capsys):
    def broken(args):
        raise BrokenPipeError(32, "Broken pipe: ffmpeg")
    monkeypatch.setattr("mmcsplat.cli.configs.run", broken)
    assert main(["configs"]) == 2
    assert "mmcsplat configs: error: [Errno 32] Broken pipe: ffmpeg" in capsys.readouterr().err
