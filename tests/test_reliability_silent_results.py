"""Reliability, class 1: no silent wrong result. Each bad input ends in exit 2 and one line naming the
file, camera, frame or key at fault — never in a number computed from zeros or from a shifted frame."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import rig_fixtures as rig
from fitting_scene import subject, write_config, write_fitted_run, write_session

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
    # A detector run through c2's folder (Pose2Sim's JSON, SLEAP's rows) numbers its images by position: frame 3 is its third.
    assert session.source_frames("c2", [0, 1, 2, 3]).tolist() == [0, 1, -1, 2]
    assert session.source_frames("c1", [0, 1, 2, 3]).tolist() == [0, 1, 2, 3]


def test_a_calibration_in_millimetres_read_as_metres_is_refused_and_read_as_millimetres_by_default(tmp_path, capsys):
    capture = tmp_path / "capture"
    capture.mkdir()
    cameras = rig.ring_cameras(("c1", "c2"))
    write_calibration(capture / "calibration.toml", cameras, units="mm")
    rig.write_image_folders(capture, cameras, 2)
    assert main(["ingest", str(capture), str(tmp_path / "m.zarr"), "--units", "m"]) == 2
    assert "pass --units mm" in capsys.readouterr().err
    assert not (tmp_path / "m.zarr").exists()
    assert main(["ingest", str(capture), str(tmp_path / "mm.zarr"), "--units", "mm"]) == 0
    capsys.readouterr()
    assert main(["ingest", str(capture), str(tmp_path / "auto.zarr")]) == 0  # --units auto: only millimetres make a real rig
    assert "calibration read in mm" in capsys.readouterr().out
    stated, auto = SessionReader(tmp_path / "mm.zarr"), SessionReader(tmp_path / "auto.zarr")
    assert auto.provenance["units"] == "auto" and auto.provenance["reader"]["units"] == "mm"
    for name in ("c1", "c2"):
        np.testing.assert_allclose(auto.camera(name).t, stated.camera(name).t)
        np.testing.assert_allclose(auto.camera(name).t, cameras[("c1", "c2").index(name)].t)


@pytest.mark.parametrize("override, message", [
    ("nosection.x=3", "unknown table(s) 'nosection'"),
    ("fitt.iterations=3", "unknown table(s) 'fitt'"),
    ("fit.iterations=-5", "iterations must be between 1 and 100000000, got -5"),
    ("fit.iterations=0", "iterations must be between 1 and 100000000, got 0"),
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


def test_a_capture_moved_after_ingest_says_its_ground_truth_is_gone(fitted, tmp_path, capsys):
    import zarr

    session, run = fitted
    assert main(["track", str(run), "--dynamics", "iterative", "--set", "dynamics.iterations=2", "--no-progress"]) == 0
    group = zarr.open_group(str(session), mode="r+")
    moved = tmp_path / "capture" / "ground_truth.zarr"  # recorded at ingest, then the capture moved
    group.attrs["provenance"] = {**group.attrs["provenance"], "reader": {"ground_truth": str(moved)}}
    capsys.readouterr()
    assert main(["evaluate", str(run), "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert f"tracking errors not measured: the capture's ground truth {moved} (recorded at ingest) is gone" in err
    assert "pass --ground-truth PATH" in err
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["tracking_median_mm"] is None and "is gone" in metrics["tracking_error"]


def test_the_ground_truth_of_another_capture_is_refused(tmp_path, capsys):
    captures = {}
    for seed in (0, 1):
        captures[seed] = tmp_path / f"capture{seed}"
        assert main(["synth", str(captures[seed]), "--num-frames", "2", "--num-cameras", "4", "--width", "48", "--height", "36",
                     "--seed", str(seed), "--no-progress"]) == 0
    assert main(["ingest", str(captures[0]), str(tmp_path / "s.zarr"), "--no-progress"]) == 0
    run = write_fitted_run(tmp_path / "run", tmp_path / "s.zarr")
    assert main(["track", str(run), "--dynamics", "iterative", "--set", "dynamics.iterations=1", "--no-progress"]) == 0
    capsys.readouterr()
    other = captures[1] / "ground_truth.zarr"
    assert main(["evaluate", str(run), "--ground-truth", str(other), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert f"{other} is the ground truth of another capture than session {tmp_path / 's.zarr'} was ingested from" in err
    assert not (run / "metrics.json").exists()
    assert main(["evaluate", str(run), "--ground-truth", str(captures[0] / "ground_truth.zarr"), "--no-progress"]) == 0


# ------------------------------------------------------------------ a run is bound to its recording


def _replace_session(session: Path, **kwargs) -> None:
    """Put another recording at ``session``'s path (a re-ingest, another infant)."""
    import shutil

    shutil.rmtree(session)
    write_session(session, **kwargs)


