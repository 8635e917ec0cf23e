"""Reliability, class 4: every user error is one line naming its cause with exit status 2, never a
traceback."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from fitting_scene import write_config, write_fitted_run, write_session

from mmcsplat.cli.main import main

THIRDPARTY = Path(__file__).parent / "thirdparty"


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> tuple[Path, Path, Path]:
    folder = tmp_path_factory.mktemp("errors")
    session = write_session(folder / "s.zarr", frames=2)
    return session, write_fitted_run(folder / "run", session), write_config(folder / "fit.toml", iterations=5)


@pytest.mark.parametrize("setting, message", [
    ("fit.iterations=abc", "parameter 'iterations' must be an integer, got 'abc'"),
    ("fit.iterations=10.7", "parameter 'iterations' must be an integer, got 10.7"),
    ("fit.lrs.bogus=1", "lrs: unknown parameter(s) bogus"),
    ("fit.checkpoint_every=0", "checkpoint_every must be ≥ 1"),
    ("fit.lrs.means=inf", "means must be a finite number > 0, got inf"),
    ("fit.frame=99", "fit.frame 99 is past the last frame of session"),
    ("fit.iterations=99999999999999999999999", "iterations must be between 1 and 100000000, got 99999999999999999999999"),
])
def test_bad_fit_settings(scene, tmp_path, capsys, setting, message):
    session, _, config = scene
    assert main(["fit", str(session), "--config", str(config), "--out", str(tmp_path / "r"), "--set", setting, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


@pytest.mark.parametrize("args, message", [
    (["--holdout", "cam_99"], "held-out camera(s) ['cam_99'] not in session"),
    (["--out", "ftp://example.org/run"], "a run directory is a local folder, not a URL"),
])
def test_bad_fit_arguments(scene, tmp_path, capsys, args, message):
    session, _, config = scene
    command = ["fit", str(session), "--config", str(config), "--out", str(tmp_path / "r"), "--no-progress", *args]
    assert main(command) == 2 and message in capsys.readouterr().err
    assert not Path("ftp:").exists()


def test_outputs_below_a_file_and_unknown_url_schemes(scene, tmp_path, capsys):
    session, run, config = scene
    blocker = tmp_path / "a-file"
    blocker.write_text("x")
    assert main(["fit", str(session), "--config", str(config), "--out", str(blocker / "run"), "--no-progress"]) == 2
    assert "Not a directory" in capsys.readouterr().err
    assert main(["export", str(run), "--ply", str(blocker)]) == 2
    assert str(blocker) in capsys.readouterr().err
    assert main(["fit", "zip://nowhere.zip", "--config", str(config), "--out", str(tmp_path / "r"), "--no-progress"]) == 2
    assert "zip://nowhere.zip" in capsys.readouterr().err


def test_a_damaged_checkpoint_and_a_malformed_dynamics_table(scene, tmp_path, capsys):
    session, _, _ = scene
    run = write_fitted_run(tmp_path / "run", session)
    assert main(["track", str(run), "--set", "dynamics.name=3", "--no-progress"]) == 2
    assert "[dynamics] must be one table with a string 'name'" in capsys.readouterr().err
    checkpoint = run / "checkpoint.pt"
    checkpoint.write_bytes(checkpoint.read_bytes()[:100])
    assert main(["evaluate", str(run)]) == 2
    assert f"{checkpoint} is damaged or not a checkpoint" in capsys.readouterr().err


def test_an_unknown_plugin_is_named_in_plain_words(scene, tmp_path, capsys):
    _, run, _ = scene
    assert main(["track", str(run), "--dynamics", "nope", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "unknown dynamics 'nope'; registered: deformation, iterative" in err and "dynamicss" not in err


def test_a_plugin_whose_hook_returns_nonsense_breaks_nothing_else():
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(THIRDPARTY / "odd"), os.environ.get("PYTHONPATH", "")]))
    for args in (["--help"], ["--version"], ["plugins"]):
        result = subprocess.run([sys.executable, "-m", "mmcsplat.cli.main", *args], capture_output=True, text=True, env=env, timeout=120)
        assert result.returncode == 0, result.stderr
    assert "broken plugin 'odd' from mmcsplat-odd-plugin: hook mmcsplat_metrics returned" in result.stdout
    assert "psnr" in result.stdout


# ------------------------------------------------------------------------ messages that name their cause


@pytest.mark.parametrize("damage, message", [
    (lambda zarr_json: zarr_json.write_text("{ not json"), "the tracks' metadata is damaged"),
    (lambda zarr_json: zarr_json.unlink(), "the tracks' metadata is damaged"),
    (lambda zarr_json: zarr_json.write_text(zarr_json.read_text().replace('"num_frames": 2', '"num_frames": 7')),
     "it says 7 frames of"),
])
def test_damaged_tracks_metadata_is_named(scene, tmp_path, capsys, damage, message):
    session, _, _ = scene
    run = write_fitted_run(tmp_path / "run", session)
    assert main(["track", str(run), "--dynamics", "iterative", "--set", "dynamics.iterations=1", "--no-progress"]) == 0
    damage(run / "tracks.zarr" / "zarr.json")
    assert main(["export", str(run), "--ply", str(tmp_path / "ply"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert f"{run / 'tracks.zarr'}: " in err and message in err and "track the run again" in err and err.count("\n") == 1


def test_a_garbled_metrics_file_is_named_by_report(scene, tmp_path, capsys):
    session, _, _ = scene
    run = write_fitted_run(tmp_path / "run", session)
    (run / "metrics.json").write_text('{"val_psnr": 12.')
    assert main(["report", str(run)]) == 2
    err = capsys.readouterr().err
    assert f"{run / 'metrics.json'} is not readable JSON" in err and "run `mmcsplat evaluate" in err and err.count("\n") == 1


@pytest.mark.parametrize("kind, message", [("binary", "is not text (a binary file?)"), ("folder", "is a folder, not a TOML file")])
def test_a_config_that_is_not_a_toml_file_is_named(scene, tmp_path, capsys, kind, message):
    session, _, _ = scene
    config = tmp_path / "fit.toml"
    if kind == "binary":
        config.write_bytes(bytes(range(256)))
    else:
        config.mkdir()
    assert main(["fit", str(session), "--config", str(config), "--out", str(tmp_path / "r"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert f"configuration {config} {message}" in err and err.count("\n") == 1


def test_a_full_disk_is_reported_as_such(tmp_path, monkeypatch):
    import errno

    import torch

    from mmcsplat.storage.atomic import DiskFullError, write_json_atomic
    from mmcsplat.training.checkpoint import save_checkpoint

    checkpoint = tmp_path / "checkpoint.pt"
    save_checkpoint(checkpoint, {"k": 1}, {"step": 1})
    before = checkpoint.read_bytes()

    def short_write(*_args, **_kwargs):
        raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 4096 vs 2048")

    monkeypatch.setattr(torch, "save", short_write)
    with pytest.raises(DiskFullError, match=f"^disk full: cannot write {checkpoint} .*the previous version is kept"):
        save_checkpoint(checkpoint, {"k": 1}, {"step": 2})
    assert checkpoint.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["checkpoint.pt"]

    def no_space(self, *_args, **_kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Path, "write_text", no_space)
    with pytest.raises(DiskFullError, match="^disk full: cannot write .*run.json"):
        write_json_atomic(tmp_path / "run.json", {})
    assert [p.name for p in tmp_path.iterdir()] == ["checkpoint.pt"]


def test_a_landmark_source_without_its_file_says_what_to_set(scene, tmp_path, capsys):
    session, _, _ = scene
    run = write_fitted_run(tmp_path / "run", session)
    assert main(["landmarks", str(run), "--source", "trc"]) == 2
    err = capsys.readouterr().err
    assert "landmarks 'trc': set path=… (the .trc file), a required parameter (--set path=VALUE" in err and err.count("\n") == 1


@pytest.mark.parametrize("source", ["trc", "csv"])
def test_a_landmark_file_left_empty_says_what_to_set(scene, tmp_path, capsys, source):
    session, _, _ = scene
    run = write_fitted_run(tmp_path / "run", session)
    assert main(["landmarks", str(run), "--source", source, "--set", "path="]) == 2
    err = capsys.readouterr().err
    assert f"landmarks '{source}': path is empty: set path=… to a file" in err and err.count("\n") == 1


@pytest.mark.parametrize("target, message", [("folder", "is a folder: name a file to write"), ("missing/x.trc", "its folder")])
def test_a_landmark_export_onto_a_folder_or_below_a_missing_one_names_it(tmp_path, capsys, target, message):
    import numpy as np

    from mmcsplat.storage.landmark_formats import write_landmark_csv

    run = write_fitted_run(tmp_path / "run", write_session(tmp_path / "s.zarr", frames=1))
    write_landmark_csv(run / "landmarks.csv", ["knee"], np.array([0]), np.array([0.0]), np.zeros((1, 1, 3)))
    (tmp_path / "folder").mkdir()
    assert main(["export", str(run), "--trc", str(tmp_path / target)]) == 2
    err = capsys.readouterr().err
    assert message in err and str(tmp_path / target) in err and ".tmp" not in err


@pytest.mark.parametrize("command", [["render", "--depth", "--no-progress"], ["track", "--no-progress"]])
def test_a_run_whose_session_moved_says_where_it_belongs(tmp_path, capsys, command):
    session = write_session(tmp_path / "s.zarr", frames=1)
    run = write_fitted_run(tmp_path / "run", session)
    session.rename(tmp_path / "moved.zarr")
    assert main([command[0], str(run), *command[1:]]) == 2
    err = capsys.readouterr().err
    assert f"its session {session} cannot be opened" in err and "put the session back at that path" in err and err.count("\n") == 1


def _reencode(video: Path, size: tuple[int, int] | None = None, repeat_last: int = 0) -> None:
    """Write ``video`` again, each frame resized to ``size`` (width, height), the last one repeated ``repeat_last`` times."""
    import cv2

    capture = cv2.VideoCapture(str(video))
    frames = []
    while (read := capture.read())[0]:
        frames.append(read[1] if size is None else cv2.resize(read[1], size, interpolation=cv2.INTER_AREA))
    fps = capture.get(cv2.CAP_PROP_FPS)
    capture.release()
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), fps, frames[0].shape[1::-1])
    for frame in frames + frames[-1:] * repeat_last:
        writer.write(frame)
    writer.release()


@pytest.mark.parametrize("change, scale, message", [
    ({"size": (24, 18)}, "1", "the masks of camera 'cam_0' are 48×36 pixels but its video VIDEO decodes at 24×18: the ground truth belongs "
                              "to other videos"),
    ({"size": (24, 18)}, "0.5", "the masks of camera 'cam_0' are 48×36 pixels but its video VIDEO decodes at 24×18"),
    ({"repeat_last": 1}, "1", "the masks of camera 'cam_0' hold 2 frames but its video VIDEO has 3: ingest the first 2 with --frames 0:2"),
])
def test_videos_unlike_their_ground_truth_name_the_video_and_both_sizes(tmp_path, capsys, change, scale, message):
    capture = tmp_path / "capture"
    assert main(["synth", str(capture), "--num-frames", "2", "--num-cameras", "3", "--width", "48", "--height", "36", "--no-progress"]) == 0
    for video in sorted((capture / "videos").glob("*.mp4")):  # videos re-encoded smaller (or longer) than the calibration says
        _reencode(video, **change)
    capsys.readouterr()
    assert main(["ingest", str(capture), str(tmp_path / "s.zarr"), "--scale", scale, "--no-progress"]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if ": error: " in line]
    assert len(errors) == 1 and message.replace("VIDEO", str(capture / "videos" / "cam_0.mp4")) in errors[0]
    assert "move ground_truth.zarr away" in errors[0] and not (tmp_path / "s.zarr").exists()