def test_a_sessions_fingerprint_covers_its_images_and_frame_count(tmp_path):
    first = SessionReader(write_session(tmp_path / "a.zarr", frames=2)).fingerprint
    assert first is not None and SessionReader(write_session(tmp_path / "b.zarr", frames=2)).fingerprint == first  # same recording
    assert SessionReader(write_session(tmp_path / "c.zarr", frames=1)).fingerprint != first
    assert SessionReader(write_session(tmp_path / "d.zarr", frames=2, blank=("cam_3",))).fingerprint != first


@pytest.mark.parametrize("command", [["track", "--dynamics", "iterative", "--no-progress"], ["evaluate"], ["render", "--novel", "--no-progress"],
                                     ["export", "--transforms", "EXPORT"]])
def test_a_run_refuses_a_session_replaced_by_another_recording(fitted, tmp_path, capsys, command):
    session, run = fitted
    _replace_session(session, frames=2, blank=("cam_3",))
    args = [str(tmp_path / "export") if arg == "EXPORT" else arg for arg in command]
    assert main([args[0], str(run), *args[1:]]) == 2
    err = capsys.readouterr().err
    assert f"run {run} was fitted on another recording than {session} holds" in err and "re-fit with a new --out" in err
    assert len(err.strip().splitlines()) == 1
    assert not (run / "tracks.zarr").exists() and not (run / "metrics.json").exists() and not (tmp_path / "export").exists()


@pytest.mark.parametrize("command", [["evaluate"], ["export", "--ply", "EXPORT"]])
def test_tracks_copied_from_another_run_are_refused(fitted, tmp_path, capsys, command):
    import shutil

    session, run = fitted
    other = write_fitted_run(tmp_path / "other", session, truth=subject(seed=1))
    assert main(["track", str(other), "--dynamics", "iterative", "--set", "dynamics.iterations=1", "--no-progress"]) == 0
    shutil.copytree(other / "tracks.zarr", run / "tracks.zarr")
    capsys.readouterr()
    args = [str(tmp_path / "export") if arg == "EXPORT" else arg for arg in command]
    assert main([args[0], str(run), *args[1:]]) == 2
    err = capsys.readouterr().err
    assert f"{run / 'tracks.zarr'} were tracked from another fit than {run / 'checkpoint.pt'}" in err and "--overwrite" in err
    assert not (run / "metrics.json").exists() and not (tmp_path / "export").exists()
    assert main(["evaluate", str(other)]) == 0  # the run they belong to reads them


def test_a_session_replaced_by_a_shorter_one_is_another_recording(fitted, capsys):
    session, run = fitted
    _replace_session(session, frames=1)
    assert main(["track", str(run), "--dynamics", "iterative", "--no-progress"]) == 2
    assert "fitted on another recording" in capsys.readouterr().err


def test_a_fit_never_resumes_onto_another_recording(tmp_path, capsys):
    session = write_session(tmp_path / "s.zarr")
    config = write_config(tmp_path / "fit.toml", iterations=2, checkpoint_every=1)
    run = tmp_path / "run"
    assert main(["fit", str(session), "--config", str(config), "--out", str(run), "--no-progress", "--backend", "torch-reference"]) == 0
    assert json.loads((run / "run.json").read_text())["recording"] == SessionReader(session).fingerprint
    checkpoint = (run / "checkpoint.pt").read_bytes()
    _replace_session(session, blank=("cam_2",))
    assert main(["fit", str(session), "--config", str(config), "--out", str(run), "--no-progress", "--backend", "torch-reference"]) == 2
    err = capsys.readouterr().err
    assert "checkpoint.pt: its recording differ from this run's; use a new --out" in err
    assert (run / "checkpoint.pt").read_bytes() == checkpoint


def _forget_fingerprints(run: Path) -> None:
    """Make ``run`` (and its tracks) look written before fingerprints existed."""
    import zarr

    info = json.loads((run / "run.json").read_text())
    del info["recording"]
    (run / "run.json").write_text(json.dumps(info))
    if (run / "tracks.zarr").exists():
        tracks = zarr.open_group(str(run / "tracks.zarr"), mode="r+")
        for key in ("recording", "fit"):
            del tracks.attrs[key]


def test_a_run_older_than_fingerprints_says_it_cannot_check(fitted):
    session, run = fitted
    _forget_fingerprints(run)
    with pytest.warns(UserWarning, match="written before mmcsplat fingerprinted recordings: cannot check"):
        assert main(["evaluate", str(run)]) == 0


@pytest.mark.parametrize("command", [["evaluate"], ["report"], ["render", "--novel", "--no-progress"]])
def test_an_old_run_on_a_session_replaced_by_a_shorter_one_names_the_frames(fitted, capsys, command):
    session, run = fitted
    assert main(["track", str(run), "--dynamics", "iterative", "--set", "dynamics.iterations=1", "--no-progress"]) == 0
    _forget_fingerprints(run)
    _replace_session(session, frames=1)
    capsys.readouterr()
    with pytest.warns(UserWarning, match="cannot check") as caught:
        assert main([command[0], str(run), *command[1:]]) == 2
    assert sum("cannot check" in str(warning.message) for warning in caught) == 1  # said once
    err = capsys.readouterr().err
    assert f"session {session} has 1 frame(s) but run {run} needs frames up to 1 (tracked over frames 0–1)" in err
    assert "put that recording back there, or re-fit with a new --out" in err and err.count("\n") == 1
    assert not (run / "metrics.json").exists() and not (run / "report.html").exists()


# ------------------------------------------------------------------------- unfinished is never final


def _set_status(run: Path, status: str) -> None:
    info = json.loads((run / "run.json").read_text())
    (run / "run.json").write_text(json.dumps({**info, "status": status}))


@pytest.mark.parametrize("command", [["evaluate"], ["report"], ["landmarks", "--source", "synthetic"], ["export", "--ply", "PLY"],
                                     ["render", "--novel", "--no-progress"]])
def test_an_unfinished_fit_is_refused(fitted, tmp_path, capsys, command):
    _, run = fitted
    _set_status(run, "running")
    args = [str(tmp_path / "ply") if arg == "PLY" else arg for arg in command]
    assert main([args[0], str(run), *args[1:]]) == 2
    err = capsys.readouterr().err
    assert f"run {run} is unfinished: its fit is 'running' at iteration 0 (run.json)" in err and "--allow-incomplete" in err
    assert not (run / "metrics.json").exists() and not (run / "report.html").exists() and not (tmp_path / "ply").exists()
    assert not (run / "renders").exists()


def test_allow_incomplete_labels_every_output(fitted, tmp_path, capsys):
    _, run = fitted
    _set_status(run, "running")
    assert main(["evaluate", str(run), "--allow-incomplete"]) == 0
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["incomplete"] is True and "'running'" in metrics["unfinished"][0]
    assert "is unfinished" in capsys.readouterr().err
    assert main(["report", str(run), "--allow-incomplete"]) == 0
    assert "<strong>Incomplete run</strong>" in (run / "report.html").read_text()
    assert main(["export", str(run), "--ply", str(tmp_path / "ply"), "--inria", str(tmp_path / "inria"), "--allow-incomplete", "--no-progress"]) == 0
    assert b"comment mmcsplat: incomplete run" in (tmp_path / "ply" / "frame_0000.ply").read_bytes()[:400]
    assert b"comment mmcsplat: incomplete run" in next((tmp_path / "inria").rglob("point_cloud.ply")).read_bytes()[:600]
    _set_status(run, "complete")
    assert main(["evaluate", str(run)]) == 0 and json.loads((run / "metrics.json").read_text())["incomplete"] is False


def _carry_landmarks(run: Path, folder: Path, *options: str) -> int:
    """``mmcsplat landmarks`` of one landmark on the run's first Gaussian, read from a CSV file."""
    from mmcsplat.storage.landmark_formats import write_landmark_csv
    from mmcsplat.training.fitted_run import FittedRun

    position = FittedRun.load(run).params["means"][0].double().numpy()
    path = folder / "joints.csv"
    write_landmark_csv(path, ["knee"], np.array([0]), np.array([0.0]), position[None, None])
    return main(["landmarks", str(run), "--source", "csv", "--set", f"path={path}", *options])


def _labels(folder: Path) -> tuple[str | None, bool, str | None]:
    """What each landmark export in ``folder`` says is unfinished: the TRC's header, the CSV's column, the C3D's parameter."""
    import ezc3d

    from mmcsplat.storage.landmark_formats import read_landmark_csv, read_trc

    parameters = ezc3d.c3d(str(folder / "x.c3d"))["parameters"]
    c3d = parameters["MMCSPLAT"]["INCOMPLETE"]["value"][0] if "MMCSPLAT" in parameters else None
    extra = read_landmark_csv(folder / "x.csv")[4]
    return read_trc(folder / "x.trc").incomplete, bool("incomplete" in extra and (extra["incomplete"] == 1).all()), c3d


def test_allow_incomplete_labels_the_landmarks_and_their_exports(fitted, tmp_path):
    from mmcsplat.storage.landmark_formats import read_landmark_csv

    _, run = fitted
    exports = [f"--{kind}={tmp_path / f'x.{kind}'}" for kind in ("trc", "csv", "c3d")]
    _set_status(run, "running")
    assert _carry_landmarks(run, tmp_path) == 2  # refused without the flag
    assert _carry_landmarks(run, tmp_path, "--allow-incomplete") == 0
    assert json.loads((run / "landmarks.json").read_text())["incomplete"] is True
    assert json.loads((run / "movement.json").read_text())["incomplete"] is True
    assert (run / "movement.csv").read_text().splitlines()[-1] == "run,incomplete,1,"
    assert (read_landmark_csv(run / "landmarks.csv")[4]["incomplete"] == 1).all()
    assert main(["export", str(run), *exports]) == 2
    assert main(["export", str(run), *exports, "--allow-incomplete"]) == 0
    trc, csv_labelled, c3d = _labels(tmp_path)
    assert trc == c3d and f"incomplete run {run}: its fit is 'running'" in trc and csv_labelled
    _set_status(run, "complete")  # finished since: the landmarks carried before stay labelled, in exports and the report
    assert main(["export", str(run), *exports]) == 0
    trc, csv_labelled, c3d = _labels(tmp_path)
    assert "its landmarks were carried before it was finished" in trc and trc == c3d and csv_labelled
    assert main(["report", str(run)]) == 0 and "its landmarks were carried before it was finished" in (run / "report.html").read_text()
    assert _carry_landmarks(run, tmp_path) == 0 and main(["export", str(run), *exports]) == 0
    assert _labels(tmp_path) == (None, False, None)
    assert "incomplete" not in (run / "movement.csv").read_text()


def test_a_report_of_metrics_scored_before_the_end_has_a_banner(fitted):
    _, run = fitted
    assert main(["evaluate", str(run)]) == 0
    metrics = json.loads((run / "metrics.json").read_text())
    (run / "metrics.json").write_text(json.dumps({**metrics, "incomplete": True}))
    assert main(["report", str(run)]) == 0
    assert "scored it before it was finished" in (run / "report.html").read_text()


def test_a_stopped_tracking_is_unfinished(fitted, capsys):
    _, run = fitted
    (run / "tracking.unfinished").write_text("{}")
    assert main(["evaluate", str(run)]) == 2
    assert "its tracking was stopped or failed before it finished" in capsys.readouterr().err


def test_no_metrics_are_written_for_a_run_another_process_holds(fitted, capsys):
    from mmcsplat.storage.locking import run_lock

    _, run = fitted
    with run_lock(run):
        assert main(["evaluate", str(run), "--allow-incomplete"]) == 2
    assert "is being written by another mmcsplat process" in capsys.readouterr().err and not (run / "metrics.json").exists()


def test_evaluate_holds_the_runs_lock_while_it_scores_and_writes(fitted, monkeypatch):
    import mmcsplat.pipeline.evaluate as evaluation
    from mmcsplat.storage.locking import BusyError, run_lock

    _, run = fitted
    write, refused = evaluation.write_json_atomic, []

    def write_while_another_writer_starts(path, payload):
        try:  # a fit, a track or a second evaluate taking the run now
            run_lock(run).release()
        except BusyError as error:
            refused.append(str(error))
        write(path, payload)

    monkeypatch.setattr(evaluation, "write_json_atomic", write_while_another_writer_starts)
    assert main(["evaluate", str(run)]) == 0
    assert refused and f"run {run} is being written by another mmcsplat process" in refused[0]
    assert (run / "metrics.json").exists() and not (run / ".mmcsplat.lock").exists()


def test_a_fold_killed_before_its_first_checkpoint_is_missing_not_left_out(tmp_path, capsys):
    import shutil

    session = write_session(tmp_path / "s.zarr")
    config = write_config(tmp_path / "fit.toml", iterations=2, checkpoint_every=1)
    run = tmp_path / "folds"
    fit = ["fit", str(session), "--config", str(config), "--out", str(run), "--folds", "cam_0,cam_1", "--no-progress", "--backend", "torch-reference"]
    assert main(fit) == 0
    assert json.loads((run / "folds.json").read_text()) == {"folds": ["cam_0", "cam_1"]}
    shutil.rmtree(run / "cam_1")  # killed before its first checkpoint: none of its files written
    capsys.readouterr()
    assert main(["evaluate", str(run)]) == 2
    err = capsys.readouterr().err
    assert f"run {run} is unfinished: fold cam_1 has no fit" in err and "run the same `mmcsplat fit --folds` again" in err
    assert not (run / "metrics.json").exists()
    assert main(["evaluate", str(run), "--allow-incomplete"]) == 0
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["incomplete"] is True and "fold cam_1 has no fit" in metrics["unfinished"][0] and list(metrics["folds"]) == ["cam_0"]
    assert main(fit) == 0  # the same command fits the missing fold
    _set_status(run / "cam_0", "running")  # killed after a checkpoint: refused, never scored from the half fit
    capsys.readouterr()
    assert main(["evaluate", str(run)]) == 2
    assert f"run {run / 'cam_0'} is unfinished: its fit is 'running'" in capsys.readouterr().err
    _set_status(run / "cam_0", "complete")
    assert main(["evaluate", str(run)]) == 0
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["incomplete"] is False and metrics["unfinished"] == [] and list(metrics["folds"]) == ["cam_0", "cam_1"]


def test_a_fold_plan_only_grows_and_a_garbled_one_is_named(tmp_path):
    from mmcsplat.plugin_api.errors import InputError
    from mmcsplat.storage.folds import planned_folds, write_fold_plan

    run = tmp_path / "folds"
    assert planned_folds(run) is None
    write_fold_plan(run, ["cam_0", "cam_1"])
    write_fold_plan(run, ["cam_1", "cam_2"])  # a rerun with other folds adds them, drops none
    assert planned_folds(run) == ("cam_0", "cam_1", "cam_2")
    (run / "folds.json").write_text('{"folds": [')
    with pytest.raises(InputError, match="folds.json is not a fold plan .* delete it and run `mmcsplat fit --folds` with every fold again"):
        planned_folds(run)


def test_a_run_folder_is_not_taken_for_a_one_fold_leave_one_out_run(tmp_path):
    # `mmcsplat run`'s OUT holds OUT/run: evaluating OUT must not average it as the only fold of an unplanned
    # leave-one-camera-out run (folds before plans were written are folders named by the camera they hold out).
    from mmcsplat.pipeline.evaluate import fold_runs
    from mmcsplat.plugin_api.errors import MissingFileError

    session = write_session(tmp_path / "s.zarr", frames=1)
    out = tmp_path / "out"
    write_fitted_run(out / "run", session)
    with pytest.raises(MissingFileError, match=rf"holds no fit run .* nor fold runs: it holds the run {out / 'run'}, evaluate that"):
        fold_runs(out)
    legacy = tmp_path / "legacy"
    for camera in ("cam_0", "cam_1"):
        info_path = write_fitted_run(legacy / camera, session) / "run.json"
        info = json.loads(info_path.read_text())
        info_path.write_text(json.dumps({**info, "heldout_cameras": [camera]}))
    assert fold_runs(legacy) == [legacy / "cam_0", legacy / "cam_1"]


# ------------------------------------------------------------ what would desynchronise or warp a capture


def test_videos_at_different_frame_rates_are_refused(tmp_path, capsys):
    capture = tmp_path / "capture"
    cameras = rig.make_capture(capture, names=("cam_a", "cam_b", "cam_c"), frames=3)
    rig.write_videos(capture, cameras[1:2], 3, fps=25.0)  # one camera at 25 fps among 30 fps ones
    assert main(["ingest", str(capture), str(tmp_path / "s.zarr")]) == 2
    err = capsys.readouterr().err
    assert "different frame rates (cam_a 30 fps, cam_b 25 fps, cam_c 30 fps)" in err and "out of sync" in err
    assert not (tmp_path / "s.zarr").exists()


@pytest.mark.parametrize("distortion, message", [
    ([50.0, 0.0, 0.0, 0.0], "moves the image's corner"),  # k1 = 50: pixels thrown far off the image
    ([-3.0, 0.0, 0.0, 0.0, 0.0], "folds the image over itself"),  # the radial mapping turns back
    ([0.0, 0.0, 0.0, 0.0, -40.0], "folds the image over itself"),
])
def test_implausible_distortion_is_refused_naming_the_camera(tmp_path, capsys, distortion, message):
    import attrs

    capture = tmp_path / "capture"
    cameras = rig.make_capture(capture, frames=2)
    write_calibration(capture / "calibration.toml", [cameras[0], attrs.evolve(cameras[1], distortion=distortion)])
    assert main(["ingest", str(capture), str(tmp_path / "s.zarr")]) == 2
    err = capsys.readouterr().err
    assert f"camera '{cameras[1].name}': its distortion (k1 = " in err and message in err and len(err.strip().splitlines()) == 1


def test_plausible_distortion_is_accepted():
    import attrs

    from mmcsplat.storage.calibration import check_distortion

    camera = rig.ring_cameras(("c1",))[0]
    for distortion in ([-0.35, 0.18, 0.0, 0.0, -0.05], [-0.05, 0.15, 0.0, 0.001], [0.1, 0.0, 0.0, 0.0]):  # as in real calibrations (Pose2Sim, anipose)
        check_distortion(attrs.evolve(camera, distortion=distortion), "test")


def test_replaced_tracks_take_what_they_made_with_them(fitted, tmp_path, capsys):
    """Scores, landmarks, renders and the report describe the tracks (or the fit alone) they were made of: new tracks
    remove them (export, evaluate, view and the report would read them as the new tracks'), and say so."""
    _, run = fitted
    track = ["track", str(run), "--dynamics", "iterative", "--set", "dynamics.iterations=1", "--no-progress"]
    assert main(["evaluate", str(run)]) == 0 and _carry_landmarks(run, tmp_path) == 0  # of the fit alone: one frame
    assert main(track) == 0
    assert not (run / "metrics.json").exists() and not (run / "landmarks.csv").exists()  # the first tracks take them too
    assert main(["evaluate", str(run)]) == 0 and _carry_landmarks(run, tmp_path) == 0
    (run / "renders").mkdir()
    (run / "renders" / "novel.mp4").write_bytes(b"old")
    made = {path.name for path in run.iterdir()}
    assert {"metrics.json", "landmarks.csv", "landmarks.json", "movement.json", "movement.csv", "renders"} <= made
    capsys.readouterr()
    assert main([*track, "--overwrite"]) == 0
    out = capsys.readouterr().out
    assert "removed metrics.json, landmarks.csv, landmarks.json, movement.json, movement.csv, renders: made before these tracks" in out
    assert not {"metrics.json", "landmarks.csv", "landmarks.json", "movement.json", "movement.csv", "renders"} & {p.name for p in run.iterdir()}
    assert json.loads((run / "track.json").read_text())["removed"] == ["metrics.json", "landmarks.csv", "landmarks.json", "movement.json",
                                                                      "movement.csv", "renders"]
    assert main(["export", str(run), f"--trc={tmp_path / 'j.trc'}"]) == 2  # no landmarks to export until carried again


def test_backend_says_the_configurations_renderer_parameters_it_drops_and_records_what_rendered(tmp_path, capsys):
    """`fit --backend B` builds B at its defaults: the configuration's [renderer] parameters, another renderer's,
    were dropped without a word and run.json recorded that table beside `renderer: B`. Now they are said, run.json
    records B's table, and a backend that is the table's own renderer keeps its parameters."""
    session = write_session(tmp_path / "s.zarr")
    config = write_config(tmp_path / "fit.toml", iterations=2, checkpoint_every=1)
    config.write_text(config.read_text().replace('name = "torch-reference"\n', 'name = "torch-reference"\ntiles = 3\n', 1))
    run = tmp_path / "run"
    with pytest.warns(UserWarning, match=r"--backend torch-cpu: the configuration's \[renderer\] parameters \(tiles\) are 'torch-reference''s "
                                          "and are not used"):
        assert main(["fit", str(session), "--config", str(config), "--out", str(run), "--no-progress", "--backend", "torch-cpu"]) == 0
    record = json.loads((run / "run.json").read_text())
    assert record["renderer"] == "torch-cpu" and record["config_values"]["renderer"] == {"name": "torch-cpu"}
    assert main(["fit", str(session), "--config", str(config), "--out", str(tmp_path / "own"), "--no-progress", "--backend",
                 "torch-reference"]) == 2
    assert "rejected its parameters ['tiles']" in capsys.readouterr().err  # kept: the backend is the table's own renderer
